"""The check history of a calibration: ``cal.json`` -> ``cal.checks.jsonl``, one JSON object a
line, each a :class:`~spacecal.records.CheckResult` bound to the content hash of the calibration
it checked (``calibration_sha256``).

Appending is durable (each line flushed and synced); reading is forgiving (the history is
advisory: a corrupt line is counted, never fatal), and a calibration replaced at the same path
never shows the checks of the one before it.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import NamedTuple

from spacecal.core.errors import InvalidInputError
from spacecal.io.results_json import read_json_object
from spacecal.records import CheckResult
from spacecal.records.integrity import content_sha256


def history_path(calibration_path: str | Path) -> Path:
    """``cal.json`` -> ``cal.checks.jsonl``."""
    path = Path(calibration_path)
    return path.with_name(path.stem + ".checks.jsonl")


#: The key of a history line that binds it to the content hash of the calibration it checked.
CALIBRATION_HASH_KEY = "calibration_sha256"


class History(NamedTuple):
    """The checks of one calibration, oldest first, and the lines left out: unreadable ones,
    and those of another calibration (one replaced at the same path, or lines written before
    checks recorded the calibration's hash)."""

    checks: list[CheckResult]
    unreadable: int
    other_calibrations: int


def calibration_content_sha256(calibration_path: str | Path) -> str:
    """The content hash of the calibration file as it stands (see :mod:`spacecal.records.integrity`)."""
    return content_sha256(read_json_object(calibration_path, "calibration"))


def append_history(
    calibration_path: str | Path, result: CheckResult, calibration_sha256: str | None = None
) -> Path:
    """Append a check to the calibration's history (one JSON object per line), bound to the
    content hash of the calibration checked (by default, of the file as it stands)."""
    if calibration_sha256 is None:
        calibration_sha256 = calibration_content_sha256(calibration_path)
    path = history_path(calibration_path)
    line = {**result.to_dict(), CALIBRATION_HASH_KEY: calibration_sha256}
    with open(path, "a", encoding="utf-8") as handle:
        handle.write(json.dumps(line, allow_nan=False) + "\n")
        handle.flush()
        os.fsync(handle.fileno())
    return path


def read_history(calibration_path: str | Path, calibration_sha256: str | None = None) -> History:
    """The checks logged for the calibration of content hash ``calibration_sha256`` (by
    default, of the file as it stands), oldest first; lines of any other calibration and lines
    that could not be read are counted, not returned (a corrupt line is never fatal: the
    history is advisory). A calibration replaced at the same path thus never shows the checks
    of the one before it."""
    path = history_path(calibration_path)
    if not path.is_file():
        return History([], 0, 0)
    if calibration_sha256 is None:
        calibration_sha256 = calibration_content_sha256(calibration_path)
    checks, unreadable, others = [], 0, 0
    for line in path.read_bytes().decode("utf-8", errors="replace").splitlines():
        if not line.strip():
            continue
        try:
            data = json.loads(line)
            if not isinstance(data, dict):
                raise InvalidInputError("not an object")
            check = CheckResult.from_dict(data, what=str(path))
        except (ValueError, RecursionError):
            unreadable += 1
            continue
        if data.get(CALIBRATION_HASH_KEY) != calibration_sha256:
            others += 1
        else:
            checks.append(check)
    return History(checks, unreadable, others)
