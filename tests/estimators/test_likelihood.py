"""Maximum likelihood, its uncertainty, the Cramér–Rao bound, and the robust variant."""

import numpy as np
import pytest

from spacecal.core.errors import InvalidInputError
from spacecal.estimators import calibrate
from spacecal.estimators.methods.ml import jacobian, predict_spheres
from spacecal.estimators.methods.observations import build_observations, sphere_noise_from_marker_rms
from spacecal.experiments.monte_carlo import cramer_rao_tre_mm, run_monte_carlo, true_sphere_sigma_mm
from spacecal.experiments.truth import calibration_error
from spacecal.models.kinematics import apply_pose_step


def test_noise_free_recording_is_recovered_exactly(noise_free_simulation):
    result = calibrate(noise_free_simulation.recording, "ml")
    world = noise_free_simulation.world
    assert np.allclose(result.tracker_from_base, world.tracker_from_base, atol=1e-9)
    assert np.allclose(result.tcp_from_marker, world.tcp_from_marker, atol=1e-9)


def test_analytic_jacobian_matches_finite_differences(white_simulation):
    obs = build_observations(white_simulation.recording)
    t, x = white_simulation.world.tracker_from_base, white_simulation.world.tcp_from_marker
    jac = jacobian(obs, t, x)
    eps = 1e-6
    for k in range(12):
        step = np.zeros(12)
        step[k] = eps
        plus = predict_spheres(obs, *apply_pose_step(t, x, step))
        minus = predict_spheres(obs, *apply_pose_step(t, x, -step))
        assert np.allclose((plus - minus) / (2 * eps), jac[..., k], atol=1e-4)


def test_noise_is_estimated_from_the_trackers_rms(white_simulation):
    sigma = sphere_noise_from_marker_rms(white_simulation.recording.marker_rms_mm, 4)
    assert sigma == pytest.approx(true_sphere_sigma_mm(white_simulation), rel=0.1)


def test_ml_reaches_the_cramer_rao_bound_and_predicts_its_own_error(white_simulation):
    # 200 trials: the RMS over trials is then known to about +-3.5 %.
    bound = cramer_rao_tre_mm(white_simulation)
    ml, paper = run_monte_carlo(white_simulation, ["ml", "paper"], trials=200)
    assert ml.tre_rms_mm <= 1.1 * bound
    assert ml.tre_rms_mm >= 0.9 * bound  # no estimator beats the bound beyond Monte Carlo noise
    assert abs(ml.predicted_tre_rms_mm / ml.tre_rms_mm - 1.0) < 0.2
    assert paper.tre_rms_mm > 1.5 * ml.tre_rms_mm  # the paper's estimator leaves accuracy on the table


def test_result_carries_covariance_prediction_and_diagnostics(white_simulation):
    site = white_simulation.world.site_in_base
    result = calibrate(white_simulation.recording, "ml", targets_in_base=[site + [50.0, 0, 0]])
    covariance = np.array(result.covariance["matrix"])
    assert covariance.shape == (12, 12) and np.all(np.linalg.eigvalsh(covariance) > 0)
    assert result.predicted_tre_mm["site"] > 0 and len(result.predicted_tre_mm["targets"]) == 1
    diagnostics = result.diagnostics
    assert diagnostics["variance_factor"] == pytest.approx(1.0, abs=0.15)
    assert len(result.assessment.residuals.per_sample) == int(white_simulation.recording.visible.sum())
    assert result.verdict.grade == "good"


def test_verdict_warns_when_systematic_errors_dominate(realistic_simulation):
    # the verdict grades the expected error (which holds the systematic part), not the
    # noise-only TRE, and says that systematic error dominates
    result = calibrate(realistic_simulation.recording, "ml")
    assert result.diagnostics["variance_factor"] > 1.5
    verdict = result.verdict
    assert verdict.grade in ("good", "acceptable", "poor", "unusable")
    assert "systematic error" in verdict.text
    assert result.expected_error.to_dict()["position_mm"] > 5 * result.predicted_tre_mm["site"]


def test_robust_flags_the_injected_outliers_and_keeps_clean_accuracy(
    outlier_simulation, realistic_simulation
):
    injected = set(
        np.flatnonzero((outlier_simulation.outlier_kind != "") & outlier_simulation.recording.visible)
    )
    robust = calibrate(outlier_simulation.recording, "robust")
    flagged = {o["row"] for o in robust.diagnostics["outliers"]}
    assert len(flagged & injected) >= 0.9 * len(injected)
    assert len(flagged - injected) <= 0.02 * len(outlier_simulation.recording)
    # same world (same seed) without outliers: the robust error stays within 20 % of clean ML
    clean = calibration_error(calibrate(realistic_simulation.recording, "ml"), realistic_simulation.world)
    survived = calibration_error(robust, outlier_simulation.world)
    plain = calibration_error(calibrate(outlier_simulation.recording, "ml"), outlier_simulation.world)
    assert survived["tre_rms_mm"] <= 1.2 * clean["tre_rms_mm"]
    # the outliers do hurt plain ML (stale frames are 0.1-0.4 s old at the tracker's rate, as
    # the device-path simulator produces them; over seeds plain ML is 1.1-3x the clean error)
    assert plain["tre_rms_mm"] > survived["tre_rms_mm"]


def test_robust_changes_nothing_on_clean_white_data(white_simulation):
    robust = calibrate(white_simulation.recording, "robust")
    assert len(robust.diagnostics["outliers"]) <= 0.01 * len(white_simulation.recording)


def test_options_a_method_does_not_take_are_refused(white_simulation):
    with pytest.raises(
        InvalidInputError, match="does not take sigma_mm .methods that do: kinematic, ml, robust"
    ):
        calibrate(white_simulation.recording, "paper", sigma_mm=0.1)


@pytest.mark.parametrize("method", ["paper", "shah", "tsai"])
def test_methods_without_likelihood_get_bootstrap_uncertainty(method, white_simulation):
    result = calibrate(white_simulation.recording, method)
    assert "bootstrap" in result.covariance["note"]
    assert np.array(result.covariance["matrix"]).shape == (12, 12)
    error = calibration_error(result, white_simulation.world)["tre_rms_mm"]
    # one realisation: the true error lies within a few predicted standard errors
    assert error < 4 * result.predicted_tre_mm["cube_rms"]
    assert result.verdict is not None
