"""Raw two-stream recordings: the robot's states and the tracker's frames, each on its own clock.

``<stem>.robot.csv`` — one row per controller state::

    time_s, segment, q1_rad .. q6_rad [, q7_rad ...],
    tcp_x_mm, tcp_y_mm, tcp_z_mm, tcp_qw, tcp_qx, tcp_qy, tcp_qz

``<stem>.tracker.csv`` — one row per tracker frame (marker cells empty when not seen)::

    time_s, marker_x_mm, marker_y_mm, marker_z_mm, marker_qw, marker_qx, marker_qy, marker_qz, marker_rms_mm
    [, arrival_robot_time_s] [, marker_status] [, sphere1_x_mm, sphere1_y_mm, sphere1_z_mm, ...]

Times are each device's own clock, in seconds; the optional ``arrival_robot_time_s`` is the
newest robot timestamp when the frame arrived (written by ``spacecal acquire``), which links
the two clocks when they count from unrelated epochs. ``spacecal calibrate STEM.robot.csv
--tracker-stream STEM.tracker.csv`` pairs them (estimating the offset) before calibrating;
``spacecal acquire`` writes both streams as they arrive (:class:`RawStreamWriter`) and the
paired recording (:mod:`spacecal.io.recording_csv`) derived from them.
"""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.core.ports import FRAME_MISSING, FRAME_OK, FRAME_STATUSES, RobotState
from spacecal.core.text import quoted
from spacecal.core.units import check_lengths_in_mm
from spacecal.geometry.transforms import transform_from_position_quaternion, transform_to_position_quaternion
from spacecal.io.atomic import write_text_atomic
from spacecal.io.background_sync import BackgroundSync
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
from spacecal.records import RawRecording


def robot_columns(joint_count: int) -> list[str]:
    """The robot stream's columns for an arm of ``joint_count`` joints, in the order written."""
    return ["time_s", "segment"] + joint_columns(joint_count) + TCP_COLUMNS


#: The robot stream's required columns (a six-joint arm's).
ROBOT_COLUMNS = robot_columns(len(JOINT_COLUMNS))
TRACKER_COLUMNS = ["time_s"] + MARKER_COLUMNS
ARRIVAL_COLUMN = "arrival_robot_time_s"
STATUS_COLUMN = "marker_status"


def stream_paths(stem: str | Path) -> tuple[Path, Path, Path]:
    """(robot CSV, tracker CSV, metadata JSON) of a raw recording stem."""
    stem = Path(stem)
    return (
        stem.with_name(stem.name + ".robot.csv"),
        stem.with_name(stem.name + ".tracker.csv"),
        stem.with_name(stem.name + ".meta.json"),
    )


def raw_stem(recording_path: str | Path) -> Path:
    """``rec.csv`` -> ``rec``: the stem of the raw streams a paired recording is derived from."""
    path = Path(recording_path)
    return path.with_name(path.stem)


def raw_stream_paths(recording_path: str | Path) -> tuple[Path, Path]:
    """``rec.csv`` -> (``rec.robot.csv``, ``rec.tracker.csv``): the raw streams behind it."""
    robot, tracker, _ = stream_paths(raw_stem(recording_path))
    return robot, tracker


def write_raw_recording(raw: RawRecording, stem: str | Path) -> tuple[Path, Path]:
    """Write both streams and the metadata; returns the two CSV paths."""
    robot_path, tracker_path, meta_path = stream_paths(stem)
    robot_text, tracker_text = io.StringIO(), io.StringIO()
    writer = csv.writer(robot_text)
    writer.writerow(robot_columns(raw.joints_rad.shape[1]))
    positions, quaternions = transform_to_position_quaternion(raw.base_from_tcp_stack)
    for k in range(len(raw.robot_time_s)):
        writer.writerow(
            [format_number(raw.robot_time_s[k]), raw.robot_segment[k]]
            + [format_number(v) for v in raw.joints_rad[k]]
            + [format_number(v) for v in positions[k]]
            + [format_number(v) for v in quaternions[k]]
        )
    writer = csv.writer(tracker_text)
    writer.writerow(TRACKER_COLUMNS)
    for k in range(len(raw.tracker_time_s)):
        pose = raw.tracker_from_marker_stack[k]
        if np.all(np.isfinite(pose)):
            position, quaternion = transform_to_position_quaternion(pose)
            cells = (
                [format_number(v) for v in position]
                + [format_number(v) for v in quaternion]
                + [format_number(raw.marker_rms_mm[k])]
            )
        else:
            cells = [""] * len(MARKER_COLUMNS)
        writer.writerow([format_number(raw.tracker_time_s[k])] + cells)
    write_json(raw.metadata, meta_path)
    write_text_atomic(robot_text.getvalue(), robot_path)
    write_text_atomic(tracker_text.getvalue(), tracker_path)
    return robot_path, tracker_path


class RawStreamWriter:
    """Append both raw streams as the devices deliver them, flushing to disk as it goes.

    Nothing recorded is lost: a fault or a kill mid-run leaves every complete row in readable
    files (a half-written last row is cut when the run is resumed).

    Parameters
    ----------
    stem : str or Path
        ``STEM.robot.csv``, ``STEM.tracker.csv`` and ``STEM.meta.json`` are written.
    metadata : dict
        Written (atomically) to ``STEM.meta.json`` when starting a new pair of streams.
    sphere_count : int
        Raw-sphere column triples in the tracker stream (0: none).
    append : bool
        Continue existing streams (a resumed run), keeping their headers.
    durable : bool
        Force every row to the disk (``fsync``) as it is written, so that a power cut keeps
        it: what a run on real devices needs. The forcing runs on a thread of its own
        (:class:`~spacecal.io.background_sync.BackgroundSync`): the device loop that writes
        never waits for the disk, which on a busy computer can take seconds. A simulated run
        (which can be made again from its seed) only flushes to the operating system, which a
        killed process survives too.
    """

    def __init__(
        self,
        stem: str | Path,
        metadata: dict,
        sphere_count: int = 0,
        append: bool = False,
        durable: bool = True,
    ):
        self.durable = durable
        self.robot_path, self.tracker_path, meta_path = stream_paths(stem)
        self.robot_path.parent.mkdir(parents=True, exist_ok=True)
        resuming = append and self.robot_path.is_file() and self.tracker_path.is_file()
        if resuming:
            for path in (self.robot_path, self.tracker_path):
                drop_partial_last_row(path)
            header = read_text_file(self.tracker_path, "stream").splitlines()[0].split(",")
            sphere_count = sum(1 for c in header if c.startswith("sphere") and c.endswith("_x_mm"))
        else:
            write_json(metadata, meta_path)
        self.sphere_count = sphere_count
        self._files = [open(path, "a" if resuming else "w", newline="") for path in self.paths]
        self._robot, self._tracker = (csv.writer(f) for f in self._files)
        self._sync = BackgroundSync(self._files, "spacecal raw-stream sync") if durable else None
        if not resuming:
            self._robot.writerow(ROBOT_COLUMNS)
            self._tracker.writerow(
                TRACKER_COLUMNS + [ARRIVAL_COLUMN, STATUS_COLUMN] + sphere_columns(sphere_count)
            )
            self.flush()
        self._last_robot_time = -np.inf

    @property
    def paths(self) -> tuple[Path, Path]:
        return self.robot_path, self.tracker_path

    def add_robot_states(self, states, segment: str) -> None:
        """Write controller states (``RobotState``), skipping any not newer than the last written."""
        newer: list[RobotState] = []
        for state in states:
            if state.time_s > (newer[-1].time_s if newer else self._last_robot_time):
                newer.append(state)
        if not newer:
            return
        # one conversion for the whole batch: a controller streams 125-500 states a second
        positions, quaternions = transform_to_position_quaternion(np.array([s.base_from_tcp for s in newer]))
        for state, position, quaternion in zip(newer, positions, quaternions):
            self._robot.writerow(
                [format_number(state.time_s), segment]
                + [format_number(v) for v in state.joints_rad]
                + [format_number(v) for v in position]
                + [format_number(v) for v in quaternion]
            )
        self._last_robot_time = newer[-1].time_s

    def add_tracker_frame(
        self,
        time_s: float,
        tracker_from_marker: np.ndarray | None,
        marker_rms_mm: float,
        arrival_robot_time_s: float,
        spheres_in_tracker: np.ndarray | None = None,
        status: str = FRAME_OK,
    ) -> None:
        """Write one tracker frame, then flush both streams.

        ``tracker_from_marker`` is None when the tracker reported no pose; ``status`` is the
        frame's status (a pose reported as e.g. partially out of volume is kept with it).
        """
        if tracker_from_marker is None or not np.all(np.isfinite(tracker_from_marker)):
            cells = [""] * len(MARKER_COLUMNS)
        else:
            position, quaternion = transform_to_position_quaternion(tracker_from_marker)
            cells = [format_number(v) for v in [*position, *quaternion, marker_rms_mm]]
        spheres = np.full(3 * self.sphere_count, np.nan)
        if self.sphere_count and spheres_in_tracker is not None and cells[0]:
            given = np.asarray(spheres_in_tracker, dtype=float).reshape(-1)
            spheres[: min(len(given), len(spheres))] = given[: len(spheres)]
        if not cells[0] and status == FRAME_OK:
            status = FRAME_MISSING
        self._tracker.writerow(
            [format_number(time_s)]
            + cells
            + [format_number(arrival_robot_time_s), status]
            + [format_number(v) for v in spheres]
        )
        self.flush()

    def flush(self) -> None:
        """Hand every row to the operating system, and (durable) ask for them on the disk."""
        for handle in self._files:
            handle.flush()
        if self._sync is not None:
            self._sync.request()

    def close(self) -> None:
        """Flush, force to the disk and close both streams (the last sync waits for the disk)."""
        sync, self._sync = self._sync, None
        try:
            if sync is not None:
                sync.close()
        finally:
            for handle in self._files:
                if not handle.closed:
                    handle.flush()
                    os.fsync(handle.fileno())
                    handle.close()


def _rows(path: Path, columns: list[str]) -> tuple[list[list[str]], dict, list[str]]:
    """The data rows, the index of each required column, and the header (optional columns)."""
    if not path.is_file():
        raise InvalidInputError(f"{path}: no such stream file")
    text = read_text_file(path, "stream")
    rows = [r for r in csv.reader(io.StringIO(text, newline="")) if any(c.strip() for c in r)]
    if not rows:
        raise InvalidInputError(f"{path}: the stream is empty")
    header = [h.strip() for h in rows[0]]
    missing = [c for c in columns if c not in header]
    if missing:
        raise InvalidInputError(f"{path}: missing column(s): {', '.join(missing)}")
    if len(rows) < 11:
        raise InvalidInputError(f"{path}: the stream has {len(rows) - 1} rows; at least 10 are needed")
    # a missing cell, or a value beyond the header's columns (a shifted row), is refused
    wrong = [
        k + 2
        for k, row in enumerate(rows[1:])
        if len(row) < len(header) or any(cell.strip() for cell in row[len(header) :])
    ]
    if wrong:
        raise InvalidInputError(f"{path}: line {wrong[0]} does not have the header's {len(header)} cells")
    return rows[1:], {c: header.index(c) for c in columns}, header


def _increasing(times: np.ndarray, path: Path) -> None:
    bad = np.flatnonzero(np.diff(times) <= 0)
    if len(bad):
        raise InvalidInputError(f"{path}: time_s is not increasing at line {bad[0] + 3}")


def read_raw_recording(robot_path: str | Path, tracker_path: str | Path) -> RawRecording:
    """Read and validate the two streams (metadata from the robot stream's stem, if present)."""
    robot_path, tracker_path = Path(robot_path), Path(tracker_path)
    rows, index, robot_header = _rows(robot_path, ROBOT_COLUMNS)
    joint_names = joint_columns(joint_count_in_header(robot_header))
    index.update({c: robot_header.index(c) for c in joint_names})
    numeric = ["time_s"] + joint_names + TCP_COLUMNS
    values = np.empty((len(rows), len(numeric)))
    for k, row in enumerate(rows):
        # joints may be unrecorded (a robot pose from tf in a ROS bag): all their cells empty
        joints_missing = not any(row[index[c]].strip() for c in joint_names)
        values[k] = [
            np.nan
            if joints_missing and c in joint_names
            else parse_number(row[index[c]], k + 2, c, robot_path)
            for c in numeric
        ]
    # columns: time, the J joints, the TCP position and quaternion
    joints = values[:, 1 : 1 + len(joint_names)]
    tcp_position = values[:, 1 + len(joint_names) : 4 + len(joint_names)]
    tcp_quaternion = values[:, 4 + len(joint_names) : 8 + len(joint_names)]
    segments = np.array([r[index["segment"]].strip() for r in rows])
    _increasing(values[:, 0], robot_path)
    lines = np.arange(2, len(rows) + 2)
    check_quaternions(tcp_quaternion, lines, "tcp", robot_path)
    check_lengths_in_mm(tcp_position, f"{robot_path}: tcp_x_mm..tcp_z_mm")
    no_marker = np.full((len(rows), 3), np.nan)
    check_ranges(robot_path, lines, values[:, 0], joints, tcp_position, no_marker, no_marker[:, 0])

    rows, index, header = _rows(tracker_path, TRACKER_COLUMNS)
    times = np.array(
        [parse_number(r[index["time_s"]], k + 2, "time_s", tracker_path) for k, r in enumerate(rows)]
    )
    arrival = _optional_column(rows, header, ARRIVAL_COLUMN, tracker_path)
    status = None
    if STATUS_COLUMN in header:
        column = header.index(STATUS_COLUMN)
        status = np.array([r[column].strip() or FRAME_MISSING for r in rows])
        unknown = sorted(set(status.tolist()) - set(FRAME_STATUSES))
        if unknown:
            raise InvalidInputError(
                f"{tracker_path}: unknown marker_status {quoted(unknown[0])}; "
                f"expected one of {', '.join(FRAME_STATUSES)}"
            )
    spheres = _optional_spheres(rows, header, tracker_path)
    _increasing(times, tracker_path)
    marker = np.full((len(rows), 8), np.nan)
    for k, r in enumerate(rows):
        cells = [r[index[c]].strip() for c in MARKER_COLUMNS]
        if any(cells[:7]):
            marker[k, :7] = [
                parse_number(c, k + 2, name, tracker_path) for c, name in zip(cells[:7], MARKER_COLUMNS)
            ]
            if cells[7]:
                marker[k, 7] = parse_number(cells[7], k + 2, MARKER_COLUMNS[7], tracker_path)
    seen = np.isfinite(marker[:, 0])
    if not seen.any():
        raise InvalidInputError(f"{tracker_path}: the marker was not visible in any frame")
    check_quaternions(marker[seen, 3:7], np.arange(2, len(rows) + 2)[seen], "marker", tracker_path)
    check_lengths_in_mm(marker[seen, :3], f"{tracker_path}: marker_x_mm..marker_z_mm")
    tracker_lines = np.arange(2, len(rows) + 2)
    check_ranges(
        tracker_path,
        tracker_lines,
        times,
        np.zeros((len(rows), 6)),
        np.zeros((len(rows), 3)),
        marker[:, :3],
        marker[:, 7],
    )
    tracker_from_marker = np.full((len(rows), 4, 4), np.nan)
    tracker_from_marker[seen] = transform_from_position_quaternion(marker[seen, :3], marker[seen, 3:7])
    meta = metadata_path(robot_path)
    metadata = read_json_object(meta, "recording metadata") if meta.is_file() else {}
    check_metadata(metadata, meta)
    base_from_tcp = transform_from_position_quaternion(tcp_position, tcp_quaternion)
    check_tcp_against_kinematics(joints, base_from_tcp, metadata, robot_path)
    return RawRecording(
        values[:, 0],
        segments,
        joints,
        base_from_tcp,
        times,
        tracker_from_marker,
        marker[:, 7],
        metadata,
        spheres_in_tracker=spheres,
        arrival_robot_time_s=arrival,
        marker_status=status,
    )


def _optional_column(rows: list[list[str]], header: list[str], name: str, path: Path) -> np.ndarray | None:
    """A numeric column that older streams do not have (None then); empty cells are NaN."""
    if name not in header:
        return None
    column = header.index(name)
    return np.array(
        [
            parse_number(r[column], k + 2, name, path) if r[column].strip() else np.nan
            for k, r in enumerate(rows)
        ]
    )


def _optional_spheres(rows: list[list[str]], header: list[str], path: Path) -> np.ndarray | None:
    """The raw sphere centres (T, K, 3), mm, when the stream has sphere columns."""
    count = sum(1 for c in header if c.startswith("sphere") and c.endswith("_x_mm"))
    if not count:
        return None
    columns = [c for c in sphere_columns(count) if c in header]
    if len(columns) != 3 * count:
        raise InvalidInputError(f"{path}: the sphere columns are incomplete")
    values = np.full((len(rows), len(columns)), np.nan)
    for k, name in enumerate(columns):
        values[:, k] = _optional_column(rows, header, name, path)
    return values.reshape(len(rows), count, 3)
