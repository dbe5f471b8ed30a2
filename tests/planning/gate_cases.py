"""Motions for the motion gate's tests: moves timed as the planners time them, poses near the
arm's singularities, and hostile variants of a good plan (shared with ``tests/fuzz``)."""

from __future__ import annotations

import dataclasses

import numpy as np

from spacecal.geometry.transforms import axis_angle_transform, make_transform, matrix_to_rotvec
from spacecal.models.kinematics import RobotModel, forward_kinematics
from spacecal.planning.motion import MotionLimits, TimedMove, trapezoid_duration

LIMITS = MotionLimits()


def timed(start, end, label="transit", period=0.0, limits=LIMITS) -> TimedMove:
    """A straight move from ``start`` to ``end`` timed at ``limits`` (as the planners time it)."""
    start, end = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
    distance = float(np.linalg.norm(end[:3, 3] - start[:3, 3]))
    angle = float(np.linalg.norm(matrix_to_rotvec(start[:3, :3].T @ end[:3, :3])))
    duration, accel = max(
        trapezoid_duration(distance, limits.linear_speed_mm_s, limits.linear_accel_mm_s2),
        trapezoid_duration(angle, limits.angular_speed_rad_s, limits.angular_accel_rad_s2),
    )
    if duration == 0:  # a hold
        return TimedMove(label, start, end, 0.5, 0.0, period)
    return TimedMove(label, start, end, duration, accel, period)


def shifted(pose, offset_mm) -> np.ndarray:
    """``pose`` translated by ``offset_mm`` (3,) in the base frame."""
    out = np.array(pose, dtype=float)
    out[:3, 3] += offset_mm
    return out


def turned(pose, axis, angle_rad) -> np.ndarray:
    """``pose`` rotated about its own (TCP) ``axis`` by ``angle_rad``."""
    return np.asarray(pose, dtype=float) @ axis_angle_transform(axis, angle_rad)


def with_start(move: TimedMove, start) -> TimedMove:
    return dataclasses.replace(move, start=np.asarray(start, dtype=float))


def with_end(move: TimedMove, end) -> TimedMove:
    return dataclasses.replace(move, end=np.asarray(end, dtype=float))


def wrist_singular_crossing(model: RobotModel, home_joints, direction, half_mm=100.0) -> list[TimedMove]:
    """From home to a point ``half_mm`` before the pose with joint 5 at 0 (the wrist
    singularity), then straight through it to ``half_mm`` beyond."""
    joints = np.array(home_joints, dtype=float)
    joints[4] = 0.0
    singular = forward_kinematics(model, joints)
    direction = np.asarray(direction, dtype=float) / np.linalg.norm(direction)
    before, after = shifted(singular, -half_mm * direction), shifted(singular, half_mm * direction)
    home = forward_kinematics(model, home_joints)
    return [timed(home, before), timed(before, after, "through")]


def spin_about_tool(home, count, step_deg=170.0) -> list[TimedMove]:
    """``count`` rotations of ``step_deg`` about the TCP's z axis, one after another: joint 6
    winds up past its +-360 degree limit."""
    moves, pose = [], np.asarray(home, dtype=float)
    for _ in range(count):
        nxt = turned(pose, [0, 0, 1], np.radians(step_deg))
        moves.append(timed(pose, nxt, "spin"))
        pose = nxt
    return moves


def base_pose(home, point=(0.0, 0.0, 50.0)) -> np.ndarray:
    """The home orientation with the TCP at ``point`` (mm, base): at the robot's base."""
    return make_transform(np.asarray(home)[:3, :3], np.asarray(point, dtype=float))
