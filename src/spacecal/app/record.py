"""Writing calibrations and checks to the record (``--record PATH_OR_URL``): the command line
and the station call these after ``calibrate`` and ``check``, so both fill the same record."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from spacecal.app.result import CommandResult
from spacecal.io.results_json import read_calibration
from spacecal.records import CalibrationResult

if TYPE_CHECKING:
    from spacecal.app.checking import CheckOutput
    from spacecal.ledger import Ledger


def open_record(url: str) -> Ledger:
    """The record at ``url`` (an SQLite file path or an SQLAlchemy URL), created or migrated.

    Raises
    ------
    MissingExtraError
        The station extra (SQLAlchemy) is not installed.
    InvalidInputError
        The record cannot be opened.
    """
    from spacecal.ledger import Ledger

    return Ledger.open(url)


def record_calibration(
    ledger: Ledger,
    output: CommandResult[CalibrationResult],
    source: str,
    robot_id: int | None = None,
    tracker_id: int | None = None,
    tool_id: int | None = None,
) -> int:
    """Record the calibration ``calibrate`` wrote (made with the robot, tracker and tool of
    those ids in the record, when known); returns its id in the record."""
    return ledger.record_calibration(
        output.record,
        output.files_written[0],
        source,
        robot_id=robot_id,
        tracker_id=tracker_id,
        tool_id=tool_id,
    )


def record_check(
    ledger: Ledger, calibration_path: str | Path, output: CommandResult[CheckOutput], source: str
) -> int | None:
    """Record the check ``check`` made of the calibration at ``calibration_path`` (recorded
    too, if it was not yet); None after a dry run (nothing was checked)."""
    if output.record.result is None:
        return None
    calibration = read_calibration(calibration_path)
    calibration_id = ledger.record_calibration(calibration, calibration_path, source)
    return ledger.record_check(calibration_id, output.record.result, source)
