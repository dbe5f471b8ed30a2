"""Writing calibrations and checks to the record (``--record PATH_OR_URL``): the command line
and the station call these after ``calibrate`` and ``check``, so both fill the same record."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from spacecal.app.result import CommandResult
from spacecal.core.errors import RecordError
from spacecal.core.text import sanitize_for_terminal
from spacecal.io.results_json import read_calibration
from spacecal.records import CalibrationResult, CheckResult

if TYPE_CHECKING:
    from spacecal.ledger import Ledger


class CheckMade(Protocol):
    """What ``check`` gives (its :class:`~spacecal.app.check_settings.CheckOutput`): the check,
    None after a dry run."""

    @property
    def result(self) -> CheckResult | None: ...


def open_record(url: str) -> Ledger:
    """The record at ``url`` (an SQLite file path or an SQLAlchemy URL), created or migrated.

    Raises
    ------
    MissingExtraError
        The station extra (SQLAlchemy) or the database's driver is not installed.
    InvalidInputError
        ``url`` is not a database URL, or the record is of a newer spacecal.
    RecordError
        The record cannot be opened (unreachable, locked, damaged); the URL in the message
        shows no password.
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
    those ids in the record, when known); returns its id in the record.

    Raises
    ------
    RecordError
        The record failed the write: the message says the calibration file was written and
        is not recorded.
    """
    try:
        return ledger.record_calibration(
            output.record,
            output.files_written[0],
            source,
            robot_id=robot_id,
            tracker_id=tracker_id,
            tool_id=tool_id,
        )
    except RecordError as exc:
        raise RecordError(f"{_written(output.files_written[0])} was written but not recorded: {exc}") from exc


def record_check(
    ledger: Ledger, calibration_path: str | Path, output: CommandResult[CheckMade], source: str
) -> int | None:
    """Record the check ``check`` made of the calibration at ``calibration_path`` (recorded
    too, if it was not yet); None after a dry run (nothing was checked).

    Raises
    ------
    RecordError
        The record failed the write: the message says the check is in the calibration's
        check history and not in the record.
    """
    if output.record.result is None:
        return None
    calibration = read_calibration(calibration_path)
    try:
        calibration_id = ledger.record_calibration(calibration, calibration_path, source)
        return ledger.record_check(calibration_id, output.record.result, source)
    except RecordError as exc:
        kept = f"its history {_written(output.files_written[0])}" if output.files_written else "no file"
        raise RecordError(f"the check was written to {kept} but not recorded: {exc}") from exc


def _written(path: str | Path) -> str:
    return sanitize_for_terminal(Path(path).name, 80)
