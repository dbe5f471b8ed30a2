"""Raw two-stream recordings: the robot's states and the tracker's frames, each on its own clock.

``<stem>.robot.csv`` — one row per controller state::

    time_s, segment, q1_rad .. q6_rad, tcp_x_mm, tcp_y_mm, tcp_z_mm, tcp_qw, tcp_qx, tcp_qy, tcp_qz

``<stem>.tracker.csv`` — one row per tracker frame (marker cells empty when not seen)::

    time_s, marker_x_mm, marker_y_mm, marker_z_mm, marker_qw, marker_qx, marker_qy, marker_qz, marker_rms_mm

Times are each device's own clock, in seconds; ``spacecal calibrate STEM.robot.csv
--tracker-stream STEM.tracker.csv`` pairs them (estimating the offset) before calibrating.
The paired format (:mod:`spacecal.io.recording_csv`) is unchanged.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.core.units import check_lengths_in_mm
from spacecal.geometry.transforms import transform_from_position_quaternion, transform_to_position_quaternion
from spacecal.io.atomic import write_text_atomic
from spacecal.io.recording_csv import (
    JOINT_COLUMNS,
    MARKER_COLUMNS,
    TCP_COLUMNS,
    _check_quaternions,
    _format,
    _number,
    check_metadata,
    check_ranges,
    check_tcp_against_kinematics,
)
from spacecal.io.results_json import read_json_object, write_json
from spacecal.io.text import read_text_file
from spacecal.records import RawRecording

ROBOT_COLUMNS = ["time_s", "segment"] + JOINT_COLUMNS + TCP_COLUMNS
TRACKER_COLUMNS = ["time_s"] + MARKER_COLUMNS


def stream_paths(stem: str | Path) -> tuple[Path, Path, Path]:
    """(robot CSV, tracker CSV, metadata JSON) of a raw recording stem."""
    stem = Path(stem)
    return (
        stem.with_name(stem.name + ".robot.csv"),
        stem.with_name(stem.name + ".tracker.csv"),
        stem.with_name(stem.name + ".meta.json"),
    )


def write_raw_recording(raw: RawRecording, stem: str | Path) -> tuple[Path, Path]:
    """Write both streams and the metadata; returns the two CSV paths."""
    robot_path, tracker_path, meta_path = stream_paths(stem)
    robot_text, tracker_text = io.StringIO(), io.StringIO()
    writer = csv.writer(robot_text)
    writer.writerow(ROBOT_COLUMNS)
    positions, quaternions = transform_to_position_quaternion(raw.base_from_tcp_stack)
    for k in range(len(raw.robot_time_s)):
        writer.writerow(
            [_format(raw.robot_time_s[k]), raw.robot_segment[k]]
            + [_format(v) for v in raw.joints_rad[k]]
            + [_format(v) for v in positions[k]]
            + [_format(v) for v in quaternions[k]]
        )
    writer = csv.writer(tracker_text)
    writer.writerow(TRACKER_COLUMNS)
    for k in range(len(raw.tracker_time_s)):
        pose = raw.tracker_from_marker_stack[k]
        if np.all(np.isfinite(pose)):
            position, quaternion = transform_to_position_quaternion(pose)
            cells = (
                [_format(v) for v in position]
                + [_format(v) for v in quaternion]
                + [_format(raw.marker_rms_mm[k])]
            )
        else:
            cells = [""] * len(MARKER_COLUMNS)
        writer.writerow([_format(raw.tracker_time_s[k])] + cells)
    write_json(raw.metadata, meta_path)
    write_text_atomic(robot_text.getvalue(), robot_path)
    write_text_atomic(tracker_text.getvalue(), tracker_path)
    return robot_path, tracker_path


def _rows(path: Path, columns: list[str]) -> tuple[list[list[str]], dict]:
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
    short = [k + 2 for k, row in enumerate(rows[1:]) if len(row) < len(header)]
    if short:
        raise InvalidInputError(
            f"{path}: line {short[0]} has fewer cells than the header's {len(header)} columns"
        )
    return rows[1:], {c: header.index(c) for c in columns}


def _increasing(times: np.ndarray, path: Path) -> None:
    bad = np.flatnonzero(np.diff(times) <= 0)
    if len(bad):
        raise InvalidInputError(f"{path}: time_s is not increasing at line {bad[0] + 3}")


def read_raw_recording(robot_path: str | Path, tracker_path: str | Path) -> RawRecording:
    """Read and validate the two streams (metadata from the robot stream's stem, if present)."""
    robot_path, tracker_path = Path(robot_path), Path(tracker_path)
    rows, index = _rows(robot_path, ROBOT_COLUMNS)
    numeric = ["time_s"] + JOINT_COLUMNS + TCP_COLUMNS
    values = np.empty((len(rows), len(numeric)))
    for k, row in enumerate(rows):
        # joints may be unrecorded (a robot pose from tf in a ROS bag): all six cells empty
        joints_missing = not any(row[index[c]].strip() for c in JOINT_COLUMNS)
        values[k] = [
            np.nan if joints_missing and c in JOINT_COLUMNS else _number(row[index[c]], k + 2, c, robot_path)
            for c in numeric
        ]
    segments = np.array([r[index["segment"]].strip() for r in rows])
    _increasing(values[:, 0], robot_path)
    lines = np.arange(2, len(rows) + 2)
    _check_quaternions(values[:, 10:14], lines, "tcp", robot_path)
    check_lengths_in_mm(values[:, 7:10], f"{robot_path}: tcp_x_mm..tcp_z_mm")
    no_marker = np.full((len(rows), 3), np.nan)
    check_ranges(robot_path, lines, values[:, 0], values[:, 1:7], values[:, 7:10], no_marker, no_marker[:, 0])

    rows, index = _rows(tracker_path, TRACKER_COLUMNS)
    times = np.array([_number(r[index["time_s"]], k + 2, "time_s", tracker_path) for k, r in enumerate(rows)])
    _increasing(times, tracker_path)
    marker = np.full((len(rows), 8), np.nan)
    for k, r in enumerate(rows):
        cells = [r[index[c]].strip() for c in MARKER_COLUMNS]
        if any(cells[:7]):
            marker[k, :7] = [
                _number(c, k + 2, name, tracker_path) for c, name in zip(cells[:7], MARKER_COLUMNS)
            ]
            if cells[7]:
                marker[k, 7] = _number(cells[7], k + 2, MARKER_COLUMNS[7], tracker_path)
    seen = np.isfinite(marker[:, 0])
    if not seen.any():
        raise InvalidInputError(f"{tracker_path}: the marker was not visible in any frame")
    _check_quaternions(marker[seen, 3:7], np.arange(2, len(rows) + 2)[seen], "marker", tracker_path)
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
    meta = robot_path.with_name(robot_path.name.replace(".robot.csv", ".meta.json"))
    metadata = read_json_object(meta, "recording metadata") if meta.is_file() else {}
    check_metadata(metadata, meta)
    base_from_tcp = transform_from_position_quaternion(values[:, 7:10], values[:, 10:14])
    check_tcp_against_kinematics(values[:, 1:7], base_from_tcp, metadata, robot_path)
    return RawRecording(
        values[:, 0],
        segments,
        values[:, 1:7],
        base_from_tcp,
        times,
        tracker_from_marker,
        marker[:, 7],
        metadata,
    )
