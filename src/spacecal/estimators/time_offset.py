"""Robot–tracker clock offset, estimated jointly with the calibration.

Samples taken while the robot moves pair a tracker frame with a robot state; if the two
clocks are offset, every moving sample is paired with the wrong robot pose (1 ms at
100 mm/s is 0.1 mm). With the raw streams, a tracker frame at tracker time t is paired with
the robot state interpolated at robot time ``t + offset`` (joints linearly, the TCP pose
linearly in position and along the geodesic in rotation). The offset is the one whose pairs
the maximum-likelihood calibration fits best. A coarse value comes cheaply from matching the
two streams' angular speeds (both see the tool's rotation rate): first by cross-correlation
over every offset at which the streams overlap (the clocks may count from epochs hours
apart), then on a 1 ms grid around it; a bounded Brent search of the fit's chi-square
around that, each fit warm-started from the previous one, refines it. The offset is always
the robot clock minus the tracker clock.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from spacecal.core.errors import DegenerateDataError, InvalidInputError
from spacecal.estimators.methods.likelihood import fit_ml, variance_factor_of
from spacecal.estimators.methods.ml import levenberg_marquardt
from spacecal.estimators.methods.observations import build_observations
from spacecal.geometry.arrays import BoolArray, FloatArray, IntArray, as_float_array
from spacecal.geometry.transforms import MEASURED_TRANSFORM_ATOL, check_transform, interpolate_transforms
from spacecal.records import RawRecording, Recording

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
    searched around the coarse link of :func:`clock_link_s` (over every offset at which the
    streams overlap when the frames carry no arrival times).

    When the data hold no information on the offset (the robot never rotated while sampled,
    e.g. stop-and-go stations, or a run stopped early), the coarse link is used and the note
    says so: samples taken at rest do not depend on it.
    """
    link = clock_link_s(raw)
    # the link already puts the offset within the transport delays: no need to search wider
    linked = raw.arrival_robot_time_s is not None and bool(np.isfinite(raw.arrival_robot_time_s).any())
    try:
        offset = link + estimate_time_offset(_shifted(raw, link), whole_overlap=not linked).offset_s
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


def check_overlap(raw: RawRecording, offset_s: float, what: str = "clock offset") -> None:
    """Refuse an offset at which no tracker frame falls within the robot stream's time span.

    Raises
    ------
    InvalidInputError
        One line naming ``what``, the offset and both streams' time ranges.
    """
    if not np.isfinite(offset_s):
        raise InvalidInputError(f"{what} must be a finite number, got {offset_s}")
    robot_t, tracker_t = raw.robot_time_s, raw.tracker_time_s
    if len(robot_t) and len(tracker_t):
        query = tracker_t + offset_s
        if np.any((query >= robot_t[0]) & (query <= robot_t[-1])):
            return
    robot = f"{robot_t[0]:.3f}..{robot_t[-1]:.3f} s" if len(robot_t) else "empty"
    tracker = (
        f"{tracker_t[0]:.3f}..{tracker_t[-1]:.3f} s, at {offset_s * 1000:+.3f} ms "
        f"{tracker_t[0] + offset_s:.3f}..{tracker_t[-1] + offset_s:.3f} s on the robot's clock"
        if len(tracker_t)
        else "empty"
    )
    raise InvalidInputError(
        f"{what} {offset_s * 1000:+.3f} ms: the streams do not overlap (robot {robot}; tracker {tracker})"
    )


def _shifted(raw: RawRecording, offset_s: float) -> RawRecording:
    """The streams with the tracker's times moved onto the robot's clock by ``offset_s``."""
    return dataclasses.replace(raw, tracker_time_s=raw.tracker_time_s + offset_s, arrival_robot_time_s=None)


@dataclass
class OffsetEstimate:
    """The estimated offset (robot clock minus tracker clock) and the coarse scans that found it.

    ``scan_speed_mismatch`` is the mean squared difference (rad^2/s^2) of the robot's and the
    tracker's angular speeds at each ``scan_offsets_s`` (+-``search_s`` around ``centre_s``),
    whose best is ``coarse_offset_s``. ``whole_overlap`` is the search over every offset at
    which the streams overlap, which set ``centre_s`` (0 when it found the offset within
    +-``search_s`` of 0, or was not run). The streams paired at :attr:`offset_s`
    (:func:`pair_streams`) are calibrated like any recording (:func:`spacecal.estimators.calibrate`).
    """

    offset_s: float
    raw: RawRecording
    scan_offsets_s: np.ndarray
    scan_speed_mismatch: np.ndarray
    coarse_offset_s: float
    search_s: float
    whole_overlap: CoarseOffset | None = None
    centre_s: float = 0.0

    def describe(self) -> str:
        """How the offset was found, in a few words for the calibration's note."""
        fine = "refined by the ML fit"
        if self.whole_overlap is None:
            return f"angular speeds matched within +-{self.search_s * 1000:.0f} ms, {fine}"
        return f"{self.whole_overlap.describe()}; {fine}"


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


#: Smallest share of the shorter stream's motion signal that a candidate offset must overlap
#: in the whole-overlap search (at the true offset the two streams of one run overlap wholly).
MIN_OVERLAP_FRACTION = 0.5
#: A runner-up correlation peak at least this share of the best one makes the coarse offset
#: ambiguous (e.g. stop-and-go stations, where the tracker sees only the tool at rest).
AMBIGUITY_RATIO = 0.9
#: A best correlation below this is no match at all (it leaves three quarters of the speeds'
#: variance unexplained): too little motion seen by both streams.
MIN_CORRELATION = 0.5
#: Nor is one that noise alone reaches: this many standard deviations (1 / sqrt(n)) of the
#: correlation of two unrelated signals over n independent samples.
NOISE_SIGMAS = 4.0
#: Shortest window of the angular speeds correlated (or the slower stream's frame period if
#: longer): differencing poses closer in time than this amplifies the tracker's noise, and the
#: coarse offset needs only to fall within the +-``search_s`` scan that follows.
SPEED_WINDOW_S = 0.1
#: The correlation signal's grid: at most this many samples per stream (a coarser step beyond).
LARGEST_GRID = 2**22


@dataclass(frozen=True)
class CoarseOffset:
    """Where the whole-overlap search put the clock offset, and how sharply.

    Attributes
    ----------
    offset_s : float
        Robot clock minus tracker clock at the correlation peak, s (parabolic sub-step).
    correlation : float
        Normalised cross-correlation of the two angular-speed signals at the peak (1 = alike).
    runner_up_offset_s, runner_up_correlation : float or None
        The highest other local peak more than ``separation_s`` from the best one; None when
        the curve has none.
    separation_s : float
        How far from the best offset a peak counts as another candidate, s.
    overlap_fraction : float
        Share of the shorter signal that overlaps the other at the peak.
    independent_samples : float
        Overlap at the peak over the window: about how many independent speed values the
        peak's correlation rests on (:attr:`noise_correlation`).
    searched_s : (float, float)
        The offsets searched: every one at which the signals overlap by at least
        ``min_overlap_fraction`` of the shorter, s.
    min_overlap_fraction, step_s, window_s : float
        The search's settings: overlap asked for, grid step and the angular-speed window.
    """

    offset_s: float
    correlation: float
    runner_up_offset_s: float | None
    runner_up_correlation: float | None
    separation_s: float
    overlap_fraction: float
    independent_samples: float
    searched_s: tuple[float, float]
    min_overlap_fraction: float
    step_s: float
    window_s: float

    @property
    def ambiguity(self) -> float:
        """Runner-up over best correlation: near 1 when another offset matches about as well."""
        if self.runner_up_correlation is None or self.correlation <= 0:
            return 0.0
        return max(self.runner_up_correlation, 0.0) / self.correlation

    @property
    def noise_correlation(self) -> float:
        """A correlation that unrelated signals reach by chance (:data:`NOISE_SIGMAS`)."""
        return NOISE_SIGMAS / float(np.sqrt(max(self.independent_samples, 1.0)))

    @property
    def ambiguous(self) -> bool:
        """Whether the peak is too weak, or another too close to it, to be trusted."""
        return self.refusal() is not None

    def refusal(self) -> str | None:
        """Why the peak cannot be trusted (one line), or None when it can."""
        if self.ambiguity >= AMBIGUITY_RATIO:
            return (
                f"the clock offset is ambiguous: the angular speeds match about as well at "
                f"{self.runner_up_offset_s:+.3f} s (correlation {self.runner_up_correlation:.2f}) as at "
                f"{self.offset_s:+.3f} s ({self.correlation:.2f})"
            )
        if self.correlation < max(MIN_CORRELATION, self.noise_correlation):
            return (
                f"the clock offset is ambiguous: the angular speeds correlate at best {self.correlation:.2f} "
                f"(at {self.offset_s:+.3f} s; chance reaches {self.noise_correlation:.2f}), too little "
                f"motion seen by both streams"
            )
        return None

    def describe(self) -> str:
        """One clause saying how the offset was found, for a calibration note."""
        runner = (
            "no other peak"
            if self.runner_up_offset_s is None or self.runner_up_correlation is None
            else f"next best {self.runner_up_correlation:.2f} at {self.runner_up_offset_s:+.3f} s"
        )
        low, high = self.searched_s
        return (
            f"angular speeds correlated over offsets {low:+.1f}..{high:+.1f} s: "
            f"peak {self.correlation:.2f} at {self.offset_s:+.3f} s, {runner}"
        )

    def to_dict(self) -> dict[str, object]:
        return {
            **dataclasses.asdict(self),
            "searched_s": list(self.searched_s),
            "ambiguity": self.ambiguity,
            "noise_correlation": self.noise_correlation,
            "definition": "robot clock minus tracker clock",
        }


def angular_speed_signal(
    time_s: FloatArray, rotation_stack: FloatArray, window_s: float, step_s: float
) -> tuple[float, FloatArray, BoolArray]:
    """The angular speed (rad/s) on a regular grid: rotation angle between poses ``window_s``
    apart over their time difference.

    The angle of a relative rotation is the same whichever fixed frames the poses are expressed
    in and whichever rigid offset the body has (``tracker_from_base`` and ``tcp_from_marker``
    rotate it by conjugation), so the robot's and the tracker's signals are the same function
    of time up to the clock offset and the noise (Furrer et al., "Evaluation of combined
    time-offset estimation and hand-eye calibration on robotic datasets", FSR 2017, correlate
    the same signal). One window for both streams filters them alike.

    Parameters
    ----------
    time_s : numpy.ndarray, shape (N,)
        Increasing sample times on the stream's own clock, s.
    rotation_stack : numpy.ndarray, shape (N, 3, 3)
        Rotations of the tool in the stream's fixed frame; NaN rows are left out.
    window_s, step_s : float
        Window between the poses compared, and the grid step, s.

    Returns
    -------
    start_s : float
        Time of the first grid point (the stream's clock).
    speed_rad_s : numpy.ndarray, shape (G,)
        The speed at ``start_s + step_s * arange(G)``, linearly interpolated.
    valid : numpy.ndarray of bool, shape (G,)
        False inside gaps of the stream (no two poses within twice the window around it).
    """
    finite = np.all(np.isfinite(rotation_stack.reshape(len(rotation_stack), -1)), axis=1)
    time_s, rotation_stack = time_s[finite], rotation_stack[finite]
    empty = (0.0, np.zeros(0), np.zeros(0, dtype=bool))
    if len(time_s) < 3:
        return empty
    period = float(np.median(np.diff(time_s)))
    first = np.arange(len(time_s))
    second = np.searchsorted(time_s, time_s + window_s - 0.5 * period)
    inside = second < len(time_s)
    first, second = first[inside], second[inside]
    dt = time_s[second] - time_s[first]
    usable = (dt > 0) & (dt <= 2.0 * window_s)
    first, second, dt = first[usable], second[usable], dt[usable]
    if len(dt) < 2:
        return empty
    relative = np.swapaxes(rotation_stack[first], 1, 2) @ rotation_stack[second]
    cosine = np.clip((np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    mid = 0.5 * (time_s[first] + time_s[second])
    speed = np.arccos(cosine) / dt
    count = int(np.floor((mid[-1] - mid[0]) / step_s)) + 1
    grid = mid[0] + step_s * np.arange(count)
    upper = np.clip(np.searchsorted(mid, grid, side="right"), 1, len(mid) - 1)
    valid = (mid[upper] - mid[upper - 1]) <= 2.0 * window_s
    return float(mid[0]), np.interp(grid, mid, speed), valid


def _masked_correlation(
    robot: FloatArray, robot_valid: BoolArray, tracker: FloatArray, tracker_valid: BoolArray
) -> tuple[IntArray, FloatArray, FloatArray]:
    """Normalised cross-correlation of two signals with gaps, at every lag, by FFT.

    At lag k the robot's sample i + k meets the tracker's sample i; each lag's mean and
    variance are those of the samples both signals have there (Padfield, "Masked object
    registration in the Fourier domain", IEEE Trans. Image Process. 21(5), 2012).

    Returns
    -------
    lags : numpy.ndarray of int, shape (L,)
    correlation : numpy.ndarray, shape (L,)
        NaN where one signal is constant over the overlap.
    overlap : numpy.ndarray, shape (L,)
        Number of samples both signals have at each lag.
    """
    # centred first, so that the sums below do not cancel
    a = np.where(robot_valid, robot - robot[robot_valid].mean(), 0.0)
    b = np.where(tracker_valid, tracker - tracker[tracker_valid].mean(), 0.0)
    ma, mb = robot_valid.astype(float), tracker_valid.astype(float)

    from scipy import signal  # here, not at the top: it takes longer to import than spacecal itself

    def correlate(x: FloatArray, y: FloatArray) -> FloatArray:
        return as_float_array(signal.correlate(x, y, mode="full", method="fft"))

    overlap = np.round(correlate(ma, mb))
    sum_a, sum_b = correlate(a, mb), correlate(ma, b)
    n = np.maximum(overlap, 1.0)
    covariance = correlate(a, b) - sum_a * sum_b / n
    variance_a = correlate(a * a, mb) - sum_a**2 / n
    variance_b = correlate(ma, b * b) - sum_b**2 / n
    # a signal constant over the overlap (the tool at rest there) says nothing about the lag
    floor_a = 1e-9 * float(np.sum(a * a)) / max(int(robot_valid.sum()), 1)
    floor_b = 1e-9 * float(np.sum(b * b)) / max(int(tracker_valid.sum()), 1)
    informative = (variance_a > floor_a * n) & (variance_b > floor_b * n) & (overlap > 2)
    correlation = np.full(len(overlap), np.nan)
    correlation[informative] = covariance[informative] / np.sqrt(
        variance_a[informative] * variance_b[informative]
    )
    lags = np.asarray(signal.correlation_lags(len(a), len(b), mode="full"), dtype=np.intp)
    return lags, correlation, overlap


def coarse_offset_by_correlation(
    raw: RawRecording,
    min_overlap_fraction: float = MIN_OVERLAP_FRACTION,
    separation_s: float = 0.2,
) -> CoarseOffset:
    """The robot–tracker clock offset over every offset at which the streams overlap.

    The two angular-speed signals (:func:`angular_speed_signal`, frame-free) are resampled on
    one grid step, each from its own first sample (so the clocks' epochs cost nothing, hours
    apart or not), and their normalised cross-correlation is taken at every lag where they
    overlap by at least ``min_overlap_fraction`` of the shorter signal. The best lag is refined
    to a fraction of a step by a parabola through it and its neighbours.

    Parameters
    ----------
    raw : RawRecording
    min_overlap_fraction : float
        In (0, 1].
    separation_s : float
        A peak further than this (or than five windows, whichever is longer) from the best one
        is a rival candidate: it sets :attr:`CoarseOffset.runner_up_correlation`.

    Raises
    ------
    DegenerateDataError
        When either stream has too little rotation to correlate, or the best match lies at the
        smallest overlap allowed (a longer overlap would have to be searched).
    """
    if not 0.0 < min_overlap_fraction <= 1.0:
        raise InvalidInputError(f"min_overlap_fraction must be in (0, 1], got {min_overlap_fraction}")
    robot_period = _median_period(raw.robot_time_s)
    tracker_period = _median_period(raw.tracker_time_s[np.isfinite(raw.tracker_from_marker_stack[:, 0, 0])])
    window = max(robot_period, tracker_period, SPEED_WINDOW_S)
    span = max(
        float(np.ptp(raw.robot_time_s)) if len(raw.robot_time_s) else 0.0,
        float(np.ptp(raw.tracker_time_s)) if len(raw.tracker_time_s) else 0.0,
    )
    step = max(min(max(window / 5.0, 1e-3), 1e-2), span / LARGEST_GRID)
    robot_start, robot_speed, robot_valid = angular_speed_signal(
        raw.robot_time_s, raw.base_from_tcp_stack[:, :3, :3], window, step
    )
    tracker_start, tracker_speed, tracker_valid = angular_speed_signal(
        raw.tracker_time_s, raw.tracker_from_marker_stack[:, :3, :3], window, step
    )
    if robot_valid.sum() < 10 or tracker_valid.sum() < 10:
        raise DegenerateDataError("too few poses in a stream to correlate the angular speeds")
    lags, correlation, overlap = _masked_correlation(robot_speed, robot_valid, tracker_speed, tracker_valid)
    shorter = min(int(robot_valid.sum()), int(tracker_valid.sum()))
    searched = overlap >= min_overlap_fraction * shorter
    correlation = np.where(searched, correlation, np.nan)
    offsets = robot_start - tracker_start + lags * step
    if not np.isfinite(correlation).any():
        raise DegenerateDataError(
            "the angular speeds do not vary where the streams overlap: the clock offset cannot be estimated"
        )
    best = int(np.nanargmax(correlation))
    neighbours = correlation[max(best - 1, 0) : best + 2]
    if best in (0, len(correlation) - 1) or len(neighbours) < 3 or not np.isfinite(neighbours).all():
        raise DegenerateDataError(
            f"the angular speeds match best at {offsets[best]:+.3f} s, at the edge of the offsets "
            f"searched (streams overlapping by {min_overlap_fraction:.0%} or more)"
        )
    # parabola through the peak and its neighbours
    below, peak, above = (float(v) for v in neighbours)
    curvature = below - 2.0 * peak + above
    shift = 0.5 * (below - above) / curvature if curvature < 0 else 0.0
    separation = max(separation_s, 5.0 * window)
    filled = np.where(np.isfinite(correlation), correlation, -2.0)
    from scipy import signal

    peaks, _ = signal.find_peaks(filled)
    rivals = peaks[(np.abs(offsets[peaks] - offsets[best]) > separation) & (filled[peaks] > -2.0)]
    runner = int(rivals[np.argmax(filled[rivals])]) if len(rivals) else None
    searched_offsets = offsets[searched]
    return CoarseOffset(
        offset_s=float(offsets[best] + shift * step),
        correlation=peak,
        runner_up_offset_s=None if runner is None else float(offsets[runner]),
        runner_up_correlation=None if runner is None else float(correlation[runner]),
        separation_s=separation,
        overlap_fraction=float(overlap[best]) / shorter,
        independent_samples=float(overlap[best]) * step / window,
        searched_s=(float(searched_offsets[0]), float(searched_offsets[-1])),
        min_overlap_fraction=min_overlap_fraction,
        step_s=step,
        window_s=window,
    )


def _median_period(time_s: FloatArray) -> float:
    positive = np.diff(time_s)
    positive = positive[positive > 0]
    return float(np.median(positive)) if len(positive) else 0.0


def estimate_time_offset(
    raw: RawRecording,
    search_s: float = 0.2,
    refine_s: float = 0.01,
    xatol_s: float = 5e-5,
    whole_overlap: bool = True,
    min_overlap_fraction: float = MIN_OVERLAP_FRACTION,
) -> OffsetEstimate:
    """Estimate the robot–tracker clock offset jointly with the ML calibration.

    0. Whole overlap (``whole_overlap``): the offset at which the two streams' angular speeds
       correlate best, over every offset at which they overlap by ``min_overlap_fraction``
       (:func:`coarse_offset_by_correlation`): any size, the clocks may be hours apart. When
       it lies within +-``search_s`` of 0 the steps below run as they would without it;
       otherwise they run around it.
    1. Coarse: the offset (1 ms grid over +-``search_s``) at which the robot's angular speed
       best matches the tracker's (:func:`coarse_offset_from_angular_speed`); no fit needed.
    2. Fine: a bounded Brent search within +-``refine_s`` of it (four times wider if the
       optimum lands on the edge, then brackets as wide centred on each edge the optimum
       reaches, :data:`MAX_BRACKETS` in all) for the offset whose pairs the ML calibration fits
       best (smallest variance factor), each fit warm-started from the last. When the
       whole-overlap offset lies more than ``refine_s`` from the scan's, the search starts from
       whichever of the two the fit prefers.

    Raises
    ------
    InvalidInputError
        When a pose stream is not a stack of rigid transforms (NaN rows mark frames without
        the marker).
    DegenerateDataError
        When the best offset sits at the edge of the search (widen it), the robot never
        rotated while sampled (no information on the offset), or the whole-overlap search is
        ambiguous: another offset matches the angular speeds about as well as the best
        (:data:`AMBIGUITY_RATIO`) or none matches well (:data:`MIN_CORRELATION`), as in a
        stop-and-go recording whose frames all show the tool at rest. Then the offset must be
        given.
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
    still = DegenerateDataError(
        "the robot did not rotate while sampled: the clock offset cannot be estimated"
    )
    _, robot_speed = angular_speeds(raw.robot_time_s, raw.base_from_tcp_stack[:, :3, :3])
    if len(robot_speed) == 0 or np.max(robot_speed) < np.radians(1.0):
        raise still
    found, centre = None, 0.0
    if whole_overlap:
        found = coarse_offset_by_correlation(raw, min_overlap_fraction, separation_s=search_s)
        refusal = found.refusal()
        if refusal:
            raise DegenerateDataError(refusal)
        if abs(found.offset_s) > search_s:
            centre = found.offset_s
    # around the whole-overlap offset: the tracker's times moved onto the robot's clock by it
    local = _shifted(raw, centre) if centre else raw
    offsets, mismatch = coarse_offset_from_angular_speed(local, search_s)
    if not np.isfinite(mismatch).any():
        raise still
    best = int(np.argmin(mismatch))
    if best in (0, len(offsets) - 1):
        raise DegenerateDataError(
            f"the clock offset lies outside +-{search_s * 1000:.0f} ms"
            + (f" of {centre:+.3f} s" if centre else "")
            + ": widen the search"
        )
    coarse = float(offsets[best])
    warm: dict[str, np.ndarray] = {}

    def cost(offset_s: float) -> float:
        paired = pair_streams(local, offset_s)
        if warm:
            obs = build_observations(paired)
            fit = levenberg_marquardt(obs, warm["tracker_from_base"], warm["tcp_from_marker"])
        else:
            obs, fit = fit_ml(paired)
        warm["tracker_from_base"], warm["tcp_from_marker"] = fit.tracker_from_base, fit.tcp_from_marker
        return variance_factor_of(obs, fit.tracker_from_base, fit.tcp_from_marker)

    if found is not None and abs(centre + coarse - found.offset_s) > refine_s:
        # the two coarse values disagree (consecutive poses of a fast, noisy robot stream make
        # the 1 ms scan's speeds noisy; the correlation's window blurs fast motion): the fit decides
        candidate = found.offset_s - centre
        if cost(candidate) < cost(coarse):
            coarse = candidate
    middle, width = coarse, refine_s
    for _ in range(MAX_BRACKETS):
        refined = minimize_scalar(
            cost, bounds=(middle - width, middle + width), method="bounded", options={"xatol": xatol_s}
        )
        if abs(float(refined.x) - middle) < 0.95 * width:
            break
        # an optimum at the edge of the bracket: the angular speeds misled (a noisy tracker's
        # orientation adds to its angular speed), so look four times wider, then follow the
        # fit's descent with brackets centred on each edge it reaches
        if width == refine_s:
            width = 4.0 * refine_s
        else:
            middle = float(refined.x)
    return OffsetEstimate(
        centre + float(refined.x), raw, centre + offsets, mismatch, centre + coarse, search_s, found, centre
    )
