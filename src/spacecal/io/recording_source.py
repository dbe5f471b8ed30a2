"""One way to open a recording, whatever form it took, and to reopen a calibration's.

A recording is a paired CSV or two raw streams (:mod:`spacecal.records.recording_source`).
:func:`open_path` opens a file the user named: it decides what kind it is
(:func:`~spacecal.io.recording_files.recording_kind`), takes the sha256 of each of its files,
pairs raw streams by the one pairing rule (:func:`pair_raw`) and returns the paired
:class:`~spacecal.records.Recording` with the :class:`~spacecal.records.RecordingSource` that
says all of this; ``calibrate`` keeps that source in the calibration's provenance.
:func:`open_source` reopens such a source: each file must still have the sha256 recorded, and
raw streams are paired again at the offset the calibration paired them at, so ``report``,
``verify``, ``check`` and ``bound`` work on the samples the calibration was made from.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from spacecal.core.errors import InvalidInputError
from spacecal.estimators.time_offset import (
    LARGEST_GAP_PERIODS,
    LARGEST_GAP_S,
    check_overlap,
    estimate_time_offset,
    pair_at_estimated_offset,
    pair_streams,
)
from spacecal.io.digest import file_sha256
from spacecal.io.raw_streams import read_raw_recording
from spacecal.io.recording_csv import read_recording
from spacecal.io.recording_files import (
    TRACKER_STREAM_SUFFIX,
    metadata_path,
    recording_kind,
    tracker_stream_beside,
)
from spacecal.records import CalibrationResult, RawRecording, Recording
from spacecal.records.recording_source import (
    METADATA,
    OFFSET_ARRIVAL_LINK,
    OFFSET_ESTIMATED,
    OFFSET_GIVEN,
    PAIRED_CSV,
    RAW_STREAMS,
    RECORDING,
    TRACKER_STREAM,
    RecordingSource,
    SourceFile,
    StreamPairing,
    finite_or_none,
)

#: What lets a changed recording through on the command line.
ACCEPT_EDITED = "--accept-edited"


@dataclass(frozen=True)
class OpenedRecording:
    """A recording as opened, and how.

    Attributes
    ----------
    recording : Recording
        The paired samples.
    source : RecordingSource
        Its files with their sha256 now, and how raw streams were paired.
    how : str
        One line: ``paired CSV``, or the streams and where the offset came from.
    pairing_note : str or None
        For raw streams opened from the names given: the line saying how they were paired
        (``calibrate`` prints it).
    """

    recording: Recording
    source: RecordingSource
    how: str = "paired CSV"
    pairing_note: str | None = None

    @property
    def path(self) -> Path:
        """The file named: the paired CSV, or the raw robot stream."""
        return Path(self.source.recording)

    @property
    def tracker_stream(self) -> Path | None:
        stream = self.source.tracker_stream
        return None if stream is None else Path(stream)

    @property
    def time_offset_s(self) -> float | None:
        """The offset raw streams were paired at (robot clock minus tracker clock, s)."""
        return self.source.time_offset_s


def pair_raw(
    raw: RawRecording,
    offset_s: float | None = None,
    *,
    fall_back_to_link: bool = False,
    what: str = "clock offset",
) -> tuple[Recording, StreamPairing, str]:
    """Pair two raw streams: the one rule every command pairs by.

    Parameters
    ----------
    raw : RawRecording
    offset_s : float, optional
        Robot clock minus tracker clock (s) to pair at (it must overlap the streams); estimated
        when omitted (:func:`~spacecal.estimators.time_offset.estimate_time_offset`).
    fall_back_to_link : bool
        When the streams hold no information on the offset (the robot never rotated while
        sampled), pair at the arrival-time link instead of refusing (an acquisition keeps what
        it recorded; :func:`~spacecal.estimators.time_offset.pair_at_estimated_offset`).
    what : str
        What names the given offset in a refusal (``--time-offset-ms``).

    Returns
    -------
    tuple of (Recording, StreamPairing, str)
        The paired samples, how they were paired, and one line saying how.

    Raises
    ------
    InvalidInputError
        A given offset at which the streams do not overlap.
    DegenerateDataError
        No offset can be estimated from the streams (without ``fall_back_to_link``).
    """
    if offset_s is not None:
        check_overlap(raw, offset_s, what)
        origin, note = OFFSET_GIVEN, f"clock offset given: {offset_s * 1000:.2f} ms"
        recording = pair_streams(raw, offset_s)
    elif fall_back_to_link:
        recording, found = pair_at_estimated_offset(raw)
        offset_s, note = found.offset_s, found.note
        origin = OFFSET_ESTIMATED if found.estimated else OFFSET_ARRIVAL_LINK
    else:
        estimate = estimate_time_offset(raw)
        offset_s = estimate.offset_s
        origin = OFFSET_ESTIMATED
        note = (
            f"clock offset estimated: robot clock {offset_s * 1000:.2f} ms ahead of the tracker's "
            f"({estimate.describe()})"
        )
        recording = pair_streams(raw, offset_s)
    return recording, StreamPairing(offset_s, origin, LARGEST_GAP_PERIODS, LARGEST_GAP_S), note


def _file(role: str, path: str | Path) -> SourceFile:
    return SourceFile(role, str(Path(path).resolve()), file_sha256(path))


def _origin(metadata: dict[str, Any]) -> str | None:
    origin = metadata.get("source")
    return origin if isinstance(origin, str) else None


def _recorded_pairing(metadata: dict[str, Any]) -> StreamPairing | None:
    """How a paired CSV derived from raw streams (an acquisition's) was paired, as its metadata
    says; None when it says nothing."""
    pairing = metadata.get("pairing")
    stations = metadata.get("stations_averaged")
    stations = int(stations) if isinstance(stations, int) and not isinstance(stations, bool) else None
    if not isinstance(pairing, dict):
        return None if stations is None else StreamPairing(None, "not recorded", stations_averaged=stations)
    offset = finite_or_none(pairing.get("offset_s"))
    origin = OFFSET_ESTIMATED if pairing.get("estimated") is True else OFFSET_ARRIVAL_LINK
    return StreamPairing(offset, origin, LARGEST_GAP_PERIODS, LARGEST_GAP_S, stations)


def open_path(
    path: str | Path,
    tracker_stream: str | Path | None = None,
    time_offset_s: float | None = None,
    *,
    offset_option: str = "clock offset",
    fall_back_to_link: bool = False,
) -> OpenedRecording:
    """Open a recording the user named: a paired CSV, or a raw robot stream with its tracker
    stream (named, or ``STEM.tracker.csv`` beside ``STEM.robot.csv``).

    Parameters
    ----------
    path : str or Path
        A paired recording CSV, or a raw robot stream.
    tracker_stream : str or Path, optional
        The raw tracker stream: ``path`` is then the robot stream.
    time_offset_s : float, optional
        Robot clock minus tracker clock (s) to pair raw streams at; estimated when omitted.
    offset_option : str
        What names the given offset in a refusal.
    fall_back_to_link : bool
        Pair raw streams that hold no information on the offset at the arrival-time link
        instead of refusing them (see :func:`pair_raw`).

    Returns
    -------
    OpenedRecording
        The recording with its source (each file's sha256 taken now).

    Raises
    ------
    InvalidInputError
        For a raw robot stream without its tracker stream, or a file that is no recording.
    DegenerateDataError
        For raw streams whose offset cannot be estimated (see :func:`pair_raw`).
    """
    path = Path(path)
    if tracker_stream is None and recording_kind(path) == RAW_STREAMS:
        tracker_stream = tracker_stream_beside(path)
        if tracker_stream is None:
            raise InvalidInputError(
                f"{path}: a raw robot stream; its tracker stream (STEM{TRACKER_STREAM_SUFFIX}) is not "
                "beside it: pass it with --tracker-stream"
            )
    meta = metadata_path(path)
    # read first: a file that is not there is refused by the reader, in its words
    if tracker_stream is None:
        recording = read_recording(path)
        files = [_file(RECORDING, path)] + ([_file(METADATA, meta)] if meta.is_file() else [])
        source = RecordingSource(
            PAIRED_CSV, tuple(files), _recorded_pairing(recording.metadata), _origin(recording.metadata)
        )
        return OpenedRecording(recording, source)
    raw = read_raw_recording(path, tracker_stream)
    files = [_file(RECORDING, path), _file(TRACKER_STREAM, tracker_stream)]
    files += [_file(METADATA, meta)] if meta.is_file() else []
    paired, pairing, note = pair_raw(
        raw, time_offset_s, fall_back_to_link=fall_back_to_link, what=offset_option
    )
    source = RecordingSource(RAW_STREAMS, tuple(files), pairing, _origin(raw.metadata))
    return OpenedRecording(paired, source, f"raw streams paired: {note}", note)


def refuse_changed(source: RecordingSource, accept_edited: bool = False) -> None:
    """Refuse, in one line, a source whose files changed since their sha256 was recorded (a
    file not there now is :func:`open_source`'s to refuse), unless ``accept_edited``.

    A recording changed since, or another one written over it (an acquisition started again),
    is not what the calibration describes: its residuals and figures would be shown beside
    numbers of another recording.

    Raises
    ------
    InvalidInputError
        Naming the file, both sha256 and ``--accept-edited``.
    """
    if accept_edited:
        return
    changed = changed_file(source)
    if changed is not None:
        entry, now = changed
        raise InvalidInputError(
            f"{entry.path}: changed since the calibration was made from it "
            f"(sha256 {(entry.sha256 or '')[:12]}... then, {now[:12]}... now): the calibration does not "
            f"describe it; {ACCEPT_EDITED} uses it anyway"
        )


def changed_file(source: RecordingSource) -> tuple[SourceFile, str] | None:
    """The first of ``source``'s files on disk whose sha256 is not the one recorded, with its
    sha256 now; None when every file there is as recorded (a file not there, or recorded without
    a sha256, is not compared)."""
    for entry in source.files:
        if entry.sha256 is None or not Path(entry.path).is_file():
            continue
        now = file_sha256(entry.path)
        if now != entry.sha256:
            return entry, now
    return None


def open_source(source: RecordingSource, *, accept_edited: bool = False) -> OpenedRecording:
    """Reopen a calibration's recording into the samples it was made from.

    Each file must still have its recorded sha256 (:func:`refuse_changed`); raw streams are
    paired at the recorded offset (estimated again when a file of an older version recorded
    none).

    Raises
    ------
    InvalidInputError
        A file changed (unless ``accept_edited``) or is gone.
    """
    for entry in source.files:
        if not Path(entry.path).is_file() and (entry.role != METADATA or not accept_edited):
            what = {RECORDING: "recording", TRACKER_STREAM: "tracker stream", METADATA: "metadata file"}
            raise InvalidInputError(
                f"{source.recording}: the calibration's {what[entry.role]} {entry.path} is missing"
            )
    refuse_changed(source, accept_edited)
    if source.kind == PAIRED_CSV:
        return OpenedRecording(read_recording(source.recording), source)
    assert source.tracker_stream is not None  # a raw-streams source has one
    raw = read_raw_recording(source.recording, source.tracker_stream)
    offset = source.time_offset_s
    paired, _, _ = pair_raw(raw, offset, what="the calibration's clock offset")
    if offset is None:
        estimated = float(paired.metadata["paired_with_offset_s"])
        how = f"raw streams paired at the estimated clock offset {estimated * 1000:.2f} ms"
    else:
        how = f"raw streams paired at the calibration's clock offset {offset * 1000:.2f} ms"
    return OpenedRecording(paired, source, how)


def open_calibrated_recording(
    calibration: CalibrationResult, path: str | Path | None = None, accept_edited: bool = False
) -> OpenedRecording | None:
    """The recording ``calibration`` came from (:func:`open_source`), or ``path`` when it names
    another file (opened as given, :func:`open_path`); None when there is none or it is gone.

    Raises
    ------
    InvalidInputError
        The calibration's own recording changed since it was made (unless ``accept_edited``),
        or one of its other files is missing.
    """
    source = calibration.provenance.source
    own = source is not None and (path is None or Path(path).resolve() == Path(source.recording).resolve())
    if not own:
        if path is None or not Path(path).is_file():
            return None
        return open_path(path)
    assert source is not None
    if not Path(source.recording).is_file():
        return None
    return open_source(source, accept_edited=accept_edited)


__all__ = [
    "ACCEPT_EDITED",
    "OpenedRecording",
    "changed_file",
    "open_calibrated_recording",
    "open_path",
    "open_source",
    "pair_raw",
    "refuse_changed",
]
