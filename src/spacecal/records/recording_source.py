"""Where a calibration's recording came from: its files, their sha256, and how it was paired.

A :class:`RecordingSource` is what a calibration's provenance says of its recording, so that
``report``, ``verify``, ``check`` and ``bound`` reopen exactly the samples it was made from
(:func:`spacecal.io.recording_source.open_source`), and refuse them once the files changed.

Two kinds of file hold a recording; every importer writes one of them (the ``origin`` says
which importer, as the recording's metadata names it):

``paired_csv``
    One paired recording CSV, each tracker frame beside its robot state (``spacecal simulate``,
    ``acquire``, ``import-plus``, ``import-easy-handeye``, ``import-bag`` of a paired bag).
``raw_streams``
    A robot stream and a tracker stream on their own clocks (``acquire``'s raw files,
    ``simulate --raw``, ``import-bag``, ``import-poses``), paired at a clock offset
    (:class:`StreamPairing`).

Calibration files written before this record (schema 2 and 3 without ``provenance.source``)
held the same facts in loose provenance fields and ``diagnostics["time_offset_s"]``;
:meth:`RecordingSource.from_old_provenance` reads them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from spacecal.core.errors import InvalidInputError
from spacecal.records.integrity import is_sha256

PAIRED_CSV = "paired_csv"
RAW_STREAMS = "raw_streams"
#: The kinds of recording file (see the module's docstring).
RECORDING_KINDS = (PAIRED_CSV, RAW_STREAMS)

#: The roles of a recording's files: the paired CSV or the robot stream, the tracker stream
#: beside a robot stream, and the metadata file of either.
RECORDING, TRACKER_STREAM, METADATA = "recording", "tracker_stream", "metadata"
FILE_ROLES = (RECORDING, TRACKER_STREAM, METADATA)

#: Where a pairing's clock offset came from: estimated from the streams, given by the user,
#: the arrival-time link (the streams held no information on it), or not recorded (a
#: calibration file written before the origin was).
OFFSET_ESTIMATED, OFFSET_GIVEN, OFFSET_ARRIVAL_LINK, OFFSET_NOT_RECORDED = (
    "estimated",
    "given",
    "arrival link",
    "not recorded",
)
OFFSET_ORIGINS = (OFFSET_ESTIMATED, OFFSET_GIVEN, OFFSET_ARRIVAL_LINK, OFFSET_NOT_RECORDED)


def _optional_number(data: Mapping[str, Any], key: str, what: str) -> float | None:
    value = data.get(key)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InvalidInputError(f"{what}: {key!r} must be a finite number or null")
    return float(value)


def finite_or_none(value: Any) -> float | None:
    """``value`` as a finite number, or None for anything else: a clock offset an older file or
    a recording's metadata states, which is estimated again when it is unusable."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return None
    return float(value)


def _optional_str(data: Mapping[str, Any], key: str, what: str) -> str | None:
    value = data.get(key)
    if value is not None and not isinstance(value, str):
        raise InvalidInputError(f"{what}: {key!r} must be a string or null")
    return value


@dataclass(frozen=True)
class SourceFile:
    """One file of a recording.

    Attributes
    ----------
    role : str
        One of :data:`FILE_ROLES`.
    path : str
        Absolute path when the calibration was made.
    sha256 : str or None
        Its sha256 then (None: not taken, as in files of older versions).
    """

    role: str
    path: str
    sha256: str | None = None

    def __post_init__(self) -> None:
        if self.role not in FILE_ROLES:
            raise InvalidInputError(f"recording source: file role {self.role!r} is not one of {FILE_ROLES}")
        if not isinstance(self.path, str) or not self.path:
            raise InvalidInputError(f"recording source: the {self.role}'s path must be a non-empty string")
        if self.sha256 is not None and not is_sha256(self.sha256):
            raise InvalidInputError(
                f"recording source: the {self.role}'s sha256 must be 64 hex digits or null"
            )

    def to_dict(self) -> dict[str, Any]:
        return {"role": self.role, "path": self.path, "sha256": self.sha256}

    @classmethod
    def from_dict(cls, data: Any, what: str) -> SourceFile:
        if not isinstance(data, Mapping):
            raise InvalidInputError(f"{what}: each of 'files' must be an object")
        role, path = data.get("role"), data.get("path")
        if not isinstance(role, str) or not isinstance(path, str):
            raise InvalidInputError(f"{what}: a file's 'role' and 'path' must be strings")
        try:
            return cls(role, path, _optional_str(data, "sha256", what))
        except InvalidInputError as exc:
            raise InvalidInputError(f"{what}: {exc}") from None


@dataclass(frozen=True)
class StreamPairing:
    """How two raw streams were paired into samples.

    A tracker frame at tracker time ``t`` is paired with the robot state interpolated at robot
    time ``t + offset_s``; frames in a gap of the robot stream longer than ``max_gap_periods``
    median robot periods or ``max_gap_s`` (whichever is longer) are dropped.

    Attributes
    ----------
    offset_s : float or None
        Robot clock minus tracker clock, s; None when not recorded (reopening estimates it).
    offset_origin : str
        One of :data:`OFFSET_ORIGINS`.
    max_gap_periods, max_gap_s : float or None
        The gap rule above (None: not recorded, files of older versions).
    stations_averaged : int or None
        Stations averaged into one sample each (a stop-and-go run), None when none were.
    """

    offset_s: float | None
    offset_origin: str
    max_gap_periods: float | None = None
    max_gap_s: float | None = None
    stations_averaged: int | None = None

    def __post_init__(self) -> None:
        if self.offset_origin not in OFFSET_ORIGINS:
            raise InvalidInputError(
                f"recording source: offset origin {self.offset_origin!r} is not one of {OFFSET_ORIGINS}"
            )
        if self.offset_s is not None and not math.isfinite(self.offset_s):
            raise InvalidInputError("recording source: the clock offset must be a finite number of s")

    def to_dict(self) -> dict[str, Any]:
        return {
            "offset_s": self.offset_s,
            "offset_origin": self.offset_origin,
            "offset_definition": "robot clock minus tracker clock",
            "max_gap_periods": self.max_gap_periods,
            "max_gap_s": self.max_gap_s,
            "stations_averaged": self.stations_averaged,
        }

    @classmethod
    def from_dict(cls, data: Any, what: str) -> StreamPairing:
        if not isinstance(data, Mapping):
            raise InvalidInputError(f"{what}: 'pairing' must be an object")
        origin = data.get("offset_origin", OFFSET_NOT_RECORDED)
        if origin not in OFFSET_ORIGINS:
            raise InvalidInputError(
                f"{what}: pairing 'offset_origin' must be one of {', '.join(OFFSET_ORIGINS)}"
            )
        stations = _optional_number(data, "stations_averaged", what)
        return cls(
            _optional_number(data, "offset_s", what),
            origin,
            _optional_number(data, "max_gap_periods", what),
            _optional_number(data, "max_gap_s", what),
            None if stations is None else int(stations),
        )


@dataclass(frozen=True)
class RecordingSource:
    """A recording as a calibration was made from it.

    Attributes
    ----------
    kind : str
        One of :data:`RECORDING_KINDS`.
    files : tuple of SourceFile
        Its files: the ``recording`` (the paired CSV, or the robot stream), for raw streams the
        ``tracker_stream``, and the ``metadata`` file where there was one.
    pairing : StreamPairing or None
        How raw streams were paired (for a paired CSV: how it was paired when it was made,
        where its metadata says so, as an acquisition's does; else None).
    origin : str or None
        Where the recording came from, as its metadata's ``source`` says (``spacecal
        acquire``, ``TUM import``, ``PLUS sequence ...``, ``easy_handeye2 samples``, ...).
    """

    kind: str
    files: tuple[SourceFile, ...]
    pairing: StreamPairing | None = None
    origin: str | None = None

    def __post_init__(self) -> None:
        if self.kind not in RECORDING_KINDS:
            raise InvalidInputError(f"recording source: kind {self.kind!r} is not one of {RECORDING_KINDS}")
        roles = [f.role for f in self.files]
        if roles.count(RECORDING) != 1 or len(set(roles)) != len(roles):
            raise InvalidInputError("recording source: one recording file, and each role at most once")
        if (TRACKER_STREAM in roles) != (self.kind == RAW_STREAMS):
            raise InvalidInputError("recording source: raw streams have a tracker stream, a paired CSV none")
        object.__setattr__(self, "files", tuple(self.files))

    @classmethod
    def paired_csv(cls, path: str, sha256: str | None = None) -> RecordingSource:
        """A paired CSV alone (no metadata file recorded), its sha256 if known."""
        return cls(PAIRED_CSV, (SourceFile(RECORDING, path, sha256),))

    def file(self, role: str) -> SourceFile | None:
        """The file of ``role`` (:data:`FILE_ROLES`), None when there is none."""
        return next((f for f in self.files if f.role == role), None)

    @property
    def recording(self) -> str:
        """The paired CSV, or the robot stream of raw streams (absolute path)."""
        found = self.file(RECORDING)
        assert found is not None  # checked on construction
        return found.path

    @property
    def recording_sha256(self) -> str | None:
        found = self.file(RECORDING)
        return None if found is None else found.sha256

    @property
    def tracker_stream(self) -> str | None:
        found = self.file(TRACKER_STREAM)
        return None if found is None else found.path

    @property
    def tracker_stream_sha256(self) -> str | None:
        found = self.file(TRACKER_STREAM)
        return None if found is None else found.sha256

    @property
    def time_offset_s(self) -> float | None:
        """The clock offset raw streams were paired at (robot minus tracker, s), None for a
        paired CSV or when not recorded."""
        if self.kind != RAW_STREAMS or self.pairing is None:
            return None
        return self.pairing.offset_s

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "files": [f.to_dict() for f in self.files],
            "pairing": None if self.pairing is None else self.pairing.to_dict(),
            "origin": self.origin,
        }

    @classmethod
    def from_dict(cls, data: Any, what: str = "recording source") -> RecordingSource:
        if not isinstance(data, Mapping):
            raise InvalidInputError(f"{what}: must be an object")
        kind, files = data.get("kind"), data.get("files")
        if kind not in RECORDING_KINDS:
            raise InvalidInputError(f"{what}: 'kind' must be one of {', '.join(RECORDING_KINDS)}")
        if not isinstance(files, list):
            raise InvalidInputError(f"{what}: 'files' must be a list")
        pairing = data.get("pairing")
        try:
            return cls(
                kind,
                tuple(SourceFile.from_dict(f, what) for f in files),
                None if pairing is None else StreamPairing.from_dict(pairing, what),
                _optional_str(data, "origin", what),
            )
        except InvalidInputError as exc:
            message = str(exc)
            raise InvalidInputError(message if message.startswith(what) else f"{what}: {message}") from None

    @classmethod
    def from_old_provenance(
        cls, provenance: Mapping[str, Any], older_keys: Mapping[str, Any], what: str
    ) -> RecordingSource | None:
        """The source a calibration file of an older version describes in loose fields:
        ``provenance.recording`` / ``recording_sha256`` / ``tracker_stream`` /
        ``tracker_stream_sha256`` and the offset ``time_offset_s`` in ``older_keys`` (that
        file's diagnostics object); None when it names no recording."""
        recording = _optional_str(provenance, "recording", f"{what}: provenance")
        if not recording:
            return None
        stream = _optional_str(provenance, "tracker_stream", f"{what}: provenance")
        files = [SourceFile(RECORDING, recording, _old_digest(provenance, "recording_sha256", what))]
        if not stream:
            return cls(PAIRED_CSV, tuple(files))
        files.append(
            SourceFile(TRACKER_STREAM, stream, _old_digest(provenance, "tracker_stream_sha256", what))
        )
        offset = finite_or_none(older_keys.get("time_offset_s"))
        return cls(RAW_STREAMS, tuple(files), StreamPairing(offset, OFFSET_NOT_RECORDED))


def _old_digest(provenance: Mapping[str, Any], key: str, what: str) -> str | None:
    value = provenance.get(key)
    if value is not None and not is_sha256(value):
        raise InvalidInputError(f"{what}: provenance {key!r} must be a sha256 (64 hex digits) or null")
    return value
