"""Diagnostics every estimator reports: per-sample residuals, motion spread, a verdict."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.estimators.expected_error import probability_within
from spacecal.geometry.arrays import ArrayLike, FloatArray, IndexArray, IntArray, as_float_array
from spacecal.geometry.rotations import mean_rotation, rotation_angle
from spacecal.geometry.transforms import invert_transform, make_transform, matrix_to_rotvec
from spacecal.records import Recording
from spacecal.records.verdict import Verdict

#: A posteriori variance factor above which residuals are called systematic: white noise
#: gives 1 (measured 0.98–1.02 on the white-noise scenario).
SYSTEMATIC_VARIANCE_FACTOR = 1.5


def sample_counts(
    recording: Recording,
    used: ArrayLike,
    considered: ArrayLike | None = None,
    extra_rejections: dict[str, int] | None = None,
    per_segment: Sequence[str] = (),
) -> dict[str, Any]:
    """How many samples a method used and why the others were left out (every method's
    ``sample_counts``).

    Parameters
    ----------
    recording : Recording
    used : array_like of bool, shape (N,), or of int, shape (U,)
        The samples used (mask or row indices).
    considered : array_like of bool, shape (N,), optional
        The samples the method looks at (e.g. the paper's six sweeps); invisible ones among
        them count as ``rejected_not_visible``. All samples when omitted.
    extra_rejections : dict, optional
        Further ``rejected_<reason>`` counts, e.g. ``{"outlier": 12}``.
    per_segment : sequence of str
        Segment labels to count the used samples of.
    """
    mask = np.zeros(len(recording), dtype=bool)
    used_array = np.asarray(used)
    if used_array.dtype == bool:
        mask[:] = used_array
    else:
        mask[used_array.astype(int)] = True
    looked_at = (
        np.ones(len(recording), dtype=bool) if considered is None else np.asarray(considered, dtype=bool)
    )
    counts: dict[str, Any] = {
        "total": int(len(recording)),
        "used": int(mask.sum()),
        "rejected": int(len(recording) - mask.sum()),
        "rejected_not_visible": int((looked_at & ~recording.visible).sum()),
    }
    for reason, count in (extra_rejections or {}).items():
        counts[f"rejected_{reason}"] = int(count)
    if per_segment:
        counts["per_segment"] = {
            label: int((mask & (recording.segment == label)).sum()) for label in per_segment
        }
    return counts


def sample_residuals(
    recording: Recording,
    tracker_from_base: FloatArray,
    tcp_from_marker: FloatArray,
    rms_rows: IndexArray | None = None,
) -> dict[str, Any]:
    """Residuals of every visible frame: measured vs predicted ``tracker_from_marker``.

    Parameters
    ----------
    rms_rows : array_like of int, optional
        The frames the RMS figures summarise (e.g. without flagged outliers); default all.

    Returns
    -------
    dict
        ``rows`` (indices), ``position_mm`` (marker origin distance), ``rotation_deg``,
        and their RMS over ``rms_rows``.
    """
    rows = np.flatnonzero(recording.visible)
    predicted = tracker_from_base @ recording.base_from_tcp_stack[rows] @ tcp_from_marker
    measured = recording.tracker_from_marker_stack[rows]
    position = np.linalg.norm(predicted[:, :3, 3] - measured[:, :3, 3], axis=1)
    rotation = np.degrees(rotation_angle(predicted[:, :3, :3] @ np.swapaxes(measured[:, :3, :3], 1, 2)))
    summarised = np.ones(len(rows), bool) if rms_rows is None else np.isin(rows, rms_rows)
    return {
        "rows": rows,
        "position_mm": position,
        "rotation_deg": rotation,
        "position_rms_mm": float(np.sqrt(np.mean(position[summarised] ** 2))),
        "rotation_rms_deg": float(np.sqrt(np.mean(rotation[summarised] ** 2))),
    }


def motion_spread(base_from_tcp_stack: ArrayLike) -> dict[str, Any]:
    """How much the tool rotated and moved: principal spreads of orientation and position.

    Small second or third rotation spreads mean the tool turned about (nearly) one axis:
    the marker offset along that axis is then poorly determined.
    """
    stack = np.asarray(base_from_tcp_stack)
    reference = mean_rotation(stack[:, :3, :3])
    rotvecs = matrix_to_rotvec(stack[:, :3, :3] @ reference.T)
    rot_spread = np.sqrt(np.clip(np.linalg.eigvalsh(np.cov(rotvecs.T)), 0, None))[::-1]
    positions = stack[:, :3, 3]
    pos_spread = np.sqrt(np.clip(np.linalg.eigvalsh(np.cov(positions.T)), 0, None))[::-1]
    return {"rotation_sd_deg": np.degrees(rot_spread).tolist(), "position_sd_mm": pos_spread.tolist()}


def residual_table(
    recording: Recording, residuals: dict[str, Any], outlier_rows: Sequence[int] | IntArray = ()
) -> list[dict[str, Any]]:
    """Per-sample residual rows for result files (time, segment, position, rotation, outlier)."""
    outliers = set(int(r) for r in outlier_rows)
    return [
        {
            "row": int(r),
            "time_s": float(recording.time_s[r]),
            "segment": str(recording.segment[r]),
            "position_mm": float(p),
            "rotation_deg": float(a),
            "outlier": int(r) in outliers,
        }
        for r, p, a in zip(residuals["rows"], residuals["position_mm"], residuals["rotation_deg"])
    ]


@dataclass(frozen=True)
class ErrorThresholds:
    """Upper limits (mm) of the expected position error at a target for each grade.

    Above ``poor_mm`` a calibration is ``unusable``.
    """

    good_mm: float = 0.5
    acceptable_mm: float = 1.0
    poor_mm: float = 2.0

    def __post_init__(self) -> None:
        values = (self.good_mm, self.acceptable_mm, self.poor_mm)
        if not all(np.isfinite(v) and v > 0 for v in values) or not (
            self.good_mm <= self.acceptable_mm <= self.poor_mm
        ):
            raise InvalidInputError(
                f"error thresholds must be positive and increasing (good <= acceptable <= poor), got {values}"
            )

    @classmethod
    def parse(cls, text: str) -> ErrorThresholds:
        """From ``"good,acceptable,poor"`` in mm, e.g. ``"0.5,1,2"``."""
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            values = []
        if len(values) != 3:
            raise InvalidInputError(f"thresholds take good,acceptable,poor in mm, got {text!r}")
        return cls(*values)


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
    (``expected["position_mm"]``, see :mod:`spacecal.estimators.expected_error`) against
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


def site_in_base(recording: Recording, rows: IndexArray | None = None) -> FloatArray:
    """The surgical site proxy: centroid of the TCP positions of the used samples (3,), mm."""
    used = np.flatnonzero(recording.visible) if rows is None else rows
    return as_float_array(recording.base_from_tcp_stack[used, :3, 3].mean(axis=0))


def tracker_from_base_from_samples(
    recording: Recording, tcp_from_marker: FloatArray, rows: IndexArray
) -> FloatArray:
    """Mean of tracker_from_marker_i @ marker_from_tcp @ tcp_from_base_i over rows."""
    each = (
        recording.tracker_from_marker_stack[rows]
        @ invert_transform(tcp_from_marker)
        @ invert_transform(recording.base_from_tcp_stack[rows])
    )
    return make_transform(mean_rotation(each[:, :3, :3]), each[:, :3, 3].mean(axis=0))
