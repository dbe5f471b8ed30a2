"""The Franka adapter's pure parts: minimum-jerk paths within their limits, stops that reach
rest with a continuous velocity and acceleration, libfranka's column-major poses, and what the
robot's modes mean for a run. No robot, no simulator."""

import numpy as np
import pytest

from spacecal.adapters import DEVICE_SCHEMES, device_address
from spacecal.adapters.franka import (
    advice,
    condition,
    error_names,
    pose_from_franka,
    pose_to_franka,
)
from spacecal.adapters.franka_motion import PathClock, interpolate_pose, path_duration, stop_duration
from spacecal.core.errors import InvalidInputError
from spacecal.core.ports import SAFETY_NORMAL
from spacecal.geometry.rotations import rotation_angle
from spacecal.geometry.transforms import make_transform, rotvec_to_matrix

DT = 0.001  # libfranka's control cycle, s


def sampled(clock: PathClock, stop_at_s: float | None = None) -> np.ndarray:
    """s at every cycle until the clock is finished."""
    values = [clock.advance(0.0)]
    while not clock.finished:
        if stop_at_s is not None and clock.elapsed_s >= stop_at_s:
            clock.stop()
        values.append(clock.advance(DT))
        assert len(values) < 100_000
    return np.array(values)


@pytest.mark.parametrize("distance, speed, accel", [(1.0, 1.0, 2.0), (0.05, 1.0, 2.0), (300.0, 100.0, 400.0)])
def test_a_path_keeps_within_its_limits_and_reaches_one_of_them(distance, speed, accel):
    duration = path_duration(distance, speed, accel)
    position = distance * sampled(PathClock(duration, stop_s=0.1))
    velocity = np.diff(position) / DT
    acceleration = np.diff(velocity) / DT
    assert position[-1] == pytest.approx(distance)
    assert np.max(np.abs(velocity)) <= speed * 1.001 and np.max(np.abs(acceleration)) <= accel * 1.01
    assert np.max(np.abs(velocity)) > 0.99 * speed or np.max(np.abs(acceleration)) > 0.98 * accel
    assert duration == pytest.approx(len(position) * DT, abs=2 * DT)


@pytest.mark.parametrize("stop_fraction", [0.05, 0.3, 0.5, 0.8])
def test_a_stop_reaches_rest_smoothly_and_short_of_the_end(stop_fraction):
    distance, speed, accel, stop_accel = 1.0, 1.0, 2.0, 5.0
    duration = path_duration(distance, speed, accel)
    stop_s = stop_duration(1.875 * distance / duration, stop_accel)
    free = distance * sampled(PathClock(duration, stop_s))
    stopped = distance * sampled(PathClock(duration, stop_s), stop_at_s=stop_fraction * duration)
    velocity = np.diff(stopped) / DT
    acceleration = np.diff(velocity) / DT
    assert stopped[-1] < free[-1]  # it did not run on to the end
    assert abs(velocity[-1]) < 1e-3 * speed  # at rest
    # continuous acceleration (the robot's acceleration-discontinuity check judges the jerk):
    # the jerk stays within the free path's (60 D / T^3) plus the slowing clock's (its rate's
    # second derivative peaks at 6 / Ts^2, times the path's peak speed), far below an FR3's
    # 5000 rad/s^3; a cut in velocity would be a jerk of ~1e6 here
    bound = 60 * distance / duration**3 + 6 * 1.875 * distance / (duration * stop_s**2)
    assert np.max(np.abs(np.diff(acceleration))) / DT < 1.1 * bound
    decel_after_stop = acceleration[int(stop_fraction * duration / DT) + 2 :]
    assert np.max(np.abs(decel_after_stop)) < stop_accel + accel


def test_a_path_needs_a_positive_speed_and_acceleration():
    for speed, accel in ((0.0, 1.0), (1.0, -1.0), (float("nan"), 1.0)):
        with pytest.raises(InvalidInputError, match="positive speed"):
            path_duration(1.0, speed, accel)
    assert path_duration(0.0, 1.0, 1.0) == 0.0


def test_straight_line_poses_keep_to_the_line_and_the_axis():
    start = make_transform(np.eye(3), [500.0, 0.0, 300.0])
    end = make_transform(rotvec_to_matrix([0.0, 0.0, 0.6]), [600.0, 100.0, 300.0])
    half = interpolate_pose(start, end, 0.5)
    assert np.allclose(half[:3, 3], [550.0, 50.0, 300.0])
    assert rotation_angle(start[:3, :3].T @ half[:3, :3]) == pytest.approx(0.3)
    assert np.allclose(interpolate_pose(start, end, 1.0), end)


def test_libfranka_poses_are_column_major_metres():
    pose = make_transform(rotvec_to_matrix([0.1, -0.2, 0.3]), [554.4, -12.0, 731.8])
    values = pose_to_franka(pose)
    assert values[12:15] == pytest.approx([0.5544, -0.012, 0.7318])  # the translation column, m
    assert values[3] == 0.0 and values[15] == 1.0
    assert np.allclose(pose_from_franka(values), pose)


def test_what_the_robot_modes_mean_for_a_run():
    assert condition("Idle", []) == SAFETY_NORMAL and condition("Move", []) == SAFETY_NORMAL
    assert condition("Reflex", ["joint_reflex"]) == "stopped_by_a_reflex"
    assert condition("UserStopped", []) == "user_stop_pressed"
    assert condition("Idle", ["power_limit_violation"]) == "stopped_by_an_error"
    assert condition("Sleeping", []) == "not_running_(mode_Sleeping)"
    assert "(joint_reflex, cartesian_reflex)" in advice("Reflex", ["joint_reflex", "cartesian_reflex"])
    assert "release it" in advice("UserStopped", [])
    assert error_names('["joint_reflex", "cartesian_reflex"]') == ["joint_reflex", "cartesian_reflex"]
    assert error_names("[]") == []


def test_a_franka_url_is_a_host_only():
    assert DEVICE_SCHEMES["franka"].role == "robot"
    address = device_address("franka://Robot.local", "robot")
    assert (address.scheme, address.host, address.port) == ("franka", "robot.local", None)
