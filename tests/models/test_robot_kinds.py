"""The robot-kind registry: the kinds' models, modified DH, numeric inverse kinematics."""

import dataclasses

import numpy as np
import pytest

from spacecal.core.errors import InvalidInputError, UnreachableError
from spacecal.models import robot_kinds
from spacecal.models.gravity import STANDARD_GRAVITY_M_S2, gravity_joint_torques, link_dynamics_of
from spacecal.models.kinematics import (
    _link_transforms,
    _pose_error_vector,
    fit_reported_kinematics,
    forward_kinematics,
    geometric_jacobian,
    inverse_kinematics,
    uses_ur_closed_form,
    with_dh_corrections,
)
from spacecal.models.robot_kinds import (
    ROBOT_KINDS,
    LinkDynamics,
    RobotKind,
    register_robot_kind,
    robot_kind,
)

#: Franka's published Denavit–Hartenberg table (Craig's convention) of the Panda and the FR3,
#: in metres and radians as printed: rows (a, d, alpha) of joints 1-7 and of the flange.
FRANKA_TABLE_M = [
    (0.0, 0.333, 0.0),
    (0.0, 0.0, -np.pi / 2),
    (0.0, 0.316, np.pi / 2),
    (0.0825, 0.0, np.pi / 2),
    (-0.0825, 0.384, -np.pi / 2),
    (0.0, 0.0, np.pi / 2),
    (0.088, 0.0, np.pi / 2),
    (0.0, 0.107, 0.0),  # the flange, a fixed row
]


def craig_chain_mm(joints_rad):
    """base_from_flange of a Franka arm built link by link from the printed table, by 4x4
    products of the elementary transforms Rot_x(alpha) Trans_x(a) Rot_z(theta) Trans_z(d)."""

    def rot_x(angle):
        c, s = np.cos(angle), np.sin(angle)
        return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])

    def rot_z(angle):
        c, s = np.cos(angle), np.sin(angle)
        return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])

    def trans(x=0.0, z=0.0):
        out = np.eye(4)
        out[0, 3], out[2, 3] = x, z
        return out

    pose = np.eye(4)
    for (a, d, alpha), theta in zip(FRANKA_TABLE_M, list(joints_rad) + [0.0]):
        pose = pose @ rot_x(alpha) @ trans(x=a) @ rot_z(theta) @ trans(z=d)
    pose[:3, 3] *= 1000.0
    return pose


@pytest.mark.parametrize("name", ["FR3", "Panda"])
def test_franka_forward_kinematics_is_the_published_craig_chain(name):
    model = robot_kind(name).model()
    assert model.dh_convention == "modified"
    # Franka's zero pose: the flange 88 mm forward and 926 mm up, its z axis pointing down
    zero = forward_kinematics(model, np.zeros(7))
    assert np.allclose(zero[:3, 3], [88.0, 0.0, 926.0], atol=1e-9)
    assert np.allclose(zero[:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-12)
    rng = np.random.default_rng(11)
    joints = rng.uniform(model.joint_lower_rad, model.joint_upper_rad, (6, 7))
    poses = forward_kinematics(model, joints)
    for q, pose in zip(joints, poses):
        assert np.allclose(pose, craig_chain_mm(q), atol=1e-9)


def test_a_modified_dh_jacobian_is_the_derivative_of_the_pose():
    model = robot_kind("FR3").model(
        np.array([[1, 0, 0, 10.0], [0, 1, 0, -20.0], [0, 0, 1, 150.0], [0, 0, 0, 1]])
    )
    q = np.array([0.3, -0.5, 0.2, -2.0, 0.4, 1.8, -0.6])
    jac = geometric_jacobian(model, q)[0]
    step = 1e-6
    for j in range(7):
        plus, minus = q.copy(), q.copy()
        plus[j] += step
        minus[j] -= step
        up, down = forward_kinematics(model, plus), forward_kinematics(model, minus)
        assert np.allclose(jac[:3, j], (up[:3, 3] - down[:3, 3]) / (2 * step), atol=1e-5)
        twist = _pose_error_vector(up, down) / (2 * step)
        assert np.allclose(jac[3:, j], twist[3:], atol=1e-7)


def _round_trip(name, count, seed_sd_rad, rng):
    model = robot_kind(name).model(np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 120.0], [0, 0, 0, 1.0]]))
    assert not uses_ur_closed_form(model)
    margin = 0.05  # keep the true joints off the limits so a seed near them is inside too
    lower, upper = model.joint_lower_rad + margin, model.joint_upper_rad - margin
    truth = rng.uniform(lower, upper, (count, 7))
    seeds = np.clip(truth + rng.normal(0.0, seed_sd_rad, truth.shape), lower, upper)
    targets = forward_kinematics(model, truth)
    solved = inverse_kinematics(model, targets, seeds)
    error = _pose_error_vector(targets, forward_kinematics(model, solved))
    return model, truth, seeds, solved, error


@pytest.mark.parametrize("name", ["FR3", "LBR iiwa 7 R800"])
def test_numeric_inverse_kinematics_round_trips_near_the_seed_within_limits(name):
    rng = np.random.default_rng(5)
    model, truth, seeds, solved, error = _round_trip(name, 25, 0.15, rng)
    assert np.max(np.linalg.norm(error[:, :3], axis=1)) < 1e-6
    assert np.max(np.linalg.norm(error[:, 3:], axis=1)) < 1e-8
    assert np.all((solved >= model.joint_lower_rad) & (solved <= model.joint_upper_rad))
    # redundancy resolved towards the seed: no farther from it than the configuration the
    # pose was made from (which lies on the same self-motion), and a real move along it
    distance = np.linalg.norm(solved - seeds, axis=1)
    assert np.all(distance <= np.linalg.norm(truth - seeds, axis=1) + 1e-9)
    assert np.max(np.abs(solved - truth)) > 1e-3


def test_a_far_seed_still_finds_a_solution_inside_the_limits():
    rng = np.random.default_rng(8)
    model, _, _, solved, error = _round_trip("FR3", 8, 1.5, rng)
    assert np.max(np.linalg.norm(error[:, :3], axis=1)) < 1e-6
    assert np.all((solved >= model.joint_lower_rad) & (solved <= model.joint_upper_rad))


def test_an_unreachable_pose_is_one_clear_line():
    model = robot_kind("LBR iiwa 7 R800").model()
    far = np.eye(4)
    far[:3, 3] = [2000.0, 0.0, 300.0]
    with pytest.raises(UnreachableError, match=r"^pose 0 cannot be reached by the LBR iiwa 7 R800") as caught:
        inverse_kinematics(model, far, np.zeros(7))
    assert "\n" not in str(caught.value)


def test_an_unknown_kind_is_one_line_naming_the_known_ones():
    with pytest.raises(InvalidInputError) as caught:
        robot_kind("UR11")
    message = str(caught.value)
    assert "\n" not in message
    assert message.startswith("unknown robot kind 'UR11'; known: UR3, UR5, UR10")
    assert "FR3" in message and "LBR iiwa 14 R820" in message


def test_the_ur_kinds_keep_their_tables_and_side_figures():
    # the numbers the UR tables, the repeatability and the joint-speed tables held before
    ur10, ur5e = robot_kind("UR10"), robot_kind("UR5e")
    assert ur10.d_mm == (127.3, 0, 0, 163.941, 115.7, 92.2)
    assert ur10.a_mm == (0, -612.0, -572.3, 0, 0, 0)
    assert ur5e.d_mm == (162.5, 0, 0, 133.3, 99.7, 99.6)
    assert np.array_equal(ur10.model().alpha_rad, [np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0])
    assert np.array_equal(ur10.model().joint_upper_rad, np.full(6, 2 * np.pi))
    assert (ur10.controller_hz, ur5e.controller_hz) == (125.0, 500.0)
    assert [robot_kind(n).repeatability_mm for n in ("UR3", "UR5e", "UR10e")] == [0.1, 0.03, 0.05]
    assert ur10.joint_speed_deg_s == (120.0, 120.0, 180.0, 180.0, 180.0, 180.0)
    assert ur10.dynamics is not None and np.array_equal(
        ur10.dynamics.masses_kg, [7.1, 12.7, 4.27, 2.0, 2.0, 0.365]
    )
    for kind in ROBOT_KINDS.values():
        model = kind.model()
        assert uses_ur_closed_form(model) == (kind.inverse_kinematics == "ur_closed_form")


def test_every_kind_states_its_sources_and_datasheet_figures():
    expected_repeatability = {"FR3": 0.1, "Panda": 0.1, "LBR iiwa 7 R800": 0.1, "LBR iiwa 14 R820": 0.15}
    for name, value in expected_repeatability.items():
        assert robot_kind(name).repeatability_mm == value
    for kind in ROBOT_KINDS.values():
        assert kind.sources and all(kind.sources)
        assert kind.payload_kg > 0
        # no vendor of these arms publishes an absolute accuracy: the registry says so
        assert kind.kinematic_accuracy_mm == (None, None)
    assert np.allclose(robot_kind("FR3").joint_speed_deg_s[:4], np.degrees(2.62))


def test_a_modified_model_survives_corrections_identification_and_a_calibration_file():
    from spacecal.records.calibration import robot_model_from_dict, robot_model_to_dict

    nominal = robot_kind("FR3").model()
    rng = np.random.default_rng(2)
    true = with_dh_corrections(nominal, rng.normal(0.0, 1.0, 28) * np.repeat([0.5, 0.5, 0.001, 0.001], 7))
    assert true.dh_convention == "modified"
    joints = rng.uniform(nominal.joint_lower_rad, nominal.joint_upper_rad, (60, 7))
    fitted, rms_mm = fit_reported_kinematics(nominal, joints, forward_kinematics(true, joints))
    assert fitted.dh_convention == "modified" and rms_mm < 1e-6
    again = robot_model_from_dict(robot_model_to_dict(fitted), "calibration")
    assert again.dh_convention == "modified"
    assert np.allclose(forward_kinematics(again, joints), forward_kinematics(true, joints), atol=1e-5)
    assert "dh_convention" not in robot_model_to_dict(robot_kind("UR10").model())


@pytest.mark.parametrize("name", ["FR3", "UR10"])
def test_gravity_torques_are_the_gradient_of_the_potential_in_either_convention(name):
    model = robot_kind(name).model()
    joints_count = model.n_joints
    rng = np.random.default_rng(4)
    dynamics = LinkDynamics(
        name, rng.uniform(0.5, 4.0, joints_count), rng.uniform(-50, 50, (joints_count, 3))
    )

    def potential(q):
        links = _link_transforms(model, q[None])[0]
        frame, energy = np.eye(4), 0.0
        for i in range(joints_count):
            frame = frame @ links[i]
            centre = frame[:3, :3] @ dynamics.centres_of_mass_mm[i] + frame[:3, 3]
            energy += dynamics.masses_kg[i] * STANDARD_GRAVITY_M_S2 * centre[2] * 1e-3
        return energy

    q = rng.uniform(-1.5, 1.5, joints_count)
    torques = gravity_joint_torques(model, q, dynamics=dynamics)[0]
    step = 1e-6
    for j in range(joints_count):
        up, down = q.copy(), q.copy()
        up[j] += step
        down[j] -= step
        assert np.isclose(torques[j], -(potential(up) - potential(down)) / (2 * step), atol=1e-6)


def test_only_kinds_with_published_dynamics_have_a_gravity_model():
    assert link_dynamics_of("UR10") is not None
    assert link_dynamics_of("FR3") is None and link_dynamics_of("UR5e") is None
    assert link_dynamics_of("no such arm") is None


def test_a_kind_made_at_run_time_joins_the_registry_once():
    base = robot_kind("LBR iiwa 7 R800")
    made = dataclasses.replace(base, name="iiwa from a URDF", sources=("a URDF",))
    try:
        register_robot_kind(made)
        register_robot_kind(made)  # the same kind again is fine
        assert robot_kind("iiwa from a URDF").model().n_joints == 7
        with pytest.raises(InvalidInputError, match="already registered with other parameters"):
            register_robot_kind(dataclasses.replace(made, payload_kg=1.0))
    finally:
        robot_kinds._KINDS.pop(made.name, None)  # leave the registry as the other tests expect
    with pytest.raises(InvalidInputError, match="lower limit must be below"):
        dataclasses.replace(made, joint_lower_rad=made.joint_upper_rad)
    assert isinstance(made, RobotKind)


def test_a_ur_controller_takes_only_ur_kinds():
    from spacecal.adapters.ur import _ur_nominal

    assert _ur_nominal("UR10e").name == "UR10e"
    with pytest.raises(
        InvalidInputError, match="FR3 is a Franka Robotics arm; a UR controller drives one of UR3"
    ):
        _ur_nominal("FR3")
    with pytest.raises(InvalidInputError, match="unknown robot kind 'UR11'"):
        _ur_nominal("UR11")
