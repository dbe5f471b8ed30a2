"""JSON files for results: one writer (atomic) and one reader that insists on an object.

The content of each file is its record's ``to_dict()``; reading goes through the record's
``from_dict()``, which validates every field (see :mod:`spacecal.records`).
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

from spacecal.core.errors import InvalidInputError
from spacecal.records import CalibrationResult
from spacecal.records.fields import plain

#: Larger than this is not a spacecal result file.
MAX_JSON_BYTES = 200 * 1024 * 1024


def write_text_atomic(text: str, path: str | Path) -> Path:
    """Write ``text`` to ``path`` through a temporary file in the same folder and a rename,
    so an interrupted write never leaves a half-written file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(handle, "w", encoding="utf-8") as stream:
            stream.write(text)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
    return path


def write_json(data: dict[str, Any], path: str | Path) -> Path:
    """Write a dict (numpy values allowed) as indented JSON, atomically; returns the path."""
    text = json.dumps(plain(data), indent=2, allow_nan=False)
    return write_text_atomic(text + "\n", path)


def read_json_object(path: str | Path, what: str) -> dict[str, Any]:
    """Read a JSON file that must hold an object; one-line errors name the file and ``what`` it is."""
    path = Path(path)
    if not path.is_file():
        raise InvalidInputError(f"{path}: no such {what} file")
    raw = path.read_bytes()
    if len(raw) > MAX_JSON_BYTES:
        raise InvalidInputError(f"{path}: too large for a {what} file ({len(raw)} bytes)")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise InvalidInputError(f"{path}: not UTF-8 text (a {what} file is JSON)") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InvalidInputError(f"{path}: not valid JSON: {exc.msg} (line {exc.lineno})") from None
    except RecursionError:
        raise InvalidInputError(f"{path}: JSON nested too deeply for a {what} file") from None
    if not isinstance(data, dict):
        raise InvalidInputError(f"{path}: a {what} file holds a JSON object")
    return data


def write_calibration(result: CalibrationResult, path: str | Path) -> Path:
    """Write a calibration result file (schema 2)."""
    return write_json(result.to_dict(), path)


def read_calibration(path: str | Path) -> CalibrationResult:
    """Read and validate a calibration result file (schema 1 or 2)."""
    return CalibrationResult.from_dict(read_json_object(path, "calibration"), what=str(path))
