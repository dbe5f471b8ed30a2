import numpy as np
import pytest

from spacecal.core.errors import InvalidInputError, UnreachableError
from spacecal.geometry.transforms import axis_angle_transform, make_transform
from spacecal.models.kinematics import (
    apply_pose_step,
    chain_points_in_tracker,
    forward_kinematics,
    geometric_jacobian,
    inverse_kinematics,
    inverse_kinematics_gauss_newton,
    pose_point_jacobian,
    pose_step_between,
    within_joint_limits,
)
from spacecal.models.robot_kinds import robot_kind, ur_kind_names

TOOL = make_transform(np.eye(3), [10.0, -5.0, 200.0])


def test_zero_pose_of_ur10_matches_published_geometry():
    # At q = 0 a UR stretches along -x: x = a2 + a3, y = -(d4 + d6), z = d1 - d5.
    pose = forward_kinematics(robot_kind("UR10").model(), np.zeros(6))
    assert np.allclose(pose[:3, 3], [-612.0 - 572.3, -163.941 - 92.2, 127.3 - 115.7])


@pytest.mark.parametrize("name", sorted(ur_kind_names()))
def test_inverse_kinematics_round_trip_to_1e_9_mm(name):
    model = robot_kind(name).model(TOOL)
    rng = np.random.default_rng(abs(hash(name)) % 2**32)
    joints = rng.uniform(-np.pi, np.pi, (40, 6))
    poses = forward_kinematics(model, joints)
    solved = inverse_kinematics(model, poses, joints, tol_mm=1e-9)
    reached = forward_kinematics(model, solved)
    assert np.max(np.abs(reached[:, :3, 3] - poses[:, :3, 3])) < 1e-9
    assert np.max(np.abs(reached[:, :3, :3] - poses[:, :3, :3])) < 1e-12
    # nearest to the reference: the configuration we started from
    assert np.allclose(solved, joints, atol=1e-7)


def test_inverse_kinematics_on_a_model_with_dh_errors():
    rng = np.random.default_rng(5)
    model = (
        robot_kind("UR10")
        .model(TOOL)
        .with_dh_errors(
            rng.normal(scale=0.5, size=6),
            rng.normal(scale=0.5, size=6),
            rng.normal(scale=1e-3, size=6),
            rng.normal(scale=1e-3, size=6),
        )
    )
    joints = np.radians([10, -100, 100, -90, -80, 20])
    pose = forward_kinematics(model, joints)
    solved = inverse_kinematics(model, pose, joints)
    assert np.max(np.abs(forward_kinematics(model, solved)[:3, 3] - pose[:3, 3])) < 1e-9


def test_all_eight_branches_reach_the_same_pose():
    model = robot_kind("UR5").model()
    pose = forward_kinematics(model, np.radians([20, -80, 70, -60, 85, 30]))
    references = np.radians([[20, -80, 70, -60, 85, 30], [-160, -100, -70, -120, -85, -150]])
    first, second = (inverse_kinematics(model, pose, r) for r in references)
    assert not np.allclose(first, second, atol=1e-3)
    for solved in (first, second):
        assert np.allclose(forward_kinematics(model, solved), pose, atol=1e-9)


def test_unreachable_pose_raises():
    with pytest.raises(UnreachableError, match="workspace"):
        inverse_kinematics(robot_kind("UR3").model(), make_transform(np.eye(3), [3000.0, 0, 0]))


def test_joint_limits_are_respected():
    model = robot_kind("UR10").model()
    narrow = type(model)(
        **{**model.__dict__, "joint_lower_rad": np.full(6, -0.1), "joint_upper_rad": np.full(6, 0.1)}
    )
    pose = forward_kinematics(model, np.radians([90, -90, 90, -90, -90, 0]))
    with pytest.raises(UnreachableError, match="joint limits"):
        inverse_kinematics(narrow, pose)
    assert within_joint_limits(model, np.zeros((2, 6))).all()


def test_jacobian_matches_finite_differences():
    model = robot_kind("UR10e").model(TOOL)
    q = np.radians([15, -95, 105, -80, -70, 40])
    jac = geometric_jacobian(model, q)[0]
    eps = 1e-7
    for j in range(6):
        dq = np.zeros(6)
        dq[j] = eps
        forward = forward_kinematics(model, q + dq)[:3, 3]
        backward = forward_kinematics(model, q - dq)[:3, 3]
        assert np.allclose((forward - backward) / (2 * eps), jac[:3, j], atol=1e-4)


def test_unknown_model_lists_known_ones():
    with pytest.raises(InvalidInputError, match="UR10e"):
        robot_kind("UR11").model()


def test_gauss_newton_ik_converges_from_nearby_and_reports_failure():
    model = robot_kind("UR10").model(TOOL)
    joints = np.radians([[15, -95, 105, -80, -70, 40], [-30, -70, 90, -100, -90, 10]])
    poses = forward_kinematics(model, joints)
    solved, converged = inverse_kinematics_gauss_newton(
        model, poses, joints + 0.05, max_iterations=30, position_tol_mm=1e-9, rotation_tol_rad=1e-12
    )
    assert converged and np.allclose(forward_kinematics(model, solved), poses, atol=1e-9)
    far = make_transform(np.eye(3), [5000.0, 0.0, 0.0])[None]
    _, converged = inverse_kinematics_gauss_newton(
        model, far, joints[:1], max_iterations=30, position_tol_mm=1e-9, rotation_tol_rad=1e-12
    )
    assert not converged


def test_pose_step_round_trip_and_analytic_jacobian():
    rng = np.random.default_rng(2)
    tracker_from_base = axis_angle_transform([1, 2, 3], 0.7, [100.0, -50.0, -1200.0])
    tcp_from_marker = axis_angle_transform([0, 1, 1], -0.4, [20.0, 80.0, 40.0])
    step = rng.normal(scale=[1, 1, 1, 0.01, 0.01, 0.01, 1, 1, 1, 0.01, 0.01, 0.01])
    moved = apply_pose_step(tracker_from_base, tcp_from_marker, step)
    assert np.allclose(pose_step_between(tracker_from_base, tcp_from_marker, *moved), step, atol=1e-12)
    base_from_tcp = forward_kinematics(robot_kind("UR5").model(), rng.uniform(-2, 2, (4, 6)))
    points = rng.normal(size=(3, 3)) * 40
    jac = pose_point_jacobian(base_from_tcp, tracker_from_base, tcp_from_marker, points)
    assert jac.shape == (4, 3, 3, 12)
    eps = 1e-6
    for k in range(12):
        delta = np.zeros(12)
        delta[k] = eps
        plus = chain_points_in_tracker(
            base_from_tcp, *apply_pose_step(tracker_from_base, tcp_from_marker, delta), points
        )
        minus = chain_points_in_tracker(
            base_from_tcp, *apply_pose_step(tracker_from_base, tcp_from_marker, -delta), points
        )
        assert np.allclose((plus - minus) / (2 * eps), jac[..., k], atol=1e-4)


@pytest.mark.parametrize("angle_rad", [0.0, 1e-9, 1e-4, 0.3, 2.0, 2.99, 3.05, np.pi - 1e-6])
def test_ik_rotation_error_is_the_rotation_vector(angle_rad):
    """IK's closed-form log map agrees with scipy's general conversion at every angle."""
    from scipy.spatial.transform import Rotation

    from spacecal.models.kinematics import _rotation_error_vector

    axes = np.random.default_rng(3).normal(size=(50, 3))
    vectors = angle_rad * axes / np.linalg.norm(axes, axis=1, keepdims=True)
    matrices = Rotation.from_rotvec(vectors).as_matrix()
    np.testing.assert_allclose(_rotation_error_vector(matrices), vectors, atol=1e-9)
