"""Arms of any joint count: a KUKA LBR iiwa's seven joints in standard DH form."""

import numpy as np
import pytest

from spacecal.core.errors import InvalidInputError, UnreachableError
from spacecal.models.kinematics import (
    RobotModel,
    dh_point_jacobian,
    fit_reported_kinematics,
    forward_kinematics,
    geometric_jacobian,
    inverse_kinematics,
    with_dh_corrections,
)

#: KUKA LBR iiwa 7 R800: the 340 mm base-to-shoulder, 400 mm shoulder-to-elbow, 400 mm
#: elbow-to-wrist and 126 mm wrist-to-flange lengths of its data sheet, twists of +-90 deg.
IIWA7 = RobotModel(
    name="iiwa7",
    a_mm=np.zeros(7),
    d_mm=np.array([340.0, 0.0, 400.0, 0.0, 400.0, 0.0, 126.0]),
    alpha_rad=np.radians([-90.0, 90.0, 90.0, -90.0, -90.0, 90.0, 0.0]),
)


def test_the_iiwa_stands_straight_up_at_zero():
    # the data sheet's height of the flange over the base with every joint at zero
    pose = forward_kinematics(IIWA7, np.zeros(7))
    assert np.allclose(pose[:3, 3], [0.0, 0.0, 340.0 + 400.0 + 400.0 + 126.0])
    # bending the elbow (joint 4) by 90 deg puts the forearm and wrist (526 mm) horizontal
    bent = forward_kinematics(IIWA7, np.radians([0, 0, 0, 90, 0, 0, 0]))
    assert np.isclose(bent[2, 3], 740.0)
    assert np.isclose(np.linalg.norm(bent[:2, 3]), 526.0)


def test_the_jacobian_of_seven_joints_is_the_derivative_of_the_pose():
    rng = np.random.default_rng(7)
    joints = rng.uniform(-2.0, 2.0, 7)
    jacobian = geometric_jacobian(IIWA7, joints)[0]
    assert jacobian.shape == (6, 7)
    step = 1e-6
    for j in range(7):
        plus, minus = joints.copy(), joints.copy()
        plus[j] += step
        minus[j] -= step
        moved = forward_kinematics(IIWA7, plus)[:3, 3] - forward_kinematics(IIWA7, minus)[:3, 3]
        velocity = moved / (2 * step)
        assert np.allclose(jacobian[:3, j], velocity, atol=1e-5)


def test_dh_corrections_have_four_per_joint():
    rng = np.random.default_rng(1)
    joints = rng.uniform(-2.0, 2.0, (5, 7))
    delta = rng.normal(0.0, 0.1, 28)
    corrected = with_dh_corrections(IIWA7, delta)
    assert np.allclose(corrected.d_mm - IIWA7.d_mm, delta[7:14])
    points = np.array([[0.0, 0.0, 0.0], [50.0, 0.0, 0.0]])
    jacobian = dh_point_jacobian(IIWA7, joints, np.eye(4), np.eye(4), points)
    assert jacobian.shape == (5, 2, 3, 28)


def test_a_seven_joint_controllers_model_is_identified_from_its_poses():
    rng = np.random.default_rng(3)
    true = with_dh_corrections(IIWA7, rng.normal(0.0, 1.0, 28) * np.repeat([0.5, 0.5, 0.001, 0.001], 7))
    joints = rng.uniform(-2.0, 2.0, (60, 7))
    model, rms_mm = fit_reported_kinematics(IIWA7, joints, forward_kinematics(true, joints))
    assert rms_mm < 1e-6
    test_joints = rng.uniform(-2.0, 2.0, (20, 7))
    reached = forward_kinematics(model, test_joints)[:, :3, 3]
    assert np.max(np.abs(reached - forward_kinematics(true, test_joints)[:, :3, 3])) < 1e-5


def test_what_seven_joints_cannot_do_is_said_in_one_line():
    far = np.eye(4)
    far[0, 3] = 3000.0  # beyond the 1266 mm the arm reaches
    with pytest.raises(UnreachableError, match="pose 0 cannot be reached by the iiwa7"):
        inverse_kinematics(IIWA7, far)
    with pytest.raises(InvalidInputError, match="iiwa7 has 7 joints; got reference joints"):
        inverse_kinematics(IIWA7, np.eye(4), np.zeros(6))
    with pytest.raises(InvalidInputError, match="iiwa7 has 7 joints"):
        forward_kinematics(IIWA7, np.zeros(6))
    with pytest.raises(InvalidInputError, match="d_mm must be 7 finite numbers"):
        RobotModel(name="iiwa7", a_mm=np.zeros(7), d_mm=np.zeros(6), alpha_rad=np.zeros(7))
    with pytest.raises(InvalidInputError, match="13 joints"):
        RobotModel(name="long", a_mm=np.zeros(13), d_mm=np.zeros(13), alpha_rad=np.zeros(13))


def test_a_calibration_file_keeps_a_seven_joint_model():
    from spacecal.records.calibration import robot_model_from_dict, robot_model_to_dict

    again = robot_model_from_dict(robot_model_to_dict(IIWA7), "calibration")
    assert again.n_joints == 7
    assert np.array_equal(again.d_mm, IIWA7.d_mm)
    assert np.array_equal(again.joint_upper_rad, IIWA7.joint_upper_rad)
    too_long = robot_model_to_dict(IIWA7) | {"a_mm": [0.0] * 13}
    with pytest.raises(InvalidInputError, match="13 joints; 1 to 12 are read"):
        robot_model_from_dict(too_long, "calibration")
    mismatched = robot_model_to_dict(IIWA7) | {"d_mm": [0.0] * 6}
    with pytest.raises(InvalidInputError, match="d_mm"):
        robot_model_from_dict(mismatched, "calibration")
