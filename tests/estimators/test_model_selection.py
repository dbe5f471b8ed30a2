"""How much kinematic identification corrects: the prior scale the held-out misfit shows; subset selection."""

import dataclasses

import numpy as np
import pytest

from spacecal.estimators import calibrate
from spacecal.estimators.methods.kinematic import (
    IDENTIFY_MIN_SIGNIFICANCE,
    SELECTION_MIN_GAIN,
    select_corrections,
)
from spacecal.experiments.simulation import simulate
from spacecal.experiments.verification import verify_in_simulation
from spacecal.sim.scenario import PRESETS

from ..conftest import NOISE_FREE


def linear_problem(effects: np.ndarray, seed: int = 0):
    """A whitened linear problem: 6 blocks of 40 frames, 12 residuals a frame, 12 pose columns and
    5 candidate columns, residual = unit white noise + the candidates' columns times ``effects``."""
    rng = np.random.default_rng(seed)
    frames, rows = 240, 12
    pose = rng.normal(size=(frames, rows, 12))
    dh = rng.normal(size=(frames, rows, 5))
    residual = rng.normal(size=(frames, rows)) + dh @ effects
    blocks = np.array_split(np.arange(frames), 6)
    return pose, dh, residual, blocks


def test_selection_frees_the_corrections_the_data_shows_and_no_other():
    # two candidates move the residual by 0.5 noise s.d. a row (about 700 units of held-out
    # sum of squares each); three move nothing
    pose, dh, residual, blocks = linear_problem(np.array([0.0, 0.5, 0.0, -0.5, 0.0]))
    chosen, path = select_corrections(pose, dh, residual, np.full(5, 10.0), blocks)
    assert sorted(chosen) == [1, 3]
    assert path[0]["freed"] is None and [p["freed"] for p in path[1:]] == chosen
    gains = -np.diff([p["held_out_ss"] for p in path])
    assert np.all(gains > SELECTION_MIN_GAIN)


def test_selection_frees_nothing_on_noise_alone():
    for seed in range(5):
        pose, dh, residual, blocks = linear_problem(np.zeros(5), seed)
        chosen, path = select_corrections(pose, dh, residual, np.full(5, 10.0), blocks)
        assert chosen == [] and len(path) == 1


def test_on_an_arm_matching_its_model_kinematic_is_ml(white_simulation):
    recording = white_simulation.recording
    ml = calibrate(recording, "ml", uncertainty=False)
    kinematic = calibrate(recording, "kinematic", uncertainty=False)
    report = kinematic.diagnostics["kinematic_identification"]
    # the held-out misfit shows nothing beyond the white noise: nothing is freed ...
    assert report["identified"] == [] and report["rank"] > 0
    assert report["prior_sd"]["length_mm"] == 0.0
    assert report["held_out_significance"] < IDENTIFY_MIN_SIGNIFICANCE
    # ... and the pose is the ML solution itself
    assert np.allclose(kinematic.tracker_from_base, ml.tracker_from_base, atol=1e-9)
    assert np.allclose(kinematic.tcp_from_marker, ml.tcp_from_marker, atol=1e-9)
    scenario = PRESETS["paper-white"]
    assert verify_in_simulation(kinematic, scenario).statistics()["position_mm"]["mean"] == pytest.approx(
        verify_in_simulation(ml, scenario).statistics()["position_mm"]["mean"], rel=1e-6
    )


def test_a_pose_only_tracker_on_an_arm_matching_its_model_frees_nothing(white_simulation):
    # the noise comes from the fit's own residuals; a fixed prior instead frees every
    # identifiable correction (the test below) and fits noise
    recording = white_simulation.recording.as_pose_only()
    kinematic = calibrate(recording, "kinematic", uncertainty=False)
    report = kinematic.diagnostics["kinematic_identification"]
    assert report["identified"] == [] and report["prior_sd"]["from_data"]
    assert report["held_out_significance"] < IDENTIFY_MIN_SIGNIFICANCE
    ml = calibrate(recording, "ml", uncertainty=False)
    assert np.allclose(kinematic.tracker_from_base, ml.tracker_from_base, atol=1e-9)


def test_a_pose_only_tracker_still_shows_an_arm_s_dh_errors():
    scenario = dataclasses.replace(
        NOISE_FREE, white_noise_rms_mm=0.1, dh_length_error_sd_mm=0.3, dh_angle_error_sd_deg=0.03
    )
    recording = simulate(scenario).recording.as_pose_only()
    report = calibrate(recording, "kinematic", uncertainty=False).diagnostics["kinematic_identification"]
    assert report["held_out_significance"] > IDENTIFY_MIN_SIGNIFICANCE and report["prior_sd"]["from_data"]
    assert len(report["identified"]) == report["rank"]


def test_a_fixed_prior_fits_noise_on_an_arm_matching_its_model(white_simulation):
    # what the data-set prior avoids: every identifiable correction freed under the fixed
    # 1 mm / 0.002 rad prior moves the needle by several times ML's error
    scenario = PRESETS["paper-white"]
    fixed = calibrate(white_simulation.recording, "kinematic", uncertainty=False, prior_from_data=False)
    ml = calibrate(white_simulation.recording, "ml", uncertainty=False)
    assert len(fixed.diagnostics["kinematic_identification"]["identified"]) > 0
    assert (
        verify_in_simulation(fixed, scenario).statistics()["position_mm"]["mean"]
        > 2 * verify_in_simulation(ml, scenario).statistics()["position_mm"]["mean"]
    )


def test_the_prior_scale_follows_the_arm_s_dh_errors():
    # no tracker error beyond 0.1 mm white noise: the scale the held-out misfit shows is that
    # of the injected DH errors (0.3 mm lengths, 0.03 deg = 0.0005 rad angles, i.e. 0.26 mm on
    # the 0.002 rad/mm scale), within a factor of two either way (one arm, 24 draws)
    scenario = dataclasses.replace(
        NOISE_FREE, white_noise_rms_mm=0.1, dh_length_error_sd_mm=0.3, dh_angle_error_sd_deg=0.03
    )
    recording = simulate(scenario).recording
    result = calibrate(recording, "kinematic", uncertainty=False)
    report = result.diagnostics["kinematic_identification"]
    assert report["held_out_significance"] > IDENTIFY_MIN_SIGNIFICANCE and report["prior_sd"]["from_data"]
    assert 0.15 < report["prior_sd"]["length_mm"] < 0.6
    assert report["prior_sd"]["angle_rad"] == pytest.approx(0.002 * report["prior_sd"]["length_mm"])
    assert len(report["identified"]) == report["rank"]


def test_subset_selection_frees_some_corrections_when_the_arm_is_off_its_model():
    scenario = dataclasses.replace(
        NOISE_FREE, white_noise_rms_mm=0.1, dh_length_error_sd_mm=0.3, dh_angle_error_sd_deg=0.03
    )
    recording = simulate(scenario).recording
    selected = calibrate(
        recording, "kinematic", uncertainty=False, prior_from_data=False, model_selection=True
    )
    report = selected.diagnostics["kinematic_identification"]
    assert 0 < len(report["identified"]) < report["rank"]
    path = report["model_selection"]["path"]
    assert all(a["held_out_ss"] - b["held_out_ss"] > SELECTION_MIN_GAIN for a, b in zip(path, path[1:]))
    assert sorted(c["parameter"] for c in report["identified"]) == sorted(p["freed"] for p in path[1:])
