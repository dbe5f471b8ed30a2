"""Names written into other tools' files, checked before anything is written.

A frame name given on the command line ends up inside a Python launch file, a URDF, a YAML
file or a PLUS configuration. Each writer escapes what it writes (XML and YAML through
emitters, Python through literals), and on top of that every name must follow the naming rule
of the tool that reads it, so a name that the tool would reject (or misread) is refused here
with one line naming the option, instead of producing a file that breaks later.

The rules (docs/formats.md lists them for users):

ROS frame names (tf2 frame ids, URDF links and joints)
    One or more tokens separated by single ``/``; each token starts with an ASCII letter or
    ``_`` and continues with ASCII letters, digits or ``_``; at most
    :data:`MAX_ROS_NAME_CHARS` characters. This is the syntax of ROS graph resource names
    (ROS wiki, *Names*, section 1.1.1 "Valid Names"; ROS 2 design article *Topic and Service
    name mapping to DDS*: alphanumerics, ``_`` and ``/``, no token starting with a digit, no
    empty token, no trailing ``/``), used as a *relative* name because tf2 refuses frame ids
    that start with ``/`` ("in tf2 frame_ids cannot start with a '/'"; REP 105 names the
    standard frames the same way: ``base_link``, ``odom``, ``map``).
ROS node names
    One token of the rule above (no ``/``), as ``rmw_validate_node_name`` requires.
easy_handeye2 calibration names
    easy_handeye2 stores a calibration as ``<name>.calib``; the name is a portable file name
    stem (POSIX portable filename character set: ASCII letters, digits, ``.``, ``_``, ``-``),
    not starting with ``.`` or ``-``.
PLUS coordinate frame names
    PLUS joins two frame names into one transform name ``<From>To<To>`` and splits it again
    (``PlusTransformName::SetTransformName``): a frame name starts with an upper-case ASCII
    letter and continues with ASCII letters and digits, and the joined name must hold exactly
    one ``To`` followed by a character that is not lower case.
"""

from __future__ import annotations

import re

from spacecal.core.errors import InvalidInputError
from spacecal.core.text import quoted

#: Longest frame name accepted (a node name made of two of them stays under rmw's 255).
MAX_ROS_NAME_CHARS = 100
_ROS_TOKEN = r"[A-Za-z_][A-Za-z0-9_]*"
_ROS_NAME = re.compile(rf"{_ROS_TOKEN}(?:/{_ROS_TOKEN})*", re.ASCII)
_ROS_NODE_NAME = re.compile(_ROS_TOKEN, re.ASCII)
_FILE_STEM = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*", re.ASCII)
_PLUS_FRAME = re.compile(r"[A-Z][A-Za-z0-9]*", re.ASCII)
#: Longest easy_handeye2 calibration name and PLUS frame name accepted.
MAX_NAME_CHARS = 100


def _ros_name_problem(name: str, max_chars: int) -> str:
    """Why ``name`` is not a ROS frame name (one short phrase)."""
    if not name:
        return "it is empty"
    if len(name) > max_chars:
        return f"longer than {max_chars} characters"
    if name.startswith("/"):
        return "tf2 frame ids cannot start with '/'; drop it"
    if name.endswith("/") or "//" in name:
        return "'/' must separate two names"
    bad = next((c for c in name if not (c.isascii() and (c.isalnum() or c in "_/"))), None)
    if bad is not None:
        return f"{quoted(bad)} is not allowed (only ASCII letters, digits, '_' and '/')"
    return "a name must not start with a digit (after '/' neither)"


def check_ros_frame_name(name: object, what: str = "frame name", max_chars: int = MAX_ROS_NAME_CHARS) -> str:
    """``name`` if it is a ROS frame name (see the module docstring), else one line naming ``what``.

    Parameters
    ----------
    name : object
        The name to check (anything but a ``str`` is refused).
    what : str
        Named in the error: the option (``--tracker-frame``) or the field.
    max_chars : int
        Longest name accepted (a URDF joint named after two frames may take 255).
    """
    if not isinstance(name, str):
        raise InvalidInputError(f"{what}: expected a ROS frame name, got {type(name).__name__}")
    if _ROS_NAME.fullmatch(name) and len(name) <= max_chars:
        return name
    raise InvalidInputError(
        f"{what} {quoted(name)} is not a ROS frame name: {_ros_name_problem(name, max_chars)} "
        "(see 'names' in docs/formats.md)"
    )


def check_ros_node_name(name: object, what: str = "node name") -> str:
    """``name`` if it is a ROS node name (one token: ASCII letters, digits, ``_``; not starting
    with a digit; at most 255 characters), else one line naming ``what``."""
    if isinstance(name, str) and _ROS_NODE_NAME.fullmatch(name) and len(name) <= 255:
        return name
    raise InvalidInputError(
        f"{what} {quoted(name)} is not a ROS node name (ASCII letters, digits and '_', not starting "
        "with a digit)"
    )


def check_calibration_name(name: object, what: str = "calibration name") -> str:
    """``name`` if it is a portable file name stem (easy_handeye2 writes ``<name>.calib``)."""
    if isinstance(name, str) and _FILE_STEM.fullmatch(name) and len(name) <= MAX_NAME_CHARS:
        return name
    raise InvalidInputError(
        f"{what} {quoted(name)} is not a portable name: ASCII letters, digits, '.', '_' and '-', "
        f"not starting with '.' or '-', at most {MAX_NAME_CHARS} characters"
    )


def plus_to_count(transform_name: str) -> int:
    """How many ``To`` PLUS finds in a transform name: a ``To`` followed by a character that
    ``toupper`` leaves unchanged (``PlusTransformName::SetTransformName``)."""
    return sum(
        1
        for k in range(len(transform_name) - 2)
        if transform_name.startswith("To", k) and not transform_name[k + 2].islower()
    )


def check_plus_frame_names(from_frame: object, to_frame: object) -> tuple[str, str]:
    """``(from_frame, to_frame)`` if PLUS can name and split the transform ``<From>To<To>``."""
    for label, name in (("From", from_frame), ("To", to_frame)):
        if not (isinstance(name, str) and _PLUS_FRAME.fullmatch(name) and len(name) <= MAX_NAME_CHARS):
            raise InvalidInputError(
                f"PLUS {label} frame {quoted(name)} is not a PLUS frame name: an upper-case ASCII "
                f"letter, then ASCII letters and digits, at most {MAX_NAME_CHARS} characters"
            )
    assert isinstance(from_frame, str) and isinstance(to_frame, str)  # checked above
    joined = f"{from_frame}To{to_frame}"
    if plus_to_count(joined) != 1:
        raise InvalidInputError(
            f"PLUS cannot split the transform name {quoted(joined)} into its two frames (a frame name "
            "must not hold 'To' followed by an upper-case letter or a digit, nor end with 'To')"
        )
    return from_frame, to_frame


def check_xml_text(text: str, what: str) -> str:
    """``text`` if XML 1.0 can hold it (no NUL, no control characters but tab, newline and carriage
    return, no surrogates, no U+FFFE/U+FFFF), else one line naming ``what``."""
    for character in text:
        code = ord(character)
        if not (
            code in (0x9, 0xA, 0xD)
            or 0x20 <= code <= 0xD7FF
            or 0xE000 <= code <= 0xFFFD
            or 0x10000 <= code <= 0x10FFFF
        ):
            raise InvalidInputError(
                f"{what} {quoted(text)}: XML cannot hold the character {quoted(character)}"
            )
    return text
