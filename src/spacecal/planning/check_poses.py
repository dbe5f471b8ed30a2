"""Check poses around the surgical site: where a pre-operative check sends the robot."""

from __future__ import annotations

import numpy as np

from spacecal.geometry.transforms import axis_angle_transform, make_transform
from spacecal.models.kinematics import RobotModel, forward_kinematics, inverse_kinematics


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
