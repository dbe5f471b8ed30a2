"""The KinHEC benchmark's conversion (``benchmarks/kinhec_conversion.py``) gets the frames right.

On sequences of KinHEC's smoke tier, generated here: KinHEC's noise-free columns fit its ground
truth through the converted chain exactly, its measurements fit it as closely as the noise it
injected allows, and spacecal's ML estimator recovers the ground truth within a few standard
errors of that noise. Skipped without the ``kinhec`` package (the ``test`` extra has it).
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("kinhec")

from spacecal.estimators import calibrate
from spacecal.estimators.time_offset import pair_streams

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


def _benchmark(name: str):
    """``benchmarks/<name>.py``, loaded by path (benchmarks is no package)."""
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


conversion = _benchmark("kinhec_conversion")


def _tier_sequence(tier_name: str, sequence_id: str):
    """One sequence of a KinHEC tier, generated from its seeded recipe (about a second)."""
    import kinhec
    from kinhec.generator import generate_sequence
    from kinhec.io import Sequence
    from kinhec.plans import build_plan, load_tier

    track = sequence_id.rsplit("-", 1)[0]
    tier = load_tier(str(Path(kinhec.__file__).parent / "configs" / f"{tier_name}.yaml"))
    (config,) = [c for c in build_plan(tier, [track])[track] if c.sequence_id == sequence_id]
    record = generate_sequence(config)
    return Sequence(record.manifest, record.robot_table, record.camera_table)


def _smoke_sequence(sequence_id: str):
    """One sequence of KinHEC's smoke tier (:func:`_tier_sequence`)."""
    return _tier_sequence("smoke", sequence_id)


@pytest.fixture(scope="module", params=["noise-000000", "noise-000004"], ids=["eye-in-hand", "eye-to-hand"])
def sequence(request):
    """UR5e, 4 s of joint sinusoids at 30 Hz, robot noise r2 and camera noise c1."""
    return _smoke_sequence(request.param)


def test_noise_free_data_fit_the_ground_truth_exactly(sequence):
    worst_mm, worst_deg = conversion.check_exact(sequence)
    assert worst_mm < 1e-9 and worst_deg < conversion.EXACT_TOLERANCE_DEG


def test_measurements_fit_the_ground_truth_as_the_injected_noise_allows(sequence):
    recording = conversion.to_recording(sequence)
    assert recording.metadata["robot"]["model"] == "UR5e"
    assert np.all(np.isfinite(recording.joints_rad))
    assert np.all(np.isnan(recording.marker_rms_mm))  # pose only: no fit RMS
    distance, angle = conversion.chain_residuals(recording, *conversion.truth(sequence))
    noise_mm, noise_deg = conversion.expected_residual_rms(sequence)
    # about 120 frames x 3 axes: the RMS is within a few per cent of the noise's
    assert 0.8 < np.sqrt(np.mean(distance**2)) / noise_mm < 1.25
    assert 0.8 < np.sqrt(np.mean(angle**2)) / noise_deg < 1.25


def test_ml_recovers_the_ground_truth_within_the_noise(sequence):
    recording = conversion.to_recording(sequence)
    true_tracker_from_base, true_tcp_from_marker = conversion.truth(sequence)
    result = calibrate(recording, "ml")
    noise_mm, noise_deg = conversion.expected_residual_rms(sequence)
    frames = int(recording.has_pose.sum())
    # three standard errors of 12 unknowns fitted to the frames' noise
    shrink = 3.0 * np.sqrt(12.0 / frames)
    rotation_x, translation_x = conversion.pose_error(result.tcp_from_marker, true_tcp_from_marker)
    rotation_y, _ = conversion.pose_error(result.tracker_from_base, true_tracker_from_base)
    site = recording.base_from_tcp_stack[recording.has_pose, :3, 3]
    site_mm = conversion.site_error_mm(result.tracker_from_base, true_tracker_from_base, site)
    assert rotation_x < shrink * noise_deg and rotation_y < shrink * noise_deg
    assert translation_x < shrink * noise_mm
    assert site_mm < shrink * noise_mm


def test_two_streams_pair_at_the_offset_kinhec_injected():
    """Temporal track: the camera clock 50 ms ahead. Paired at the converted offset the frames
    fit the ground truth as the synchronous ones do; at the opposite sign they do not."""
    sequence = _smoke_sequence("temporal-000000")
    converted = conversion.to_raw_recording(sequence)
    assert converted.true_offset_s == pytest.approx(-0.05)
    truth = conversion.truth(sequence)
    noise_mm, _ = conversion.expected_residual_rms(sequence)
    right, _ = conversion.chain_residuals(pair_streams(converted.raw, converted.true_offset_s), *truth)
    wrong, _ = conversion.chain_residuals(pair_streams(converted.raw, -converted.true_offset_s), *truth)
    assert np.sqrt(np.mean(right**2)) < 1.25 * noise_mm
    assert np.sqrt(np.mean(wrong**2)) > 3.0 * noise_mm


#: A small-tier sequence of each KinHEC arm spacecal has no name for: a KUKA LBR iiwa (standard
#: DH, seven joints), a Franka Panda (Craig's modified DH) and an ABB IRB 120 (axis 3 counted
#: the other way).
ARM_SEQUENCES = {"iiwa14": "noise-000096", "panda": "noise-000048", "irb120": "outliers-000028"}


@pytest.mark.parametrize("arm", sorted(ARM_SEQUENCES))
def test_the_metadata_model_gives_the_flange_poses_kinhec_reported(arm):
    """The model in ``robot.kinematic_model``, at the joint values written, puts the flange where
    KinHEC's own forward kinematics put it (its noise-free columns: true joint angles and flange
    poses), whatever DH convention or joint sense KinHEC describes the arm in."""
    from spacecal.estimators.methods.recorded_model import nominal_robot_model
    from spacecal.models.kinematics import forward_kinematics

    recording = conversion.to_recording(_tier_sequence("small", ARM_SEQUENCES[arm]), noise_free=True)
    model = nominal_robot_model(recording)
    assert model is not None and model.name == arm
    assert np.all(np.isfinite(recording.joints_rad))
    reported = forward_kinematics(model, recording.joints_rad)
    assert np.max(np.abs(reported - recording.base_from_tcp_stack)) < 1e-6


#: KinHEC's small tier, robot-error track: a UR5e's 30 static camera views with DH errors of
#: 0.1 or 1 mm and 0.01 or 0.1 deg, two motion seeds each.
#: The DH-error sequences of KinHEC's small robot-error track, per arm: a UR5e (six joints,
#: named in the metadata) and a KUKA LBR iiwa 7 (seven, its DH table in the metadata).
DH_SEQUENCES = {
    "UR5e": [f"robot_error-{k:06d}" for k in (2, 3, 4, 5, 8, 9, 10, 11)],
    "iiwa7": [f"robot_error-{k:06d}" for k in (14, 15, 16, 17, 20, 21, 22, 23)],
}


@pytest.mark.parametrize("arm", sorted(DH_SEQUENCES))
def test_the_noise_beyond_the_dh_errors_is_the_camera_noise_kinhec_injected(arm):
    """One frame per pose and no fit RMS: the noise spacecal takes from what the residuals leave
    beyond the pose and the arm's DH errors, against the camera noise KinHEC injected (its
    measured minus its noise-free target poses, at the marker's spheres)."""
    from spacecal.estimators.assessment.white_noise import white_noise_beyond_kinematics
    from spacecal.estimators.methods.observations import build_observations
    from spacecal.estimators.methods.recorded_model import nominal_robot_model
    from spacecal.models.kinematics import forward_kinematics

    ratios, relative_errors = [], []
    for sequence_id in DH_SEQUENCES[arm]:
        sequence = _tier_sequence("small", sequence_id)
        recording = conversion.to_recording(sequence)
        clean = conversion.to_recording(sequence, noise_free=True)
        model = nominal_robot_model(recording)
        assert model is not None and model.name == arm
        # the model the metadata carries is the one the reported flange poses come from
        reported = forward_kinematics(model, recording.joints_rad)
        assert np.max(np.abs(reported - recording.base_from_tcp_stack)) < 1e-6
        result = calibrate(recording, "ml")
        observations = build_observations(recording)
        injected = observations.spheres_in_tracker - build_observations(clean).spheres_in_tracker
        true_power = float(np.mean(np.sum(injected**2, axis=(1, 2))))
        measured = white_noise_beyond_kinematics(
            model,
            recording.joints_rad[observations.rows],
            observations,
            result.tracker_from_base,
            result.tcp_from_marker,
        )
        ratios.append(measured["power_mm2"] / true_power)
        relative_errors.append(measured["relative_error"])
    # the mean ratio of eight sequences, within three of its standard errors of one (each
    # estimate's own relative error, from its degrees of freedom, about 0.2)
    assert abs(np.mean(ratios) - 1.0) < 3.0 * np.sqrt(np.mean(np.square(relative_errors)) / len(ratios))


@pytest.mark.parametrize("sequence_id", ["noise-000039", "noise-000134"], ids=["UR5e", "iiwa14"])
def test_twenty_views_of_a_noisy_camera_measure_their_noise_beyond_the_dh_errors(sequence_id):
    """A camera's 20 static views (KinHEC camera noise c3, mostly along the line of sight) leave
    14 to 19 effective residual degrees of freedom beyond the pose and the DH errors: enough to
    measure the noise within its own relative error, and the expected error takes it from there
    rather than counting all of the misfit as systematic."""
    from spacecal.estimators.assessment.white_noise import white_noise_beyond_kinematics
    from spacecal.estimators.methods.observations import build_observations
    from spacecal.estimators.methods.recorded_model import nominal_robot_model

    sequence = _tier_sequence("small", sequence_id)
    recording = conversion.to_recording(sequence)
    observations = build_observations(recording)
    injected = (
        observations.spheres_in_tracker
        - build_observations(conversion.to_recording(sequence, noise_free=True)).spheres_in_tracker
    )
    result = calibrate(recording, "ml")
    measured = white_noise_beyond_kinematics(
        nominal_robot_model(recording),
        recording.joints_rad[observations.rows],
        observations,
        result.tracker_from_base,
        result.tcp_from_marker,
    )
    ratio = measured["power_mm2"] / float(np.mean(np.sum(injected**2, axis=(1, 2))))
    assert measured["dof"] < 20
    assert abs(ratio - 1.0) < 3.0 * measured["relative_error"]
    assert "beyond the white noise the residuals leave" in result.expected_error.to_dict()["basis"]


@pytest.mark.parametrize(
    "sequence_id",
    ["robot_error-000005", "robot_error-000011", "noise-000036", "noise-000039"],
    ids=["eye-in-hand", "eye-in-hand-2", "eye-to-hand", "eye-to-hand-c3"],
)
def test_the_bound_s_camera_noise_is_the_noise_kinhec_injected(sequence_id):
    """``benchmarks/kinhec_identification_bound.py`` whitens by KinHEC's stated camera noise:
    the noise KinHEC injected, whitened by it, is chi-square with six degrees of freedom per frame
    (a pose's noise), mean 6 over the 30 views within three of its standard errors."""
    bound = _benchmark("kinhec_identification_bound")
    import kinhec
    from kinhec.plans import load_tier

    from spacecal.estimators.methods.observations import build_observations

    tier = load_tier(str(Path(kinhec.__file__).parent / "configs" / "small.yaml"))
    sequence = _tier_sequence("small", sequence_id)
    clean = conversion.to_recording(sequence, noise_free=True)
    observations = build_observations(clean)
    injected = (
        build_observations(conversion.to_recording(sequence)).spheres_in_tracker
        - observations.spheres_in_tracker
    )
    covariances = bound.camera_noise_covariances(
        clean.tracker_from_marker_stack[observations.rows],
        observations.spheres_in_marker,
        sequence.eye_in_hand,
        *bound.camera_noise_of(tier, sequence),
    )
    flat = injected.reshape(len(injected), -1)
    statistic = np.einsum(
        "ni,nij,nj->n", flat, np.linalg.pinv(covariances, rcond=1e-10, hermitian=True), flat
    )
    assert abs(np.mean(statistic) - 6.0) < 3.0 * np.sqrt(12.0 / len(statistic))


def test_kinematic_with_the_arm_s_stated_dh_uncertainty_beats_ml_on_uncalibrated_arms():
    """KinHEC's uncalibrated arms (DH errors drawn with 1 mm and 0.01 or 0.1 deg s.d.; a UR5e and
    an iiwa 7, 30 views of a camera without fit RMS each): identification with that prior lands
    closer to the truth than ml does. The data are weighed against the prior by the noise the
    residuals show; weighed by a 1 mm placeholder instead, one UR5e landed 8.0 mm off (ml: 4.4)."""
    from spacecal.estimators.methods.kinematic import calibrate_kinematic

    truth_of = _benchmark("kinhec_tracks").Truth

    errors = {"ml": [], "kinematic": []}
    for k in (4, 5, 10, 11, 16, 17, 22, 23):
        sequence = _tier_sequence("small", f"robot_error-{k:06d}")
        angle_deg = float(sequence.manifest["level"].split("dh_ang_deg=")[1])
        recording = conversion.to_recording(sequence)
        truth = truth_of(sequence)
        for name, result in (
            ("ml", calibrate(recording, "ml")),
            (
                "kinematic",
                calibrate_kinematic(
                    recording,
                    prior_from_data=False,
                    prior_length_sd_mm=1.0,
                    prior_angle_sd_rad=np.radians(angle_deg),
                ),
            ),
        ):
            x, y = conversion.kinhec_from_spacecal(result.tracker_from_base, result.tcp_from_marker)
            errors[name].append(truth.errors(x, y)["site_error_mm"])
    assert np.mean(errors["kinematic"]) < 0.75 * np.mean(errors["ml"])
    assert max(errors["kinematic"]) < max(errors["ml"])
