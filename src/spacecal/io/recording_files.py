"""The names of a recording's files, and what kind of recording a file is.

Every name of a recording file is made here, so code outside :mod:`spacecal.io` never spells
one: the paired CSV ``STEM.csv`` with its metadata ``STEM.meta.json``; the raw streams
``STEM.robot.csv`` and ``STEM.tracker.csv``, whose metadata is the stem's; the station's
recording in its folder. :func:`recording_kind` is the one place that tells a paired CSV from
a raw robot stream by its header.
"""

from __future__ import annotations

from pathlib import Path

from spacecal.io.csv_core import RAW_ROBOT_SUFFIX, metadata_path
from spacecal.io.raw_streams import raw_stem, raw_stream_paths, stream_paths
from spacecal.records.recording_source import PAIRED_CSV, RAW_STREAMS

#: The tracker stream's suffix beside ``STEM.robot.csv`` (see :func:`stream_paths`).
TRACKER_STREAM_SUFFIX = ".tracker.csv"
#: The stem of the recording a folder holds (the station's, the demo's).
DEFAULT_STEM = "recording"
#: The ends of a recording's metadata file and of an acquisition's progress file.
METADATA_SUFFIX = ".meta.json"
_PROGRESS_SUFFIX = ".progress.json"

__all__ = [
    "DEFAULT_STEM",
    "METADATA_SUFFIX",
    "TRACKER_STREAM_SUFFIX",
    "is_recording",
    "metadata_path",
    "paired_files",
    "raw_stem",
    "raw_stream_paths",
    "recording_in",
    "recording_kind",
    "stream_paths",
    "tracker_stream_beside",
]


def recording_in(folder: str | Path, stem: str = DEFAULT_STEM) -> Path:
    """The paired recording CSV of ``stem`` in ``folder`` (``folder/recording.csv`` by default)."""
    return Path(folder) / f"{stem}.csv"


def paired_files(recording_path: str | Path) -> tuple[Path, Path]:
    """(the paired CSV, its metadata file): what writing a paired recording creates."""
    path = Path(recording_path)
    return path, metadata_path(path)


def tracker_stream_beside(robot_stream: str | Path) -> Path | None:
    """The tracker stream of the same stem as ``robot_stream`` (``STEM.robot.csv`` ->
    ``STEM.tracker.csv``), None when the name does not follow that form or it is missing."""
    robot_stream = Path(robot_stream)
    if not robot_stream.name.endswith(RAW_ROBOT_SUFFIX):
        return None
    candidate = robot_stream.with_name(robot_stream.name[: -len(RAW_ROBOT_SUFFIX)] + TRACKER_STREAM_SUFFIX)
    return candidate if candidate.is_file() else None


def _header(path: Path, size: int = 65536) -> bytes | None:
    try:
        with open(path, "rb") as handle:
            return handle.readline(size)
    except OSError:
        return None


def recording_kind(path: str | Path) -> str | None:
    """What kind of recording ``path`` is, by its CSV header: ``raw_streams`` for a raw robot
    stream (times, TCP columns, no marker columns), ``paired_csv`` for any other CSV with a
    ``time_s`` column (a paired recording, or a tracker stream, which reading then refuses),
    None for a file that is no recording or is not there."""
    path = Path(path)
    if not path.is_file():
        return None
    header = _header(path)
    if header is None or b"time_s" not in header:
        return None
    if b"marker_x_mm" not in header and b"tcp_x_mm" in header:
        return RAW_STREAMS
    return PAIRED_CSV


def is_recording(path: str | Path) -> bool:
    """True for an existing recording file: a CSV whose header has ``time_s`` (paired or raw
    stream), a recording's metadata file or an acquisition's progress file."""
    path = Path(path)
    if not path.is_file():
        return False
    if path.name.endswith((METADATA_SUFFIX, _PROGRESS_SUFFIX)):
        return True
    if path.suffix.lower() != ".csv":
        return False
    header = _header(path, 4096)
    return header is not None and b"time_s" in header
