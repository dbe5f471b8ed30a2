"""How well can any prediction of a verification error do? The oracle of a fixed number.

A seed's verification mean (the paper's 15-point experiment, §5.2) is one draw of errors the
recording cannot show: on white noise the estimation error itself (for least squares under
Gaussian noise the estimate's error is independent of the residuals, so nothing in the data
predicts the draw), with realistic errors the part of the arm's kinematic error that moves
the tip without moving the marker. A predictor that does not know the draw can at best state
one number per world; this module measures how often the best such number falls within a
tolerance of the measured value.

For a 3-D Gaussian error the verification mean is close to the length of one Gaussian
vector (the targets lie close together, their errors nearly equal): a chi distribution with
3 degrees of freedom, whose best fixed number is within +-30 % of only 52 % of its draws.
"""

from __future__ import annotations

import numpy as np

from spacecal.estimators import calibrate
from spacecal.experiments.simulation import Simulation, simulate
from spacecal.experiments.verification import verify_in_simulation
from spacecal.geometry.arrays import ArrayLike, FloatArray, as_float_array
from spacecal.sim.scenario import Scenario

#: The tolerance of the issue's criterion: predicted within +-30 % of the measured value.
TOLERANCE = 0.3


def best_fixed_share(measured: ArrayLike, tolerance: float = TOLERANCE) -> tuple[float, float]:
    """The largest share of measured values one fixed prediction has within +-``tolerance``.

    A prediction ``c`` is within tolerance of a measured ``m`` when ``|c / m - 1| <= tolerance``,
    i.e. ``c / (1 + tolerance) <= m <= c / (1 - tolerance)``; the best ``c`` is found exactly
    by sliding that window over the sorted values.

    Parameters
    ----------
    measured : array_like, shape (N,)
        Positive measured values (e.g. verification means, mm).
    tolerance : float
        Relative tolerance in (0, 1).

    Returns
    -------
    (float, float)
        The share in [0, 1], and the prediction reaching it (unit of ``measured``; the middle
        of the range of predictions that do).
    """
    values = np.sort(np.asarray(measured, dtype=float).ravel())
    if len(values) == 0 or not np.all(values > 0) or not 0 < tolerance < 1:
        raise ValueError("best_fixed_share needs positive values and a tolerance in (0, 1)")
    upper = np.searchsorted(values, values * (1 + tolerance) / (1 - tolerance), side="right")
    counts = upper - np.arange(len(values))
    best = int(np.argmax(counts))
    # every c in [largest * (1 - tolerance), smallest * (1 + tolerance)] reaches it: the middle
    middle = 0.5 * (values[best] * (1 + tolerance) + values[upper[best] - 1] * (1 - tolerance))
    return float(counts[best] / len(values)), float(middle)


def share_within(predicted: ArrayLike, measured: ArrayLike, tolerance: float = TOLERANCE) -> float:
    """Share of pairs with ``|predicted / measured - 1| <= tolerance`` (shapes (N,), same unit)."""
    ratio = np.asarray(predicted, dtype=float) / np.asarray(measured, dtype=float)
    return float(np.mean(np.abs(ratio - 1.0) <= tolerance))


def noise_draws(
    scenario: Scenario,
    draws: int,
    method: str = "ml",
    first: int = 0,
    simulation: Simulation | None = None,
) -> FloatArray:
    """One world's verification means and stated expected errors over fresh tracker noise.

    The scenario's motion is simulated once; it is then recorded again ``draws`` times with
    fresh tracker noise (:meth:`spacecal.experiments.simulation.Simulation.remeasure`, trials
    ``first`` to ``first + draws - 1``), each recording calibrated by ``method`` and verified
    in the same world.

    Parameters
    ----------
    scenario : Scenario
        The world (its seed fixes the arm's and tracker's systematic errors).
    draws : int
    method : str
    first : int
        First trial number (draws can be split between processes).
    simulation : Simulation, optional
        The scenario's simulation when already at hand.

    Returns
    -------
    numpy.ndarray, shape (draws, 2)
        Per draw: the measured verification mean position error and the expected error the
        calibration states (``expected_error.position_mm``), mm.
    """
    simulation = simulate(scenario) if simulation is None else simulation
    rows = []
    for trial in range(first, first + draws):
        recording, _ = simulation.remeasure(trial)
        result = calibrate(recording, method)
        measured = verify_in_simulation(result, scenario).statistics()["position_mm"]["mean"]
        stated = None if result.expected_error is None else result.expected_error.position_mm
        rows.append((float(measured), float("nan") if stated is None else stated))
    return as_float_array(np.array(rows, dtype=float).reshape(-1, 2))
