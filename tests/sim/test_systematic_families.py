"""The systematic error families a calibration was not designed against: joint compliance under
gravity, a depth-dependent tracker scale, a polynomial tracker bias and marker geometry errors.

Each changes the simulated measurements by the size injected; off (the default) none changes
anything.
"""

import dataclasses

import numpy as np
import pytest

from spacecal.core.errors import InvalidInputError
from spacecal.geometry.fitting import fit_rigid
from spacecal.geometry.transforms import invert_transform, make_transform, rotvec_to_matrix
from spacecal.models.gravity import STANDARD_GRAVITY_M_S2, gravity_joint_torques
from spacecal.models.kinematics import _link_transforms, forward_kinematics, geometric_jacobian
from spacecal.models.robot_kinds import robot_kind
from spacecal.sim.scenario import PRESETS, scenario_from_dict
from spacecal.sim.world import _points_in_volume, build_world

QUIET = dict(white_noise_rms_mm=0.0, volumetric_error_rms_mm=0.0, repeatability_mm=0.0)
NEW_FAMILIES = dict(
    joint_stiffness_nm_per_rad=(3e4, 3e4),
    payload_kg=0.5,
    depth_scale_per_100mm=1e-4,
    polynomial_error_rms_mm=0.1,
    marker_geometry_error_sd_mm=0.05,
)


def random_joints(world, count, seed=0):
    return world.home_joints_rad + np.random.default_rng(seed).uniform(-0.3, 0.3, (count, 6))


# -- off by default: nothing changes ---------------------------------------------------------
@pytest.mark.parametrize("preset", ["paper-realistic", "paper-realistic-nominal", "paper-white"])
def test_the_families_are_off_in_the_existing_presets(preset):
    scenario = PRESETS[preset]
    for key in NEW_FAMILIES:
        assert not np.any(getattr(scenario, key)), key
    world = build_world(scenario)
    assert world.bias_field is None and world.true_spheres_in_marker is None
    joints = random_joints(world, 20)
    assert not np.any(world.joint_deflections_rad(joints))
    assert np.array_equal(
        world.true_base_from_tcp(joints, jitter=False), forward_kinematics(world.true_model, joints)
    )


def test_switching_a_family_on_leaves_the_rest_of_the_world_and_its_noise_unchanged():
    base = PRESETS["paper-realistic"]
    plain, other = build_world(base), build_world(dataclasses.replace(base, **NEW_FAMILIES))
    for name in ("tracker_from_base", "tcp_from_marker", "site_in_base"):
        assert np.array_equal(getattr(plain, name), getattr(other, name))
    assert np.array_equal(plain.true_model.a_mm, other.true_model.a_mm)
    assert np.array_equal(plain.controller_model.d_mm, other.controller_model.d_mm)
    assert np.array_equal(plain.error_field.amplitudes_mm, other.error_field.amplitudes_mm)
    assert np.array_equal(plain.noise_rng.random(5), other.noise_rng.random(5))


def test_the_measurements_of_a_default_scenario_follow_the_volumetric_and_white_noise_model_only():
    world = build_world(PRESETS["paper-realistic"])
    poses = np.tile(np.eye(4), (50, 1, 1))
    poses[:, :3, 3] = world.tracker.volume.centre() + np.random.default_rng(1).uniform(-100, 100, (50, 3))
    truth = np.einsum("nij,kj->nki", poses[:, :3, :3], world.marker.spheres_in_marker) + poses[:, None, :3, 3]
    expected_rng = np.random.default_rng([world.scenario.seed, 1])
    lateral_sd = world.scenario.white_noise_rms_mm / np.sqrt(3.0)
    expected = truth + world.error_field(truth) + expected_rng.normal(scale=lateral_sd, size=truth.shape)
    assert np.array_equal(world.measure_spheres(poses), expected)


# -- joint compliance -------------------------------------------------------------------------
def potential_energy_j(model, joints, payload_kg):
    """Gravitational potential energy (J) of the point masses gravity_joint_torques uses."""
    dynamics = robot_kind(model.name).dynamics
    links = _link_transforms(model, np.atleast_2d(joints))
    frame = np.eye(4)
    height = 0.0
    for i in range(6):
        frame = frame @ links[0, i]
        height += dynamics.masses_kg[i] * (frame[:3, :3] @ dynamics.centres_of_mass_mm[i] + frame[:3, 3])[2]
    tool_mid = frame[:3, :3] @ (0.5 * model.flange_from_tcp[:3, 3]) + frame[:3, 3]
    height += payload_kg * tool_mid[2]
    return STANDARD_GRAVITY_M_S2 * height * 1e-3


def test_gravity_torques_are_the_gradient_of_the_potential_energy():
    world = build_world(PRESETS["paper-realistic"])
    joints = random_joints(world, 5)
    torques = gravity_joint_torques(world.true_model, joints, payload_kg=0.5)
    step = 1e-6
    for q, tau in zip(joints, torques):
        for j in range(6):
            up, down = q.copy(), q.copy()
            up[j] += step
            down[j] -= step
            gradient = (
                potential_energy_j(world.true_model, up, 0.5)
                - potential_energy_j(world.true_model, down, 0.5)
            ) / (2 * step)
            # a generalised force is minus the gradient of the potential; central differences of
            # a smooth function of O(100) J are good to about 1e-4 N m at this step
            assert tau[j] == pytest.approx(-gradient, abs=1e-3)
    assert np.allclose(torques[:, 0], 0.0, atol=1e-9)  # the base axis is vertical


def test_compliance_moves_the_real_tcp_by_the_deflection_the_controller_does_not_see():
    stiffness = 3e4
    scenario = dataclasses.replace(
        PRESETS["paper-realistic"], joint_stiffness_nm_per_rad=(stiffness, stiffness), payload_kg=0.5
    )
    world = build_world(scenario)
    joints = random_joints(world, 30)
    deflection = world.joint_deflections_rad(joints)
    torques = gravity_joint_torques(world.true_model, joints, 0.5)
    assert np.allclose(deflection[:, 1:3], torques[:, 1:3] / stiffness)
    assert not np.any(deflection[:, [0, 3, 4, 5]])
    rigid = forward_kinematics(world.true_model, joints)
    sagged = world.true_base_from_tcp(joints, jitter=False)
    moved = sagged[:, :3, 3] - rigid[:, :3, 3]
    # first order: the position Jacobian times the deflection; the second-order remainder is
    # about |J| |dq|^2, under 1 % of the move for deflections of a few mrad
    predicted = np.array(
        [geometric_jacobian(world.true_model, q).reshape(6, 6)[:3] @ dq for q, dq in zip(joints, deflection)]
    )
    assert np.allclose(moved, predicted, rtol=0, atol=0.01 * np.abs(predicted).max())
    assert np.linalg.norm(moved, axis=1).min() > 0.5  # mm: torques of tens of N m at 3e4 N m/rad
    # the controller reports through its model of the encoder angles, without the sag
    assert np.array_equal(
        world.controller_model.a_mm, build_world(PRESETS["paper-realistic"]).controller_model.a_mm
    )


# -- tracker bias fields ----------------------------------------------------------------------
def quiet_world(**families):
    return build_world(dataclasses.replace(PRESETS["paper-realistic"], **QUIET, **families))


def single_points(points):
    """Marker poses that put the marker origin (its first sphere) at ``points`` (N, 3)."""
    poses = np.tile(np.eye(4), (len(points), 1, 1))
    poses[:, :3, 3] = points
    return poses


def test_depth_scale_is_zero_at_the_reference_depth_and_scales_with_depth():
    scale = 1e-4
    world = quiet_world(depth_scale_per_100mm=scale)
    reference = world.bias_field.reference_depth_mm
    rng = np.random.default_rng(3)
    for offset in (0.0, 100.0, -200.0):
        points = np.column_stack([rng.uniform(-150, 150, (40, 2)), np.full(40, -(reference + offset))])
        measured = world.measure_spheres(single_points(points))[:, 0]
        expected = scale * offset / 100.0 * points
        assert np.allclose(measured - points, expected, rtol=1e-9, atol=1e-12)


def test_polynomial_bias_has_the_injected_rms_over_the_volume():
    rms = 0.1
    world = quiet_world(polynomial_error_rms_mm=rms)
    points = _points_in_volume(np.random.default_rng(11), world.tracker, 20000)
    error = world.measure_spheres(single_points(points))[:, 0] - points
    squared = np.sum(error**2, axis=1)
    measured = np.sqrt(squared.mean())
    # the field was scaled on 4000 other points of the volume: both estimates of the mean
    # square scatter with s.d. sd(e^2) / sqrt(n); allow 4 such s.d. of the RMS
    tolerance = 4 * squared.std() / np.sqrt(4000) / (2 * rms)
    assert measured == pytest.approx(rms, abs=tolerance * rms + 1e-12)
    assert tolerance < 0.2
    # smooth: neighbouring points 1 mm apart differ by far less than the field
    step = world.measure_spheres(single_points(points[:100] + [1.0, 0.0, 0.0]))[:, 0] - (
        points[:100] + [1, 0, 0]
    )
    assert np.abs(step - error[:100]).max() < 0.01 * rms * 10


# -- marker geometry --------------------------------------------------------------------------
def test_marker_geometry_errors_have_the_injected_size():
    sd = 0.1
    offsets = np.concatenate(
        [
            build_world(
                dataclasses.replace(PRESETS["paper-realistic"], seed=seed, marker_geometry_error_sd_mm=sd)
            ).true_spheres_in_marker
            - build_world(PRESETS["paper-realistic"]).marker.spheres_in_marker
            for seed in range(1, 41)
        ]
    ).ravel()
    # 480 normals: the sample s.d. is within 4 of its standard errors sd / sqrt(2 n)
    assert offsets.std() == pytest.approx(sd, abs=4 * sd / np.sqrt(2 * len(offsets)))


def test_the_tracker_fits_the_definition_to_the_true_spheres():
    world = quiet_world(marker_geometry_error_sd_mm=0.1)
    true_spheres = world.true_spheres_in_marker
    marker_from_fit, fit_rms = fit_rigid(
        points_in_source=world.marker.spheres_in_marker, points_in_target=true_spheres
    )
    rng = np.random.default_rng(5)
    facing = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])  # marker x (face) to tracker +z
    poses = make_transform(
        rotvec_to_matrix(rng.normal(scale=0.2, size=(20, 3))) @ facing,
        world.tracker.volume.centre() + rng.uniform(-100, 100, (20, 3)),
    )
    frames = world.track_marker(poses)
    seen = np.isfinite(frames.rms_mm)
    assert seen.sum() >= 10
    for truth, measured, rms in zip(poses[seen], frames.tracker_from_marker[seen], frames.rms_mm[seen]):
        # the fit is off by one fixed transform in the marker frame, whatever the view ...
        assert np.allclose(invert_transform(truth) @ measured, marker_from_fit, atol=1e-9)
        # ... and reports the misfit of the definition to the true spheres as its RMS
        assert rms == pytest.approx(float(fit_rms), rel=1e-6)
    assert 0.0 < float(fit_rms) < 3 * 0.1


# -- fields and presets -----------------------------------------------------------------------
@pytest.mark.parametrize(
    "key,value",
    [
        ("joint_stiffness_nm_per_rad", [-1.0, 3e4]),
        ("joint_stiffness_nm_per_rad", 3e4),
        ("payload_kg", -0.1),
        ("depth_scale_per_100mm", 0.5),
        ("polynomial_error_rms_mm", -0.1),
        ("marker_geometry_error_sd_mm", 11.0),
    ],
)
def test_family_fields_are_checked(key, value):
    with pytest.raises(InvalidInputError, match=key):
        scenario_from_dict({key: value})


@pytest.mark.parametrize(
    "preset",
    [
        "systematic-nominal",
        "systematic-nominal-angles",
        "systematic-calibrated-compliant",
        "systematic-nominal-all",
        "systematic-calibrated-all",
    ],
)
def test_systematic_presets_build_and_load_by_name(preset):
    scenario = scenario_from_dict({"preset": preset})
    assert scenario == PRESETS[preset] and scenario.name == preset
    assert scenario.motion == "stations" and scenario.stations == 120
    world = build_world(scenario)
    assert (world.controller_model is world.nominal_model) == (scenario.controller_kinematics == "nominal")
