"""The recording file: CSV, one header row, one row per tracker frame.

Columns (extra columns are allowed and ignored)::

    time_s, segment, q1_rad .. q6_rad [, q7_rad ...],
    tcp_x_mm, tcp_y_mm, tcp_z_mm, tcp_qw, tcp_qx, tcp_qy, tcp_qz,          base_from_tcp
    marker_x_mm, marker_y_mm, marker_z_mm, marker_qw, marker_qx, marker_qy,
    marker_qz, marker_rms_mm                                               tracker_from_marker
    marker_status                                                          (optional)

An arm of more than six joints (a KUKA LBR iiwa) adds ``q7_rad`` ... after ``q6_rad``. The
joint cells may all be empty when the joints were not recorded (imports). The
marker cells are empty when the marker was not seen (``marker_rms_mm`` alone may be empty
when the tracker does not report it). ``marker_status`` is the tracker's frame status (one of
:data:`spacecal.core.ports.FRAME_STATUSES`): ``ok`` needs the marker cells, ``missing`` leaves
them empty, and any other status (``partially_out_of_volume``, ``out_of_volume``, ...) may keep
the pose the tracker reported, which estimation then leaves out by default. Files written
before the column existed read as ``ok`` where a pose is present and ``missing`` elsewhere.
Optional raw sphere centres
follow as ``sphere1_x_mm, sphere1_y_mm, sphere1_z_mm, sphere2_x_mm, ...`` (tracker frame,
empty when not seen); the likelihood estimators use them when present. Metadata (robot model, TCP in
flange, tracker, marker geometry) lives next to the CSV in ``<stem>.meta.json``; the
estimators need none of it.
"""

from __future__ import annotations

import csv
import difflib
import io
import math
import os
from pathlib import Path

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.core.ports import FRAME_MISSING, FRAME_OK, FRAME_STATUSES
from spacecal.core.strict_numbers import parse_float
from spacecal.core.text import quoted
from spacecal.core.units import check_lengths_in_mm
from spacecal.geometry.transforms import transform_from_position_quaternion, transform_to_position_quaternion
from spacecal.io.atomic import atomic_path
from spacecal.io.csv_core import (
    JOINT_COLUMNS,
    MARKER_COLUMNS,
    TCP_COLUMNS,
    check_metadata,
    check_quaternions,
    check_ranges,
    check_tcp_against_kinematics,
    drop_partial_last_row,
    format_number,
    joint_columns,
    joint_count_in_header,
    metadata_path,
    parse_number,
    sphere_columns,
)
from spacecal.io.results_json import read_json_object, write_json
from spacecal.io.text import read_text_file
from spacecal.records import Recording


def columns(joint_count: int) -> list[str]:
    """The required columns of a recording of ``joint_count`` joints, in the order written."""
    return ["time_s", "segment"] + joint_columns(joint_count) + TCP_COLUMNS + MARKER_COLUMNS


#: The required columns of a six-joint (UR) recording.
COLUMNS = columns(len(JOINT_COLUMNS))
#: The tracker's frame status; optional when reading (older files), always written.
STATUS_COLUMN = "marker_status"

#: Smallest number of samples a recording must hold to be worth calibrating from.
MIN_SAMPLES = 10


class RecordingWriter:
    """Append samples to a recording CSV, flushing each row to disk as it is written.

    Acquisition must never lose data: a fault mid-run leaves every row written so far in a
    readable file. Use as a context manager.

    Parameters
    ----------
    path : str or Path
    metadata : dict, optional
        Written to ``<stem>.meta.json``.
    sphere_count : int, optional
        Raw-sphere columns to add; by default one triple per sphere of the marker in the
        metadata (0 without one).
    append : bool
        Continue an existing file (resume), keeping its header.
    joint_count : int
        Joints per row (six for a UR arm; more add ``q7_rad`` ... columns).
    """

    def __init__(
        self,
        path: str | Path,
        metadata: dict | None = None,
        sphere_count: int | None = None,
        append: bool = False,
        joint_count: int = len(JOINT_COLUMNS),
    ):
        self.path = Path(path)
        self.joint_count = joint_count
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if append and self.path.is_file() and self.path.stat().st_size > 0:
            drop_partial_last_row(self.path)
            header = read_text_file(self.path, "recording").splitlines()[0].split(",")
            self.sphere_count = sum(1 for c in header if c.startswith("sphere") and c.endswith("_x_mm"))
            self.has_status = STATUS_COLUMN in header  # a file from before the column keeps its layout
            self.joint_count = joint_count_in_header([c.strip() for c in header])
            self._file = open(self.path, "a", newline="")
            self._writer = csv.writer(self._file)
            return
        if sphere_count is None:
            sphere_count = len((metadata or {}).get("marker", {}).get("spheres_in_marker_mm", []))
        self.sphere_count = sphere_count
        self.has_status = True
        if metadata is not None:
            write_json(metadata, metadata_path(self.path))
        self._file = open(self.path, "w", newline="")
        self._writer = csv.writer(self._file)
        self._writer.writerow(columns(joint_count) + [STATUS_COLUMN] + sphere_columns(sphere_count))
        self._flush()

    def _flush(self) -> None:
        self._file.flush()
        os.fsync(self._file.fileno())

    def append(
        self,
        time_s: float,
        segment: str,
        joints_rad,
        base_from_tcp,
        tracker_from_marker=None,
        marker_rms_mm: float = float("nan"),
        spheres_in_tracker=None,
        flush: bool = True,
        status: str | None = None,
    ) -> None:
        """Write one sample; ``tracker_from_marker`` None (or NaN) when the marker was not seen.

        ``spheres_in_tracker`` (K, 3), mm, fills the raw-sphere columns when the writer has them.
        ``status`` is the tracker's frame status (default: ``ok`` with a pose, ``missing``
        without); a pose reported with another status is written with it. A ``missing`` frame
        never carries a pose and an ``ok`` frame without one is ``missing``.
        """
        has_pose = tracker_from_marker is not None and bool(np.all(np.isfinite(tracker_from_marker)))
        if status is None or status == FRAME_OK:
            status = FRAME_OK if has_pose else FRAME_MISSING
        elif status not in FRAME_STATUSES:
            raise InvalidInputError(
                f"unknown marker status {status!r}; expected one of {', '.join(FRAME_STATUSES)}"
            )
        if status == FRAME_MISSING:
            has_pose = False
        tcp_position, tcp_quaternion = transform_to_position_quaternion(base_from_tcp)
        joints = np.asarray(joints_rad, dtype=float).ravel()
        if len(joints) != self.joint_count:
            raise InvalidInputError(
                f"{self.path}: {len(joints)} joint angles for a recording of {self.joint_count} joints"
            )
        row = [format_number(time_s), segment] + [format_number(v) for v in joints]
        row += [format_number(v) for v in tcp_position] + [format_number(v) for v in tcp_quaternion]
        if not has_pose:
            row += [""] * len(MARKER_COLUMNS)
        else:
            position, quaternion = transform_to_position_quaternion(tracker_from_marker)
            row += (
                [format_number(v) for v in position]
                + [format_number(v) for v in quaternion]
                + [format_number(marker_rms_mm)]
            )
        if self.has_status:
            row.append(status)
        if self.sphere_count:
            spheres = (
                np.full(3 * self.sphere_count, np.nan)
                if spheres_in_tracker is None
                else np.asarray(spheres_in_tracker, dtype=float).reshape(-1)
            )
            row += [format_number(v) for v in spheres]
        self._writer.writerow(row)
        if flush:
            self._flush()

    def close(self) -> None:
        if not self._file.closed:
            self._flush()
            self._file.close()

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def last_time_s(path: str | Path) -> float | None:
    """The time of the last complete row of a recording (None without one), to continue it."""
    path = Path(path)
    if not path.is_file():
        return None
    lines = read_text_file(path, "recording").splitlines()
    if len(lines) < 2:
        return None
    header = [h.strip() for h in next(csv.reader([lines[0]]))]
    if "time_s" not in header:
        return None
    column = header.index("time_s")
    for line in reversed(lines[1:]):
        cells = next(csv.reader([line]), [])
        if len(cells) == len(header):
            try:
                value = parse_float(cells[column])
            except ValueError:
                continue
            if math.isfinite(value):
                return value
    return None


def write_recording(recording: Recording, path: str | Path) -> Path:
    """Write a recording and its metadata (``<stem>.meta.json``), each atomically (a temporary
    file renamed into place), so an interruption never leaves half a recording; returns the
    CSV path."""
    spheres = recording.spheres_in_tracker
    count = 0 if spheres is None else spheres.shape[1]
    if recording.metadata:
        write_json(recording.metadata, metadata_path(path))
    with (
        atomic_path(path) as temporary,
        RecordingWriter(temporary, None, count, joint_count=recording.joints_rad.shape[1]) as writer,
    ):
        for k in range(len(recording)):
            writer.append(
                recording.time_s[k],
                str(recording.segment[k]),
                recording.joints_rad[k],
                recording.base_from_tcp_stack[k],
                recording.tracker_from_marker_stack[k],
                recording.marker_rms_mm[k],
                None if spheres is None else spheres[k],
                flush=False,
                status=str(recording.marker_status[k]) if recording.marker_status is not None else None,
            )
    return Path(path)


def _check_header(header: list[str], path: Path) -> dict[str, int]:
    names = [h.strip() for h in header]
    missing = [c for c in COLUMNS if c not in names]
    if missing:
        hints = []
        unrecognised = [n for n in names if n not in COLUMNS]
        for column in missing:
            close = difflib.get_close_matches(column, unrecognised, n=1, cutoff=0.6)
            hints.append(f"{column} (found {quoted(close[0])}?)" if close else column)
        raise InvalidInputError(f"{path}: missing column(s): {', '.join(hints)}")
    return {c: names.index(c) for c in COLUMNS}


def read_recording(path: str | Path) -> Recording:
    """Read and validate a recording CSV (and its metadata, if present).

    Raises
    ------
    InvalidInputError
        With one line naming the problem: empty file, missing or misspelt columns, NaN or
        text in numeric cells, partly empty marker cells, non-increasing time, non-unit
        quaternions, lengths that look like metres, too few samples, no visible sample.
    """
    path = Path(path)
    if not path.is_file():
        raise InvalidInputError(f"{path}: no such recording file")
    rows = list(csv.reader(io.StringIO(read_text_file(path, "recording"), newline="")))
    rows = [r for r in rows if any(cell.strip() for cell in r)]
    if not rows:
        raise InvalidInputError(f"{path}: the recording is empty")
    index = _check_header(rows[0], path)
    body = rows[1:]
    if len(body) < MIN_SAMPLES:
        raise InvalidInputError(
            f"{path}: the recording has {len(body)} samples; at least {MIN_SAMPLES} are needed"
        )

    names = [h.strip() for h in rows[0]]
    sphere_count = 0
    while all(c in names for c in sphere_columns(sphere_count + 1)[-3:]):
        sphere_count += 1
    sphere_index = [names.index(c) for c in sphere_columns(sphere_count)]
    status_index = names.index(STATUS_COLUMN) if STATUS_COLUMN in names else None
    n = len(body)
    status_cells: list[str] = []
    spheres = np.full((n, 3 * sphere_count), np.nan) if sphere_count else None
    joint_names = joint_columns(joint_count_in_header(names))
    joint_count = len(joint_names)
    numeric = joint_names + TCP_COLUMNS
    index.update({c: names.index(c) for c in joint_names})
    values = np.empty((n, len(numeric)))
    marker = np.full((n, len(MARKER_COLUMNS)), np.nan)
    time_s = np.empty(n)
    segment = []
    lines = np.arange(2, n + 2)
    for k, row in enumerate(body):
        line = k + 2
        # a cell beyond the header is a value without a column (a shifted row): refused, as a
        # missing cell is; empty ones (a spreadsheet's trailing comma) are nothing
        if len(row) < len(rows[0]) or any(cell.strip() for cell in row[len(rows[0]) :]):
            raise InvalidInputError(
                f"{path}: line {line} has {len(row)} cells; the header has {len(rows[0])}"
            )
        time_s[k] = parse_number(row[index["time_s"]], line, "time_s", path)
        segment.append(row[index["segment"]].strip())
        joint_cells = [row[index[c]].strip() for c in joint_names]
        if not any(joint_cells):
            values[k, :joint_count] = np.nan  # joints not recorded (e.g. imported from a tracker-only source)
        for j, column in enumerate(numeric):
            if j < joint_count and not any(joint_cells):
                continue
            values[k, j] = parse_number(row[index[column]], line, column, path)
        cells = [row[index[c]].strip() for c in MARKER_COLUMNS]
        pose_cells = cells[:7]  # marker_rms_mm may be empty: some trackers (OpenIGTLink) do not report it
        if any(cells):
            if not all(pose_cells):
                raise InvalidInputError(
                    f"{path}: line {line}: marker cells are partly empty; leave all of them empty "
                    "when the marker was not seen"
                )
            marker[k, :7] = [parse_number(c, line, name, path) for c, name in zip(pose_cells, MARKER_COLUMNS)]
            if cells[7]:
                marker[k, 7] = parse_number(cells[7], line, MARKER_COLUMNS[7], path)
            if spheres is not None and any(row[i].strip() for i in sphere_index):
                spheres[k] = [parse_number(row[i], line, names[i], path) for i in sphere_index]
        status_cells.append(row[status_index].strip() if status_index is not None else "")

    steps = np.diff(time_s)
    if np.any(steps <= 0):
        k = int(np.flatnonzero(steps <= 0)[0]) + 1
        raise InvalidInputError(
            f"{path}: time_s is not increasing at line {k + 2} "
            f"({float(time_s[k]):g} s after {float(time_s[k - 1]):g} s)"
        )
    joints = values[:, :joint_count]
    tcp_position = values[:, joint_count : joint_count + 3]
    tcp_quaternion = values[:, joint_count + 3 : joint_count + 7]
    seen = np.isfinite(marker[:, 0])
    if not seen.any():
        raise InvalidInputError(f"{path}: the marker was not visible in any of the {n} samples")
    # checked after the rows' own cells, so a file whose marker cells were all blanked says so
    status = np.array([_status(c, bool(p), int(ln), path) for c, p, ln in zip(status_cells, seen, lines)])
    check_quaternions(tcp_quaternion, lines, "tcp", path)
    check_quaternions(marker[seen, 3:7], lines[seen], "marker", path)
    check_lengths_in_mm(tcp_position, f"{path}: tcp_x_mm..tcp_z_mm")
    check_lengths_in_mm(marker[seen, :3], f"{path}: marker_x_mm..marker_z_mm")

    check_ranges(path, lines, time_s, joints, tcp_position, marker[:, :3], marker[:, 7])

    tracker_from_marker = np.full((n, 4, 4), np.nan)
    tracker_from_marker[seen] = transform_from_position_quaternion(marker[seen, :3], marker[seen, 3:7])
    meta_file = metadata_path(path)
    metadata = read_json_object(meta_file, "recording metadata") if meta_file.is_file() else {}
    check_metadata(metadata, meta_file)
    base_from_tcp = transform_from_position_quaternion(tcp_position, tcp_quaternion)
    check_tcp_against_kinematics(joints, base_from_tcp, metadata, path)
    return Recording(
        time_s=time_s,
        segment=np.array(segment),
        joints_rad=joints,
        base_from_tcp_stack=base_from_tcp,
        tracker_from_marker_stack=tracker_from_marker,
        marker_rms_mm=marker[:, 7],
        metadata=metadata,
        spheres_in_tracker=None if spheres is None else spheres.reshape(n, sphere_count, 3),
        marker_status=status,
    )


def _status(cell: str, has_pose: bool, line: int, path: Path) -> str:
    """One ``marker_status`` cell, checked against the marker cells; empty (or no column) means
    ``ok`` with a pose and ``missing`` without."""
    if not cell:
        return FRAME_OK if has_pose else FRAME_MISSING
    if cell not in FRAME_STATUSES:
        raise InvalidInputError(
            f"{path}: line {line}: marker_status {quoted(cell)} is not one of {', '.join(FRAME_STATUSES)}"
        )
    if cell == FRAME_OK and not has_pose:
        raise InvalidInputError(f"{path}: line {line}: marker_status is ok but the marker cells are empty")
    if cell == FRAME_MISSING and has_pose:
        raise InvalidInputError(
            f"{path}: line {line}: marker_status is missing but the marker cells hold a pose"
        )
    return cell
