"""YAML at the boundary: a strict reader and a quoting writer.

Reading (needs PyYAML, the ``ros`` extra): YAML's anchors and aliases let a 600-byte file
describe gigabytes (each alias repeats a whole earlier node: the "billion laughs"); nothing
spacecal reads uses them, so any anchor or alias is refused while the file is parsed, before a
node is built. Numbers are read in their plain decimal forms only: YAML 1.1's ``1_000``,
``0x10``, ``0o17``, ``1:30`` (sexagesimal) and dates stay strings (and are then refused where
a number is expected), ``1e-05`` is a float as YAML 1.2 (and the ROS tools' yaml-cpp) reads it.

Writing needs no library: names are written plain only when no YAML reader can take them for
anything but a string, otherwise double-quoted with every character outside printable ASCII
escaped; floats always carry a ``.`` before their exponent, so YAML 1.1 readers (PyYAML, which
xacro uses) read them as floats too; comments are one line of printable ASCII.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from spacecal.core.errors import InvalidInputError, MissingExtraError
from spacecal.core.strict_numbers import parse_float, parse_int
from spacecal.core.text import double_quoted_ascii, one_line_ascii, quoted
from spacecal.io.ros_common import number_text
from spacecal.io.text import read_text_file

_PLAIN = re.compile(r"[A-Za-z_][A-Za-z0-9_/]*", re.ASCII)
#: Plain scalars some YAML reader takes for a boolean or null (YAML 1.1 and yaml-cpp's y/n).
_RESERVED = frozenset({"y", "n", "yes", "no", "on", "off", "true", "false", "null"})
_INT_TAG = "tag:yaml.org,2002:int"
_FLOAT_TAG = "tag:yaml.org,2002:float"
_TIMESTAMP_TAG = "tag:yaml.org,2002:timestamp"
_STRICT_INT = re.compile(r"^[-+]?[0-9]+$")
_STRICT_FLOAT = re.compile(
    r"^(?:[-+]?(?:[0-9]+\.[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?|[-+]?[0-9]+[eE][-+]?[0-9]+"
    r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$"
)
_YAML_NON_FINITE = {".inf": float("inf"), "+.inf": float("inf"), "-.inf": float("-inf"), ".nan": float("nan")}


#: The largest YAML file read, bytes: a configuration or an easy_handeye sample list of a few
#: thousand poses is well under 1 MB; PyYAML's pure-Python parser takes about a minute and
#: several hundred MB for 200 MB, which no such file needs.
MAX_YAML_BYTES = 16 * 1024 * 1024


def require_yaml() -> Any:
    """The ``yaml`` module (PyYAML), or :class:`MissingExtraError` naming the extra that brings it."""
    try:
        import yaml
    except ImportError as exc:  # pragma: no cover - the extra is installed in CI
        raise MissingExtraError(
            "reading ROS tools' YAML files needs PyYAML: pip install 'spacecal[ros]'"
        ) from exc
    return yaml


class _Refused(Exception):
    """Raised inside the loader; turned into an InvalidInputError naming the file."""


_LOADER: Any = None


def _strict_loader() -> Any:
    """A ``yaml.SafeLoader`` subclass without anchors, aliases, YAML 1.1 number forms or dates."""
    global _LOADER
    if _LOADER is not None:
        return _LOADER
    yaml = require_yaml()

    class StrictLoader(yaml.SafeLoader):  # type: ignore[name-defined]
        def compose_node(self, parent, index):
            event = self.peek_event()
            line = event.start_mark.line + 1
            if isinstance(event, yaml.AliasEvent):
                raise _Refused(f"a YAML alias (*) at line {line}; aliases and anchors are not accepted")
            if getattr(event, "anchor", None) is not None:
                raise _Refused(f"a YAML anchor (&) at line {line}; aliases and anchors are not accepted")
            return super().compose_node(parent, index)

    StrictLoader.yaml_implicit_resolvers = {
        first: [(tag, regexp) for tag, regexp in entries if tag not in (_INT_TAG, _FLOAT_TAG, _TIMESTAMP_TAG)]
        for first, entries in yaml.SafeLoader.yaml_implicit_resolvers.items()
    }
    StrictLoader.add_implicit_resolver(_INT_TAG, _STRICT_INT, list("-+0123456789"))
    StrictLoader.add_implicit_resolver(_FLOAT_TAG, _STRICT_FLOAT, list("-+0123456789."))

    def construct_int(loader, node):  # also for an explicit !!int: no 0x, 0o, 1_000, 1:30
        value = loader.construct_scalar(node)
        try:
            return parse_int(value)
        except ValueError:
            raise _Refused(
                f"{quoted(value)} at line {node.start_mark.line + 1} is not a plain decimal integer"
            ) from None

    def construct_float(loader, node):
        value = loader.construct_scalar(node)
        if value.lower() in _YAML_NON_FINITE:
            return _YAML_NON_FINITE[value.lower()]
        try:
            return parse_float(value)
        except ValueError:
            raise _Refused(
                f"{quoted(value)} at line {node.start_mark.line + 1} is not a plain decimal number"
            ) from None

    StrictLoader.add_constructor(_INT_TAG, construct_int)
    StrictLoader.add_constructor(_FLOAT_TAG, construct_float)
    _LOADER = StrictLoader
    return StrictLoader


def parse_yaml(text: str, where: str, what: str) -> Any:
    """The data of a YAML document (see the module docstring); one clear line when it is refused.

    Parameters
    ----------
    text : str
    where : str
        The file, named in errors.
    what : str
        What the file should be (``"easy_handeye calibration"``), named in errors.
    """
    yaml = require_yaml()
    try:
        return yaml.load(text, Loader=_strict_loader())  # a SafeLoader subclass
    except _Refused as exc:
        raise InvalidInputError(f"{where}: {exc} ({what})") from None
    except RecursionError:
        raise InvalidInputError(f"{where}: YAML nested too deeply for a {what}") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f" at line {mark.line + 1}" if mark is not None else ""
        raise InvalidInputError(f"{where}: not valid YAML{at}; expected a {what}") from None


def check_yaml_file(path: str | Path, what: str) -> None:
    """Parse a YAML file only to refuse what :func:`parse_yaml` refuses (aliases, anchors), for
    files another library reads afterwards (a ROS 2 bag's ``metadata.yaml``)."""
    path = Path(path)
    parse_yaml(read_text_file(path, what, MAX_YAML_BYTES), str(path), what)


def load_yaml_mapping(path: str | Path, what: str) -> dict:
    """Read a YAML file whose top level is a mapping; one clear line when it is not."""
    path = Path(path)
    require_yaml()
    if not path.is_file():
        raise InvalidInputError(f"{path}: no such {what} file")
    data = parse_yaml(read_text_file(path, what, MAX_YAML_BYTES), str(path), what)
    if not isinstance(data, dict):
        raise InvalidInputError(f"{path}: expected a {what} (a YAML mapping), found {type(data).__name__}")
    return data


def yaml_string(value: str) -> str:
    """A YAML scalar that every reader reads back as exactly ``value`` (a ``str``).

    Plain (``base_link``, ``ur/tool0``) when it starts with a letter or ``_``, holds only ASCII
    letters, digits, ``_`` and ``/`` and is no boolean or null word; otherwise double-quoted,
    printable ASCII only (``"1_000"``, ``"x\\ny"``, ``"caf\\xe9"``).
    """
    if not isinstance(value, str):
        raise InvalidInputError(f"expected text to write to YAML, got {type(value).__name__}")
    if _PLAIN.fullmatch(value) and value.lower() not in _RESERVED:
        return value
    return double_quoted_ascii(value)


def yaml_number(value: float) -> str:
    """A float as YAML that YAML 1.1 and 1.2 readers both read back as exactly that float.

    The shortest round-trip text (:func:`~spacecal.io.ros_common.number_text`), with a ``.``
    added to a mantissa without one (``1e-05`` -> ``1.0e-05``): YAML 1.1 readers (PyYAML, which
    xacro uses) read ``1e-05`` as a string.
    """
    text = number_text(value)
    mantissa, e, exponent = text.partition("e")
    if e and "." not in mantissa:
        text = f"{mantissa}.0e{exponent}"
    return text


def yaml_comment(text: str) -> str:
    """``# text`` as one line of printable ASCII (a newline in ``text`` cannot start a new key)."""
    return "# " + one_line_ascii(text)
