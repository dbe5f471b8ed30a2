"""The recording file: CSV, one header row, one row per tracker frame.

Columns (extra columns are allowed and ignored)::

    time_s, segment, q1_rad .. q6_rad,
    tcp_x_mm, tcp_y_mm, tcp_z_mm, tcp_qw, tcp_qx, tcp_qy, tcp_qz,          base_from_tcp
    marker_x_mm, marker_y_mm, marker_z_mm, marker_qw, marker_qx, marker_qy,
    marker_qz, marker_rms_mm                                               tracker_from_marker
    marker_status                                                          (optional)

The six joint cells may all be empty when the joints were not recorded (imports). The
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
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.core.ports import FRAME_MISSING, FRAME_OK, FRAME_STATUSES
from spacecal.core.text import quoted
from spacecal.core.units import check_lengths_in_mm
from spacecal.geometry.transforms import transform_from_position_quaternion, transform_to_position_quaternion
from spacecal.io.atomic import atomic_path
from spacecal.io.results_json import read_json_object, write_json
from spacecal.io.strict_numbers import parse_float
from spacecal.io.text import read_text_file
from spacecal.records import Recording

JOINT_COLUMNS = [f"q{i}_rad" for i in range(1, 7)]
TCP_COLUMNS = ["tcp_x_mm", "tcp_y_mm", "tcp_z_mm", "tcp_qw", "tcp_qx", "tcp_qy", "tcp_qz"]
MARKER_COLUMNS = [
    "marker_x_mm",
    "marker_y_mm",
    "marker_z_mm",
    "marker_qw",
    "marker_qx",
    "marker_qy",
    "marker_qz",
    "marker_rms_mm",
]
COLUMNS = ["time_s", "segment"] + JOINT_COLUMNS + TCP_COLUMNS + MARKER_COLUMNS
#: The tracker's frame status; optional when reading (older files), always written.
STATUS_COLUMN = "marker_status"

#: Smallest number of samples a recording must hold to be worth calibrating from.
MIN_SAMPLES = 10
#: Largest deviation of a quaternion's norm from 1 that is taken for rounding.
QUATERNION_NORM_TOLERANCE = 1e-3
#: Plausible ranges of the numeric columns: times (s; ROS stamps are seconds since 1970),
#: joint angles (rad; UR joints turn +-2 pi, a simulated arm may wind further), positions
#: (mm), the tracker's fit RMS (mm).
MAX_ABS_TIME_S = 1e10
MAX_ABS_JOINT_RAD = 4 * math.pi
MAX_ABS_POSITION_MM = 1e5
MAX_MARKER_RMS_MM = 10.0
#: Largest distance (mm) and angle (deg) between a recorded TCP pose and the forward
#: kinematics of the recorded joints: beyond them the TCP columns are in another unit, another
#: quaternion order, or hold the marker's pose. A controller's own calibration moves the TCP
#: by a few mm at most.
TCP_KINEMATICS_TOLERANCE_MM = 20.0
TCP_KINEMATICS_TOLERANCE_DEG = 5.0
#: Share of rows allowed beyond those tolerances.
TCP_KINEMATICS_BAD_FRACTION = 0.05


def sphere_columns(count: int) -> list[str]:
    """Names of the optional raw-sphere columns for ``count`` spheres."""
    return [f"sphere{k}_{axis}_mm" for k in range(1, count + 1) for axis in "xyz"]


#: The raw robot stream's suffix: its metadata is that of the whole stem.
RAW_ROBOT_SUFFIX = ".robot.csv"


def metadata_path(recording_path: str | Path) -> Path:
    """``rec.csv`` -> ``rec.meta.json``; a raw robot stream ``STEM.robot.csv`` -> ``STEM.meta.json``."""
    path = Path(recording_path)
    if path.name.endswith(RAW_ROBOT_SUFFIX):
        return path.with_name(path.name[: -len(RAW_ROBOT_SUFFIX)] + ".meta.json")
    return path.with_name(path.stem + ".meta.json")


def _format(value: float) -> str:
    return "" if not math.isfinite(value) else repr(float(value))


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
    """

    def __init__(
        self,
        path: str | Path,
        metadata: dict | None = None,
        sphere_count: int | None = None,
        append: bool = False,
    ):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if append and self.path.is_file() and self.path.stat().st_size > 0:
            _drop_partial_last_row(self.path)
            header = read_text_file(self.path, "recording").splitlines()[0].split(",")
            self.sphere_count = sum(1 for c in header if c.startswith("sphere") and c.endswith("_x_mm"))
            self.has_status = STATUS_COLUMN in header  # a file from before the column keeps its layout
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
        self._writer.writerow(COLUMNS + [STATUS_COLUMN] + sphere_columns(sphere_count))
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
        row = [_format(time_s), segment] + [_format(v) for v in joints_rad]
        row += [_format(v) for v in tcp_position] + [_format(v) for v in tcp_quaternion]
        if not has_pose:
            row += [""] * len(MARKER_COLUMNS)
        else:
            position, quaternion = transform_to_position_quaternion(tracker_from_marker)
            row += (
                [_format(v) for v in position] + [_format(v) for v in quaternion] + [_format(marker_rms_mm)]
            )
        if self.has_status:
            row.append(status)
        if self.sphere_count:
            spheres = (
                np.full(3 * self.sphere_count, np.nan)
                if spheres_in_tracker is None
                else np.asarray(spheres_in_tracker, dtype=float).reshape(-1)
            )
            row += [_format(v) for v in spheres]
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


def _drop_partial_last_row(path: Path) -> None:
    """Cut a row that an interruption left half-written (no line end) before appending."""
    with open(path, "rb+") as handle:
        data = handle.read()
        if data and not data.endswith(b"\n"):  # an interrupted row; the header stays
            if b"\n" not in data:
                raise InvalidInputError(f"{path}: the recording has no complete header row")
            handle.truncate(data.rfind(b"\n") + 1)


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
    with atomic_path(path) as temporary, RecordingWriter(temporary, None, count) as writer:
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


def _number(cell: str, line: int, column: str, path: Path) -> float:
    try:
        value = parse_float(cell)
    except ValueError:
        raise InvalidInputError(
            f"{path}: line {line}, column {column}: {quoted(cell)} is not a number"
            + (" (digit groups with '_' are not accepted)" if "_" in cell else "")
        ) from None
    if not math.isfinite(value):
        raise InvalidInputError(
            f"{path}: line {line}, column {column}: {quoted(cell)} is not a finite number"
        )
    return value


def _check_quaternions(quaternions: np.ndarray, lines: np.ndarray, what: str, path: Path) -> None:
    norms = np.linalg.norm(quaternions, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > QUATERNION_NORM_TOLERANCE)
    if len(bad):
        k = bad[0]
        raise InvalidInputError(
            f"{path}: line {lines[k]}: {what} quaternion has norm {norms[k]:.4f}; quaternions must "
            f"be unit ({len(bad)} row(s) affected)"
        )


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
    numeric = JOINT_COLUMNS + TCP_COLUMNS
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
        time_s[k] = _number(row[index["time_s"]], line, "time_s", path)
        segment.append(row[index["segment"]].strip())
        joint_cells = [row[index[c]].strip() for c in JOINT_COLUMNS]
        if not any(joint_cells):
            values[k, :6] = np.nan  # joints not recorded (e.g. imported from a tracker-only source)
        for j, column in enumerate(numeric):
            if j < 6 and not any(joint_cells):
                continue
            values[k, j] = _number(row[index[column]], line, column, path)
        cells = [row[index[c]].strip() for c in MARKER_COLUMNS]
        pose_cells = cells[:7]  # marker_rms_mm may be empty: some trackers (OpenIGTLink) do not report it
        if any(cells):
            if not all(pose_cells):
                raise InvalidInputError(
                    f"{path}: line {line}: marker cells are partly empty; leave all of them empty "
                    "when the marker was not seen"
                )
            marker[k, :7] = [_number(c, line, name, path) for c, name in zip(pose_cells, MARKER_COLUMNS)]
            if cells[7]:
                marker[k, 7] = _number(cells[7], line, MARKER_COLUMNS[7], path)
            if spheres is not None and any(row[i].strip() for i in sphere_index):
                spheres[k] = [_number(row[i], line, names[i], path) for i in sphere_index]
        status_cells.append(row[status_index].strip() if status_index is not None else "")

    steps = np.diff(time_s)
    if np.any(steps <= 0):
        k = int(np.flatnonzero(steps <= 0)[0]) + 1
        raise InvalidInputError(
            f"{path}: time_s is not increasing at line {k + 2} "
            f"({float(time_s[k]):g} s after {float(time_s[k - 1]):g} s)"
        )
    joints = values[:, :6]
    tcp_position, tcp_quaternion = values[:, 6:9], values[:, 9:13]
    seen = np.isfinite(marker[:, 0])
    if not seen.any():
        raise InvalidInputError(f"{path}: the marker was not visible in any of the {n} samples")
    # checked after the rows' own cells, so a file whose marker cells were all blanked says so
    status = np.array([_status(c, bool(p), int(ln), path) for c, p, ln in zip(status_cells, seen, lines)])
    _check_quaternions(tcp_quaternion, lines, "tcp", path)
    _check_quaternions(marker[seen, 3:7], lines[seen], "marker", path)
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


def check_ranges(
    path: Path,
    lines: np.ndarray,
    time_s: np.ndarray,
    joints_rad: np.ndarray,
    tcp_in_base_mm: np.ndarray,
    marker_in_tracker_mm: np.ndarray,
    marker_rms_mm: np.ndarray,
) -> None:
    """Refuse numbers that are finite but absurd (1e308, a joint at 1000 rad, a negative RMS).

    Arrays are rows of the file (NaN where a cell is empty); ``lines`` (N,) are their line
    numbers.
    """
    checks = (
        ("time_s", time_s[:, None], -MAX_ABS_TIME_S, MAX_ABS_TIME_S, "s"),
        ("q1_rad..q6_rad", joints_rad, -MAX_ABS_JOINT_RAD, MAX_ABS_JOINT_RAD, "rad"),
        ("tcp_x_mm..tcp_z_mm", tcp_in_base_mm, -MAX_ABS_POSITION_MM, MAX_ABS_POSITION_MM, "mm"),
        ("marker_x_mm..marker_z_mm", marker_in_tracker_mm, -MAX_ABS_POSITION_MM, MAX_ABS_POSITION_MM, "mm"),
        ("marker_rms_mm", marker_rms_mm[:, None], 0.0, MAX_MARKER_RMS_MM, "mm"),
    )
    for name, values, low, high, unit in checks:
        with np.errstate(invalid="ignore"):
            bad = np.flatnonzero(np.any((values < low) | (values > high), axis=1))
        if len(bad):
            k = bad[0]
            value = values[k][(values[k] < low) | (values[k] > high)][0]
            raise InvalidInputError(
                f"{path}: line {lines[k]}: {name} {value:.6g} is outside {low:g}..{high:g} {unit} "
                f"({len(bad)} row(s) affected)"
            )


def check_metadata(metadata: Mapping, path: Path) -> None:
    """Refuse recording metadata whose known keys have the wrong type or unit."""
    for key in ("robot", "tracker", "marker", "scenario", "units", "frames"):
        if key in metadata and metadata[key] is not None and not isinstance(metadata[key], Mapping):
            raise InvalidInputError(f"{path}: {key!r} must be an object, got {type(metadata[key]).__name__}")
    if "source" in metadata and not isinstance(metadata["source"], str):
        raise InvalidInputError(f"{path}: 'source' must be a string, got {type(metadata['source']).__name__}")
    if "simulated" in metadata and metadata["simulated"] is not None:
        if not isinstance(metadata["simulated"], bool):
            raise InvalidInputError(f"{path}: 'simulated' must be true or false")
    length = (metadata.get("units") or {}).get("length", "mm")
    if length != "mm":
        raise InvalidInputError(f"{path}: units.length is {quoted(length)}; spacecal recordings are in 'mm'")
    robot = metadata.get("robot") or {}
    if "model" in robot and not isinstance(robot["model"], str):
        raise InvalidInputError(f"{path}: robot.model must be a string such as 'UR10'")
    if "flange_from_tcp" in robot:
        from spacecal.records.fields import as_transform

        as_transform(robot["flange_from_tcp"], "robot.flange_from_tcp", str(path))


def check_tcp_against_kinematics(
    joints_rad: np.ndarray, base_from_tcp_stack: np.ndarray, metadata: Mapping, path: Path
) -> None:
    """Refuse TCP columns that disagree with the forward kinematics of the recorded joints.

    The robot model and the TCP in the flange come from the metadata, so the scale is known:
    TCP positions in cm or inches, quaternions in x, y, z, w order or conjugated, or the
    marker's pose in the TCP columns all put the recorded TCP far from where the joints put
    it. Without joints or a known UR model there is nothing to compare with.

    Parameters
    ----------
    joints_rad : numpy.ndarray, shape (N, 6)
        NaN rows where the joints were not recorded.
    base_from_tcp_stack : numpy.ndarray, shape (N, 4, 4)
        The recorded TCP poses, mm.
    """
    from spacecal.models.kinematics import UR_TABLES, forward_kinematics, ur_model

    robot = metadata.get("robot") or {}
    name = robot.get("model")
    recorded = np.all(np.isfinite(joints_rad), axis=1)
    if not isinstance(name, str) or name not in UR_TABLES or recorded.sum() == 0:
        return
    flange_from_tcp = robot.get("flange_from_tcp")
    model = ur_model(name, None if flange_from_tcp is None else np.asarray(flange_from_tcp, dtype=float))
    predicted = forward_kinematics(model, joints_rad[recorded])
    actual = base_from_tcp_stack[recorded]
    distance_mm = np.linalg.norm(predicted[:, :3, 3] - actual[:, :3, 3], axis=1)
    relative = np.einsum("nji,njk->nik", predicted[:, :3, :3], actual[:, :3, :3])
    cosine = np.clip((np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    angle_deg = np.degrees(np.arccos(cosine))
    bad = (distance_mm > TCP_KINEMATICS_TOLERANCE_MM) | (angle_deg > TCP_KINEMATICS_TOLERANCE_DEG)
    # a few rows may be off (a glitch); a conjugated 180 deg rotation is right, so count rows
    if bad.mean() > TCP_KINEMATICS_BAD_FRACTION:
        raise InvalidInputError(
            f"{path}: the TCP columns disagree with the {name}'s forward kinematics of the recorded "
            f"joints in {int(bad.sum())} of {len(bad)} rows (up to {np.max(distance_mm):.0f} mm, "
            f"{np.max(angle_deg):.0f} deg): TCP positions not in mm, quaternions not w,x,y,z, or the "
            "marker and TCP columns swapped?"
        )
