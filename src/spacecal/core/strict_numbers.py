"""Numbers in text files and on the command line: the plain decimal forms only, one parser for
every reader.

Python's ``float()`` and ``int()`` (and numpy's string conversion) accept more than a
number in a data file should be: ``1_000`` (digit grouping), digits of other scripts
(``'١٢'`` is 12), and surrounding Unicode spaces. A cell ``1_000`` is far more likely a
typing or export error than a thousand, so the readers of recordings, raw streams, pose
files, PLUS and Slicer files and ROS command lines parse numbers here and refuse those forms,
as does spacecal's own command line for its option values (:func:`decimal`, :func:`integer`).

Accepted: an optional sign, ASCII digits with an optional decimal point, an optional
exponent (``-12``, ``0.5``, ``.5``, ``5.``, ``1e-05``, ``1.5E+3``), and the spelled-out
non-finite values (``nan``, ``inf``, ``infinity``, any case, with a sign) so that readers can
say "not finite" rather than "not a number". ASCII spaces and tabs around the number are
ignored, as in a CSV written with ``", "`` separators.
"""

from __future__ import annotations

import math
import re

import numpy as np

_DECIMAL = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?", re.ASCII)
_NON_FINITE = re.compile(r"[+-]?(?:nan|inf|infinity)", re.ASCII | re.IGNORECASE)
_INTEGER = re.compile(r"[+-]?[0-9]+", re.ASCII)
#: Longer than this is not a number a file of ours holds (and ``int()`` of 4,300 digits raises).
MAX_NUMBER_CHARS = 400
_SPACE = " \t"
#: Separators of a list of numbers: ASCII whitespace only (a no-break space is not one).
_SEPARATOR = re.compile(r"[ \t\r\n]+")


def parse_float(text: str) -> float:
    """The float of a plain decimal number (see the module docstring).

    Raises
    ------
    ValueError
        For anything else: ``1_000``, ``0x10``, ``1,5``, digits of other scripts, an empty cell.
        Callers add the file, line and column.
    """
    stripped = text.strip(_SPACE) if isinstance(text, str) else ""
    if len(stripped) <= MAX_NUMBER_CHARS and (
        _DECIMAL.fullmatch(stripped) or _NON_FINITE.fullmatch(stripped)
    ):
        return float(stripped)
    raise ValueError("not a plain decimal number")


def parse_int(text: str) -> int:
    """The int of a plain decimal integer (optional sign, ASCII digits); ValueError otherwise."""
    stripped = text.strip(_SPACE) if isinstance(text, str) else ""
    if len(stripped) <= MAX_NUMBER_CHARS and _INTEGER.fullmatch(stripped):
        return int(stripped)
    raise ValueError("not a plain decimal integer")


def parse_floats(text: str) -> np.ndarray:
    """The numbers of a whitespace-separated list (a PLUS ``Matrix``, a URDF ``xyz``), shape (K,).

    Raises
    ------
    ValueError
        When any item is not a plain decimal number.
    """
    if not isinstance(text, str):
        raise ValueError("not a list of numbers")
    items = _SEPARATOR.split(text.strip(_SPACE + "\r\n"))
    return np.array([parse_float(item) for item in items if item], dtype=float)


def decimal(text: str) -> float:
    """:func:`parse_float` under the name a command line's usage error shows
    (``invalid decimal value: '1_000'``)."""
    return parse_float(text)


def integer(text: str) -> int:
    """:func:`parse_int` under the name a command line's usage error shows."""
    return parse_int(text)


def number_value(value: object, max_abs: float | None = None) -> float:
    """The float of a number a parser already made (a YAML or JSON ``int`` or ``float``), when it
    is finite and, with ``max_abs``, no larger in magnitude.

    A parser gives integers as Python ints of any size: ``10**31`` (a translation in metres
    written as 32 digits) is no number ``numpy`` takes, and one beyond 1.8e308 is no float at
    all; a float such as ``1e308`` is finite, but multiplied once (metres to mm) it is not.
    Integers are compared with ``max_abs`` before they are converted, so no size of them
    raises anything but this ValueError.

    Parameters
    ----------
    value : object
    max_abs : float, optional
        The largest magnitude accepted (in the caller's unit).

    Raises
    ------
    ValueError
        A bool or anything but an int or float ("not a number"), NaN or infinity ("not
        finite"), an integer beyond a float's range, or a magnitude beyond ``max_abs``; the
        message says which (the caller adds the file and field).
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError("not a number")
    if isinstance(value, int):
        if max_abs is not None and abs(value) > max_abs:
            raise ValueError(f"an integer beyond {max_abs:g} in magnitude")
        try:
            value = float(value)
        except OverflowError:
            raise ValueError("an integer too large for a floating-point number") from None
    if not np.isfinite(value):
        raise ValueError("not finite")
    if max_abs is not None and abs(value) > max_abs:
        raise ValueError(f"beyond {max_abs:g} in magnitude")
    return float(value)


def number_shown(value: object, limit: int = 40) -> str:
    """A number read from a file, short enough for an error message: an integer of more
    digits than ``limit`` as its digit count (``str()`` of one beyond 4,300 digits raises)."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**limit:
        digits = int(math.log10(abs(value))) + 1
        # the float logarithm may be one off near a power of ten: settle it with exact ints
        digits += (abs(value) >= 10**digits) - (abs(value) < 10 ** (digits - 1))
        return f"an integer of {digits} digits"
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."
