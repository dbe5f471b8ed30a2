import numpy as np
import pytest

from spacecal.core.errors import InvalidInputError, UnreachableError
from spacecal.geometry.transforms import make_transform
from spacecal.models.kinematics import (
    UR_TABLES,
    forward_kinematics,
    geometric_jacobian,
    inverse_kinematics,
    ur_model,
    within_joint_limits,
)

TOOL = make_transform(np.eye(3), [10.0, -5.0, 200.0])


def test_zero_pose_of_ur10_matches_published_geometry():
    # At q = 0 a UR stretches along -x: x = a2 + a3, y = -(d4 + d6), z = d1 - d5.
    pose = forward_kinematics(ur_model("UR10"), np.zeros(6))
    assert np.allclose(pose[:3, 3], [-612.0 - 572.3, -163.941 - 92.2, 127.3 - 115.7])


@pytest.mark.parametrize("name", sorted(UR_TABLES))
def test_inverse_kinematics_round_trip_to_1e_9_mm(name):
    model = ur_model(name, TOOL)
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
    model = ur_model("UR10", TOOL).with_dh_errors(
        rng.normal(scale=0.5, size=6),
        rng.normal(scale=0.5, size=6),
        rng.normal(scale=1e-3, size=6),
        rng.normal(scale=1e-3, size=6),
    )
    joints = np.radians([10, -100, 100, -90, -80, 20])
    pose = forward_kinematics(model, joints)
    solved = inverse_kinematics(model, pose, joints)
    assert np.max(np.abs(forward_kinematics(model, solved)[:3, 3] - pose[:3, 3])) < 1e-9


def test_all_eight_branches_reach_the_same_pose():
    model = ur_model("UR5")
    pose = forward_kinematics(model, np.radians([20, -80, 70, -60, 85, 30]))
    references = np.radians([[20, -80, 70, -60, 85, 30], [-160, -100, -70, -120, -85, -150]])
    first, second = (inverse_kinematics(model, pose, r) for r in references)
    assert not np.allclose(first, second, atol=1e-3)
    for solved in (first, second):
        assert np.allclose(forward_kinematics(model, solved), pose, atol=1e-9)


def test_unreachable_pose_raises():
    with pytest.raises(UnreachableError, match="workspace"):
        inverse_kinematics(ur_model("UR3"), make_transform(np.eye(3), [3000.0, 0, 0]))


def test_joint_limits_are_respected():
    model = ur_model("UR10")
    narrow = type(model)(
        **{**model.__dict__, "joint_lower_rad": np.full(6, -0.1), "joint_upper_rad": np.full(6, 0.1)}
    )
    pose = forward_kinematics(model, np.radians([90, -90, 90, -90, -90, 0]))
    with pytest.raises(UnreachableError, match="joint limits"):
        inverse_kinematics(narrow, pose)
    assert within_joint_limits(model, np.zeros((2, 6))).all()


def test_jacobian_matches_finite_differences():
    model = ur_model("UR10e", TOOL)
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
        ur_model("UR11")
