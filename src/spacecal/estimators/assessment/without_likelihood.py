"""The assessment of a method without a likelihood (the paper's, the closed forms).

Its covariance comes from a bootstrap over frames (:mod:`spacecal.estimators.assessment.uncertainty`),
or, where the bootstrap fails, from the ML information at its solution; its expected error is
cross-validated with ML refits and adds its distance from the ML solution.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from spacecal.core.errors import SpacecalError
from spacecal.estimators.assessment.report import report_uncertainty
from spacecal.estimators.assessment.uncertainty import RESAMPLES, bootstrap_covariance
from spacecal.estimators.methods.likelihood import variance_factor_of
from spacecal.estimators.methods.ml import covariance_from_information, information_matrix
from spacecal.estimators.methods.observations import Observations, build_observations
from spacecal.estimators.methods.solution import Solution
from spacecal.geometry.arrays import ArrayLike, FloatArray
from spacecal.records import CalibrationResult, NeedleTip, Recording
from spacecal.records.assessment import ErrorThresholds


def _reported_at_result(
    result: CalibrationResult,
    recording: Recording,
    obs: Observations,
    covariance: FloatArray,
    variance_factor: float,
    covariance_note: str,
    targets_in_base: ArrayLike | None = None,
    needle_tip: NeedleTip | None = None,
    thresholds: ErrorThresholds | None = None,
) -> CalibrationResult:
    """The uncertainty report of ``result``'s own transforms with a covariance found for them
    outside its estimator (ML information, or a bootstrap): one place for both. The result is
    not the ML fit of ``obs``: its held-out refits are ML's."""
    return report_uncertainty(
        Solution(
            result.method,
            recording,
            obs,
            result.tracker_from_base,
            result.tcp_from_marker,
            covariance,
            variance_factor,
            likelihood_based=False,
            covariance_note=covariance_note,
            targets_in_base=targets_in_base,
            needle_tip=needle_tip,
        ),
        thresholds,
    )


def with_expected_error(
    result: CalibrationResult,
    recording: Recording,
    needle_tip: NeedleTip | None = None,
    thresholds: ErrorThresholds | None = None,
) -> CalibrationResult:
    """Expected error and verdict for a result without a covariance of its own.

    The noise-only part comes from the ML information at the result's solution, so every
    method gets a verdict however it was called. ``thresholds`` are the verdict's
    (:class:`~spacecal.records.assessment.ErrorThresholds`; the defaults when omitted).
    """
    obs = build_observations(recording)
    try:
        information = information_matrix(obs, result.tracker_from_base, result.tcp_from_marker)
        variance_factor = variance_factor_of(obs, result.tracker_from_base, result.tcp_from_marker)
        scale = max(variance_factor, 1.0) if obs.sigma_known else variance_factor
        covariance = covariance_from_information(information) * scale
    except (SpacecalError, np.linalg.LinAlgError):
        return result
    reported = _reported_at_result(
        result,
        recording,
        obs,
        covariance,
        variance_factor,
        "ML information at this solution (no bootstrap); mm, rad",
        needle_tip=needle_tip,
        thresholds=thresholds,
    )
    keep = ("motion_spread", "variance_factor")
    return result.replace(
        diagnostics={**result.diagnostics, **{k: reported.diagnostics[k] for k in keep}},
        needle_tip=needle_tip,
        assessment=reported.assessment,
    )


def with_bootstrap_uncertainty(
    result: CalibrationResult,
    recording: Recording,
    solver: Callable[..., CalibrationResult],
    targets_in_base: ArrayLike | None = None,
    needle_tip: NeedleTip | None = None,
    thresholds: ErrorThresholds | None = None,
) -> CalibrationResult:
    """Add covariance (bootstrap over frames), predicted TRE and the assessment (residuals,
    expected error, a verdict graded against ``thresholds``) to a result from an estimator
    without a likelihood; its transforms are unchanged."""

    def solve(resampled: Recording) -> tuple[FloatArray, FloatArray]:
        again = solver(resampled)
        return again.tracker_from_base, again.tcp_from_marker

    covariance = bootstrap_covariance(recording, solve, result.tracker_from_base, result.tcp_from_marker)
    if covariance is None:
        failed = result.replace(
            diagnostics={
                **result.diagnostics,
                "uncertainty": "bootstrap failed: too few resamples could be solved",
            }
        )
        return with_expected_error(failed, recording, needle_tip, thresholds)
    obs = build_observations(recording)
    variance_factor = variance_factor_of(obs, result.tracker_from_base, result.tcp_from_marker)
    reported = _reported_at_result(
        result,
        recording,
        obs,
        covariance,
        variance_factor,
        f"bootstrap over frames ({RESAMPLES} resamples) in the ML perturbation parameters; mm, rad",
        targets_in_base,
        needle_tip,
        thresholds,
    )
    return result.replace(
        covariance=reported.covariance,
        predicted_tre_mm=reported.predicted_tre_mm,
        needle_tip=needle_tip,
        diagnostics={**reported.diagnostics, **result.diagnostics},
        assessment=reported.assessment,
        noise=reported.noise,
    )
