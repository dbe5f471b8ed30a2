"""Robot–tracker clock offset, estimated jointly with the calibration.

Samples taken while the robot moves pair a tracker frame with a robot state; if the two
clocks are offset, every moving sample is paired with the wrong robot pose (1 ms at
100 mm/s is 0.1 mm). With the raw streams, a tracker frame at tracker time t is paired with
the robot state interpolated at robot time ``t + offset`` (joints linearly, the TCP pose
linearly in position and along the geodesic in rotation). The offset is the one whose pairs
the maximum-likelihood calibration fits best. A coarse value comes cheaply from matching the
two streams' angular speeds (both see the tool's rotation rate); a bounded Brent search of
the fit's chi-square around it, each fit warm-started from the previous one, refines it.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from spacecal.core.errors import DegenerateDataError
from spacecal.estimators.likelihood import calibrate_ml, fit_ml, variance_factor_of
from spacecal.estimators.ml import levenberg_marquardt
from spacecal.estimators.observations import build_observations
from spacecal.geometry.transforms import MEASURED_TRANSFORM_ATOL, check_transform, interpolate_transforms
from spacecal.records import CalibrationResult, RawRecording, Recording

#: A frame is paired only between robot states at most this many median robot periods, or
#: ``LARGEST_GAP_S``, apart, whichever is longer: a state stream read by polling may miss a few
#: ticks, but nothing is interpolated across a stretch the robot was not recorded (at 400 mm/s^2,
#: interpolating linearly across 50 ms misplaces the TCP by at most a dt^2 / 8 = 0.13 mm).
LARGEST_GAP_PERIODS = 3.0
LARGEST_GAP_S = 0.05

#: Brent brackets :func:`estimate_time_offset` tries before it takes an optimum at an edge.
MAX_BRACKETS = 6


def pair_streams(raw: RawRecording, offset_s: float) -> Recording:
    """A paired recording: each tracker frame with the robot state at ``tracker time + offset_s``.

    Frames outside the robot stream's time span, or in a gap of it (see ``LARGEST_GAP_S``),
    are dropped.
    """
    robot_t = raw.robot_time_s
    query = raw.tracker_time_s + offset_s
    upper = np.clip(np.searchsorted(robot_t, query, side="right"), 1, len(robot_t) - 1)
    inside = (query >= robot_t[0]) & (query <= robot_t[-1])
    if len(robot_t) > 1:
        largest = max(LARGEST_GAP_PERIODS * float(np.median(np.diff(robot_t))), LARGEST_GAP_S)
        inside &= (robot_t[upper] - robot_t[upper - 1]) <= largest
    query, upper = query[inside], upper[inside]
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
        spheres_in_tracker=None if raw.spheres_in_tracker is None else raw.spheres_in_tracker[inside],
        marker_status=None if raw.marker_status is None else raw.marker_status[inside],
    )


def clock_link_s(raw: RawRecording) -> float:
    """A coarse robot-minus-tracker clock offset from when the frames arrived, s (0 without it).

    The two devices may count from unrelated epochs (the controller since it booted, the
    tracker from its frame counter). Each frame's ``arrival_robot_time_s`` is the newest robot
    timestamp when the frame reached us; the median of its difference to the frame's own time
    is the offset to within the transport delays, which :func:`estimate_time_offset` then
    resolves.
    """
    if raw.arrival_robot_time_s is None:
        return 0.0
    difference = raw.arrival_robot_time_s - raw.tracker_time_s
    difference = difference[np.isfinite(difference)]
    return float(np.median(difference)) if len(difference) else 0.0


@dataclass(frozen=True)
class Pairing:
    """How two raw streams were paired: the offset used and where it came from."""

    offset_s: float
    clock_link_s: float
    estimated: bool
    note: str

    def to_dict(self) -> dict[str, object]:
        return {
            "offset_s": self.offset_s,
            "clock_link_s": self.clock_link_s,
            "estimated": self.estimated,
            "note": self.note,
            "definition": "robot clock minus tracker clock",
        }


def pair_at_estimated_offset(raw: RawRecording) -> tuple[Recording, Pairing]:
    """Pair the streams at the clock offset estimated from them (:func:`estimate_time_offset`),
    searched around the coarse link of :func:`clock_link_s`.

    When the data hold no information on the offset (the robot never rotated while sampled,
    e.g. stop-and-go stations, or a run stopped early), the coarse link is used and the note
    says so: samples taken at rest do not depend on it.
    """
    link = clock_link_s(raw)
    try:
        offset = link + estimate_time_offset(_shifted(raw, link)).offset_s
        pairing = Pairing(
            offset, link, True, f"robot clock {offset * 1000:+.2f} ms from the tracker's (estimated)"
        )
    except DegenerateDataError as exc:
        offset = link
        pairing = Pairing(
            offset, link, False, f"clock offset not estimated ({exc}); paired at the arrival-time link"
        )
    recording = pair_streams(raw, offset)
    recording.metadata["pairing"] = pairing.to_dict()
    return recording, pairing


def _shifted(raw: RawRecording, offset_s: float) -> RawRecording:
    """The streams with the tracker's times moved onto the robot's clock by ``offset_s``."""
    return dataclasses.replace(raw, tracker_time_s=raw.tracker_time_s + offset_s, arrival_robot_time_s=None)


@dataclass
class OffsetEstimate:
    """The estimated offset (robot clock minus tracker clock), the coarse scan, and the fit.

    ``scan_speed_mismatch`` is the mean squared difference (rad^2/s^2) of the robot's and the
    tracker's angular speeds at each ``scan_offsets_s``. :attr:`calibration` is computed on
    first use (a caller that pairs the streams and calibrates by another method need not pay
    for it).
    """

    offset_s: float
    raw: RawRecording
    scan_offsets_s: np.ndarray
    scan_speed_mismatch: np.ndarray
    coarse_offset_s: float
    search_s: float

    @functools.cached_property
    def calibration(self) -> CalibrationResult:
        """The ML calibration of the streams paired at the estimated offset."""
        calibration = calibrate_ml(pair_streams(self.raw, self.offset_s))
        calibration.diagnostics["time_offset"] = {
            "offset_s": self.offset_s,
            "coarse_offset_s": self.coarse_offset_s,
            "search_s": self.search_s,
            "definition": "robot clock minus tracker clock",
        }
        return calibration


def angular_speeds(
    time_s: np.ndarray, rotation_stack: np.ndarray, largest_gap_factor: float = 3.0
) -> tuple[np.ndarray, np.ndarray]:
    """Angular speed (rad/s) between consecutive samples, at their mid-times.

    Pairs with a missing pose (NaN) or a gap above ``largest_gap_factor`` times the median
    sample period are left out.

    Parameters
    ----------
    time_s : numpy.ndarray, shape (N,)
    rotation_stack : numpy.ndarray, shape (N, 3, 3)

    Returns
    -------
    mid_time_s, speed_rad_s : numpy.ndarray, shape (M,)
    """
    dt = np.diff(time_s)
    finite = np.all(np.isfinite(rotation_stack.reshape(len(rotation_stack), -1)), axis=1)
    positive = dt[dt > 0]
    if len(positive) == 0:
        return np.zeros(0), np.zeros(0)
    usable = finite[:-1] & finite[1:] & (dt > 0) & (dt <= largest_gap_factor * np.median(positive))
    first, second = rotation_stack[:-1][usable], rotation_stack[1:][usable]
    relative = np.swapaxes(first, 1, 2) @ second
    cosine = np.clip((np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return (time_s[:-1] + 0.5 * dt)[usable], np.arccos(cosine) / dt[usable]


def coarse_offset_from_angular_speed(
    raw: RawRecording, search_s: float, step_s: float = 0.001
) -> tuple[np.ndarray, np.ndarray]:
    """Mismatch of the two streams' angular speeds over candidate offsets.

    The marker is rigid on the tool, so both streams see the same angular speed (a frame-
    free quantity): the tracker's at tracker time t equals the robot's at robot time t + offset.

    Returns
    -------
    offsets_s, mismatch : numpy.ndarray
        Candidate offsets and the mean squared speed difference (rad^2/s^2) at each.
    """
    robot_t, robot_speed = angular_speeds(raw.robot_time_s, raw.base_from_tcp_stack[:, :3, :3])
    tracker_t, tracker_speed = angular_speeds(raw.tracker_time_s, raw.tracker_from_marker_stack[:, :3, :3])
    offsets = np.arange(-search_s, search_s + 1e-12, step_s)
    mismatch = np.full(len(offsets), np.inf)
    if len(robot_t) < 2 or len(tracker_t) < 2:
        return offsets, mismatch
    for k, offset in enumerate(offsets):
        query = tracker_t + offset
        inside = (query >= robot_t[0]) & (query <= robot_t[-1])
        if inside.sum() >= 10:
            difference = np.interp(query[inside], robot_t, robot_speed) - tracker_speed[inside]
            mismatch[k] = float(np.mean(difference**2))
    return offsets, mismatch


def estimate_time_offset(
    raw: RawRecording, search_s: float = 0.2, refine_s: float = 0.01, xatol_s: float = 5e-5
) -> OffsetEstimate:
    """Estimate the robot–tracker clock offset jointly with the ML calibration.

    1. Coarse: the offset (1 ms grid over +-``search_s``) at which the robot's angular speed
       best matches the tracker's (:func:`coarse_offset_from_angular_speed`); no fit needed.
    2. Fine: a bounded Brent search within +-``refine_s`` of it (four times wider if the
       optimum lands on the edge, then brackets as wide centred on each edge the optimum
       reaches, :data:`MAX_BRACKETS` in all) for the offset whose pairs the ML calibration fits
       best (smallest variance factor), each fit warm-started from the last.

    Raises
    ------
    InvalidInputError
        When a pose stream is not a stack of rigid transforms (NaN rows mark frames without
        the marker).
    DegenerateDataError
        When the best offset sits at the edge of the search (widen it) or the robot never
        rotated while sampled (no information on the offset).
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
    offsets, mismatch = coarse_offset_from_angular_speed(raw, search_s)
    _, robot_speed = angular_speeds(raw.robot_time_s, raw.base_from_tcp_stack[:, :3, :3])
    if len(robot_speed) == 0 or np.max(robot_speed) < np.radians(1.0) or not np.isfinite(mismatch).any():
        raise DegenerateDataError(
            "the robot did not rotate while sampled: the clock offset cannot be estimated"
        )
    best = int(np.argmin(mismatch))
    if best in (0, len(offsets) - 1):
        raise DegenerateDataError(
            f"the clock offset lies outside +-{search_s * 1000:.0f} ms: widen the search"
        )
    coarse = float(offsets[best])
    warm: dict[str, np.ndarray] = {}

    def cost(offset_s: float) -> float:
        paired = pair_streams(raw, offset_s)
        if warm:
            obs = build_observations(paired)
            fit = levenberg_marquardt(obs, warm["tracker_from_base"], warm["tcp_from_marker"])
        else:
            obs, fit = fit_ml(paired)
        warm["tracker_from_base"], warm["tcp_from_marker"] = fit.tracker_from_base, fit.tcp_from_marker
        return variance_factor_of(obs, fit.tracker_from_base, fit.tcp_from_marker)

    centre, width = coarse, refine_s
    for _ in range(MAX_BRACKETS):
        refined = minimize_scalar(
            cost, bounds=(centre - width, centre + width), method="bounded", options={"xatol": xatol_s}
        )
        if abs(float(refined.x) - centre) < 0.95 * width:
            break
        # an optimum at the edge of the bracket: the angular speeds misled (a noisy tracker's
        # orientation adds to its angular speed), so look four times wider, then follow the
        # fit's descent with brackets centred on each edge it reaches
        if width == refine_s:
            width = 4.0 * refine_s
        else:
            centre = float(refined.x)
    return OffsetEstimate(float(refined.x), raw, offsets, mismatch, coarse, search_s)
