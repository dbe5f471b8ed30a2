"""The assessment of a method's solution: covariance, predicted TRE, expected error, residuals, verdict.

Every method ends in a :class:`~spacecal.estimators.methods.solution.Solution` (a likelihood
method directly, the others through a bootstrap or the ML information at their solution, see
:mod:`spacecal.estimators.registry`); :func:`report_uncertainty` turns it into the
:class:`~spacecal.records.CalibrationResult` users read.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from spacecal.core.errors import DegenerateDataError
from spacecal.estimators.assessment.expected_error import expected_error
from spacecal.estimators.assessment.grading import verdict
from spacecal.estimators.methods.likelihood import MAX_OUTLIER_FRACTION, tre_summary
from spacecal.estimators.methods.ml import PARAMETER_NAMES
from spacecal.estimators.methods.recorded_model import nominal_robot_model
from spacecal.estimators.methods.samples import (
    motion_spread,
    residual_table,
    sample_counts,
    sample_residuals,
    site_in_base,
)
from spacecal.estimators.methods.solution import Solution
from spacecal.records import CalibrationResult, NeedleTip
from spacecal.records.assessment import Assessment, ErrorThresholds, ExpectedError, ResidualRow, Residuals
from spacecal.records.fit_evidence import NoiseSummary


def report_uncertainty(solution: Solution, thresholds: ErrorThresholds | None = None) -> CalibrationResult:
    """A calibration result with covariance, predicted TRE, spread and its :class:`Assessment`
    (expected error, residuals, verdict), from an estimate and its covariance.

    Parameters
    ----------
    solution : Solution
    thresholds : ErrorThresholds, optional
        What the verdict grades against (``--thresholds-mm``); the defaults when omitted.
    """
    s = solution
    recording, obs, outlier_rows = s.recording, s.obs, s.outlier_rows
    site = site_in_base(recording, obs.rows)
    tre = tre_summary(s.tracker_from_base, s.covariance, site, s.targets_in_base)
    spread = motion_spread(recording.base_from_tcp_stack[obs.rows])
    expected = expected_error_of(s, s.likelihood_based, s.needle_tip)
    if len(outlier_rows) > MAX_OUTLIER_FRACTION * len(obs.rows) and "refusal" not in expected:
        expected = {
            **expected,
            "refusal": f"{len(outlier_rows)} frames disagree with the {len(obs.rows)} kept: the recording "
            "does not describe one rigid set-up (units, a moved marker or tracker?)",
        }
    variance_factor = s.variance_factor if obs.sigma_known else None
    noise = NoiseSummary(
        obs.sigma_mm if obs.sigma_known else None,
        "given or the tracker's RMS"
        if obs.sigma_known
        else "unknown (the recording has no marker_rms_mm): covariance scaled by the residuals",
        "raw spheres"
        if obs.dof_per_frame > 6
        else "marker poses (model spheres placed by the measured pose)",
    )
    diagnostics = {
        "variance_factor": variance_factor,
        "motion_spread": spread,
        **s.diagnostics,
    }
    counts = sample_counts(recording, obs.rows, extra_rejections={"outlier": len(outlier_rows)})
    return CalibrationResult(
        s.method,
        s.tracker_from_base,
        s.tcp_from_marker,
        counts,
        diagnostics,
        covariance={
            "parameters": PARAMETER_NAMES,
            "matrix": s.covariance.tolist(),
            "note": s.covariance_note,
        },
        predicted_tre_mm=tre,
        robot_model=s.identified_model,
        needle_tip=s.needle_tip,
        assessment=assess(s, expected, spread, variance_factor, thresholds),
        noise=noise,
    )


def assess(
    solution: Solution,
    expected: dict[str, Any],
    spread: dict[str, Any],
    variance_factor: float | None,
    thresholds: ErrorThresholds | None = None,
) -> Assessment:
    """The one :class:`Assessment` of a solution: its expected error, its marker residuals on
    the recording, and the verdict graded against ``thresholds``.

    Parameters
    ----------
    solution : Solution
    expected : dict
        Its expected error (:func:`expected_error_of`), with ``refusal`` when refused.
    spread : dict
        The motion's spread (:func:`~spacecal.estimators.methods.samples.motion_spread`).
    variance_factor : float or None
        The a posteriori variance factor where the tracker's noise is known, else None.
    thresholds : ErrorThresholds, optional
        The grades' limits (mm); the defaults when omitted.
    """
    s = solution
    recording, outlier_rows = s.recording, s.outlier_rows
    thresholds = thresholds or ErrorThresholds()
    residuals = sample_residuals(recording, s.tracker_from_base, s.tcp_from_marker, rms_rows=s.obs.rows)
    rows = residual_table(recording, residuals, outlier_rows)
    judged = verdict(
        None if "refusal" in expected else expected,
        spread,
        len(outlier_rows) / max(int(recording.visible.sum()), 1),
        variance_factor,
        thresholds,
        refusal=expected.get("refusal"),
    )
    return Assessment(
        expected_error=ExpectedError.from_dict(expected),
        residuals=Residuals(
            residuals["position_rms_mm"],
            residuals["rotation_rms_deg"],
            tuple(ResidualRow.from_dict(row) for row in rows),
        ),
        verdict=judged,
        thresholds=thresholds,
    )


def expected_error_of(
    solution: Solution, likelihood_based: bool, needle_tip: NeedleTip | None = None
) -> dict[str, Any]:
    """``diagnostics["expected_error"]`` (see :mod:`spacecal.estimators.assessment.expected_error`).

    Holds ``refusal`` (and no numbers) when the data cannot support a calibration: held-out
    blocks that cannot be refitted (too few frames to leave any out). The frame count alone
    is never a refusal: ten well-spread poses are judged by what they say.
    """
    s = solution
    model = s.robot_model if s.robot_model is not None else nominal_robot_model(s.recording)
    try:
        return expected_error(
            s.obs,
            s.recording.segment[s.obs.rows],
            s.tracker_from_base,
            s.tcp_from_marker,
            s.covariance,
            robot_model=model,
            joints_rad=None if model is None else s.recording.joints_rad[s.obs.rows],
            absorbed_dh=s.absorbed_dh,
            likelihood_based=likelihood_based,
            dh_error_scale_mm=s.dh_error_scale_mm,
            needle_tip=needle_tip,
        )
    except (DegenerateDataError, np.linalg.LinAlgError) as exc:
        return {"refusal": f"the expected error cannot be cross-validated ({exc})", "basis": "not estimated"}
