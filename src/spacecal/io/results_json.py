"""JSON files for results: one writer (atomic) and one reader that insists on an object.

The content of each file is its record's ``to_dict()``; reading goes through the record's
``from_dict()``, which validates every field (see :mod:`spacecal.records`).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from spacecal.core.errors import InvalidInputError
from spacecal.io.atomic import write_text_atomic
from spacecal.io.text import read_text_file
from spacecal.records import CalibrationResult
from spacecal.records.fields import plain

#: Larger than this is not a spacecal result file.
MAX_JSON_BYTES = 200 * 1024 * 1024
#: The integers a result file holds: counts, seeds, schema versions and nanosecond times all fit
#: in 64 bits. A larger one is no number numpy takes (an object array, whose ``isfinite``
#: raises), and past 4,300 digits Python's ``int()`` raises a plain ValueError.
MIN_INT, MAX_INT = -(2**63), 2**63 - 1
#: Characters of a number shown in an error message.
_SHOWN_CHARS = 40


class _NotANumber(ValueError):
    """The complete reason, for the error line after the file's name."""


def _shown(text: str) -> str:
    return text if len(text) <= _SHOWN_CHARS else f"{text[:_SHOWN_CHARS]}... ({len(text)} characters)"


def _no_constant(name: str) -> float:
    raise _NotANumber(f"{name} is not a number JSON allows")


def _finite_float(text: str) -> float:
    value = float(text)
    if value in (float("inf"), float("-inf")):
        raise _NotANumber(f"{_shown(text)} is too large for a floating-point number")
    return value


def _bounded_int(text: str) -> int:
    digits = len(text.lstrip("-"))
    # the length first: int() of thousands of digits is slow, and raises past 4,300
    if digits > len(str(MAX_INT)) or not MIN_INT <= int(text) <= MAX_INT:
        raise _NotANumber(f"an integer of {digits} digits is beyond the 64-bit integers a result file holds")
    return int(text)


def write_json(data: dict[str, Any], path: str | Path) -> Path:
    """Write a dict (numpy values allowed) as indented JSON, atomically; returns the path."""
    text = json.dumps(plain(data), indent=2, allow_nan=False)
    return write_text_atomic(text + "\n", path)


def read_json_object(path: str | Path, what: str) -> dict[str, Any]:
    """Read a JSON file that must hold an object; one-line errors name the file and ``what`` it is."""
    path = Path(path)
    if path.is_file() and path.stat().st_size > MAX_JSON_BYTES:
        raise InvalidInputError(f"{path}: too large for a {what} file ({path.stat().st_size} bytes)")
    text = read_text_file(path, what)
    try:
        data = json.loads(
            text, parse_constant=_no_constant, parse_float=_finite_float, parse_int=_bounded_int
        )
    except json.JSONDecodeError as exc:
        raise InvalidInputError(f"{path}: not valid JSON: {exc.msg} (line {exc.lineno})") from None
    except RecursionError:
        raise InvalidInputError(f"{path}: JSON nested too deeply for a {what} file") from None
    except _NotANumber as exc:
        raise InvalidInputError(f"{path}: {exc.args[0]} (a {what} file)") from None
    if not isinstance(data, dict):
        raise InvalidInputError(f"{path}: a {what} file holds a JSON object, not {type(data).__name__}")
    return data


def write_calibration(result: CalibrationResult, path: str | Path) -> Path:
    """Write a calibration result file (the current schema, with its content hash)."""
    return write_json(result.to_dict(), path)


def read_calibration(path: str | Path) -> CalibrationResult:
    """Read and validate a calibration result file (schema 1, 2 or 3).

    An edited file is read, not refused: its ``integrity`` says how it stands against its
    content hash, and the app decides (:func:`spacecal.app._common.open_calibration`)."""
    return CalibrationResult.from_dict(read_json_object(path, "calibration"), what=str(path))
