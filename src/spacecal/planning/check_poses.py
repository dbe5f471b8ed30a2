"""Check poses around the surgical site: where a pre-operative check sends the robot."""

from __future__ import annotations

import numpy as np

from spacecal.geometry.transforms import axis_angle_transform, make_transform
from spacecal.models.kinematics import RobotModel, forward_kinematics, inverse_kinematics
from spacecal.planning.held_poses import SETTLE_S, hold_plan
from spacecal.planning.motion import MotionLimits, MotionPlan

#: Label of the hold at check pose k (1-based): the frames recorded there are averaged.
CHECK_LABEL = "check-{}"


def check_joints(model: RobotModel, home_joints_rad: np.ndarray, count: int = 3) -> np.ndarray:
    """``count`` configurations (count, 6): home, then poses 40 mm away tilted by 10 degrees."""
    home = forward_kinematics(model, home_joints_rad)
    offsets = [np.zeros(3), np.array([40.0, 0.0, 0.0]), np.array([0.0, -40.0, 20.0])]
    tilts = [np.zeros(3), np.radians([0.0, 10.0, 0.0]), np.radians([10.0, 0.0, 0.0])]
    joints = []
    for offset, tilt in list(zip(offsets, tilts))[:count]:
        tilt_matrix = axis_angle_transform(tilt if np.any(tilt) else [0, 0, 1], np.linalg.norm(tilt))[:3, :3]
        pose = make_transform(home[:3, :3] @ tilt_matrix, home[:3, 3] + home[:3, :3] @ offset)
        joints.append(inverse_kinematics(model, pose, home_joints_rad))
    return np.array(joints)


def check_plan(
    model: RobotModel,
    home_joints_rad: np.ndarray,
    count: int,
    limits: MotionLimits,
    frame_period_s: float,
    frames_per_pose: int = 10,
    settle_s: float = SETTLE_S,
) -> MotionPlan:
    """The check as a plan: from home, a transit to each check pose, a hold there while
    ``frames_per_pose`` frames are taken (after ``settle_s``), and back home.

    Running the check through the acquisition loop gives it the same safety as a calibration
    run: safety stops, a lost tracker and a move past its deadline end it with the robot stopped.

    Parameters
    ----------
    model : RobotModel
    home_joints_rad : numpy.ndarray, shape (6,)
        Where the robot stands (near the site).
    count : int
        Two or three check poses (:func:`check_joints`).
    limits : MotionLimits
    frame_period_s : float
        Tracker frame period, s.
    frames_per_pose : int
    settle_s : float
        Rest before frames count, s (the arm settles after the move).

    Returns
    -------
    MotionPlan
        Holds are labelled ``check-1``, ``check-2``...; transits are not recorded.
    """
    joints = check_joints(model, np.asarray(home_joints_rad, dtype=float), count)
    return hold_plan(
        model,
        home_joints_rad,
        np.array([forward_kinematics(model, q) for q in joints]),
        [CHECK_LABEL.format(k + 1) for k in range(len(joints))],
        limits,
        frame_period_s,
        frames_per_pose,
        settle_s,
        summary={"check_poses": count},
    )
