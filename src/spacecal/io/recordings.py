"""The one public entry to recordings for code outside :mod:`spacecal.io`: naming their files,
telling their kind, opening them (with the source a calibration keeps) and writing them.

Commands, workflows and the station import recordings from here only, so how a recording is
named, read, paired and checked is decided in one place.
"""

from __future__ import annotations

from spacecal.io.raw_streams import RawStreamWriter, write_raw_recording
from spacecal.io.recording_csv import RecordingWriter, last_time_s, write_recording
from spacecal.io.recording_files import (
    DEFAULT_STEM,
    is_recording,
    metadata_path,
    paired_files,
    raw_stem,
    raw_stream_paths,
    recording_in,
    recording_kind,
    stream_paths,
    tracker_stream_beside,
)
from spacecal.io.recording_source import (
    ACCEPT_EDITED,
    OpenedRecording,
    changed_file,
    open_calibrated_recording,
    open_path,
    open_source,
    pair_raw,
    refuse_changed,
)

__all__ = [
    "ACCEPT_EDITED",
    "DEFAULT_STEM",
    "OpenedRecording",
    "RawStreamWriter",
    "RecordingWriter",
    "changed_file",
    "is_recording",
    "last_time_s",
    "metadata_path",
    "open_calibrated_recording",
    "open_path",
    "open_source",
    "pair_raw",
    "paired_files",
    "raw_stem",
    "raw_stream_paths",
    "recording_in",
    "recording_kind",
    "refuse_changed",
    "stream_paths",
    "tracker_stream_beside",
    "write_raw_recording",
    "write_recording",
]
