"""Device values are checked at the boundary: a tracker pose that is not one becomes a gap,
a robot state or a controller model that is not an arm's is a device fault, never a sample."""

from __future__ import annotations

import numpy as np
import pytest

from spacecal.core.errors import DeviceError, InvalidInputError
from spacecal.core.ports import FRAME_INVALID, FRAME_OK, RobotState, TrackerFrame
from spacecal.models.robot_kinds import robot_kind


def _pose(translation=(0.0, 0.0, -1000.0)):
    pose = np.eye(4)
    pose[:3, 3] = translation
    return pose


def _scaled():
    pose = _pose()
    pose[:3, :3] *= 1.01
    return pose


def _nan():
    pose = _pose()
    pose[0, 3] = np.nan
    return pose


@pytest.mark.parametrize(
    "pose",
    [_nan(), _pose((0.0, 0.0, 1e30)), _pose((3e4, 0.0, 0.0)), _scaled(), -np.eye(4), np.zeros((4, 4))],
    ids=["nan", "1e30 mm", "30 m", "scaled rotation", "reflection", "zeros"],
)
def test_a_pose_that_is_not_one_is_an_invalid_frame_without_a_pose(pose):
    frame = TrackerFrame(1.0, 7, FRAME_OK, pose, rms_mm=0.1)
    assert frame.status == FRAME_INVALID and frame.tracker_from_marker is None and np.isnan(frame.rms_mm)


def test_a_sound_frame_is_kept_and_a_wild_rms_dropped():
    frame = TrackerFrame(1.0, 7, FRAME_OK, _pose(), rms_mm=0.12)
    assert frame.status == FRAME_OK and frame.rms_mm == 0.12
    assert np.isnan(TrackerFrame(1.0, 7, FRAME_OK, _pose(), rms_mm=1e9).rms_mm)
    with pytest.raises(DeviceError):
        TrackerFrame(float("nan"), 7, FRAME_OK, _pose())


@pytest.mark.parametrize(
    "joints, pose",
    [
        (np.full(6, np.nan), _pose()),
        (np.full(6, 100.0), _pose()),
        (np.zeros(5), _pose()),
        (np.zeros(6), _nan()),
        (np.zeros(6), _pose((0.0, 0.0, 1e7))),
    ],
    ids=["nan joints", "joints 100 rad", "five joints", "nan pose", "pose 10 km"],
)
def test_a_robot_state_that_is_not_an_arms_is_a_device_fault(joints, pose):
    with pytest.raises(DeviceError):
        RobotState(0.0, joints, pose)


@pytest.mark.parametrize("field", ["a_mm", "d_mm", "alpha_rad", "theta_offset_rad"])
def test_a_controller_model_with_nan_or_infinite_dh_is_refused(field):
    nominal = robot_kind("UR10").model()
    values = np.asarray(getattr(nominal, field), dtype=float).copy()
    values[2] = np.nan
    with pytest.raises(InvalidInputError, match=field):
        type(nominal)(**{**nominal.__dict__, field: values})
    values[2] = np.inf
    with pytest.raises(InvalidInputError, match=field):
        type(nominal)(**{**nominal.__dict__, field: values})
