"""The registry of calibration methods, chosen by name."""

from __future__ import annotations

import dataclasses
import inspect
from collections.abc import Callable
from typing import Any

import numpy as np

from spacecal.core.errors import InvalidInputError, SpacecalError, UnknownMethodError
from spacecal.estimators.closed_form import (
    HAND_EYE_SOLVERS,
    ROBOT_WORLD_SOLVERS,
    hand_eye_method,
    robot_world_method,
)
from spacecal.estimators.diagnostics import ErrorThresholds, verdict
from spacecal.estimators.kinematic import calibrate_kinematic
from spacecal.estimators.likelihood import (
    calibrate_ml,
    calibrate_robust,
    report_uncertainty,
    variance_factor_of,
)
from spacecal.estimators.ml import covariance_from_information, information_matrix
from spacecal.estimators.observations import build_observations
from spacecal.estimators.paper import calibrate_paper
from spacecal.estimators.uncertainty import RESAMPLES, bootstrap_covariance
from spacecal.geometry.arrays import ArrayLike, FloatArray
from spacecal.geometry.transforms import MEASURED_TRANSFORM_ATOL, check_points, check_transform
from spacecal.records import CalibrationResult, Recording

#: name -> ``function(recording, **options) -> CalibrationResult``
METHODS: dict[str, Callable[..., CalibrationResult]] = {
    "paper": calibrate_paper,
    "ml": calibrate_ml,
    "robust": calibrate_robust,
    "kinematic": calibrate_kinematic,
    **{name: robot_world_method(name) for name in ROBOT_WORLD_SOLVERS},
    **{name: hand_eye_method(name) for name in HAND_EYE_SOLVERS},
}


def calibrate(
    recording: Recording, method: str = "paper", uncertainty: bool = True, **options: Any
) -> CalibrationResult:
    """Estimate ``tracker_from_base`` and ``tcp_from_marker`` from a recording.

    Parameters
    ----------
    recording : Recording
    method : str
        A name from :data:`METHODS`.
    uncertainty : bool
        For methods without a likelihood, add a bootstrap covariance, predicted TRE, expected
        error and verdict (50 re-solves); Monte Carlo studies switch it off.
    **options
        Passed to the method, except ``targets_in_base`` (any method) and ``error_thresholds``, an
        :class:`~spacecal.estimators.diagnostics.ErrorThresholds` the verdict is graded against.
        Passed to the method.

    Raises
    ------
    UnknownMethodError
        For a name not in the registry; the message lists the valid ones.
    InvalidInputError
        For pose stacks that are not rigid transforms (:func:`check_recording_poses`) or
        targets that are not (M, 3) finite points.
    """
    if method not in METHODS:
        raise UnknownMethodError(f"unknown method {method!r}; valid methods: {', '.join(sorted(METHODS))}")
    thresholds = options.pop("error_thresholds", None)
    if thresholds is not None and not isinstance(thresholds, ErrorThresholds):
        raise InvalidInputError("error_thresholds must be an ErrorThresholds (good, acceptable, poor mm)")
    targets = options.pop("targets_in_base", None)
    if targets is not None:
        targets = check_points(targets, "targets_in_base")
    check_recording_poses(recording)
    accepted = inspect.signature(METHODS[method]).parameters
    unexpected = sorted(set(options) - set(accepted))
    if unexpected:
        takers = sorted(
            m for m, f in METHODS.items() if set(unexpected) <= set(inspect.signature(f).parameters)
        )
        raise InvalidInputError(
            f"method {method!r} does not take {', '.join(unexpected)}"
            + (f" (methods that do: {', '.join(takers)})" if takers else "")
        )
    if "targets_in_base" in accepted:
        result = METHODS[method](recording, targets_in_base=targets, **options)
    else:
        result = METHODS[method](recording, **options)
        if uncertainty:
            result = with_bootstrap_uncertainty(result, recording, METHODS[method], targets)
    return result if thresholds is None else regrade(result, recording, thresholds)


def regrade(
    result: CalibrationResult, recording: Recording, thresholds: ErrorThresholds
) -> CalibrationResult:
    """The result with its verdict graded against other thresholds (its numbers unchanged)."""
    d = result.diagnostics
    expected = d.get("expected_error")
    if expected is None or "motion_spread" not in d:
        return result
    outliers = len(d.get("outliers", []))
    judged = verdict(
        None if "refusal" in expected else expected,
        d["motion_spread"],
        outliers / max(int(recording.visible.sum()), 1),
        d.get("variance_factor"),
        thresholds,
        refusal=expected.get("refusal"),
    )
    return result.replace(
        diagnostics={**d, "verdict": judged.to_dict(), "thresholds_mm": dataclasses.asdict(thresholds)}
    )


def with_expected_error(result: CalibrationResult, recording: Recording) -> CalibrationResult:
    """Expected error and verdict for a result without a covariance of its own.

    The noise-only part comes from the ML information at the result's solution, so every
    method gets a verdict however it was called.
    """
    obs = build_observations(recording)
    try:
        information = information_matrix(obs, result.tracker_from_base, result.tcp_from_marker)
        variance_factor = variance_factor_of(obs, result.tracker_from_base, result.tcp_from_marker)
        scale = max(variance_factor, 1.0) if obs.sigma_known else variance_factor
        covariance = covariance_from_information(information) * scale
    except (SpacecalError, np.linalg.LinAlgError):
        return result
    reported = report_uncertainty(
        result.method,
        recording,
        obs,
        result.tracker_from_base,
        result.tcp_from_marker,
        covariance,
        variance_factor,
        None,
        {},
        covariance_note="ML information at this solution (no bootstrap); mm, rad",
    )
    keep = ("expected_error", "verdict", "motion_spread", "variance_factor")
    return result.replace(diagnostics={**result.diagnostics, **{k: reported.diagnostics[k] for k in keep}})


def check_recording_poses(recording: Recording) -> None:
    """Refuse a recording whose pose stacks are not rigid transforms (one readable line).

    Frames where the marker was not seen are rows of NaN in ``tracker_from_marker_stack``
    and pass; the tolerance is that of measured matrices (about six significant digits).

    Raises
    ------
    InvalidInputError
    """
    check_transform(
        recording.base_from_tcp_stack,
        "recording.base_from_tcp_stack",
        stack=True,
        atol=MEASURED_TRANSFORM_ATOL,
    )
    check_transform(
        recording.tracker_from_marker_stack,
        "recording.tracker_from_marker_stack",
        stack=True,
        allow_missing=True,
        atol=MEASURED_TRANSFORM_ATOL,
    )


def with_bootstrap_uncertainty(
    result: CalibrationResult,
    recording: Recording,
    solver: Callable[..., CalibrationResult],
    targets_in_base: ArrayLike | None = None,
) -> CalibrationResult:
    """Add covariance (bootstrap over frames), predicted TRE, residuals and a verdict to a
    result from an estimator without a likelihood; its transforms are unchanged."""

    def solve(resampled: Recording) -> tuple[FloatArray, FloatArray]:
        again = solver(resampled)
        return again.tracker_from_base, again.tcp_from_marker

    covariance = bootstrap_covariance(recording, solve, result.tracker_from_base, result.tcp_from_marker)
    if covariance is None:
        result.diagnostics["uncertainty"] = "bootstrap failed: too few resamples could be solved"
        return with_expected_error(result, recording)
    obs = build_observations(recording)
    variance_factor = variance_factor_of(obs, result.tracker_from_base, result.tcp_from_marker)
    reported = report_uncertainty(
        result.method,
        recording,
        obs,
        result.tracker_from_base,
        result.tcp_from_marker,
        covariance,
        variance_factor,
        targets_in_base,
        {},
        covariance_note=(
            f"bootstrap over frames ({RESAMPLES} resamples) in the ML perturbation parameters; mm, rad"
        ),
    )
    return result.replace(
        covariance=reported.covariance,
        predicted_tre_mm=reported.predicted_tre_mm,
        diagnostics={**reported.diagnostics, **result.diagnostics},
    )
