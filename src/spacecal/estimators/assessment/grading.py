"""The verdict on a calibration: the grade of its expected error against the site's thresholds, and why."""

from __future__ import annotations

from typing import Any

import numpy as np

from spacecal.estimators.assessment.gaussian import probability_within
from spacecal.records.assessment import ErrorThresholds
from spacecal.records.verdict import Verdict

#: A posteriori variance factor above which residuals are called systematic: white noise
#: gives 1 (measured 0.98–1.02 on the white-noise scenario).
SYSTEMATIC_VARIANCE_FACTOR = 1.5


def grade(position_mm: float, thresholds: ErrorThresholds) -> str:
    """The grade of an expected position error (mm)."""
    if not np.isfinite(position_mm) or position_mm > thresholds.poor_mm:
        return "unusable"
    if position_mm <= thresholds.good_mm:
        return "good"
    if position_mm <= thresholds.acceptable_mm:
        return "acceptable"
    return "poor"


def verdict(
    expected: dict[str, Any] | None,
    spread: dict[str, Any],
    outlier_fraction: float = 0.0,
    variance_factor: float | None = None,
    thresholds: ErrorThresholds | None = None,
    refusal: str | None = None,
) -> Verdict:
    """A plain-language judgement of a calibration and what to do about it.

    The grade is that of the expected error at a target near the site
    (``expected["position_mm"]``, see :mod:`spacecal.estimators.assessment.expected_error`) against
    ``thresholds``: good, acceptable, poor or unusable. The reasons follow, then notes.

    Parameters
    ----------
    expected : dict or None
        ``position_mm``, ``posture_deg`` and their ``components``; None when it could not be
        computed (the grade is then ``unusable``).
    refusal : str, optional
        A reason the data cannot give a trustworthy calibration whatever the numbers say
        (e.g. held-out blocks that cannot be refitted): the grade is ``unusable``.

    Returns
    -------
    Verdict
        The typed record (grade, expected error, limit, reasons); ``.to_dict()`` is what a
        calibration file stores.
    """
    thresholds = thresholds or ErrorThresholds()
    reasons: list[str] = []
    position: float | None = None
    posture: float | None = None
    limit: float | None = None
    chance: float | None = None
    span: tuple[float, float] | None = None
    if refusal is not None or expected is None:
        word = "unusable"
        reasons.append(
            f"{refusal or 'the expected error could not be estimated from held-out data'}; record again"
        )
    else:
        position, posture = float(expected["position_mm"]), float(expected["posture_deg"])
        word = grade(position, thresholds)
        limit = {
            "good": thresholds.good_mm,
            "acceptable": thresholds.acceptable_mm,
            "poor": thresholds.poor_mm,
            "unusable": thresholds.poor_mm,
        }[word]
        relation = "above" if word == "unusable" else "within"
        reasons.append(
            f"expected error at a target near the site {position:.2f} mm, {posture:.2f} deg "
            f"({relation} {limit:g} mm)"
        )
        if expected.get("position_covariance_mm2") is not None:
            chance = probability_within(expected["position_covariance_mm2"], thresholds.poor_mm)
            reasons.append(
                f"a target there is within {thresholds.poor_mm:g} mm with a chance of {percent(chance)}"
            )
        if expected.get("position_range_mm") is not None:
            low, high = (float(v) for v in expected["position_range_mm"])
            span = (low, high)
            if grade(low, thresholds) != grade(high, thresholds):
                # the grade itself is not pinned by so few frames: say so, and what pins it
                reasons.append(
                    f"the statement rests on a misfit this recording measures only roughly: one standard "
                    f"error either way puts it at {low:.2f}-{high:.2f} mm ({grade(low, thresholds)} to "
                    f"{grade(high, thresholds)}); more poses would pin it"
                )
        components = expected.get("components", {})
        noise = components.get("noise_tre_rms_mm")
        factor = 0.0 if variance_factor is None else variance_factor
        if factor > SYSTEMATIC_VARIANCE_FACTOR or (noise is not None and position > 2.0 * noise + 0.05):
            reasons.append(
                f"residuals are {np.sqrt(max(factor, 1.0)):.1f}x the tracker's noise, so systematic "
                "error (robot kinematics, tracker volume error, time offset or a loose marker) "
                "dominates the noise-only prediction"
            )
        if word in ("poor", "unusable"):
            reasons.append(
                "check units, the clock offset and that the marker is tight, then record more varied "
                "poses (or identify the kinematics with --method kinematic)"
            )
    if spread["rotation_sd_deg"][2] < 5.0:
        reasons.append("the tool rotated about fewer than three axes: add rotations about the missing axis")
    if outlier_fraction > 0.05:
        reasons.append(
            f"{outlier_fraction:.0%} of frames were outliers: check for reflections, "
            "occlusion or a loose marker"
        )
    return Verdict(
        word,
        position,
        posture,
        limit,
        tuple(reasons),
        tolerable_mm=thresholds.poor_mm,
        chance_within_tolerable=chance,
        expected_error_range_mm=span,
    )


def percent(chance: float) -> str:
    """A chance as a person reads it: whole percent, and "< 1 %" or "> 99 %" at the ends
    (a rounded "0 %" or "100 %" would claim a certainty no statement has)."""
    if chance < 0.01:
        return "< 1 %"
    if chance > 0.99:
        return "> 99 %"
    return f"{100 * chance:.0f} %"
