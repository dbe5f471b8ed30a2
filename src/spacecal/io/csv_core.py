"""The shared core of spacecal's CSV formats: the paired recording (:mod:`.recording_csv`)
and the raw two-stream recording (:mod:`.raw_streams`) read and write their cells, columns and
metadata by the same rules.

- column names: joints, TCP and marker poses, the optional raw sphere centres;
- cells: numbers written exactly (``repr``) and read strictly (no digit groups, no NaN or
  infinity), unit quaternions;
- rows: plausible ranges of times, joint angles, positions and fit RMS, and a row that an
  interruption left half-written cut before appending;
- metadata: ``<stem>.meta.json`` beside the CSV, its known keys' types and units, and the TCP
  columns against the forward kinematics of the recorded joints.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.core.strict_numbers import parse_float
from spacecal.core.text import quoted
from spacecal.models.kinematics import MAX_JOINTS

JOINT_COLUMNS = [f"q{i}_rad" for i in range(1, 7)]


def joint_columns(count: int) -> list[str]:
    """The joint columns of an arm of ``count`` joints: ``q1_rad`` .. ``q<count>_rad``, at
    least the six every recording file carries (a UR arm's; empty cells for fewer)."""
    return [f"q{i}_rad" for i in range(1, max(count, len(JOINT_COLUMNS)) + 1)]


def joint_count_in_header(names: list[str]) -> int:
    """How many joints a header's columns carry: six, or more where ``q7_rad``, ``q8_rad`` ...
    follow (a KUKA LBR iiwa's seven)."""
    count = len(JOINT_COLUMNS)
    while count < MAX_JOINTS and f"q{count + 1}_rad" in names:
        count += 1
    return count


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


def format_number(value: float) -> str:
    """A number cell: exact (``repr``), empty for a missing value."""
    return "" if not math.isfinite(value) else repr(float(value))


def drop_partial_last_row(path: Path) -> None:
    """Cut a row that an interruption left half-written (no line end) before appending."""
    with open(path, "rb+") as handle:
        data = handle.read()
        if data and not data.endswith(b"\n"):  # an interrupted row; the header stays
            if b"\n" not in data:
                raise InvalidInputError(f"{path}: the recording has no complete header row")
            handle.truncate(data.rfind(b"\n") + 1)


def parse_number(cell: str, line: int, column: str, path: Path) -> float:
    """A number cell of ``path`` (its ``line`` and ``column`` for the message): finite, in
    plain decimal or exponent form."""
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


def check_quaternions(quaternions: np.ndarray, lines: np.ndarray, what: str, path: Path) -> None:
    """Refuse quaternions (N, 4) that are not unit; ``lines`` (N,) name their rows."""
    norms = np.linalg.norm(quaternions, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > QUATERNION_NORM_TOLERANCE)
    if len(bad):
        k = bad[0]
        raise InvalidInputError(
            f"{path}: line {lines[k]}: {what} quaternion has norm {norms[k]:.4f}; quaternions must "
            f"be unit ({len(bad)} row(s) affected)"
        )


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
        (f"q1_rad..q{joints_rad.shape[1]}_rad", joints_rad, -MAX_ABS_JOINT_RAD, MAX_ABS_JOINT_RAD, "rad"),
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
    it. Without joints or a registered robot kind there is nothing to compare with.

    Parameters
    ----------
    joints_rad : numpy.ndarray, shape (N, J)
        NaN rows where the joints were not recorded.
    base_from_tcp_stack : numpy.ndarray, shape (N, 4, 4)
        The recorded TCP poses, mm.
    """
    from spacecal.models.kinematics import forward_kinematics
    from spacecal.models.robot_kinds import is_robot_kind, robot_kind

    robot = metadata.get("robot") or {}
    name = robot.get("model")
    recorded = np.all(np.isfinite(joints_rad), axis=1)
    if not is_robot_kind(name) or recorded.sum() == 0:
        return
    flange_from_tcp = robot.get("flange_from_tcp")
    model = robot_kind(name).model(
        None if flange_from_tcp is None else np.asarray(flange_from_tcp, dtype=float)
    )
    if joints_rad.shape[1] != model.n_joints:
        raise InvalidInputError(
            f"{path}: the recording has {joints_rad.shape[1]} joint columns and its robot, a {name}, "
            f"{model.n_joints} joints"
        )
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
