"""The paper's verification experiment (§5.2).

Needle poses X_d = [P_d, phi_d] are given in tracker space, mapped through a calibration to
robot space, reached by inverse kinematics, and the reached pose X_r is measured by an
independent instrument (the paper's laser tracker). Per point::

    position error |dP| = |P_d - P_r|
    posture error  dphi = angle of dR = R_d R_r^-1
"""

from __future__ import annotations

import numpy as np

from spacecal.core.ports import PoseReference, Robot
from spacecal.geometry.metrics import position_error, posture_error_rad
from spacecal.geometry.transforms import invert_transform
from spacecal.models.kinematics import RobotModel, inverse_kinematics
from spacecal.records import CalibrationResult, VerificationResult


def run_verification(
    calibration: CalibrationResult,
    robot: Robot,
    reference: PoseReference,
    robot_model: RobotModel,
    desired_tracker_from_needle,
    start_joints_rad,
    tcp_from_needle=None,
    speed_rad_s: float = 0.5,
    accel_rad_s2: float = 1.0,
) -> VerificationResult:
    """Drive the robot to needle poses given in tracker space and measure how close it gets.

    Parameters
    ----------
    calibration : CalibrationResult
        Supplies ``tracker_from_base``.
    robot : Robot
    reference : PoseReference
        Independent measurement of the reached needle pose in the tracker frame.
    robot_model : RobotModel
        The model IK is solved with (the controller's nominal model, or a corrected one).
    desired_tracker_from_needle : array_like, shape (N, 4, 4)
        Target needle poses in the tracker frame, mm.
    start_joints_rad : array_like, shape (6,)
        Configuration to start from, and return to between targets (the paper moves to
        each point "from another place"); IK picks the branch nearest to it.
    tcp_from_needle : array_like, shape (4, 4), optional
        Needle tip in the TCP frame; identity when the TCP is the needle tip (the paper).

    Returns
    -------
    VerificationResult
    """
    desired = np.asarray(desired_tracker_from_needle, dtype=float).reshape(-1, 4, 4)
    needle_from_tcp = np.eye(4) if tcp_from_needle is None else invert_transform(tcp_from_needle)
    base_from_tracker = invert_transform(calibration.tracker_from_base)
    start = np.asarray(start_joints_rad, dtype=float)
    reached, joints = [], []
    for target in desired:
        q = inverse_kinematics(robot_model, base_from_tracker @ target @ needle_from_tcp, start)
        robot.move_joints(start, speed_rad_s, accel_rad_s2)
        robot.move_joints(q, speed_rad_s, accel_rad_s2)
        reached.append(reference.measure_tracker_from_needle())
        joints.append(q)
    reached_stack = np.array(reached)
    return VerificationResult(
        desired_tracker_from_needle=desired,
        reached_tracker_from_needle=reached_stack,
        joints_rad=np.array(joints),
        position_error_mm=position_error(desired, reached_stack),
        posture_error_deg=np.degrees(posture_error_rad(desired, reached_stack)),
    )
