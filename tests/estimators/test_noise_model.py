"""The noise model learnt from the residuals: components recover the injected noise, ML gains
where the isotropic model is wrong and loses nothing where it is right."""

import dataclasses

import numpy as np
import pytest

from spacecal.core.errors import InvalidInputError
from spacecal.estimators import calibrate
from spacecal.estimators.methods.likelihood import fit_ml
from spacecal.estimators.methods.noise_model import NoiseProblem
from spacecal.experiments.monte_carlo import cramer_rao_tre_mm, true_sphere_sigma_mm
from spacecal.experiments.simulation import simulate
from spacecal.experiments.truth import calibration_error
from spacecal.geometry.transforms import rotvec_to_matrix
from spacecal.models.kinematics import apply_pose_step
from spacecal.records import Recording
from spacecal.sim.scenario import PRESETS

#: Pose-only noise (OpenIGTLink-like source): mm across / along the line of sight, deg per axis.
LATERAL_MM, DEPTH_MM, ROTATION_DEG = 0.05, 0.20, 0.02


def pose_only_recording(simulation, trial: int) -> Recording:
    """True marker poses with depth-dominated translation noise and a precise orientation; no
    spheres, no tracker RMS (as ``benchmarks/noise_model.py`` builds them)."""
    rng = np.random.default_rng([simulation.world.scenario.seed, 7, trial])
    rec, truth = simulation.recording, simulation.true_tracker_from_marker_stack
    poses = truth.copy()
    sight = truth[:, :3, 3] / np.linalg.norm(truth[:, :3, 3], axis=1, keepdims=True)
    noise = rng.normal(scale=LATERAL_MM, size=sight.shape)
    noise += (DEPTH_MM / LATERAL_MM - 1.0) * np.sum(noise * sight, axis=1, keepdims=True) * sight
    poses[:, :3, 3] += noise
    poses[:, :3, :3] = (
        rotvec_to_matrix(rng.normal(scale=np.radians(ROTATION_DEG), size=sight.shape)) @ truth[:, :3, :3]
    )
    poses[~rec.visible] = np.nan
    return dataclasses.replace(rec, tracker_from_marker_stack=poses).as_pose_only()


@pytest.fixture(scope="module")
def anisotropic_sphere_simulation():
    return simulate(dataclasses.replace(PRESETS["paper-white"], depth_anisotropy=3.0, record_spheres=True))


def test_pose_residual_jacobian_matches_finite_differences(white_simulation):
    obs, fit = fit_ml(white_simulation.recording)
    problem = NoiseProblem(obs, white_simulation.recording.tracker_from_marker_stack[obs.rows])
    t, x = fit.tracker_from_base, fit.tcp_from_marker
    jac = problem.residuals(t, x).jacobian
    eps = 1e-6
    for k in range(12):
        step = np.zeros(12)
        step[k] = eps
        plus = problem.residuals(*apply_pose_step(t, x, step)).values
        minus = problem.residuals(*apply_pose_step(t, x, -step)).values
        assert np.allclose((plus - minus) / (2 * eps), jac[..., k], atol=1e-5)


def test_white_noise_components_and_fit_match_the_isotropic_model(white_simulation):
    recording = white_simulation.recording
    sigma = true_sphere_sigma_mm(white_simulation)
    estimated = calibrate(recording, "ml")
    isotropic = calibrate(recording, "ml", noise_model="isotropic")
    model = estimated.diagnostics["noise_model"]
    # poses fitted from K = 4 spheres: the centroid's per-axis noise is sigma / 2, the
    # orientation that of a rigid fit of spheres with noise sigma, no orientation noise of its own
    assert model["observations"] == "poses" and model["converged"]
    assert model["lateral_mm"] == pytest.approx(sigma / 2, rel=0.15)
    assert model["depth_mm"] == pytest.approx(sigma / 2, rel=0.15)
    assert model["sphere_fit_mm"] == pytest.approx(sigma, rel=0.15)
    assert model["rotation_isotropic_deg"] < 0.5 * model["rotation_deg"]
    # the same fit to a small fraction of the bound, and the same predicted TRE
    bound = cramer_rao_tre_mm(white_simulation)
    apart = calibration_error(estimated, dataclasses.replace(white_simulation.world, **_truth_of(isotropic)))
    assert apart["tre_rms_mm"] < 0.2 * bound
    assert estimated.predicted_tre_mm["cube_rms"] == pytest.approx(
        isotropic.predicted_tre_mm["cube_rms"], rel=0.1
    )


def _truth_of(result):
    return {"tracker_from_base": result.tracker_from_base, "tcp_from_marker": result.tcp_from_marker}


def test_anisotropic_sphere_noise_is_recovered_and_beats_the_isotropic_model(anisotropic_sphere_simulation):
    simulation = anisotropic_sphere_simulation
    scenario = simulation.world.scenario
    lateral = scenario.white_noise_rms_mm / np.sqrt(2.0 + scenario.depth_anisotropy**2)
    errors: dict[str, list[float]] = {"estimated": [], "isotropic": []}
    for trial in range(3):
        recording, _ = simulation.remeasure(trial)
        for noise_model in errors:
            result = calibrate(recording, "ml", noise_model=noise_model)
            errors[noise_model].append(calibration_error(result, simulation.world)["tre_rms_mm"])
            if noise_model == "estimated":
                estimated = result.diagnostics["noise_model"]
        assert estimated["observations"] == "spheres"
        assert estimated["lateral_mm"] == pytest.approx(lateral, rel=0.15)
        assert estimated["depth_mm"] == pytest.approx(scenario.depth_anisotropy * lateral, rel=0.15)
    # about 0.6x in benchmarks/noise_model.py; three trials leave room
    assert np.sqrt(np.mean(np.square(errors["estimated"]))) < 0.85 * np.sqrt(
        np.mean(np.square(errors["isotropic"]))
    )


def test_pose_only_depth_noise_is_recovered_and_ml_is_no_worse_than_the_closed_forms(white_simulation):
    closed_forms = ("shah", "li", "dornaika", "park")
    keys = ("tre_rms_mm", "tcp_from_marker_position_error_mm", "tcp_from_marker_rotation_error_deg")
    errors: dict[str, list[dict]] = {m: [] for m in (*closed_forms, "ml")}
    for trial in range(2):
        recording = pose_only_recording(white_simulation, trial)
        for method in errors:
            result = calibrate(recording, method, uncertainty=False)
            errors[method].append(calibration_error(result, white_simulation.world))
        model = result.diagnostics["noise_model"]
        assert model["observations"] == "poses"
        assert model["lateral_mm"] == pytest.approx(LATERAL_MM, rel=0.15)
        assert model["depth_mm"] == pytest.approx(DEPTH_MM, rel=0.15)
        assert model["rotation_isotropic_deg"] == pytest.approx(ROTATION_DEG, rel=0.15)

    def rms(method, key):
        return np.sqrt(np.mean([e[key] ** 2 for e in errors[method]]))

    for key in keys:
        assert rms("ml", key) <= min(rms(m, key) for m in closed_forms), key


def test_noise_free_data_stays_exact_and_unknown_models_are_refused(noise_free_simulation):
    result = calibrate(noise_free_simulation.recording, "ml")
    assert np.allclose(result.tracker_from_base, noise_free_simulation.world.tracker_from_base, atol=1e-9)
    assert np.all(np.isfinite(result.covariance["matrix"]))
    with pytest.raises(InvalidInputError, match="estimated, isotropic"):
        calibrate(noise_free_simulation.recording, "ml", noise_model="anisotropic")
