"""The error to expect at a target near the site, from held-out data and the robot's geometry.

The predicted TRE of :mod:`spacecal.estimators.methods.ml` propagates the tracker's white noise
only. What a user sees when the robot is sent to a target also contains whatever the model
does not describe: the robot's kinematic error, the tracker's volume error, a clock offset,
a loose marker. Three facts set the expected error, each measured the same way on every path
a recording takes (paired CSV, raw streams, a ROS bag, a pose-only tracker), with or without
joint angles or the tracker's fit RMS:

1. **Held-out misfit** (cross-validation, as in mrcal). The visible frames are split into
   blocks: the recording's segments when it has several (the paper's six sweeps), otherwise
   six contiguous time blocks (blocks of stations). For each block the maximum-likelihood fit
   is redone on the others, warm-started from the full-data solution, and predicts the
   held-out frames through the chain ``tracker_from_base @ base_from_tcp @ tcp_from_marker``.
   The mean squared sphere error of those predictions, less what the white noise explains
   (its power per frame plus the refit's own prediction variance), is the power of the
   systematic error ``S`` (less two standard errors of the noise's misfit: its own scatter
   and the error of the noise level). Robot kinematics, tracker bias and timing all enter it.
2. **The white noise, from consecutive frames** (a variogram's nugget;
   :func:`white_noise_power`). A systematic error is a smooth function of where the arm is
   (of its joint angles, of the marker's place in the tracker's volume, of its velocity for a
   clock offset); white noise is independent from frame to frame. Two consecutive frames of a
   segment, whose marker moved a few mm, carry nearly the same systematic residual, so half
   the mean squared difference of their residuals is the white noise's power alone, whatever
   its shape: anisotropic, pose-only, raw spheres, the robot's own jitter. On the paper's
   sweeps the residual variogram is flat from the 5 mm between consecutive frames to 30 mm,
   and its nugget is the tracker's noise as its fit RMS gives it, plus the arm's jitter; at
   static stations the pairs are exact. Neither alternative serves every path: the tracker's
   fit RMS is missing from pose-only trackers (PLUS over OpenIGTLink, camera trackers, ROS
   poses) and leaves out white noise from other sources; in-sample residuals hold the part of
   the systematic error the fit cannot absorb, so comparing held-out with in-sample misfit
   calls that part noise and understates the error. The pairs' scatter gives the noise level's
   standard error. Where fewer than :data:`MINIMUM_NUGGET_PAIRS` nearby pairs exist (one frame
   per pose), the tracker's fit RMS stands in. Without it (a camera's static views) the noise
   is what the residuals leave once the arm's DH errors are fitted as well
   (:func:`white_noise_beyond_kinematics`), with its covariance's shape
   (:mod:`spacecal.estimators.assessment.residual_noise`; no standard errors are taken off there,
   :data:`DETECTION_STANDARD_ERRORS_BEYOND_DH`), and a systematic error the DH errors cannot
   describe then counts as noise; the basis says so. Only where no arm's geometry is
   available does all of the misfit count as systematic.
3. **What the marker cannot see** (geometry). Part of any kinematic error moves the needle
   tip without moving the marker relative to the chain: an error constant in the tool frame
   is absorbed into ``tcp_from_marker``, yet the tip is off by it (the docs' floor that only a
   tip calibration removes). For the recording's configurations the DH Jacobian of the
   marker's spheres and of the tip are projected off the columns the fit absorbs (the 12 pose
   parameters, plus identified DH corrections); with DH errors of unit scale (lengths 1 mm,
   angles 0.002 rad, the spread ``kinematic`` assumes) this gives the systematic sphere power
   per frame ``s1`` and the tip's error covariance ``C1`` (3 x 3, mean square ``f1``) at frames
   near the site. The scale the data shows is ``l^2 = S / s1``, so the unseen tip error has
   covariance ``l^2 C1``. The tip's share ``f1 / s1`` is a property of the arm and the motion,
   about 1 on the paper's sweeps, four times the per-sphere misfit: a recording without joint
   angles still needs it. Its joint angles are then solved from the reported TCP poses
   (:func:`solved_joints`): by the robot model the metadata names (which reproduces the
   recorded angles), or, without one (a ROS bag's tf), by every UR arm of the tables with its
   flange at the marker, keeping the one whose geometry hides the most (the largest
   ``f1 / s1``); the basis names it. Only when no arm reaches the poses does the held-out
   power of a frame stand for the tip's mean square.

The expected position error at a target near the site is then the mean length E|x| of a
Gaussian error x with covariance ``C_TRE + l^2 C1`` (:func:`mean_gaussian_length`), C_TRE the
noise-only covariance of the tip at the site frames; posture from the RMS of the rotation
block of the covariance and the tip frame's rotation (factor ``sqrt(8 / (3 pi))``). That is
the mean a 15-point verification there would show; one verification is one draw around it
(:mod:`spacecal.experiments.prediction_oracle`). A method other than ML adds, as a second
moment, how far its solution puts the tip from ML's at those frames.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from spacecal.core.errors import DegenerateDataError
from spacecal.estimators.assessment.dh_span import (
    DETECTION_STANDARD_ERRORS,
    DETECTION_STANDARD_ERRORS_BEYOND_DH,
    arm_and_other_parts,
    systematic_share_in_dh_span,
)
from spacecal.estimators.assessment.gaussian import MEAN_OVER_RMS_3D, mean_gaussian_length
from spacecal.estimators.assessment.held_out_misfit import (
    SITE_RADIUS_MM,
    SITE_TILT_DEG,
    Refit,
    held_out_misfit,
    ml_refit,
    near_site,
)
from spacecal.estimators.assessment.residual_noise import (
    held_out_noise_power,
)
from spacecal.estimators.assessment.unseen_kinematics import (
    GEOMETRY_FRAMES,
    geometry_rows,
    solved_joints,
    stand_in_arms,
    unseen_kinematic_error,
)
from spacecal.estimators.assessment.white_noise import (
    OVERLAPPING_PAIRS_VARIANCE,
    noise_level_relative_error,
    white_noise_beyond_kinematics,
    white_noise_power,
)
from spacecal.estimators.methods.held_out import held_out_blocks
from spacecal.estimators.methods.ml import (
    point_covariances,
    predicted_tre_mm,
)
from spacecal.estimators.methods.observations import Observations
from spacecal.geometry.arrays import BoolArray, FloatArray, as_float_array
from spacecal.geometry.rotations import rotation_angle
from spacecal.models.kinematics import (
    RobotModel,
)
from spacecal.records import NeedleTip


@dataclass(frozen=True)
class NoisePart:
    """The noise-only error at the site: the white tracker noise propagated to the tip.

    Attributes
    ----------
    site : numpy.ndarray of bool, shape (N,)
        The used frames near the site (:func:`near_site`), which stand for the targets.
    marker_in_base : numpy.ndarray, shape (S, 4, 4)
        The marker's pose at each site frame (base frame, mm).
    tip_in_base : numpy.ndarray, shape (S, 3)
        The tip at each site frame (base frame, mm): the TCP, or the measured needle tip.
    tre_ms_mm2 : float
        Mean square of the predicted TRE over those tips, mm^2.
    covariance_mm2 : numpy.ndarray, shape (3, 3)
        The noise-only error's covariance at the tip, averaged over the site frames (tracker
        frame, mm^2).
    rotation_ms_rad2 : float
        Trace of the rotation block of ``tracker_from_base``'s covariance, rad^2.
    """

    site: BoolArray
    marker_in_base: FloatArray
    tip_in_base: FloatArray
    tre_ms_mm2: float
    covariance_mm2: FloatArray
    rotation_ms_rad2: float


def noise_part(
    obs: Observations,
    tracker_from_base: FloatArray,
    tcp_from_marker: FloatArray,
    covariance: FloatArray,
    tip_in_marker: FloatArray | None,
) -> NoisePart:
    """The noise-only TRE at the site frames (the module's ``C_TRE``).

    Parameters
    ----------
    obs : Observations
    tracker_from_base, tcp_from_marker : numpy.ndarray, shape (4, 4)
        The solution (mm).
    covariance : numpy.ndarray, shape (12, 12)
        Its covariance in the pose perturbation parameters (mm, rad).
    tip_in_marker : numpy.ndarray, shape (3,), or None
        A measured needle tip in the marker frame (mm); None for the TCP.
    """
    site = near_site(obs.base_from_tcp_stack, SITE_RADIUS_MM, SITE_TILT_DEG)
    # the marker's pose at each site frame (base frame): where a measured tip is, and how the
    # pivot's error, fixed in the marker frame, turns
    marker_in_base = obs.base_from_tcp_stack[site] @ tcp_from_marker
    if tip_in_marker is None:
        tip_in_base = obs.base_from_tcp_stack[site, :3, 3]
    else:
        tip_in_base = marker_in_base[:, :3, :3] @ tip_in_marker + marker_in_base[:, :3, 3]
    tre_ms = float(np.mean(predicted_tre_mm(tracker_from_base, covariance, tip_in_base) ** 2))
    noise_covariance = np.mean(
        point_covariances(tracker_from_base, np.asarray(covariance)[:6, :6], tip_in_base), axis=0
    )
    rotation_noise_ms = float(np.trace(np.asarray(covariance)[3:6, 3:6]))
    return NoisePart(site, marker_in_base, tip_in_base, tre_ms, noise_covariance, rotation_noise_ms)


@dataclass(frozen=True)
class MethodDeviation:
    """How far a method other than ML puts the tip from ML's, and ML's solution itself.

    Attributes
    ----------
    ml_tracker_from_base, ml_tcp_from_marker : numpy.ndarray, shape (4, 4)
        The ML solution the held-out refits start from (the method's own for ML).
    position_ms_mm2 : float
        Mean square of the tip's distance from ML's over the site frames, mm^2.
    covariance_mm2 : numpy.ndarray, shape (3, 3)
        Its second moment over the site frames, added like a covariance (mm^2).
    rotation_ms_rad2 : float
        Square of the rotation between the two ``tracker_from_base``, rad^2.
    """

    ml_tracker_from_base: FloatArray
    ml_tcp_from_marker: FloatArray
    position_ms_mm2: float = 0.0
    covariance_mm2: FloatArray = field(default_factory=lambda: np.zeros((3, 3)))
    rotation_ms_rad2: float = 0.0


def method_deviation(
    obs: Observations,
    tracker_from_base: FloatArray,
    tcp_from_marker: FloatArray,
    site: BoolArray,
    likelihood_based: bool,
    refit: Refit,
) -> MethodDeviation:
    """The ML solution and a non-ML method's distance from it at the site frames (zero for ML).

    Parameters
    ----------
    obs : Observations
    tracker_from_base, tcp_from_marker : numpy.ndarray, shape (4, 4)
        The method's solution (mm).
    site : numpy.ndarray of bool, shape (N,)
        The site frames (:attr:`NoisePart.site`).
    likelihood_based : bool
        The solution is the ML fit of ``obs``: it is its own ML solution.
    refit : callable
        How ML is refitted from the method's solution.
    """
    if likelihood_based:
        return MethodDeviation(tracker_from_base, tcp_from_marker)
    ml_tracker_from_base, ml_tcp_from_marker = refit(obs, tracker_from_base, tcp_from_marker)
    method_tip = tracker_from_base @ obs.base_from_tcp_stack[site]
    ml_tip = ml_tracker_from_base @ obs.base_from_tcp_stack[site]
    deviation = method_tip[:, :3, 3] - ml_tip[:, :3, 3]
    return MethodDeviation(
        ml_tracker_from_base,
        ml_tcp_from_marker,
        float(np.mean(np.sum(deviation**2, axis=1))),
        # its second moment over the site frames, added like a covariance
        deviation.T @ deviation / len(deviation),
        float(rotation_angle(tracker_from_base[:3, :3] @ ml_tracker_from_base[:3, :3].T) ** 2),
    )


@dataclass(frozen=True)
class HeldOutPart:
    """The held-out misfit of the ML solution (the module's fact 1, before the noise is taken off).

    Attributes
    ----------
    misfit : dict
        :func:`held_out_misfit`'s result (per-frame sphere SSE and leverage, the blocks, the
        Jacobian and the blocks' normal inverses); NaN per frame where the refits were skipped.
    computed : bool
        Some frame was scored.
    mean_square_mm2 : float
        Mean held-out sphere SSE per frame, mm^2 (0 when nothing was scored).
    scored : int
        Frames scored.
    mean_leverage : float
        Mean prediction leverage of the refits over the scored frames.
    """

    misfit: dict[str, Any]
    computed: bool
    mean_square_mm2: float
    scored: int
    mean_leverage: float


def held_out_part(
    obs: Observations,
    segments: np.ndarray,
    deviation: MethodDeviation,
    refit: Refit,
    scale_given: bool,
) -> HeldOutPart:
    """The held-out misfit of the ML solution, block by block (:func:`held_out_misfit`).

    Parameters
    ----------
    obs : Observations
    segments : numpy.ndarray of str, shape (N,)
        Segment label of each used frame (the held-out blocks).
    deviation : MethodDeviation
        Holds the ML solution the refits start from.
    refit : callable
        How a held-out block's refit is done.
    scale_given : bool
        The arm's DH error scale is given (kinematic identification) and an arm's geometry is
        known: the refits would only be reported, not used, so they are not done.
    """
    if scale_given:
        block_list = held_out_blocks(segments)
        misfit: dict[str, Any] = {
            "frame_sse_mm2": np.full(len(obs.rows), np.nan),
            "frame_prediction_leverage": np.full(len(obs.rows), np.nan),
            "blocks": len(block_list),
            "blocks_refitted": 0,
            "block_indices": block_list,
            "jacobian": np.zeros((len(obs.rows), 3 * len(obs.spheres_in_marker), 12)),
            "block_normal_inverses": [None] * len(block_list),
        }
    else:
        misfit = held_out_misfit(
            obs, segments, deviation.ml_tracker_from_base, deviation.ml_tcp_from_marker, refit
        )
    sse = misfit["frame_sse_mm2"]
    computed = bool(np.isfinite(sse).any())
    return HeldOutPart(
        misfit,
        computed,
        float(np.nanmean(sse)) if computed else 0.0,
        int(np.isfinite(sse).sum()),
        float(np.nanmean(misfit["frame_prediction_leverage"])) if computed else 0.0,
    )


@dataclass(frozen=True)
class ArmGeometry:
    """The arm whose kinematic geometry scales the misfit to the tip (the module's fact 3).

    Attributes
    ----------
    arm : RobotModel
        The recording's model, or a stand-in UR arm.
    unit : dict
        :func:`unseen_kinematic_error` at unit DH error scale: ``sphere_power_mm2``,
        ``tip_position_ms_mm2``, ``tip_position_covariance_mm2`` (3 x 3, tracker frame),
        ``tip_rotation_ms_rad2``.
    joints_rad : numpy.ndarray, shape (N, J) or (G, J)
        The joint angles it was evaluated at (recorded, or solved from the TCP poses).
    scaled_by : str
        The basis's words for it.
    """

    arm: RobotModel
    unit: dict[str, Any]
    joints_rad: FloatArray
    scaled_by: str


def arm_geometry(
    obs: Observations,
    deviation: MethodDeviation,
    site: BoolArray,
    held_out: HeldOutPart,
    robot_model: RobotModel | None,
    joints_rad: FloatArray | None,
    absorbed_dh: Sequence[int],
    tip_in_marker: FloatArray | None,
) -> ArmGeometry | None:
    """The unseen-kinematics geometry: what DH errors of unit scale do to the spheres and the tip.

    With recorded joint angles and a model, that model at those angles; without them, joint
    angles solved from the reported TCP poses, by the recording's model or, without one, by the
    UR arm whose geometry hides the most of a given misfit (:func:`stand_in_arms`). None when no
    arm reaches the poses.

    Parameters
    ----------
    obs : Observations
    deviation : MethodDeviation
        Holds the ML solution.
    site : numpy.ndarray of bool, shape (N,)
    held_out : HeldOutPart
        Its blocks are the geometry's too.
    robot_model : RobotModel or None
    joints_rad : numpy.ndarray, shape (N, J), or None
    absorbed_dh : sequence of int
        DH corrections the estimator identified (absorbed, so not unseen).
    tip_in_marker : numpy.ndarray, shape (3,), or None
    """
    blocks = held_out.misfit["block_indices"]
    ml_tracker_from_base, ml_tcp_from_marker = deviation.ml_tracker_from_base, deviation.ml_tcp_from_marker
    if has_arm_model(robot_model, joints_rad) and robot_model is not None and joints_rad is not None:
        unit = unseen_kinematic_error(
            robot_model,
            joints_rad,
            obs,
            ml_tracker_from_base,
            ml_tcp_from_marker,
            site,
            blocks,
            absorbed_dh,
            tip_in_marker=tip_in_marker,
        )
        return ArmGeometry(robot_model, unit, joints_rad, "the robot's kinematic geometry")
    # no joint angles: solve them from the reported TCP poses, by the recording's robot model
    # or, without one, by the UR arm whose geometry hides the most of a given misfit, as many
    # frames as with recorded joint angles: the DH-span test needs them (on 40, a camera-grade
    # tracker's arm error went unseen on the bag and TUM paths, up to 10.6 times the statement)
    rows = geometry_rows(len(obs.rows), GEOMETRY_FRAMES)
    best: tuple[RobotModel, dict[str, Any], FloatArray] | None = None
    for arm in stand_in_arms(robot_model, ml_tcp_from_marker):
        joints = solved_joints(arm, obs.base_from_tcp_stack, rows)
        if joints is None:
            continue
        unit = unseen_kinematic_error(
            arm,
            joints,
            obs,
            ml_tracker_from_base,
            ml_tcp_from_marker,
            site,
            blocks,
            tip_in_marker=tip_in_marker,
        )
        if unit["sphere_power_mm2"] > 0 and (
            best is None
            or unit["tip_position_ms_mm2"] / unit["sphere_power_mm2"]
            > best[1]["tip_position_ms_mm2"] / best[1]["sphere_power_mm2"]
        ):
            best = (arm, unit, joints)
    if best is None:
        return None
    if robot_model is not None:
        scaled_by = (
            f"the {robot_model.name}'s kinematic geometry at joint angles solved from the reported "
            "TCP poses (the recording has none)"
        )
    else:
        scaled_by = (
            f"the kinematic geometry of a {best[0].name} with its flange at the marker, the UR arm "
            "that hides the most of it (the recording has no joint angles or robot model)"
        )
    return ArmGeometry(*best, scaled_by)


def has_arm_model(robot_model: RobotModel | None, joints_rad: FloatArray | None) -> bool:
    """A model and finite joint angles for every used frame: the arm's geometry is known."""
    return robot_model is not None and joints_rad is not None and bool(np.all(np.isfinite(joints_rad)))


@dataclass(frozen=True)
class WhiteNoisePart:
    """The white noise the held-out misfit is compared with (the module's fact 2).

    Attributes
    ----------
    white : dict or None
        :func:`white_noise_power` from consecutive frames, None where too few pairs exist.
    power_mm2 : float
        The white noise's power per frame (all spheres), mm^2.
    standard_error_mm2 : float
        Standard error of the noise's misfit: the held-out mean's own scatter and that of the
        noise level it is compared with, mm^2.
    beyond : str
        The basis's words for what the systematic misfit is beyond.
    shaped_ms_mm2 : float or None
        The noise's held-out power where it has the shape the DH fit leaves
        (:func:`white_noise_beyond_kinematics`), else None.
    detection_standard_errors : float
        Standard errors of the noise's misfit taken off before a misfit counts as systematic.
    """

    white: dict[str, Any] | None
    power_mm2: float
    standard_error_mm2: float
    beyond: str
    shaped_ms_mm2: float | None = None
    detection_standard_errors: float = DETECTION_STANDARD_ERRORS


def white_noise_part(
    obs: Observations,
    segments: np.ndarray,
    deviation: MethodDeviation,
    held_out: HeldOutPart,
    geometry: ArmGeometry | None,
) -> WhiteNoisePart:
    """The white noise: from the residuals of consecutive frames where there are enough (the
    same on every path, and every white source is in it as it is in the misfit); else from the
    tracker's fit RMS; else what the residuals leave beyond the arm's DH errors; else unknown,
    and then all the misfit counts as systematic.

    Parameters
    ----------
    obs : Observations
    segments : numpy.ndarray of str, shape (N,)
    deviation : MethodDeviation
        Holds the ML solution whose residuals are read.
    held_out : HeldOutPart
        The frames scored set the held-out mean's scatter.
    geometry : ArmGeometry or None
        For the noise beyond the DH errors.
    """
    ml_tracker_from_base, ml_tcp_from_marker = deviation.ml_tracker_from_base, deviation.ml_tcp_from_marker
    scored = held_out.scored
    try:
        white: dict[str, Any] | None = white_noise_power(
            obs, segments, ml_tracker_from_base, ml_tcp_from_marker
        )
    except DegenerateDataError:
        white = None
    if white is not None:
        standard_error = float(
            np.sqrt(
                white["variance_mm4"] * (1.0 / max(scored, 1) + OVERLAPPING_PAIRS_VARIANCE / white["pairs"])
            )
        )
        return WhiteNoisePart(
            white,
            float(white["power_mm2"]),
            standard_error,
            "beyond the white noise of consecutive frames",
        )
    if obs.sigma_known:
        # chi-square scatter of the held-out mean (2 dof sigma^4 per frame), and the error of
        # the noise level, a median of the tracker's RMS values
        white_power = obs.dof_per_frame * obs.sigma_mm**2
        standard_error = float(
            np.hypot(
                obs.sigma_mm**2 * np.sqrt(2.0 * obs.dof_per_frame / max(scored, 1)),
                white_power * noise_level_relative_error(len(obs.spheres_in_marker), len(obs.rows)),
            )
        )
        return WhiteNoisePart(
            None,
            white_power,
            standard_error,
            "beyond the tracker's noise from its fit RMS (too few nearby frames to measure the white noise)",
        )
    beyond_dh = None
    if geometry is not None:
        try:
            beyond_dh = white_noise_beyond_kinematics(
                geometry.arm, geometry.joints_rad, obs, ml_tracker_from_base, ml_tcp_from_marker
            )
        except DegenerateDataError:
            beyond_dh = None
    if beyond_dh is None:
        return WhiteNoisePart(
            None,
            0.0,
            0.0,
            "(all of it: neither nearby frames nor a tracker fit RMS measure the white noise)",
        )
    white_power = float(beyond_dh["power_mm2"])
    shape = np.asarray(beyond_dh["covariance_mm2"])
    # noise of this shape, not isotropic: the refits' prediction error and the held-out mean's
    # chi-square scatter (2 tr(Sigma^2) per frame) both follow it
    shaped = held_out_noise_power(held_out.misfit, shape) if held_out.computed else white_power
    scatter = (
        float(np.sqrt(2.0 * np.sum(shape * shape) / max(scored, 1))) / white_power if white_power > 0 else 0.0
    )
    return WhiteNoisePart(
        None,
        white_power,
        white_power * float(np.hypot(scatter, beyond_dh["relative_error"])),
        "beyond the white noise the residuals leave once the arm's DH errors are fitted too "
        "(one frame per pose and no tracker fit RMS; a systematic error DH errors cannot "
        "describe counts as noise there)",
        shaped,
        DETECTION_STANDARD_ERRORS_BEYOND_DH,
    )


@dataclass(frozen=True)
class SystematicMisfit:
    """The held-out misfit beyond the noise: the systematic error's power ``S`` per frame.

    Attributes
    ----------
    noise_ms_mm2 : float
        What the white noise explains of the held-out misfit (its power plus the refits' own
        prediction variance), mm^2.
    power_mm2 : float
        ``S``: the misfit less the noise and its detection margin, at least 0, mm^2.
    range_mm2 : list of float
        ``S`` with the margin one standard error larger and smaller (``[low, high]``).
    """

    noise_ms_mm2: float
    power_mm2: float
    range_mm2: list[float]


def systematic_misfit(obs: Observations, held_out: HeldOutPart, noise: WhiteNoisePart) -> SystematicMisfit:
    """The systematic misfit: the held-out misfit less the noise's and ``detection`` standard
    errors of it (frames of one recording cannot tell a smaller systematic misfit from a
    misjudged noise level), and one standard error either side (how far the statement's own
    estimate of it can be off on this many frames; its positive part errs upward where there
    is none).

    Parameters
    ----------
    obs : Observations
    held_out : HeldOutPart
    noise : WhiteNoisePart
    """
    noise_ms = (
        noise.shaped_ms_mm2
        if noise.shaped_ms_mm2 is not None
        else noise.power_mm2 * (1.0 + held_out.mean_leverage / obs.dof_per_frame)
    )
    held_out_ms, computed = held_out.mean_square_mm2, held_out.computed
    margin, standard_error = noise.detection_standard_errors, noise.standard_error_mm2
    systematic = max(held_out_ms - noise_ms - margin * standard_error, 0.0) if computed else 0.0
    systematic_range = [
        max(held_out_ms - noise_ms - (margin + step) * standard_error, 0.0) if computed else 0.0
        for step in (1.0, -1.0)
    ]
    return SystematicMisfit(noise_ms, systematic, systematic_range)


@dataclass(frozen=True)
class UnseenPart:
    """The tip's error the marker cannot see, scaled from the systematic misfit.

    Attributes
    ----------
    position_ms_mm2 : float
        Its mean square at the tip, mm^2.
    covariance_mm2 : numpy.ndarray, shape (3, 3)
        Its covariance (tracker frame, mm^2).
    rotation_ms_rad2 : float
        The tip frame's rotation mean square, rad^2.
    covariance_range_mm2 : list of numpy.ndarray or None
        Its covariance at the two ends of :attr:`SystematicMisfit.range_mm2`; None where the
        arm's error scale was given.
    components : dict
        What the expected error's ``components`` record of it (``dh_error_scale_mm``,
        ``systematic_dh_share``, ``unseen_tip_rms_mm``, ``kinematic_geometry``).
    detected_in_dh_span : bool
        The arm's error scale comes from the DH span alone (the misfit is within the noise's
        scatter).
    basis : str
        The basis's sentence up to here.
    """

    position_ms_mm2: float
    covariance_mm2: FloatArray
    rotation_ms_rad2: float
    covariance_range_mm2: list[FloatArray] | None
    components: dict[str, Any]
    detected_in_dh_span: bool
    basis: str


def unseen_part(
    obs: Observations,
    deviation: MethodDeviation,
    noise: WhiteNoisePart,
    systematic: SystematicMisfit,
    geometry: ArmGeometry | None,
    blocks: str,
    dh_error_scale_mm: float | None,
    tip_in_marker: FloatArray | None,
) -> UnseenPart:
    """The unseen tip error: ``l^2 C1`` with ``l^2 = S / s1`` split into the arm's part (in the
    DH span, shaped by the arm's geometry) and the rest (isotropic); without an arm, the
    held-out power of a frame stands for the tip's mean square.

    Parameters
    ----------
    obs : Observations
    deviation : MethodDeviation
        Holds the ML solution.
    noise : WhiteNoisePart
    systematic : SystematicMisfit
    geometry : ArmGeometry or None
    blocks : str
        The basis's words for the held-out blocks.
    dh_error_scale_mm : float or None
        The arm's DH error scale when given (kinematic identification).
    tip_in_marker : numpy.ndarray, shape (3,), or None
    """
    white = noise.white
    if geometry is None:
        # no arm reaches the poses: the held-out power of a frame (over all its spheres) stands
        # for the tip's mean square, as a UR arm's geometry makes it on the paper's sweeps; a
        # measured tip is a point of the marker's chain, off by what one sphere is
        per_tip = 1.0 if tip_in_marker is None else 1.0 / len(obs.spheres_in_marker)
        unseen_ms = systematic.power_mm2 * per_tip
        return UnseenPart(
            unseen_ms,
            # the misfit says nothing of its direction at the tip: isotropic
            np.eye(3) * unseen_ms / 3.0,
            0.0,
            [np.eye(3) * value * per_tip / 3.0 for value in systematic.range_mm2],
            {"kinematic_geometry": None},
            False,
            f"{blocks}: systematic misfit per frame {noise.beyond}, plus the noise-only TRE; "
            "no joint angles and no UR arm reaches these poses, so the errors the marker cannot see are "
            "taken as large as the misfit it sees",
        )
    arm, unit = geometry.arm, geometry.unit
    spheres_in_marker = len(obs.spheres_in_marker)

    def unseen_tip_covariance(arm_scale_sq: float, other_ms: float) -> FloatArray:
        """The tip's error the marker cannot see (tracker frame, mm^2): the arm's, shaped by its
        geometry, and the rest, isotropic."""
        return as_float_array(
            arm_scale_sq * np.asarray(unit["tip_position_covariance_mm2"]) + np.eye(3) * other_ms / 3.0
        )

    detected_in_dh_span = False
    unseen_range: list[FloatArray] | None = None
    if dh_error_scale_mm is not None:
        scale_sq = dh_error_scale_mm**2
        # kinematic identification: its corrections took the arm's part
        arm_scale_sq, other_ms, dh_share = scale_sq, 0.0, 1.0
    else:
        scale_sq = systematic.power_mm2 / unit["sphere_power_mm2"] if unit["sphere_power_mm2"] > 0 else 0.0
        split = None
        # the noise measured apart from the misfit (pairs, fit RMS): split the misfit by its
        # shape; the noise taken as what DH errors leave has counted the rest as noise already
        if white is not None or obs.sigma_known:
            split = systematic_share_in_dh_span(
                arm,
                geometry.joints_rad,
                obs,
                deviation.ml_tracker_from_base,
                deviation.ml_tcp_from_marker,
                noise.power_mm2,
                rigid_noise_covariance=None if white is None else white["rigid_covariance_mm2"],
                rigid_noise_dof=None if white is None else white["rigid_covariance_dof"],
            )
        arm_scale_sq, other_ms, dh_share, detected_in_dh_span = arm_and_other_parts(
            systematic.power_mm2, unit["sphere_power_mm2"], split, spheres_in_marker
        )
        unseen_range = [
            unseen_tip_covariance(
                *arm_and_other_parts(value, unit["sphere_power_mm2"], split, spheres_in_marker)[:2]
            )
            for value in systematic.range_mm2
        ]
    unseen_ms = arm_scale_sq * unit["tip_position_ms_mm2"] + other_ms
    basis = (
        f"{blocks}: systematic misfit {noise.beyond}, scaled to the tip by {geometry.scaled_by} "
        "(errors the marker cannot see), plus the noise-only TRE"
    )
    if detected_in_dh_span:
        basis += (
            "; the held-out misfit is within the noise's scatter, so the arm's error scale comes "
            "from the part of the residuals with the DH errors' shape"
        )
    return UnseenPart(
        unseen_ms,
        unseen_tip_covariance(arm_scale_sq, other_ms),
        arm_scale_sq * unit["tip_rotation_ms_rad2"],
        unseen_range,
        {
            # the whole misfit's scale: what kinematic identification takes as its DH prior
            "dh_error_scale_mm": float(np.sqrt(scale_sq)),
            "systematic_dh_share": float(dh_share),
            "unseen_tip_rms_mm": float(np.sqrt(unseen_ms)),
            "kinematic_geometry": arm.name,
        },
        detected_in_dh_span,
        basis,
    )


def needle_tip_covariance(
    tracker_from_base: FloatArray, noise: NoisePart, needle_tip: NeedleTip | None
) -> FloatArray:
    """The pivot's error of a measured tip turned into the tracker frame at each site frame and
    averaged, (3, 3) mm^2; zero without a measured tip."""
    if needle_tip is None:
        return np.zeros((3, 3))
    rotations = tracker_from_base[:3, :3] @ noise.marker_in_base[:, :3, :3]
    return as_float_array(
        np.mean(rotations @ needle_tip.covariance_mm2 @ np.swapaxes(rotations, 1, 2), axis=0)
    )


def expected_error(
    obs: Observations,
    segments: np.ndarray,
    tracker_from_base: FloatArray,
    tcp_from_marker: FloatArray,
    covariance: FloatArray,
    robot_model: RobotModel | None = None,
    joints_rad: FloatArray | None = None,
    absorbed_dh: Sequence[int] = (),
    likelihood_based: bool = True,
    refit: Refit = ml_refit,
    dh_error_scale_mm: float | None = None,
    needle_tip: NeedleTip | None = None,
) -> dict[str, Any]:
    """The expected position (mm) and posture (deg) error at a target near the site.

    The combination of the parts: the noise-only TRE (:func:`noise_part`), a non-ML method's
    distance from ML (:func:`method_deviation`), the held-out misfit (:func:`held_out_part`)
    less the white noise (:func:`white_noise_part`, :func:`systematic_misfit`), scaled to the
    tip by the arm's geometry (:func:`arm_geometry`, :func:`unseen_part`), and a measured tip's
    own error (:func:`needle_tip_covariance`).

    Parameters
    ----------
    obs : Observations
        The frames the estimator used, with the poses its robot model gives.
    segments : numpy.ndarray of str, shape (N,)
        Segment label of each used frame (the held-out blocks).
    tracker_from_base, tcp_from_marker : numpy.ndarray, shape (4, 4)
        The estimator's solution.
    covariance : numpy.ndarray, shape (12, 12)
        Its covariance in the pose perturbation parameters (mm, rad).
    robot_model : RobotModel, optional
        The model ``obs`` poses come from; with ``joints_rad`` it gives the unseen tip error.
    joints_rad : numpy.ndarray, shape (N, J), optional
    absorbed_dh : sequence of int
        DH corrections the estimator identified.
    likelihood_based : bool
        False for an estimator that is not the ML fit of ``obs`` (paper, closed forms): the
        held-out refits are then ML, and the distance of its tip from ML's is added.
    refit : callable
        How a held-out block's refit is done.
    dh_error_scale_mm : float, optional
        The scale of the robot's DH errors when known from elsewhere. Kinematic
        identification passes the one its ML start shows: after identification the
        corrections have absorbed the misfit they were fitted to, so the held-out misfit of
        refits that keep them would understate it.
    needle_tip : NeedleTip, optional
        A tip measured by a pivot, which IK aims instead of the controller's TCP: the errors
        the marker cannot see are then only those its chain cannot describe at that point,
        and the pivot's own error (its covariance, turned into the tracker frame) is added.

    Returns
    -------
    dict
        ``position_mm``, ``posture_deg``, ``basis`` (one sentence), ``components``;
        ``position_covariance_mm2`` (3 x 3, tracker frame, mm^2), whose mean Gaussian length
        ``position_mm`` is; ``position_range_mm``, ``[low, high]`` mm: ``position_mm`` with
        the systematic misfit taken one standard error of the noise's misfit lower and higher,
        how far the statement itself can be off on this many frames (None where the arm's
        error scale was given).
    """
    tip_in_marker = None if needle_tip is None else needle_tip.tip_in_marker
    noise_only = noise_part(obs, tracker_from_base, tcp_from_marker, covariance, tip_in_marker)
    deviation = method_deviation(
        obs, tracker_from_base, tcp_from_marker, noise_only.site, likelihood_based, refit
    )
    scale_given = dh_error_scale_mm is not None and has_arm_model(robot_model, joints_rad)
    held_out = held_out_part(obs, segments, deviation, refit, scale_given)
    geometry = arm_geometry(
        obs, deviation, noise_only.site, held_out, robot_model, joints_rad, absorbed_dh, tip_in_marker
    )
    noise = white_noise_part(obs, segments, deviation, held_out, geometry)
    systematic = systematic_misfit(obs, held_out, noise)
    misfit = held_out.misfit
    refits = "ML refits" if not likelihood_based or absorbed_dh else "refits"
    blocks = f"{misfit['blocks_refitted']} held-out blocks ({refits})"
    if scale_given:
        blocks = f"DH error scale {dh_error_scale_mm:.2f} mm from the ML start's held-out blocks"
    unseen = unseen_part(
        obs,
        deviation,
        noise,
        systematic,
        geometry,
        blocks,
        dh_error_scale_mm,
        tip_in_marker,
    )
    return combined(
        obs,
        noise_only,
        deviation,
        held_out,
        noise,
        systematic,
        unseen,
        likelihood_based,
        needle_tip,
        needle_tip_covariance(tracker_from_base, noise_only, needle_tip),
    )


def combined(
    obs: Observations,
    noise_only: NoisePart,
    deviation: MethodDeviation,
    held_out: HeldOutPart,
    noise: WhiteNoisePart,
    systematic: SystematicMisfit,
    unseen: UnseenPart,
    likelihood_based: bool,
    needle_tip: NeedleTip | None,
    tip_covariance: FloatArray,
) -> dict[str, Any]:
    """The expected error from its parts: the mean length of a Gaussian tip error with the sum
    of their covariances (:func:`mean_gaussian_length`), its range, the posture error from the
    rotation parts (factor :data:`MEAN_OVER_RMS_3D`), and the components and basis recorded.

    Parameters
    ----------
    obs : Observations
    noise_only, deviation, held_out, noise, systematic, unseen
        The parts (see :func:`expected_error`).
    likelihood_based : bool
    needle_tip : NeedleTip or None
    tip_covariance : numpy.ndarray, shape (3, 3)
        The measured tip's own error (:func:`needle_tip_covariance`), mm^2.

    Returns
    -------
    dict
        As :func:`expected_error` returns it.
    """
    spheres = len(obs.spheres_in_marker)
    white, computed, misfit = noise.white, held_out.computed, held_out.misfit
    components: dict[str, Any] = {
        "noise_tre_rms_mm": float(np.sqrt(noise_only.tre_ms_mm2)),
        "held_out_sphere_rms_mm": float(np.sqrt(held_out.mean_square_mm2 / spheres)) if computed else None,
        "noise_sphere_rms_mm": float(np.sqrt(systematic.noise_ms_mm2 / spheres)) if computed else None,
        "white_noise_sphere_rms_mm": None if white is None else float(np.sqrt(white["power_mm2"] / spheres)),
        "tracker_noise_sphere_rms_mm": (
            float(np.sqrt(obs.dof_per_frame * obs.sigma_mm**2 / spheres)) if obs.sigma_known else None
        ),
        "noise_pairs": 0 if white is None else white["pairs"],
        "noise_pair_displacement_mm": None if white is None else white["displacement_mm"],
        "blocks": misfit["blocks"],
        "blocks_refitted": misfit["blocks_refitted"],
        "site_frames": int(noise_only.site.sum()),
        "method_vs_ml_tip_rms_mm": float(np.sqrt(deviation.position_ms_mm2)),
        **unseen.components,
    }
    basis = unseen.basis
    if not likelihood_based:
        basis += "; plus this method's distance from the ML solution"
    components["systematic_detected"] = bool(systematic.power_mm2 > 0.0 or unseen.detected_in_dh_span)
    components["detected_in_dh_span_only"] = unseen.detected_in_dh_span
    if needle_tip is not None:
        components["needle_tip_sd_mm"] = needle_tip.sd_mm
        basis += (
            f"; the needle tip measured by a pivot ({needle_tip.frames} frames), its error "
            f"{needle_tip.sd_mm:.3f} mm per axis added"
        )
    position_covariance = (
        noise_only.covariance_mm2 + unseen.covariance_mm2 + deviation.covariance_mm2 + tip_covariance
    )
    components["position_rms_mm"] = float(
        np.sqrt(
            noise_only.tre_ms_mm2
            + unseen.position_ms_mm2
            + deviation.position_ms_mm2
            + np.trace(tip_covariance)
        )
    )
    posture_rms = np.sqrt(noise_only.rotation_ms_rad2 + unseen.rotation_ms_rad2 + deviation.rotation_ms_rad2)
    position_mm = mean_gaussian_length(position_covariance)
    position_range = None
    if unseen.covariance_range_mm2 is not None:
        # the statement lies within (an arm scale found in the DH span alone, where the misfit
        # is within the noise's scatter, need not grow with the misfit)
        known = noise_only.covariance_mm2 + deviation.covariance_mm2 + tip_covariance
        ends = [mean_gaussian_length(known + part) for part in unseen.covariance_range_mm2] + [position_mm]
        position_range = [min(ends), max(ends)]
    return {
        "position_mm": position_mm,
        "position_range_mm": position_range,
        "posture_deg": float(np.degrees(MEAN_OVER_RMS_3D * posture_rms)),
        "position_covariance_mm2": position_covariance.tolist(),
        "basis": basis,
        "components": components,
    }
