"""Robot–tracker clock offset, estimated jointly with the calibration.

Samples taken while the robot moves pair a tracker frame with a robot state; if the two
clocks are offset, every moving sample is paired with the wrong robot pose (1 ms at
100 mm/s is 0.1 mm). With the raw streams, a tracker frame at tracker time t is paired with
the robot state interpolated at robot time ``t + offset`` (joints linearly, the TCP pose
linearly in position and along the geodesic in rotation). The offset is the one whose pairs
the maximum-likelihood calibration fits best: a coarse scan over ``search_s`` then a bounded
Brent refinement of the fit's chi-square.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from spacecal.core.errors import DegenerateDataError
from spacecal.estimators.likelihood import calibrate_ml, fit_ml, variance_factor_of
from spacecal.geometry.transforms import MEASURED_TRANSFORM_ATOL, check_transform, interpolate_transforms
from spacecal.records import CalibrationResult, RawRecording, Recording


def pair_streams(raw: RawRecording, offset_s: float) -> Recording:
    """A paired recording: each tracker frame with the robot state at ``tracker time + offset_s``.

    Frames outside the robot stream's time span are dropped.
    """
    robot_t = raw.robot_time_s
    query = raw.tracker_time_s + offset_s
    inside = (query >= robot_t[0]) & (query <= robot_t[-1])
    query = query[inside]
    upper = np.clip(np.searchsorted(robot_t, query, side="right"), 1, len(robot_t) - 1)
    lower = upper - 1
    span = robot_t[upper] - robot_t[lower]
    weight = np.where(span > 0, (query - robot_t[lower]) / np.where(span > 0, span, 1.0), 0.0)
    joints = raw.joints_rad[lower] + weight[:, None] * (raw.joints_rad[upper] - raw.joints_rad[lower])
    base_from_tcp = interpolate_transforms(
        raw.base_from_tcp_stack[lower], raw.base_from_tcp_stack[upper], weight
    )
    nearest = np.where(weight < 0.5, lower, upper)
    return Recording(
        time_s=raw.tracker_time_s[inside],
        segment=raw.robot_segment[nearest],
        joints_rad=joints,
        base_from_tcp_stack=base_from_tcp,
        tracker_from_marker_stack=raw.tracker_from_marker_stack[inside],
        marker_rms_mm=raw.marker_rms_mm[inside],
        metadata={**raw.metadata, "paired_with_offset_s": float(offset_s)},
    )


@dataclass
class OffsetEstimate:
    """The estimated offset (robot clock minus tracker clock), its fit, and the scan."""

    offset_s: float
    calibration: CalibrationResult
    scan_offsets_s: np.ndarray
    scan_chi_square: np.ndarray


def _fit_cost(raw: RawRecording, offset_s: float) -> float:
    obs, fit = fit_ml(pair_streams(raw, offset_s))
    return variance_factor_of(obs, fit.tracker_from_base, fit.tcp_from_marker)


def estimate_time_offset(
    raw: RawRecording, search_s: float = 0.2, coarse_step_s: float = 0.005
) -> OffsetEstimate:
    """Estimate the robot–tracker clock offset jointly with the ML calibration.

    Raises
    ------
    InvalidInputError
        When a pose stream is not a stack of rigid transforms (NaN rows mark frames without
        the marker).
    DegenerateDataError
        When the best offset sits at the edge of the search (widen it) or the robot never
        moved while sampled (no information on the offset).
    """
    check_transform(
        raw.base_from_tcp_stack, "raw.base_from_tcp_stack", stack=True, atol=MEASURED_TRANSFORM_ATOL
    )
    check_transform(
        raw.tracker_from_marker_stack,
        "raw.tracker_from_marker_stack",
        stack=True,
        allow_missing=True,
        atol=MEASURED_TRANSFORM_ATOL,
    )
    offsets = np.arange(-search_s, search_s + 1e-12, coarse_step_s)
    costs = np.array([_fit_cost(raw, o) for o in offsets])
    best = int(np.argmin(costs))
    if best in (0, len(offsets) - 1):
        raise DegenerateDataError(
            f"the clock offset lies outside +-{search_s * 1000:.0f} ms: widen the search"
        )
    if np.ptp(costs) < 1e-6 * costs[best]:
        raise DegenerateDataError(
            "the robot did not move while sampled: the clock offset cannot be estimated"
        )
    refined = minimize_scalar(
        lambda o: _fit_cost(raw, o),
        bounds=(offsets[best - 1], offsets[best + 1]),
        method="bounded",
        options={"xatol": 1e-5},
    )
    offset = float(refined.x)
    calibration = calibrate_ml(pair_streams(raw, offset))
    calibration.diagnostics["time_offset"] = {
        "offset_s": offset,
        "search_s": search_s,
        "definition": "robot clock minus tracker clock",
    }
    return OffsetEstimate(offset, calibration, offsets, costs)
