"""Joint-compliance identification with the DH corrections (``identify_kinematics``), and the
compliance model it goes with: recovered on a compliant arm, about zero and harmless on a rigid one."""

import dataclasses

import numpy as np
import pytest

from spacecal.core.errors import InvalidInputError
from spacecal.estimators.assessment.report import report_uncertainty
from spacecal.estimators.methods.kinematic import COMPLIANCE_NAMES, identify_kinematics, joint_compliance_of
from spacecal.experiments.simulation import simulate
from spacecal.experiments.verification import verify_in_simulation
from spacecal.models.compliance import (
    JointCompliance,
    compliant_forward_kinematics,
    compliant_inverse_kinematics,
    deflected_joints,
)
from spacecal.models.kinematics import forward_kinematics
from spacecal.records import CalibrationResult
from spacecal.sim.scenario import PRESETS, scenario_from_dict
from spacecal.sim.world import build_world

STIFFNESS_NM_PER_RAD = 3e4
#: The compliant arm without any noise: no tracker noise or bias, no repeatability scatter, a
#: controller that knows the true DH parameters, and no payload (the estimator's torques then
#: are the simulator's exactly).
NOISE_FREE_COMPLIANT = dataclasses.replace(
    PRESETS["systematic-calibrated-compliant"],
    white_noise_rms_mm=0.0,
    volumetric_error_rms_mm=0.0,
    repeatability_mm=0.0,
    dropout_probability=0.0,
    calibration_residual_length_sd_mm=0.0,
    calibration_residual_angle_sd_deg=0.0,
    joint_stiffness_nm_per_rad=(STIFFNESS_NM_PER_RAD, STIFFNESS_NM_PER_RAD),
    payload_kg=0.0,
)
#: A rigid arm with DH errors seen through white tracker noise only.
RIGID_WHITE = dataclasses.replace(
    PRESETS["paper-white"], motion="stations", dh_length_error_sd_mm=0.3, dh_angle_error_sd_deg=0.03
)


def identified(recording, **options):
    """The identification's solution, assessed as the registry assesses it."""
    return report_uncertainty(identify_kinematics(recording, **options))


def mean_error_mm(calibration, scenario):
    return float(np.mean(verify_in_simulation(calibration, scenario).position_error_mm))


@pytest.fixture(scope="module")
def noise_free_compliant():
    recording = simulate(NOISE_FREE_COMPLIANT).recording
    return (
        identified(recording, joint_compliance=True),
        identified(recording, joint_compliance=False),
    )


def test_compliance_is_recovered_on_a_noise_free_compliant_arm(noise_free_compliant):
    with_compliance, _ = noise_free_compliant
    compliance = joint_compliance_of(with_compliance)
    assert compliance is not None
    truth = 1.0 / STIFFNESS_NM_PER_RAD
    report = with_compliance.diagnostics["kinematic_identification"]["joint_compliance"]
    for value, sd in zip(compliance.rad_per_nm, report["sd_rad_per_nm"]):
        # without noise what is left is the pull of the DH corrections' priors, which the
        # stated s.d. (from the fit's residuals) covers; it is itself well under 1 % of the value
        assert sd is not None and sd < 0.01 * truth
        assert abs(value - truth) < 3.0 * sd
    identified = {
        c["parameter"] for c in with_compliance.diagnostics["kinematic_identification"]["identified"]
    }
    assert set(COMPLIANCE_NAMES) <= identified


def test_the_identified_compliance_is_applied_when_reaching_targets(noise_free_compliant):
    with_compliance, without = noise_free_compliant
    compensated = mean_error_mm(with_compliance, NOISE_FREE_COMPLIANT)
    rigid = mean_error_mm(without, NOISE_FREE_COMPLIANT)
    # the rigid fit leaves the sag's change over the targets (0.06 mm here); with the compliance
    # applied only the compliance's 1e-3 error remains
    assert compensated < 1e-3
    assert compensated < 0.1 * rigid


def test_compliance_is_about_zero_on_a_rigid_arm_and_costs_no_accuracy():
    recording = simulate(RIGID_WHITE).recording
    # a fixed prior frees the corrections on this arm whatever the held-out misfit shows
    with_compliance = identified(recording, joint_compliance=True, prior_from_data=False)
    without = identified(recording, joint_compliance=False, prior_from_data=False)
    report = with_compliance.diagnostics["kinematic_identification"]["joint_compliance"]
    compliance = joint_compliance_of(with_compliance)
    assert compliance is not None
    for value, sd in zip(compliance.rad_per_nm, report["sd_rad_per_nm"]):
        if sd is not None:
            assert abs(value) < 4.0 * sd  # zero within the white noise's reach
    # and the shoulder's is determined well enough for that to say something: its s.d. is a
    # tenth of a 3e4 N m/rad joint's compliance
    assert report["sd_rad_per_nm"][0] is not None
    assert report["sd_rad_per_nm"][0] < 0.1 / STIFFNESS_NM_PER_RAD
    assert mean_error_mm(with_compliance, RIGID_WHITE) <= mean_error_mm(without, RIGID_WHITE)


def test_the_compliance_survives_the_calibration_file(noise_free_compliant):
    with_compliance, without = noise_free_compliant
    read = CalibrationResult.from_dict(with_compliance.to_dict())
    original, again = joint_compliance_of(with_compliance), joint_compliance_of(read)
    assert original is not None and again is not None
    assert np.array_equal(original.rad_per_nm, again.rad_per_nm)
    assert np.array_equal(original.reference_torques_nm, again.reference_torques_nm)
    assert joint_compliance_of(without) is None


# -- the compliance model ---------------------------------------------------------------------
def test_the_model_deflects_the_joints_as_the_simulated_arm_does():
    world = build_world(dataclasses.replace(NOISE_FREE_COMPLIANT, payload_kg=0.5))
    joints = world.home_joints_rad + np.random.default_rng(3).uniform(-0.3, 0.3, (20, 6))
    compliance = JointCompliance(np.full(2, 1.0 / STIFFNESS_NM_PER_RAD), payload_kg=0.5)
    assert np.allclose(
        deflected_joints(world.true_model, compliance, joints) - joints,
        world.joint_deflections_rad(joints),
        rtol=1e-12,
        atol=1e-15,
    )
    assert np.allclose(
        compliant_forward_kinematics(world.true_model, compliance, joints),
        world.true_base_from_tcp(joints, jitter=False),
        atol=1e-9,
    )


def test_compliant_inverse_kinematics_lands_the_deflected_arm_on_the_target():
    world = build_world(NOISE_FREE_COMPLIANT)
    compliance = JointCompliance(np.array([3e-5, 5e-5]), reference_torques_nm=np.array([20.0, 30.0]))
    targets = forward_kinematics(
        world.true_model, world.home_joints_rad + np.random.default_rng(4).uniform(-0.2, 0.2, (10, 6))
    )
    encoder = compliant_inverse_kinematics(world.true_model, compliance, targets, world.home_joints_rad)
    reached = compliant_forward_kinematics(world.true_model, compliance, encoder)
    assert np.max(np.abs(reached - targets)) < 1e-7
    # and the rigid solution would have missed by the sag
    rigid = forward_kinematics(world.true_model, encoder)
    assert np.max(np.linalg.norm(rigid[:, :3, 3] - targets[:, :3, 3], axis=1)) > 0.1


def test_an_arm_without_published_dynamics_is_identified_rigid_and_says_why():
    # the UR10e's link masses are not in the registry: no gravity model, not the UR10's
    scenario = dataclasses.replace(RIGID_WHITE, robot_model="UR10e")
    recording = simulate(scenario).recording
    calibration = identified(recording, joint_compliance=True, prior_from_data=False)
    report = calibration.diagnostics["kinematic_identification"]
    assert joint_compliance_of(calibration) is None
    assert report["joint_compliance_skipped"].startswith("the UR10e has no published link dynamics")
    assert not set(COMPLIANCE_NAMES) & {c["parameter"] for c in report["identified"]}
    rigid = identified(recording, joint_compliance=False, prior_from_data=False)
    assert rigid.diagnostics["kinematic_identification"]["joint_compliance_skipped"] is None
    with pytest.raises(InvalidInputError, match="the UR10e has no published link dynamics"):
        scenario_from_dict({"robot_model": "UR10e", "joint_stiffness_nm_per_rad": [3e4, 3e4]})
