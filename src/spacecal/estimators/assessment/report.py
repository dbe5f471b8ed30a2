"""The assessment of a method's solution: covariance, predicted TRE, expected error, residuals, verdict.

Every method ends in a :class:`~spacecal.estimators.methods.solution.Solution` (a likelihood
method directly, the others through a bootstrap or the ML information at their solution, see
:mod:`spacecal.estimators.registry`); :func:`report_uncertainty` turns it into the
:class:`~spacecal.records.CalibrationResult` users read.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from spacecal.core.errors import DegenerateDataError
from spacecal.estimators.assessment.expected_error import expected_error
from spacecal.estimators.assessment.grading import ErrorThresholds, verdict
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
from spacecal.records import CalibrationResult, NeedleTip, Recording


def report_uncertainty(solution: Solution) -> CalibrationResult:
    """A calibration result with covariance, predicted TRE, expected error, residuals, spread
    and verdict, from an estimate and its covariance."""
    s = solution
    recording, obs, outlier_rows = s.recording, s.obs, s.outlier_rows
    site = site_in_base(recording, obs.rows)
    tre = tre_summary(s.tracker_from_base, s.covariance, site, s.targets_in_base)
    residuals = sample_residuals(recording, s.tracker_from_base, s.tcp_from_marker, rms_rows=obs.rows)
    spread = motion_spread(recording.base_from_tcp_stack[obs.rows])
    outlier_fraction = len(outlier_rows) / max(int(recording.visible.sum()), 1)
    expected = expected_error_of(s, s.likelihood_based, s.needle_tip)
    if len(outlier_rows) > MAX_OUTLIER_FRACTION * len(obs.rows) and "refusal" not in expected:
        expected = {
            **expected,
            "refusal": f"{len(outlier_rows)} frames disagree with the {len(obs.rows)} kept: the recording "
            "does not describe one rigid set-up (units, a moved marker or tracker?)",
        }
    variance_factor = s.variance_factor if obs.sigma_known else None
    diagnostics = {
        "noise": {
            "sigma_per_axis_mm": obs.sigma_mm if obs.sigma_known else None,
            "source": "given or the tracker's RMS"
            if obs.sigma_known
            else "unknown (the recording has no marker_rms_mm): covariance scaled by the residuals",
            "observations": "raw spheres"
            if obs.dof_per_frame > 6
            else "marker poses (model spheres placed by the measured pose)",
        },
        "variance_factor": variance_factor,
        "residual_position_rms_mm": residuals["position_rms_mm"],
        "residual_rotation_rms_deg": residuals["rotation_rms_deg"],
        "motion_spread": spread,
        "expected_error": expected,
        "verdict": verdict(
            None if "refusal" in expected else expected,
            spread,
            outlier_fraction,
            variance_factor,
            refusal=expected.get("refusal"),
        ).to_dict(),
        "per_sample_residuals": residual_table(recording, residuals, outlier_rows),
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
