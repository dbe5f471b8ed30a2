"""Pre-operative calibration check: does the calibration still hold?

At two or three poses the tracked marker is compared with where the calibration predicts it
(``tracker_from_base @ base_from_tcp @ tcp_from_marker``). The error is reported where it
matters, at the TCP (the needle tip in the paper's set-up): the distance between the TCP
origin as the calibration places it and as the tracked marker places it, and the angle
between the two marker orientations. A bumped marker, a moved tracker or a re-mounted tool
shows up at once. Each check is appended to a history file next to the calibration.

What a sound set-up shows at a pose is not zero but the misfit the calibration left there:
kinematic and tracker errors are systematic and come back at the same configuration. The
calibration's recording measured that misfit at the configurations it passed through
(:class:`MisfitField`); the check predicts it at each check pose from the recorded frames
nearby (:func:`expected_misfit`) and fails a pose whose misfit departs from the prediction by
more than the set-up's repeatability allows (:func:`pose_tolerances`): the scatter of the
recorded misfits, the tracker's noise over the frames averaged, and the robot's repeatability.
A calibration without usable residuals falls back to :func:`check_thresholds`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from spacecal.core.errors import DegenerateDataError, InvalidInputError
from spacecal.core.ports import Robot, Tracker
from spacecal.geometry.rotations import rotation_angle
from spacecal.geometry.transforms import invert_transform, matrix_to_rotvec, mean_transform
from spacecal.models.kinematics import forward_kinematics
from spacecal.models.robot_errors import REPEATABILITY_TO_AXIS_SD
from spacecal.models.robot_kinds import ROBOT_KINDS
from spacecal.planning.motion import MotionPlan
from spacecal.records import CalibrationResult, CheckResult, Recording
from spacecal.workflows.acquisition import AcquisitionSettings, SampleCallback
from spacecal.workflows.held_poses import HeldPose, hold_poses

#: A check fails beyond this many standard deviations of what a sound calibration leaves.
CHECK_SIGMAS = 3.0
#: Smallest thresholds (a check must not fail on the tracker's own noise): mm, deg.
CHECK_FLOOR_MM, CHECK_FLOOR_DEG = 0.5, 0.25
#: Thresholds used when the calibration carries no expected error (older files): mm, deg.
FALLBACK_THRESHOLD_MM, FALLBACK_THRESHOLD_DEG = 1.0, 1.0


def check_thresholds(calibration: CalibrationResult, frames_averaged: int = 1) -> tuple[float, float, str]:
    """Thresholds (mm at the TCP, deg) a sound calibration passes, from its own numbers: the rule
    for calibrations whose recording cannot predict the misfit at the check poses.

    A check pose's misfit is the calibration's error there (its expected error,
    :mod:`spacecal.estimators.assessment.expected_error`) plus what its model leaves unexplained in one
    frame (its residual RMS), shrunk by the frames averaged at the pose. The marker's rotation
    residual reaches the TCP over the marker-to-TCP lever arm, so a frame's TCP misfit is the
    root sum of squares of the position residual and that lever times the rotation residual.
    The threshold is ``CHECK_SIGMAS`` times the total, at least ``CHECK_FLOOR_MM`` /
    ``CHECK_FLOOR_DEG``.

    Parameters
    ----------
    calibration : CalibrationResult
    frames_averaged : int
        Frames averaged into each checked pose (1 when single frames are compared).

    Returns
    -------
    threshold_mm, threshold_deg : float
    basis : str
        Where they came from, for the output.
    """
    assessment = calibration.assessment
    expected = None if assessment is None else assessment.expected_error
    residuals = None if assessment is None else assessment.residuals
    raw_numbers = [
        None if expected is None else expected.position_mm,
        None if expected is None else expected.posture_deg,
        None if residuals is None else residuals.position_rms_mm,
        None if residuals is None else residuals.rotation_rms_deg,
    ]
    if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in raw_numbers):
        return FALLBACK_THRESHOLD_MM, FALLBACK_THRESHOLD_DEG, "fixed (the calibration has no expected error)"
    position, posture, residual_mm, residual_deg = (float(v) for v in raw_numbers)  # type: ignore[arg-type]
    lever_mm = float(np.linalg.norm(calibration.tcp_from_marker[:3, 3]))
    frame_mm = math.hypot(residual_mm, lever_mm * math.radians(residual_deg))
    shrink = math.sqrt(max(1, frames_averaged))
    threshold_mm = max(CHECK_FLOOR_MM, CHECK_SIGMAS * math.hypot(position, frame_mm / shrink))
    threshold_deg = max(CHECK_FLOOR_DEG, CHECK_SIGMAS * math.hypot(posture, residual_deg / shrink))
    return (
        threshold_mm,
        threshold_deg,
        f"{CHECK_SIGMAS:g} sigma of the calibration's expected error ({position:.2f} mm, {posture:.2f} deg) "
        f"and its one-frame misfit ({frame_mm:.2f} mm, {residual_deg:.2f} deg) "
        f"over {frames_averaged} frame(s)",
    )


def robot_pose(
    calibration: CalibrationResult, state_pose: np.ndarray, joints_rad: np.ndarray | None
) -> np.ndarray:
    """The TCP pose the calibration pairs with the marker: from its identified kinematics at the
    joints when it has them (``--method kinematic``), else the pose the controller reported."""
    if calibration.robot_model is not None and joints_rad is not None and np.all(np.isfinite(joints_rad)):
        return forward_kinematics(calibration.robot_model, joints_rad)
    return np.asarray(state_pose, dtype=float)


def pose_errors(calibration: CalibrationResult, base_from_tcp, tracker_from_marker) -> tuple[float, float]:
    """(TCP position error mm, marker rotation error deg) of one pose."""
    predicted_marker = calibration.tracker_from_base @ base_from_tcp @ calibration.tcp_from_marker
    predicted_tcp = (calibration.tracker_from_base @ base_from_tcp)[:3, 3]
    measured_tcp = (tracker_from_marker @ invert_transform(calibration.tcp_from_marker))[:3, 3]
    angle = np.degrees(rotation_angle(predicted_marker[:3, :3] @ tracker_from_marker[:3, :3].T))
    return float(np.linalg.norm(predicted_tcp - measured_tcp)), float(angle)


# -- the misfit a sound set-up shows again ---------------------------------------------------

#: Chance that a sound set-up fails a check, all its poses with position and rotation together.
FALSE_ALARM_RATE = 0.01
#: Recorded frames within this distance of a check pose (TCP position and the arc a tool rotation
#: sweeps at ``NEIGHBOUR_LEVER_MM``, together, mm) predict its misfit, nearer ones weighing more.
NEIGHBOURHOOD_MM = 100.0
NEIGHBOUR_LEVER_MM = 100.0
#: Fewer recorded frames than this in a check pose's neighbourhood do not predict its misfit.
MIN_NEIGHBOURS = 20
#: Smallest tolerances (mm, deg): below what any tracker resolves, so a noise-free simulation
#: still compares numbers rather than rounding errors.
TOLERANCE_FLOOR_MM, TOLERANCE_FLOOR_DEG = 0.02, 0.01
#: A recorded frame whose misfit departs from the misfits' trend by more than this many (robust)
#: standard deviations is an outlier (a reflection, a stale frame), not part of the field.
OUTLIER_SIGMAS = 5.0
#: The stored per-sample residuals and those the recording gives again agree within these (mm,
#: deg; the recording's text keeps its numbers to the last digit): further apart, the recording or
#: the calibration changed since calibrating.
RESIDUAL_MATCH_MM, RESIDUAL_MATCH_DEG = 1e-3, 1e-4


@dataclass(frozen=True)
class MisfitField:
    """What a calibration leaves unexplained at the frames it was fitted to.

    Attributes
    ----------
    base_from_tcp_stack : numpy.ndarray, shape (N, 4, 4)
        The TCP poses the calibration pairs with the frames (:func:`robot_pose`), mm.
    misfit_mm, misfit_deg : numpy.ndarray, shape (N, 3)
        The misfits of the frames (:func:`pose_misfits`): TCP position, mm, and rotation
        vector, deg, both in the tracker frame.
    source : str
        Where the frames came from (the calibration's recording), for the output.
    """

    base_from_tcp_stack: np.ndarray
    misfit_mm: np.ndarray
    misfit_deg: np.ndarray
    source: str = ""

    def __len__(self) -> int:
        return len(self.misfit_mm)

    @cached_property
    def _trend_fit(self) -> _Trend:
        return _trend(self)


@dataclass(frozen=True)
class ExpectedMisfit:
    """The misfit a sound set-up shows at one pose, predicted from the recorded frames nearby.

    Attributes
    ----------
    misfit_mm, misfit_deg : numpy.ndarray, shape (3,)
        Predicted TCP and rotation misfit, tracker frame, mm and deg.
    prediction_sd_mm, prediction_sd_deg : float
        Standard deviation of the prediction along its worst axis.
    frame_sd_mm, frame_sd_deg : float
        Standard deviation of one recorded frame's misfit about the prediction along its worst
        axis: the frame-to-frame scatter (tracker noise, the arm's scatter while recording).
    frames : int
        Recorded frames that informed the prediction.
    nearest_mm : float
        Distance to the nearest of them (position and lever arc, mm).
    """

    misfit_mm: np.ndarray
    misfit_deg: np.ndarray
    prediction_sd_mm: float
    prediction_sd_deg: float
    frame_sd_mm: float
    frame_sd_deg: float
    frames: int
    nearest_mm: float


def pose_misfits(
    calibration: CalibrationResult, base_from_tcp_stack, tracker_from_marker_stack
) -> tuple[np.ndarray, np.ndarray]:
    """Misfit vectors of poses in the tracker frame, as :func:`pose_errors` measures them.

    Parameters
    ----------
    calibration : CalibrationResult
    base_from_tcp_stack : array_like, shape (N, 4, 4) or (4, 4)
        TCP poses the calibration pairs with the frames (:func:`robot_pose`), mm.
    tracker_from_marker_stack : array_like, shape (N, 4, 4) or (4, 4)
        Tracked marker poses, mm.

    Returns
    -------
    misfit_mm : numpy.ndarray, shape (N, 3)
        Where the tracked marker puts the TCP minus where the calibration puts it, mm.
    misfit_deg : numpy.ndarray, shape (N, 3)
        Rotation vector from the predicted marker orientation to the tracked one, deg.
    """
    base_from_tcp = np.asarray(base_from_tcp_stack, dtype=float).reshape(-1, 4, 4)
    tracked = np.asarray(tracker_from_marker_stack, dtype=float).reshape(-1, 4, 4)
    tracker_from_tcp = calibration.tracker_from_base @ base_from_tcp
    measured_tcp = (tracked @ invert_transform(calibration.tcp_from_marker))[:, :3, 3]
    predicted = tracker_from_tcp[:, :3, :3] @ calibration.tcp_from_marker[:3, :3]
    turn = tracked[:, :3, :3] @ np.swapaxes(predicted, 1, 2)
    return measured_tcp - tracker_from_tcp[:, :3, 3], np.degrees(matrix_to_rotvec(turn)).reshape(-1, 3)


def misfit_field(calibration: CalibrationResult, recording: Recording, source: str = "") -> MisfitField:
    """The misfits a calibration leaves at the frames of its own recording.

    The calibration's stored per-sample residuals (``assessment.residuals.per_sample``: the
    rows it used, their marker position and rotation residuals) name the frames and vouch for
    them: the recording must give the same residuals again, so a recording re-acquired under the
    same name or a calibration edited since cannot pass for the set-up that was calibrated. Rows
    flagged as outliers are left out.

    Raises
    ------
    DegenerateDataError
        When the calibration has no per-sample residuals (files from before they were stored,
        imported calibrations) or the recording does not reproduce them.
    """
    residuals = None if calibration.assessment is None else calibration.assessment.residuals
    rows_data = None if residuals is None else residuals.per_sample
    if not rows_data:
        raise DegenerateDataError("the calibration carries no per-sample residuals")
    # read and checked when the calibration was read (records.assessment.ResidualRow)
    rows = np.array([r.row for r in rows_data])
    stored_mm = np.array([r.position_mm for r in rows_data])
    stored_deg = np.array([r.rotation_deg for r in rows_data])
    outlier = np.array([r.outlier for r in rows_data])
    if np.any(rows < 0) or np.any(rows >= len(recording)) or not np.all(recording.has_pose[rows]):
        raise DegenerateDataError("its recording does not hold the frames the calibration used")
    base_from_tcp = np.array(
        [robot_pose(calibration, recording.base_from_tcp_stack[r], recording.joints_rad[r]) for r in rows]
    ).reshape(-1, 4, 4)
    tracked = recording.tracker_from_marker_stack[rows]

    def apart(poses: np.ndarray) -> tuple[float, float]:
        """How far the residuals at these TCP poses lie from the stored ones (mm, deg)."""
        predicted = calibration.tracker_from_base @ poses @ calibration.tcp_from_marker
        distance = np.linalg.norm(predicted[:, :3, 3] - tracked[:, :3, 3], axis=1)
        angle = np.degrees(rotation_angle(predicted[:, :3, :3] @ np.swapaxes(tracked[:, :3, :3], 1, 2)))
        return float(np.max(np.abs(distance - stored_mm))), float(np.max(np.abs(angle - stored_deg)))

    # the estimators store them at the TCP pose the calibration pairs with the frame; kinematic
    # calibrations made before that stored them at the reported pose
    found = [apart(base_from_tcp)]
    if calibration.robot_model is not None:
        found.append(apart(recording.base_from_tcp_stack[rows]))
    if not any(mm <= RESIDUAL_MATCH_MM and deg <= RESIDUAL_MATCH_DEG for mm, deg in found):
        mm, deg = min(found)
        raise DegenerateDataError(
            f"its recording does not give the calibration's residuals again (up to {mm:.3g} mm and "
            f"{deg:.3g} deg apart): the recording or the calibration changed since calibrating"
        )
    misfit_mm, misfit_deg = pose_misfits(calibration, base_from_tcp[~outlier], tracked[~outlier])
    return MisfitField(base_from_tcp[~outlier], misfit_mm, misfit_deg, source)


def _pose_features(base_from_tcp_stack: np.ndarray) -> np.ndarray:
    """What a misfit is linear in (N, 12): the TCP position, mm, and the tool's rotation matrix
    times ``NEIGHBOUR_LEVER_MM``, both in the base frame.

    Errors of the two transforms put a TCP misfit exactly linear in these: with the true
    ``Y = tracker_from_base``, ``X = tcp_from_marker``, their estimates and ``D = X X_est^-1``,
    the misfit at the TCP pose (R, t) is ``Y.R R D.t + (Y.R - Y_est.R) t + Y.t - Y_est.t``,
    however far the tool moved and turned; a rotation misfit is, to first order.
    """
    stack = np.asarray(base_from_tcp_stack, dtype=float).reshape(-1, 4, 4)
    return np.column_stack([stack[:, :3, 3], NEIGHBOUR_LEVER_MM * stack[:, :3, :3].reshape(-1, 9)])


def _pose_distances(base_from_tcp_stack: np.ndarray, base_from_tcp: np.ndarray) -> np.ndarray:
    """Distances (N,) of poses from one pose: TCP distance and the arc the rotation between them
    sweeps at ``NEIGHBOUR_LEVER_MM``, together, mm."""
    position = base_from_tcp_stack[:, :3, 3] - base_from_tcp[:3, 3]
    angle = rotation_angle(base_from_tcp_stack[:, :3, :3] @ base_from_tcp[:3, :3].T)
    return np.sqrt(np.sum(position**2, axis=1) + (NEIGHBOUR_LEVER_MM * angle) ** 2)


def _robust_scale(lengths: np.ndarray, floor: float) -> float:
    """Per-axis standard deviation of 3-D residuals from their lengths' median (the median length
    of a 3-D Gaussian residual is 1.54 per-axis standard deviations), at least ``floor``."""
    return max(float(np.median(lengths)) / 1.54, floor)


@dataclass(frozen=True)
class _Trend:
    """The misfits' linear trend over the whole recording (:func:`_pose_features`)."""

    centre: np.ndarray  # (12,) feature mean
    inverse: np.ndarray  # (13, 13) inverse of the regularised normal matrix
    coefficients: np.ndarray  # (13, 6)
    design: np.ndarray  # (M, 13) of the frames kept
    residuals: np.ndarray  # (M, 6)
    kept: np.ndarray  # (M,) indices into the field


def _design(features: np.ndarray, centre: np.ndarray) -> np.ndarray:
    return np.column_stack([np.ones(len(features)), (features - centre) / NEIGHBOURHOOD_MM])


def _trend(field: MisfitField) -> _Trend:
    """Least-squares linear trend of the misfits in the pose features, frames beyond
    ``OUTLIER_SIGMAS`` (robust) standard deviations from it left out (reflections, stale frames).

    A small ridge keeps combinations the motion does not span (a sweep turns the tool about one
    axis at a time) at zero instead of at whatever the noise says.
    """
    features = _pose_features(field.base_from_tcp_stack)
    values = np.column_stack([field.misfit_mm, field.misfit_deg])
    centre = features.mean(axis=0)
    design = _design(features, centre)
    kept = np.arange(len(field))
    for _ in range(3):
        normal = design[kept].T @ design[kept]
        normal[1:, 1:] += 1e-6 * len(kept) * np.eye(design.shape[1] - 1)
        inverse = np.linalg.inv(normal)
        coefficients = inverse @ (design[kept].T @ values[kept])
        residuals = values - design @ coefficients
        length_mm = np.linalg.norm(residuals[:, :3], axis=1)
        length_deg = np.linalg.norm(residuals[:, 3:], axis=1)
        inliers = np.flatnonzero(
            (length_mm <= OUTLIER_SIGMAS * _robust_scale(length_mm[kept], TOLERANCE_FLOOR_MM))
            & (length_deg <= OUTLIER_SIGMAS * _robust_scale(length_deg[kept], TOLERANCE_FLOOR_DEG))
        )
        if np.array_equal(inliers, kept) or len(inliers) < MIN_NEIGHBOURS:
            break
        kept = inliers
    return _Trend(centre, inverse, coefficients, design[kept], residuals[kept], kept)


def _worst_axis_sd(covariance: np.ndarray) -> float:
    return float(np.sqrt(max(float(np.max(np.linalg.eigvalsh(covariance))), 0.0)))


def expected_misfit(field: MisfitField, base_from_tcp) -> ExpectedMisfit:
    """The misfit a sound set-up shows at a pose, from the misfits recorded around it.

    The misfits' linear trend over the whole recording in the pose features (:func:`_pose_features`;
    it carries the two transforms' errors) plus the weighted average of what the trend
    leaves at the frames within ``NEIGHBOURHOOD_MM`` of the pose (the robot's kinematic and the
    tracker's volumetric errors, smooth and local; tricube weights, nearer frames weighing more).
    The prediction is linear in the recorded misfits, so its variance is a frame's variance
    times the squared length of its weights; a frame's variance is the weighted scatter of what
    the trend leaves around the pose about its average.

    Raises
    ------
    DegenerateDataError
        With fewer than ``MIN_NEIGHBOURS`` recorded frames near the pose.
    """
    pose = np.asarray(base_from_tcp, dtype=float)
    trend = field._trend_fit
    distance = _pose_distances(field.base_from_tcp_stack[trend.kept], pose)
    near = distance < NEIGHBOURHOOD_MM
    if near.sum() < MIN_NEIGHBOURS:
        nearest = f"the nearest {float(distance.min()):.0f} mm away" if len(distance) else "none recorded"
        raise DegenerateDataError(
            f"{int(near.sum())} recorded frames within {NEIGHBOURHOOD_MM:g} mm of a check pose ({nearest}); "
            f"at least {MIN_NEIGHBOURS} are needed to predict its misfit"
        )
    weights = np.where(near, (1.0 - np.clip(distance / NEIGHBOURHOOD_MM, 0.0, 1.0) ** 3) ** 3, 0.0)
    weights /= weights.sum()
    at_pose = _design(_pose_features(pose), trend.centre)[0]
    local = weights @ trend.residuals
    predicted = at_pose @ trend.coefficients + local
    # the prediction as weights on the recorded misfits: the trend at the pose plus the local
    # average of the residuals (each residual is a misfit minus the trend at its frame)
    on_trend = trend.design @ (trend.inverse @ (at_pose - trend.design.T @ weights))
    factor = float(np.sum((on_trend + weights) ** 2))
    spread = trend.residuals - local
    effective = 1.0 / float(np.sum(weights**2))
    covariance = (spread * weights[:, None]).T @ spread * effective / max(effective - 1.0, 1.0)
    frame_sd_mm = _worst_axis_sd(covariance[:3, :3])
    frame_sd_deg = _worst_axis_sd(covariance[3:, 3:])
    return ExpectedMisfit(
        misfit_mm=predicted[:3],
        misfit_deg=predicted[3:],
        prediction_sd_mm=frame_sd_mm * math.sqrt(factor),
        prediction_sd_deg=frame_sd_deg * math.sqrt(factor),
        frame_sd_mm=frame_sd_mm,
        frame_sd_deg=frame_sd_deg,
        frames=int(near.sum()),
        nearest_mm=float(distance.min()),
    )


def expected_misfits(field: MisfitField, plan: MotionPlan) -> list[ExpectedMisfit]:
    """:func:`expected_misfit` at each check pose of a check plan (its holds), in order."""
    targets = {move.label: move.end for move in plan.moves if move.sample_period_s > 0}
    return [expected_misfit(field, pose) for pose in targets.values()]


def tolerance_factor(poses: int, rate: float = FALSE_ALARM_RATE) -> float:
    """How many per-axis standard deviations a pose's misfit may depart from its prediction.

    Departure of a sound set-up is Gaussian in three dimensions, so its length in standard
    deviations follows a chi distribution with 3 degrees of freedom. A check makes two such
    tests per pose (position, rotation); with each at ``1 - (1 - rate) ** (1 / (2 * poses))``,
    a sound set-up fails with probability at most ``rate``: k = 3.90 for three poses at 1 %.
    """
    from scipy.special import gammainccinv

    per_test = 1.0 - (1.0 - rate) ** (1.0 / (2 * max(1, poses)))
    # the chi-square quantile with 3 degrees of freedom: P(chi2_3 > x) = Q(3/2, x/2)
    return float(math.sqrt(2.0 * gammainccinv(1.5, per_test)))


def pose_tolerances(
    expected: ExpectedMisfit,
    frames_averaged: int,
    robot_sd_mm: float,
    factor: float,
    check_frame_sd_mm: float = 0.0,
    check_frame_sd_deg: float = 0.0,
    drift_mm: float = 0.0,
) -> tuple[float, float]:
    """Largest departures (mm, deg) of a pose's misfit from its prediction that a sound set-up shows.

    Per axis, the departure's variance is the prediction's, one frame's over the frames averaged
    (the larger of the recorded frames' scatter and the check's own), the robot's repeatability
    (position only: where the arm comes to rest this time) and any drift allowed. The tolerance is
    ``factor`` (:func:`tolerance_factor`) standard deviations of its worst axis, at least
    ``TOLERANCE_FLOOR_MM`` / ``TOLERANCE_FLOOR_DEG``.

    Parameters
    ----------
    expected : ExpectedMisfit
    frames_averaged : int
    robot_sd_mm : float
        Per-axis standard deviation of where the arm comes to rest, mm
        (:func:`robot_repeatability_sd_mm`).
    factor : float
    check_frame_sd_mm, check_frame_sd_deg : float
        The scatter of the check's own frames at the pose (worst axis).
    drift_mm : float
        Per-axis standard deviation of drift allowed since calibrating (thermal), mm.
    """
    averaged = max(1, frames_averaged)
    noise_mm = max(expected.frame_sd_mm, check_frame_sd_mm)
    noise_deg = max(expected.frame_sd_deg, check_frame_sd_deg)
    sd_mm = math.sqrt(expected.prediction_sd_mm**2 + noise_mm**2 / averaged + robot_sd_mm**2 + drift_mm**2)
    sd_deg = math.sqrt(expected.prediction_sd_deg**2 + noise_deg**2 / averaged)
    return max(TOLERANCE_FLOOR_MM, factor * sd_mm), max(TOLERANCE_FLOOR_DEG, factor * sd_deg)


def robot_repeatability_sd_mm(robot_model: str) -> float:
    """Per-axis standard deviation (mm) of where an arm comes to rest, from its kind's datasheet
    repeatability (:attr:`spacecal.models.robot_kinds.RobotKind.repeatability_mm`; the worst
    of the registered kinds for a model not registered)."""
    kind = ROBOT_KINDS.get(robot_model)
    if kind is not None:
        repeatability = kind.repeatability_mm
    else:
        repeatability = max(k.repeatability_mm for k in ROBOT_KINDS.values())
    return repeatability * REPEATABILITY_TO_AXIS_SD


def judge_check(
    calibration: CalibrationResult,
    held: list[HeldPose],
    threshold_mm: float | None,
    threshold_deg: float | None,
    expected: list[ExpectedMisfit] | None = None,
    robot_sd_mm: float = 0.0,
    basis: str = "",
) -> CheckResult:
    """Compare the frames held at each check pose with the calibration's prediction.

    Each pose's frames are averaged; its misfit (:func:`pose_misfits`) is judged by how far it
    lies from the misfit expected there, against the pose's tolerance (:func:`pose_tolerances`,
    from the hold's own frame scatter among others) or the thresholds given.

    Parameters
    ----------
    calibration : CalibrationResult
    held : list of HeldPose
        One per check pose (:func:`~spacecal.workflows.held_poses.hold_poses`).
    threshold_mm, threshold_deg : float or None
        The largest departure that passes at every pose. None (with ``expected``): each pose's
        tolerance.
    expected : list of ExpectedMisfit, optional
        The misfit a sound set-up shows at each pose (:func:`expected_misfits`). None: none is
        expected (the whole misfit is judged; both thresholds are needed).
    robot_sd_mm : float
        Per-axis standard deviation of where the arm comes to rest, mm
        (:func:`robot_repeatability_sd_mm`).
    basis : str
        How the thresholds came about, kept with the result.
    """
    if expected is not None and len(expected) != len(held):
        raise InvalidInputError(f"{len(expected)} expected misfits for {len(held)} check poses")
    if expected is None and (threshold_mm is None or threshold_deg is None):
        raise InvalidInputError("a check without expected misfits needs both thresholds")
    factor = tolerance_factor(len(held))
    misfits_mm, misfits_deg, tolerances_mm, tolerances_deg = [], [], [], []
    for k, pose in enumerate(held):
        frames = pose.tracker_from_marker_stack
        measured = mean_transform(frames)
        base_from_tcp = robot_pose(calibration, pose.at_rest.base_from_tcp, pose.at_rest.joints_rad)
        misfit_mm, misfit_deg = pose_misfits(calibration, base_from_tcp, measured)
        misfits_mm.append(misfit_mm[0])
        misfits_deg.append(misfit_deg[0])
        if expected is None:
            assert threshold_mm is not None and threshold_deg is not None
            tolerances_mm.append(threshold_mm)
            tolerances_deg.append(threshold_deg)
            continue
        frame_mm, frame_deg = pose_misfits(calibration, np.broadcast_to(base_from_tcp, frames.shape), frames)
        tolerance_mm, tolerance_deg = pose_tolerances(
            expected[k],
            len(frames),
            robot_sd_mm,
            factor,
            _worst_axis_sd(np.cov(frame_mm.T)),
            _worst_axis_sd(np.cov(frame_deg.T)),
        )
        tolerances_mm.append(tolerance_mm if threshold_mm is None else threshold_mm)
        tolerances_deg.append(tolerance_deg if threshold_deg is None else threshold_deg)
    measured_mm, measured_deg = np.array(misfits_mm), np.array(misfits_deg)
    # without a prediction the whole misfit is judged: a sound set-up is expected to show none
    expected_mm = (
        np.zeros_like(measured_mm) if expected is None else np.array([e.misfit_mm for e in expected])
    )
    expected_deg = (
        np.zeros_like(measured_deg) if expected is None else np.array([e.misfit_deg for e in expected])
    )
    return CheckResult(
        np.linalg.norm(measured_mm - expected_mm, axis=1),
        np.linalg.norm(measured_deg - expected_deg, axis=1),
        float(max(tolerances_mm)),
        float(max(tolerances_deg)),
        [pose.label for pose in held],
        misfit_mm=measured_mm,
        expected_misfit_mm=expected_mm,
        tolerance_mm=np.array(tolerances_mm),
        misfit_deg=measured_deg,
        expected_misfit_deg=expected_deg,
        tolerance_deg=np.array(tolerances_deg),
        basis=basis,
    )


def check_with_robot(
    calibration: CalibrationResult,
    robot: Robot,
    tracker: Tracker,
    plan: MotionPlan,
    threshold_mm: float | None,
    threshold_deg: float | None,
    settings: AcquisitionSettings,
    frames_per_pose: int = 10,
    expected: list[ExpectedMisfit] | None = None,
    robot_sd_mm: float = 0.0,
    basis: str = "",
    on_sample: SampleCallback | None = None,
) -> CheckResult:
    """Run the check plan, average the frames held at each pose, and compare with the
    calibration's prediction: :func:`~spacecal.workflows.held_poses.hold_poses` (which calls
    ``on_sample``), then
    :func:`judge_check`.

    Raises
    ------
    DegenerateDataError
        When the marker was seen in fewer than half the frames at a check pose.
    DeviceError
        On a device fault (the robot was stopped; nothing is logged).
    """
    holds = list(dict.fromkeys(move.label for move in plan.moves if move.sample_period_s > 0))
    if expected is not None and len(expected) != len(holds):
        raise InvalidInputError(f"{len(expected)} expected misfits for {len(holds)} check poses")
    if expected is None and (threshold_mm is None or threshold_deg is None):
        raise InvalidInputError("a check without expected misfits needs both thresholds")
    held = hold_poses(robot, tracker, plan, settings, frames_per_pose, on_sample)
    return judge_check(calibration, held, threshold_mm, threshold_deg, expected, robot_sd_mm, basis)


def check_with_recording(
    calibration: CalibrationResult,
    recording: Recording,
    threshold_mm: float = 1.0,
    threshold_deg: float = 1.0,
) -> CheckResult:
    """Check against the visible frames of a recording, one result per segment label."""
    errors, angles, labels = [], [], []
    for label in dict.fromkeys(recording.segment.tolist()):
        rows = np.flatnonzero((recording.segment == label) & recording.visible)
        if len(rows) == 0:
            continue
        per_frame = np.array(
            [
                pose_errors(
                    calibration,
                    robot_pose(calibration, recording.base_from_tcp_stack[r], recording.joints_rad[r]),
                    recording.tracker_from_marker_stack[r],
                )
                for r in rows
            ]
        )
        errors.append(float(np.median(per_frame[:, 0])))
        angles.append(float(np.median(per_frame[:, 1])))
        labels.append(str(label))
    if not labels:
        raise DegenerateDataError("the recording has no frame with the marker visible to check against")
    return CheckResult(np.array(errors), np.array(angles), threshold_mm, threshold_deg, labels)
