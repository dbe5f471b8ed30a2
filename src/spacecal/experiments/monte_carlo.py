"""Monte Carlo over measurement noise: how estimators really do against the truth and the bound."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from spacecal.core.errors import SpacecalError
from spacecal.estimators import calibrate
from spacecal.estimators.methods.likelihood import tre_lower_bound
from spacecal.experiments.simulation import Simulation
from spacecal.experiments.truth import calibration_error


@dataclass
class MonteCarloSummary:
    """Per-method statistics over trials.

    Attributes
    ----------
    method : str
    tre_rms_mm : float
        Observed RMS TRE over the 200 mm cube, root-mean-square over trials.
    rotation_rms_deg : float
    predicted_tre_rms_mm : float or None
        The estimator's own predicted cube RMS TRE, root-mean-square over trials.
    compute_s : float
        Median compute time of one calibration.
    trials : int
    failure : str or None
        The error the method raised on these data, if it could not calibrate.
    """

    method: str
    tre_rms_mm: float
    rotation_rms_deg: float
    predicted_tre_rms_mm: float | None
    compute_s: float
    trials: int
    failure: str | None = None


def true_sphere_sigma_mm(simulation: Simulation) -> float:
    """Per-axis white sphere noise of the simulated tracker, mm (isotropic case)."""
    return simulation.world.scenario.white_noise_rms_mm / np.sqrt(3.0)


def cramer_rao_tre_mm(simulation: Simulation) -> float:
    """Cramér–Rao bound on the cube RMS TRE at the truth, for the simulation's recording."""
    world = simulation.world
    return tre_lower_bound(
        simulation.recording, world.tracker_from_base, world.tcp_from_marker, true_sphere_sigma_mm(simulation)
    )["cube_rms"]


def run_monte_carlo(simulation: Simulation, methods, trials: int) -> list[MonteCarloSummary]:
    """Re-record the simulation's motion ``trials`` times and calibrate with each method."""
    errors: dict[str, list[float]] = {m: [] for m in methods}
    rotations: dict[str, list[float]] = {m: [] for m in methods}
    predicted: dict[str, list[float]] = {m: [] for m in methods}
    times: dict[str, list[float]] = {m: [] for m in methods}
    failures: dict[str, str] = {}
    for trial in range(trials):
        recording, _ = simulation.remeasure(trial)
        for method in methods:
            if method in failures:
                continue
            start = time.perf_counter()
            try:
                result = calibrate(recording, method, uncertainty=False)
            except SpacecalError as exc:
                failures[method] = str(exc)
                continue
            times[method].append(time.perf_counter() - start)
            error = calibration_error(result, simulation.world)
            errors[method].append(error["tre_rms_mm"])
            rotations[method].append(error["rotation_error_deg"])
            if result.predicted_tre_mm:
                predicted[method].append(result.predicted_tre_mm["cube_rms"])

    def rms(values):
        return float(np.sqrt(np.mean(np.square(values)))) if values else float("nan")

    return [
        MonteCarloSummary(
            m,
            rms(errors[m]),
            rms(rotations[m]),
            rms(predicted[m]) if predicted[m] else None,
            float(np.median(times[m])) if times[m] else float("nan"),
            len(errors[m]),
            failures.get(m),
        )
        for m in methods
    ]
