"""One way to open the recording a calibration came from, whatever form it took.

A calibration's provenance names its recording: a paired CSV (``spacecal simulate``,
``acquire``, ``import-plus``, ``import-easy-handeye``), or the robot stream of two raw streams
(``acquire``'s raw files, ``import-bag``, ``import-poses``) with the tracker stream beside it
and the clock offset the calibration paired them at (``diagnostics["time_offset_s"]``).
:func:`open_recording` reads any of them into the paired :class:`~spacecal.records.Recording`
that ``report``, ``verify``, ``check`` and ``bound`` work on, so each works for every
calibration, not only for those made from a paired CSV.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from spacecal.core.errors import InvalidInputError
from spacecal.estimators.time_offset import estimate_time_offset, pair_streams
from spacecal.io.csv_core import RAW_ROBOT_SUFFIX
from spacecal.io.digest import file_sha256
from spacecal.io.raw_streams import read_raw_recording
from spacecal.io.recording_csv import read_recording
from spacecal.records import CalibrationResult, Recording

#: The tracker stream's suffix beside ``STEM.robot.csv`` (see :func:`spacecal.io.raw_streams.stream_paths`).
TRACKER_STREAM_SUFFIX = ".tracker.csv"


@dataclass(frozen=True)
class OpenedRecording:
    """A recording as opened, and how.

    Attributes
    ----------
    recording : Recording
        The paired recording.
    path : Path
        The file named (the paired CSV, or the raw robot stream).
    tracker_stream : Path or None
        The raw tracker stream, when two raw streams were paired.
    time_offset_s : float or None
        The offset they were paired at (robot clock minus tracker clock, s).
    how : str
        One line: ``paired CSV``, or the streams and where the offset came from.
    """

    recording: Recording
    path: Path
    tracker_stream: Path | None = None
    time_offset_s: float | None = None
    how: str = "paired CSV"


def _is_raw_robot_stream(path: Path) -> bool:
    """True for a raw robot stream: its header has joints and TCP columns but no marker columns."""
    try:
        with open(path, "rb") as handle:
            header = handle.readline(65536)
    except OSError:
        return False
    return b"time_s" in header and b"marker_x_mm" not in header and b"tcp_x_mm" in header


def tracker_stream_beside(robot_stream: Path) -> Path | None:
    """The tracker stream of the same stem as ``robot_stream`` (``STEM.robot.csv`` ->
    ``STEM.tracker.csv``), None when the name does not follow that form or it is missing."""
    if not robot_stream.name.endswith(RAW_ROBOT_SUFFIX):
        return None
    candidate = robot_stream.with_name(robot_stream.name[: -len(RAW_ROBOT_SUFFIX)] + TRACKER_STREAM_SUFFIX)
    return candidate if candidate.is_file() else None


def open_recording(
    path: str | Path,
    tracker_stream: str | Path | None = None,
    time_offset_s: float | None = None,
) -> OpenedRecording:
    """Open a paired recording CSV, or two raw streams paired at ``time_offset_s``.

    Parameters
    ----------
    path : str or Path
        A paired recording CSV, or a raw robot stream.
    tracker_stream : str or Path, optional
        The raw tracker stream; found beside a raw robot stream ``STEM.robot.csv`` when omitted.
    time_offset_s : float, optional
        Robot clock minus tracker clock (s) to pair raw streams at; estimated when omitted.

    Raises
    ------
    InvalidInputError
        For a raw robot stream without its tracker stream, or a file that is neither.
    """
    path = Path(path)
    if tracker_stream is None and _is_raw_robot_stream(path):
        tracker_stream = tracker_stream_beside(path)
        if tracker_stream is None:
            raise InvalidInputError(
                f"{path}: a raw robot stream; its tracker stream (STEM{TRACKER_STREAM_SUFFIX}) is not "
                "beside it: pass it with --tracker-stream"
            )
    if tracker_stream is None:
        return OpenedRecording(read_recording(path), path)
    raw = read_raw_recording(path, tracker_stream)
    if time_offset_s is None:
        time_offset_s = estimate_time_offset(raw).offset_s
        how = f"raw streams paired at the estimated clock offset {time_offset_s * 1000:.2f} ms"
    else:
        how = f"raw streams paired at the calibration's clock offset {time_offset_s * 1000:.2f} ms"
    return OpenedRecording(pair_streams(raw, time_offset_s), path, Path(tracker_stream), time_offset_s, how)


def open_calibrated_recording(
    calibration: CalibrationResult, path: str | Path | None = None, accept_edited: bool = False
) -> OpenedRecording | None:
    """The recording ``calibration`` came from (or ``path``, when given), paired as the
    calibration paired it; None when its provenance names none or the file is gone.

    The calibration's own recording must still be the file it was made from: its sha256 (and
    its tracker stream's) must be the one the calibration recorded
    (:class:`~spacecal.records.Provenance`). A recording changed since, or another one written
    over it (an acquisition started again), is not what the calibration describes: its
    residuals and figures would be shown beside numbers of another recording.

    Raises
    ------
    InvalidInputError
        The calibration's own recording (or tracker stream) changed since it was made, unless
        ``accept_edited`` (``--accept-edited``); its tracker stream is missing.
    """
    provenance = calibration.provenance
    named = path if path is not None else provenance.recording
    if not named or not Path(named).is_file():
        return None
    same = path is None or (
        provenance.recording is not None and Path(path).resolve() == Path(provenance.recording).resolve()
    )
    stream = provenance.tracker_stream if same else None
    if stream is not None and not Path(stream).is_file():
        raise InvalidInputError(f"{named}: the calibration's tracker stream {stream} is missing")
    if same and not accept_edited:
        for file, recorded in (
            (named, provenance.recording_sha256),
            (stream, provenance.tracker_stream_sha256),
        ):
            if file is not None and recorded is not None and file_sha256(file) != recorded:
                raise InvalidInputError(
                    f"{file}: changed since the calibration was made from it (sha256 {recorded[:12]}... "
                    f"then, {file_sha256(file)[:12]}... now): the calibration does not describe it; "
                    "--accept-edited uses it anyway"
                )
    offset = calibration.diagnostics.get("time_offset_s") if same else None
    offset = float(offset) if isinstance(offset, (int, float)) else None
    return open_recording(named, stream, offset)
