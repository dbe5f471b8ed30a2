"""Identifying a controller's kinematic model from pairs of its reported joints and TCP poses
(the fallback when it does not publish its calibrated DH parameters)."""

import numpy as np
import pytest

from spacecal.core.errors import InvalidInputError
from spacecal.geometry.transforms import make_transform, rotvec_to_matrix
from spacecal.models.kinematics import fit_reported_kinematics, forward_kinematics
from spacecal.models.robot_kinds import robot_kind


def test_the_fitted_model_reproduces_a_calibrated_arm_with_a_rotated_tcp_everywhere():
    rng = np.random.default_rng(11)
    nominal = robot_kind("UR10e").model()
    tool = make_transform(rotvec_to_matrix([0.02, 0.25, -0.1]), [5.0, -3.0, 195.0])
    controller = nominal.with_dh_errors(
        rng.normal(0, 1.5, 6) * [0, 1, 1, 1, 1, 0],
        rng.normal(0, 1.5, 6),
        rng.normal(0, 0.002, 6) * [1, 1, 1, 1, 1, 0],
        rng.normal(0, 0.002, 6),
    ).with_tcp(tool)
    home = np.radians([0.0, -100.0, 100.0, -90.0, -90.0, 0.0])
    joints = home + rng.normal(0, 0.3, (60, 6))
    start = nominal.with_tcp(tool @ make_transform(np.eye(3), [1.0, -1.0, 2.0]))
    fitted, rms_mm = fit_reported_kinematics(start, joints, forward_kinematics(controller, joints))
    assert rms_mm < 1e-6
    elsewhere = home + rng.normal(0, 0.3, (200, 6))
    predicted = forward_kinematics(fitted, elsewhere)
    actual = forward_kinematics(controller, elsewhere)
    assert np.max(np.linalg.norm(predicted[:, :3, 3] - actual[:, :3, 3], axis=1)) < 1e-6
    np.testing.assert_allclose(predicted[:, :3, :3], actual[:, :3, :3], atol=1e-9)
    # the nominal model with the right tool is mm off: the fit is what makes the difference
    nominal_error = forward_kinematics(nominal.with_tcp(tool), elsewhere)[:, :3, 3] - actual[:, :3, 3]
    assert np.max(np.linalg.norm(nominal_error, axis=1)) > 1.0


def test_too_few_pairs_are_refused():
    model = robot_kind("UR10").model()
    joints = np.zeros((3, 6))
    with pytest.raises(InvalidInputError, match="at least 6 pairs"):
        fit_reported_kinematics(model, joints, forward_kinematics(model, joints))
