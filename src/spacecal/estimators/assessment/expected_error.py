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

import functools
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from scipy.integrate import quad
from scipy.special import chdtri, gammaln, ndtri
from scipy.stats import norm, qmc

from spacecal.core.errors import DegenerateDataError, UnreachableError
from spacecal.estimators.assessment.residual_noise import (
    RANK_RCOND,
    frame_noise_covariance,
    held_out_noise_power,
)
from spacecal.estimators.methods.held_out import held_out_blocks
from spacecal.estimators.methods.ml import (
    jacobian,
    levenberg_marquardt,
    point_covariances,
    predict_spheres,
    predicted_tre_mm,
)
from spacecal.estimators.methods.observations import Observations
from spacecal.geometry.arrays import ArrayLike, FloatArray, IntArray, as_float_array
from spacecal.geometry.rotations import mean_rotation, rotation_angle
from spacecal.geometry.transforms import invert_transform, make_transform
from spacecal.models.kinematics import (
    N_JOINTS,
    UR_TABLES,
    RobotModel,
    dh_point_jacobian,
    forward_kinematics,
    inverse_kinematics,
    inverse_kinematics_gauss_newton,
    pose_point_jacobian,
    ur_model,
)
from spacecal.records import NeedleTip

#: The fewest frames a held-out refit is done on: two motions determine AX = YB, and the
#: refit needs a margin over that to be more than an interpolation.
MINIMUM_TRAINING_FRAMES = 6


#: Frames near the site stand for the targets: TCP within this distance of the site (mm) ...
SITE_RADIUS_MM = 100.0
#: ... and within this rotation of the mean orientation of the frames there (deg).
SITE_TILT_DEG = 30.0


def unit_dh_sd(joints: int) -> FloatArray:
    """The unit scale of the DH errors of an arm of ``joints`` joints, (4 J,): a, d, alpha,
    theta offset (:data:`UNIT_DH_SD`'s values per joint)."""
    return np.repeat([1.0, 1.0, 0.002, 0.002], joints)


#: Unit scale of the DH errors whose shape sets the unseen tip error: 1 mm for lengths and
#: 0.002 rad for angles (the ratio of the spreads :mod:`spacecal.estimators.methods.kinematic` assumes),
#: for a six-joint arm.
UNIT_DH_SD = unit_dh_sd(N_JOINTS)


#: Frames (evenly spread) on which the kinematic geometry is evaluated: its ratios need no more,
#: and the DH-span test of the misfit's shape runs on them (with recorded or solved joints).
GEOMETRY_FRAMES = 120

#: A UR arm's usual working posture (deg; shoulder lifted, elbow up, wrist down): joint
#: angles solved for a recording that has none take the branch nearest it.
WORKING_POSTURE_DEG = (0.0, -90.0, 90.0, -90.0, -90.0, 0.0)

#: Lever (mm) of the points beside the tip whose displacements give the tip frame's rotation.
ROTATION_LEVER_MM = 100.0

#: Mean over RMS of the length of an isotropic 3-D Gaussian vector, sqrt(8 / (3 pi)).
MEAN_OVER_RMS_3D = float(np.sqrt(8.0 / (3.0 * np.pi)))

#: Standard errors of the noise's held-out misfit (its chi-square scatter and the error of the
#: noise level) taken off the misfit before the rest is called systematic.
DETECTION_STANDARD_ERRORS = 2.0

#: ... and none where the noise is what the residuals leave beyond the DH errors (a camera's
#: static views): there the noise is several times the misfit an arm's 1 mm DH errors leave,
#: two standard errors hide that misfit whole, and the tip error it scales to is four times
#: it. The held-out excess itself is the unbiased estimate (its positive part, the one a
#: statement can take, errs upward where there is none). Measured on KinHEC's 24
#: robot-error sequences (30 camera views each): a 15-point verification's error over the
#: stated one, median (max), 1.43 (4.4) with two standard errors taken off and 0.86 (2.6)
#: without (docs, "One frame per pose and no fit RMS").
DETECTION_STANDARD_ERRORS_BEYOND_DH = 0.0

#: Pairs of consecutive frames whose marker moved more than this many times the pairs' median
#: displacement do not measure the white noise (a jump between stations or sweeps).
NUGGET_DISPLACEMENT_FACTOR = 2.0

#: ... nor do pairs whose marker moved more than this (mm) however the others moved: on the
#: paper's sweeps the residuals' variogram is flat to about 30 mm, and beyond it two frames
#: no longer share their systematic error (at static stations whose repeated frames are
#: identical, the only pairs left are the jumps between stations, 100 mm and more).
NUGGET_MAX_DISPLACEMENT_MM = 20.0

#: Fewer pairs of nearby frames than this cannot measure the white noise.
MINIMUM_NUGGET_PAIRS = 10
#: The fewest residual degrees of freedom the noise is taken from once the DH errors are
#: fitted too (:func:`white_noise_beyond_kinematics`): the estimate's relative error is then
#: at most sqrt(2 / 12) = 0.41. Below it every misfit counts as systematic, which is far worse
#: than a noisy noise level: a camera's 20 static views (14 to 19 effective degrees of freedom,
#: its noise mostly along the line of sight) were stated 11.5 and 16.7 mm for errors of 0.82 and
#: 0.46 mm on KinHEC's noise track, and 2.5 and 2.7 mm with the noise taken from them.
MINIMUM_RESIDUAL_DOF = 12

#: The fewest degrees of freedom a 6 x 6 noise covariance whitens the DH-span test with
#: (:func:`whitened_dh_span_test`): the inflation ``n / (n - 7)`` is then at most 2.
MINIMUM_WHITENING_DOF = 14.0

#: Overlapping pairs (i, i + 1), (i + 1, i + 2) share a frame: under Gaussian noise their
#: half squared differences correlate by 1/4, so the variance of their mean is at most 1.5
#: times that of as many independent pairs.
OVERLAPPING_PAIRS_VARIANCE = 1.5


def mean_gaussian_length(covariance: ArrayLike) -> float:
    """Mean length E|x| of a zero-mean Gaussian vector x ~ N(0, covariance), same unit as x.

    Parameters
    ----------
    covariance : array_like, shape (3, 3)
        Covariance of x (e.g. mm^2 for a tip position error).

    Returns
    -------
    float
        E|x|: ``sqrt(8 / (3 pi))`` times the RMS for an isotropic covariance, ``sqrt(2 / pi)``
        times it for an error along one direction. With eigenvalues l_i and
        ``sqrt(q) = (4 pi)^(-1/2) int_0^inf (1 - exp(-t q)) t^(-3/2) dt``,
        ``E|x| = (4 pi)^(-1/2) int_0^inf (1 - prod_i (1 + 2 t l_i)^(-1/2)) t^(-3/2) dt``,
        integrated numerically (substituting t = u^2).
    """
    eigenvalues = np.clip(np.linalg.eigvalsh(np.asarray(covariance, dtype=float)), 0.0, None)
    scale = float(eigenvalues.sum())
    if scale <= 0.0:
        return 0.0
    relative = eigenvalues / scale

    def integrand(u: float) -> float:
        # t = u^2: dt t^(-3/2) = 2 du / u^2
        return float(2.0 * (1.0 - np.prod(1.0 + 2.0 * u * u * relative) ** -0.5) / (u * u))

    value, _ = quad(integrand, 0.0, np.inf, limit=200)
    return float(np.sqrt(scale) * value / np.sqrt(4.0 * np.pi))


#: Points (log2 of their count) of the scrambled Sobol sequence :func:`probability_within`
#: averages over: 65536 standard normal vectors, whose share within a radius is known to about
#: 1e-4 (quasi-Monte Carlo), the same on every call (a fixed scramble).
GAUSSIAN_POINTS_LOG2 = 16


@functools.cache
def _standard_normal_points() -> FloatArray:
    """Standard normal 3-vectors (2^16, 3) from a scrambled Sobol sequence (fixed seed)."""
    uniform = qmc.Sobol(d=3, scramble=True, seed=20_260_101).random_base2(GAUSSIAN_POINTS_LOG2)
    return as_float_array(ndtri(np.clip(uniform, 1e-12, 1.0 - 1e-12)))


def probability_within(covariance: ArrayLike, radius: float) -> float:
    """Chance that a zero-mean Gaussian vector x ~ N(0, covariance) is no longer than ``radius``.

    The chance an error stated by its covariance stays within an application's limit (or, as
    the benchmarks use it, how often an honest statement should still see a small error). A
    stated mean length alone does not set it: an error along one direction (a camera's depth)
    is small far more often than an isotropic one of the same mean length.

    Parameters
    ----------
    covariance : array_like, shape (3, 3)
        Covariance of x (e.g. mm^2; ``position_covariance_mm2`` of :func:`expected_error`).
    radius : float
        Same unit as x.

    Returns
    -------
    float
        ``P(|x| <= radius)``: the share of :data:`GAUSSIAN_POINTS_LOG2` quasi-random standard
        normal vectors z with ``sum_i l_i z_i^2 <= radius^2`` (l_i the eigenvalues), to about
        1e-4. (Inverting the characteristic function, Imhof 1961, needs an oscillatory
        integral whose quadrature fails at either end of the radius's range.)
    """
    eigenvalues = np.clip(np.linalg.eigvalsh(np.asarray(covariance, dtype=float)), 0.0, None)
    if radius <= 0.0:
        return 0.0
    squared_lengths = (_standard_normal_points() ** 2) @ eigenvalues
    return float(np.mean(squared_lengths <= radius * radius))


#: A refit: (training observations, start tracker_from_base, start tcp_from_marker)
#: -> (tracker_from_base, tcp_from_marker).
Refit = Callable[[Observations, FloatArray, FloatArray], tuple[FloatArray, FloatArray]]


def ml_refit(
    obs: Observations, tracker_from_base: FloatArray, tcp_from_marker: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Levenberg–Marquardt on ``obs`` from a warm start (the full-data solution)."""
    fit = levenberg_marquardt(obs, tracker_from_base, tcp_from_marker, max_iterations=10, tolerance=1e-6)
    return as_float_array(fit.tracker_from_base), as_float_array(fit.tcp_from_marker)


def near_site(base_from_tcp_stack: FloatArray, radius_mm: float, tilt_deg: float) -> np.ndarray:
    """Frames (N,) whose TCP lies within ``radius_mm`` of the site and ``tilt_deg`` of its orientation.

    The site is the centroid of the TCP positions; its orientation the mean orientation of the
    frames within ``radius_mm`` of it. All frames when fewer than three qualify.
    """
    positions = base_from_tcp_stack[:, :3, 3]
    close = np.linalg.norm(positions - positions.mean(axis=0), axis=1) <= radius_mm
    if close.sum() < 3:
        return np.ones(len(positions), dtype=bool)
    reference = mean_rotation(base_from_tcp_stack[close, :3, :3])
    tilt = np.degrees(rotation_angle(base_from_tcp_stack[:, :3, :3] @ reference.T))
    selected = close & (tilt <= tilt_deg)
    return selected if selected.sum() >= 3 else np.ones(len(positions), dtype=bool)


def held_out_misfit(
    obs: Observations,
    segments: np.ndarray,
    tracker_from_base: FloatArray,
    tcp_from_marker: FloatArray,
    refit: Refit = ml_refit,
) -> dict[str, Any]:
    """Squared sphere errors of held-out frames predicted by refits that left their block out.

    Parameters
    ----------
    obs : Observations
        The used frames (``base_from_tcp_stack`` is what the robot model says).
    segments : numpy.ndarray of str, shape (N,)
    tracker_from_base, tcp_from_marker : numpy.ndarray, shape (4, 4)
        The full-data solution, the warm start of every refit.
    refit : callable
        How a block's refit is done (default :func:`ml_refit`).

    Returns
    -------
    dict
        ``frame_sse_mm2`` (N,): sum over the spheres of the squared held-out error (NaN for
        frames of blocks that could not be refitted); ``frame_prediction_leverage`` (N,):
        ``tr(J_i (J_train^T J_train)^-1 J_i^T)``, the refit's own prediction variance per unit
        per-axis noise variance; ``blocks``, ``blocks_refitted``, ``block_indices``;
        ``jacobian`` (N, 3K, 12) and ``block_normal_inverses`` (per block, ``(J_train^T
        J_train)^-1`` or None where it was not refitted), from which
        :func:`spacecal.estimators.assessment.residual_noise.held_out_noise_power` gives the prediction
        variance of noise of any shape.

    Raises
    ------
    DegenerateDataError
        When fewer than two blocks could be refitted.
    """
    n = len(obs.rows)
    frame_sse = np.full(n, np.nan)
    leverage = np.full(n, np.nan)
    blocks = held_out_blocks(segments)
    inverses: list[FloatArray | None] = [None] * len(blocks)
    refitted = 0
    # the refit's own noise makes held-out predictions worse than the noise alone: by
    # sigma^2 tr(J_i (J_train^T J_train)^-1 J_i^T) for frame i (its leverage times sigma^2)
    whole = jacobian(obs, tracker_from_base, tcp_from_marker).reshape(n, -1, 12)
    for number, block in enumerate(blocks):
        keep = np.ones(n, dtype=bool)
        keep[block] = False
        if keep.sum() < MINIMUM_TRAINING_FRAMES:
            continue
        training = replace(
            obs,
            rows=obs.rows[keep],
            base_from_tcp_stack=obs.base_from_tcp_stack[keep],
            spheres_in_tracker=obs.spheres_in_tracker[keep],
        )
        try:
            fitted = refit(training, tracker_from_base, tcp_from_marker)
        except (DegenerateDataError, np.linalg.LinAlgError):
            continue
        held_out = replace(
            obs,
            rows=obs.rows[block],
            base_from_tcp_stack=obs.base_from_tcp_stack[block],
            spheres_in_tracker=obs.spheres_in_tracker[block],
        )
        diff = predict_spheres(held_out, *fitted) - held_out.spheres_in_tracker
        frame_sse[block] = np.sum(diff**2, axis=(1, 2))
        train = whole[keep].reshape(-1, 12)
        inverse = np.linalg.inv(train.T @ train)
        inverses[number] = inverse
        leverage[block] = np.einsum("nia,ab,nib->n", whole[block], inverse, whole[block])
        refitted += 1
    if refitted < 2:
        raise DegenerateDataError("too few blocks of the recording could be refitted to cross-validate")
    return {
        "frame_sse_mm2": frame_sse,
        "frame_prediction_leverage": leverage,
        "blocks": len(blocks),
        "blocks_refitted": refitted,
        "block_indices": blocks,
        "jacobian": whole,
        "block_normal_inverses": inverses,
    }


def tip_points_in_marker(tcp_from_marker: FloatArray, tip_in_marker: FloatArray | None = None) -> FloatArray:
    """The tip and three points ``ROTATION_LEVER_MM`` from it along the TCP axes, (4, 3) in the
    marker frame, mm. The tip is the TCP origin, or ``tip_in_marker`` (3,) when measured."""
    marker_from_tcp = invert_transform(tcp_from_marker)
    tip = marker_from_tcp[:3, 3] if tip_in_marker is None else np.asarray(tip_in_marker, dtype=float)
    return as_float_array(np.vstack([tip, tip + ROTATION_LEVER_MM * marker_from_tcp[:3, :3].T]))


def _least_squares(design: FloatArray, target: FloatArray) -> FloatArray:
    """Least-squares coefficients by the normal equations (well-posed, small column count)."""
    normal = design.T @ design
    ridge = 1e-12 * np.trace(normal) * np.eye(len(normal))
    return as_float_array(np.linalg.solve(normal + ridge, design.T @ target))


def geometry_rows(count: int, frames: int = GEOMETRY_FRAMES) -> IntArray:
    """At most ``frames`` indices (evenly spread) of ``count`` frames, where the kinematic
    geometry is evaluated."""
    return np.unique(np.linspace(0, count - 1, min(frames, count)).round().astype(int))


def solved_joints(model: RobotModel, base_from_tcp_stack: FloatArray, rows: IntArray) -> FloatArray | None:
    """Joint angles (N, 6) reaching ``base_from_tcp_stack[rows]`` by ``model`` (NaN at the other
    frames), on one branch: the first frame's nearest :data:`WORKING_POSTURE_DEG`, then every
    frame by Gauss–Newton from it (the closed form nearest it where that does not converge on
    the branch). None when ``model`` cannot reach them all, or is not a six-joint UR arm (a
    redundant arm's joint angles are not set by its poses)."""
    if model.n_joints != N_JOINTS:
        return None
    targets = base_from_tcp_stack[rows]
    # a geometry needs joint angles to a micrometre, not to the solver's default nanometre
    tolerance_mm = 1e-3
    try:
        start = inverse_kinematics(model, targets[0], np.radians(WORKING_POSTURE_DEG), tol_mm=tolerance_mm)
        solved, _ = inverse_kinematics_gauss_newton(
            model,
            targets,
            np.tile(start, (len(rows), 1)),
            max_iterations=20,
            position_tol_mm=tolerance_mm,
            rotation_tol_rad=tolerance_mm * 1e-3,
        )
        reached = forward_kinematics(model, solved)
        missed = (
            ~np.all(np.isfinite(solved), axis=1)
            | (np.linalg.norm(reached[:, :3, 3] - targets[:, :3, 3], axis=1) > tolerance_mm)
            | (
                rotation_angle(reached[:, :3, :3] @ np.swapaxes(targets[:, :3, :3], 1, 2))
                > tolerance_mm * 1e-3
            )
            | (np.max(np.abs(solved - start), axis=1) > np.pi / 2)
        )
        if missed.any():
            solved[missed] = inverse_kinematics(model, targets[missed], start, tol_mm=tolerance_mm)
    except UnreachableError:
        return None
    joints = np.full((len(base_from_tcp_stack), 6), np.nan)
    joints[rows] = solved
    return joints


def stand_in_arms(robot_model: RobotModel | None, tcp_from_marker: FloatArray) -> list[RobotModel]:
    """The arms whose geometry stands in for a recording's missing joint angles.

    The recording's own model where it names one; otherwise every UR arm of
    :data:`~spacecal.models.kinematics.UR_TABLES`, with its flange at the marker (the tool
    offset is unknown too: the TCP is placed where the calibration puts it from the marker,
    with the TCP's orientation).
    """
    if robot_model is not None:
        return [robot_model]
    flange_from_tcp = make_transform(np.eye(3), -np.asarray(tcp_from_marker, dtype=float)[:3, 3])
    return [ur_model(name, flange_from_tcp) for name in UR_TABLES]


def unseen_kinematic_error(
    model: RobotModel,
    joints_rad: FloatArray,
    obs: Observations,
    tracker_from_base: FloatArray,
    tcp_from_marker: FloatArray,
    site: np.ndarray,
    blocks: Sequence[IntArray],
    absorbed_dh: Sequence[int] = (),
    frames: int = GEOMETRY_FRAMES,
    tip_in_marker: FloatArray | None = None,
) -> dict[str, Any]:
    """How unit-scale DH errors show in held-out sphere errors and at the tip (see the module).

    The same blocks are held out as in :func:`held_out_misfit`, so the held-out misfit and its
    unit-scale counterpart are alike; at most ``frames`` frames, evenly spread, are used.

    Parameters
    ----------
    model : RobotModel
        The model the poses were computed with.
    joints_rad : numpy.ndarray, shape (N, J)
    obs : Observations
    tracker_from_base, tcp_from_marker : numpy.ndarray, shape (4, 4)
    site : numpy.ndarray of bool, shape (N,)
        Frames that stand for targets.
    blocks : sequence of numpy.ndarray of int
        The held-out blocks (indices into the N frames).
    absorbed_dh : sequence of int
        DH corrections the estimator fitted (they absorb what they can, like the pose).
    tip_in_marker : numpy.ndarray, shape (3,), optional
        A tip measured in the marker frame (a pivot). IK then aims it through the fitted
        ``tcp_from_marker``, so what that transform absorbs moves the aimed tip too: only what
        the marker's own chain cannot describe is left. Without it the tip is the controller's
        TCP, which the fitted ``tcp_from_marker`` does not move.

    Returns
    -------
    dict
        ``sphere_power_mm2`` (held-out, per frame, summed over spheres), ``tip_position_ms_mm2``
        and ``tip_rotation_ms_rad2`` (mean squares at the site frames) and
        ``tip_position_covariance_mm2`` (3, 3), the tip's error covariance in the tracker frame
        averaged over the site frames, for unit-scale errors.
    """
    n = len(joints_rad)
    picked = geometry_rows(n, frames)
    site_picked = picked[site[picked]]
    spheres = obs.spheres_in_marker
    k = len(spheres)
    points = np.vstack([spheres, tip_points_in_marker(tcp_from_marker, tip_in_marker)])
    dh = dh_point_jacobian(model, joints_rad[picked], tracker_from_base, tcp_from_marker, points)
    pose = pose_point_jacobian(obs.base_from_tcp_stack[picked], tracker_from_base, tcp_from_marker, points)
    dh = dh * unit_dh_sd(model.n_joints)
    dh_count = dh.shape[-1]
    absorbed_dh = list(absorbed_dh)
    sphere_dh = dh[:, :k].reshape(len(picked), k * 3, dh_count)
    absorbing = np.concatenate(
        [pose[:, :k].reshape(len(picked), k * 3, 12), sphere_dh[..., absorbed_dh]], axis=-1
    )
    # held-out: each block's frames predicted by the absorption fitted on the other blocks
    block_of = np.full(n, -1)
    for b, block in enumerate(blocks):
        block_of[block] = b
    held_out_power = []
    for b in range(len(blocks)):
        out = block_of[picked] == b
        if out.sum() == 0 or (~out).sum() < 3:
            continue
        coefficients = _least_squares(
            absorbing[~out].reshape(-1, absorbing.shape[-1]), sphere_dh[~out].reshape(-1, dh_count)
        )
        unseen = sphere_dh[out] - absorbing[out] @ coefficients
        held_out_power.append(np.sum(unseen**2, axis=(1, 2)))
    sphere_power = float(np.mean(np.concatenate(held_out_power))) if held_out_power else 0.0
    # at the tip, the fitted tracker_from_base (and identified DH) move it; tcp_from_marker does
    # too when the tip was measured in the marker frame, not when it is the controller's TCP
    coefficients = _least_squares(absorbing.reshape(-1, absorbing.shape[-1]), sphere_dh.reshape(-1, dh_count))
    at_site = site[picked]
    tip_dh = dh[at_site, k:]
    moved_by = 6 if tip_in_marker is None else 12
    tip = tip_dh - np.einsum("npia,ab->npib", pose[at_site, k:, :, :moved_by], coefficients[:moved_by])
    if absorbed_dh:
        tip -= np.einsum("npia,ab->npib", tip_dh[..., absorbed_dh], coefficients[12:])
    position_ms = float(np.mean(np.sum(tip[:, 0] ** 2, axis=(1, 2)))) if len(site_picked) else 0.0
    # independent unit DH errors: the tip's covariance is the mean of J J^T over the site frames
    position_covariance = (
        np.mean(tip[:, 0] @ np.swapaxes(tip[:, 0], 1, 2), axis=0) if len(site_picked) else np.zeros((3, 3))
    )
    relative = tip[:, 1:] - tip[:, :1]
    # three orthogonal lever arms u_j of length L: sum_j |w x u_j|^2 = 2 |w|^2 L^2
    rotation_ms = (
        float(np.mean(np.sum(relative**2, axis=(1, 2, 3)))) / (2.0 * ROTATION_LEVER_MM**2)
        if len(site_picked)
        else 0.0
    )
    return {
        "sphere_power_mm2": sphere_power,
        "tip_position_ms_mm2": position_ms,
        "tip_position_covariance_mm2": position_covariance,
        "tip_rotation_ms_rad2": rotation_ms,
    }


def noise_level_relative_error(sphere_count: int, frames: int) -> float:
    """Relative standard error of sigma^2 estimated from ``frames`` tracker RMS values.

    :func:`spacecal.estimators.methods.observations.sphere_noise_from_marker_rms` takes sigma^2 from the
    median of rms^2, a chi-square(3K - 6) variable up to scale; a sample median's variance is
    ``1 / (4 N f(m)^2)`` with f the density at the median m, so the relative error is
    ``1 / (2 f(m) m sqrt(N))`` (0.76 / sqrt(N) for four spheres). Dimensionless.
    """
    dof = max(3 * sphere_count - 6, 1)
    median = float(chdtri(dof, 0.5))
    # the chi-square density at its median (scipy.special: the command line need not load
    # scipy.stats, a third of a second per process)
    half = 0.5 * dof
    density = np.exp((half - 1.0) * np.log(median) - 0.5 * median - half * np.log(2.0) - gammaln(half))
    return float(1.0 / (2.0 * density * median * np.sqrt(max(frames, 1))))


def white_noise_power(
    obs: Observations,
    segments: np.ndarray,
    tracker_from_base: FloatArray,
    tcp_from_marker: FloatArray,
) -> dict[str, Any]:
    """The white part of the residuals, from pairs of consecutive frames (a variogram's nugget).

    A systematic error (the arm's kinematics, the tracker's volume error, a clock offset) is a
    smooth function of where the arm is: two consecutive frames of one segment, whose marker
    moved a few mm, carry nearly the same systematic residual, and half the squared difference
    of their residuals is the white noise's power alone (the variogram
    ``gamma(h) = E|r_i - r_j|^2 / 2`` at small separation h: its nugget). No noise model is
    assumed: anisotropic, pose-only or raw-sphere noise and the robot's own jitter all enter it
    as they enter the residuals. Pairs whose marker moved more than
    :data:`NUGGET_DISPLACEMENT_FACTOR` times the pairs' median, or more than
    :data:`NUGGET_MAX_DISPLACEMENT_MM`, are left out (a jump between stations or sweeps), as
    are pairs of identical observations (a repeated, stale frame).

    Parameters
    ----------
    obs : Observations
        The used frames in time order.
    segments : numpy.ndarray of str, shape (N,)
    tracker_from_base, tcp_from_marker : numpy.ndarray, shape (4, 4)
        The full-data solution.

    Returns
    -------
    dict
        ``power_mm2``: the white noise's power per frame (sum over the spheres of the squared
        noise, mm^2); ``variance_mm4``: the variance of one frame's noise power (for standard
        errors); ``pairs``; ``displacement_mm``: the median RMS displacement of the spheres
        between the frames of a pair; ``rigid_covariance_mm2`` (6, 6): the noise's covariance
        in the rigid motion of a frame's spheres (:func:`rigid_coordinates`, mm and rad), from
        the same pairs: a camera's depth noise is many times its lateral noise;
        ``rigid_covariance_dof``: the independent steps it rests on (the pairs, fewer where they
        overlap, :data:`OVERLAPPING_PAIRS_VARIANCE`).

    Raises
    ------
    DegenerateDataError
        With fewer than :data:`MINIMUM_NUGGET_PAIRS` pairs of nearby frames.
    """
    predicted = predict_spheres(obs, tracker_from_base, tcp_from_marker)
    residuals = predicted - obs.spheres_in_tracker
    segments = np.asarray(segments)
    pairs = segments[1:] == segments[:-1]
    pairs &= np.any(obs.spheres_in_tracker[1:] != obs.spheres_in_tracker[:-1], axis=(1, 2))
    first = np.flatnonzero(pairs)
    displacement = np.sqrt(np.mean(np.sum((predicted[first + 1] - predicted[first]) ** 2, axis=2), axis=1))
    if len(first):
        near = (displacement <= NUGGET_DISPLACEMENT_FACTOR * np.median(displacement)) & (
            displacement <= NUGGET_MAX_DISPLACEMENT_MM
        )
        first, displacement = first[near], displacement[near]
    if len(first) < MINIMUM_NUGGET_PAIRS:
        raise DegenerateDataError(
            f"only {len(first)} pairs of consecutive frames to measure the tracker's noise from "
            f"(at least {MINIMUM_NUGGET_PAIRS})"
        )
    half_squares = 0.5 * np.sum((residuals[first + 1] - residuals[first]) ** 2, axis=(1, 2))
    motion = rigid_coordinates(residuals, predicted)[..., 0]
    steps = motion[first + 1] - motion[first]
    return {
        "rigid_covariance_mm2": 0.5 * steps.T @ steps / len(first),
        # overlapping pairs share frames: fewer independent steps than pairs
        "rigid_covariance_dof": len(first)
        / (OVERLAPPING_PAIRS_VARIANCE if np.any(np.diff(first) == 1) else 1.0),
        "power_mm2": float(np.mean(half_squares)),
        "variance_mm4": float(np.var(half_squares)),
        "pairs": len(first),
        "displacement_mm": float(np.median(displacement)),
    }


def residuals_and_shapes(
    model: RobotModel,
    joints_rad: FloatArray,
    obs: Observations,
    tracker_from_base: FloatArray,
    tcp_from_marker: FloatArray,
    frames: int = GEOMETRY_FRAMES,
) -> tuple[IntArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """The fit's sphere residuals and the shapes the pose and the arm's DH errors give them.

    At most ``frames`` frames with known joint angles, evenly spread: ``rows`` (M,), the
    predicted spheres (M, K, 3) and residuals (M, K, 3), mm, in the tracker frame; the pose's
    Jacobian (M, K, 3, 12) and the unit-scale DH errors' (M, K, 3, 4 J, :func:`unit_dh_sd`).
    """
    usable = np.flatnonzero(np.all(np.isfinite(joints_rad), axis=1))
    rows = usable[geometry_rows(len(usable), frames)] if len(usable) else usable
    points = obs.spheres_in_marker
    seen = predict_spheres(obs, tracker_from_base, tcp_from_marker)[rows]
    residual = seen - obs.spheres_in_tracker[rows]
    pose = pose_point_jacobian(obs.base_from_tcp_stack[rows], tracker_from_base, tcp_from_marker, points)
    dh = dh_point_jacobian(model, joints_rad[rows], tracker_from_base, tcp_from_marker, points)
    dh = dh * unit_dh_sd(model.n_joints)
    return rows, seen, residual, pose, dh


def white_noise_beyond_kinematics(
    model: RobotModel,
    joints_rad: FloatArray,
    obs: Observations,
    tracker_from_base: FloatArray,
    tcp_from_marker: FloatArray,
    frames: int = GEOMETRY_FRAMES,
) -> dict[str, Any]:
    """The white noise as what the residuals leave once the arm's DH errors are fitted as well.

    For a recording of one frame per pose whose tracker gives no fit RMS (a camera's static
    views), no nearby pairs measure the noise. The residuals at the fitted solution are then
    split by their shape: the arm's DH errors (unit scale :data:`UNIT_DH_SD`) and the pose
    parameters span a known subspace of the stacked sphere residuals; white noise spreads over
    all of it, a DH error lies in it. What both fits leave is noise, and its covariance per
    frame is what the residuals' second moments show once the share the fits absorbed is put
    back (:func:`spacecal.estimators.assessment.residual_noise.frame_noise_covariance`): a camera's pose
    noise, nearly all along three of a frame's coordinates, loses more of itself to the fitted
    parameters than isotropic noise would. A systematic error the DH errors cannot describe (a
    tracker's volume error) counts as noise here: the basis says so.

    Parameters
    ----------
    model : RobotModel
        The arm whose DH geometry shapes the systematic error.
    joints_rad : numpy.ndarray, shape (N, J)
        Its joint angles at the used frames (NaN where unknown: those frames are left out).
    obs : Observations
    tracker_from_base, tcp_from_marker : numpy.ndarray, shape (4, 4)
        The fitted solution.
    frames : int
        At most this many frames, evenly spread, are used.

    Returns
    -------
    dict
        ``power_mm2``: the white noise's power per frame (sum over the spheres, mm^2);
        ``covariance_mm2`` (3K, 3K): its covariance over a frame's stacked sphere
        coordinates (tracker frame); ``relative_error``: the relative standard error of that
        power (chi-square scatter of the residual sum of squares' effective degrees of
        freedom); ``dof``: those degrees of freedom.

    Raises
    ------
    DegenerateDataError
        When fewer than :data:`MINIMUM_RESIDUAL_DOF` residual degrees of freedom remain.
    """
    _, _, residual, pose, dh = residuals_and_shapes(
        model, joints_rad, obs, tracker_from_base, tcp_from_marker, frames
    )
    count, spheres = residual.shape[:2]
    design = np.concatenate([pose, dh], axis=-1).reshape(count, 3 * spheres, 12 + dh.shape[-1])
    noise = frame_noise_covariance(design, residual.reshape(count, 3 * spheres))
    if noise["dof"] < MINIMUM_RESIDUAL_DOF:
        raise DegenerateDataError(
            f"only {noise['dof']:.0f} residual degrees of freedom beyond the pose and the DH errors "
            f"(at least {MINIMUM_RESIDUAL_DOF})"
        )
    return {
        "power_mm2": noise["power_mm2"],
        "covariance_mm2": noise["covariance_mm2"],
        "relative_error": float(np.sqrt(2.0 / noise["dof"])),
        "dof": noise["dof"],
    }


def rigid_coordinates(displacements: FloatArray, points: FloatArray) -> FloatArray:
    """Each frame's point displacements as the small rigid motion that explains them best.

    Parameters
    ----------
    displacements : numpy.ndarray, shape (N, K, 3) or (N, K, 3, M), mm
        Per frame, the displacement of each of K points (M sets of them, e.g. Jacobian columns).
    points : numpy.ndarray, shape (N, K, 3), mm
        Where the points are.

    Returns
    -------
    numpy.ndarray, shape (N, 6, M) (M = 1 for one set), mm and rad
        The least-squares translation of the points' centroid and rotation about it (tracker
        frame), ``(v, w)``.
    """
    centred = points - points.mean(axis=1, keepdims=True)
    n, k, _ = points.shape
    basis = np.zeros((n, k, 3, 6))
    basis[..., :3] = np.eye(3)
    # the rotation w moves a point p by w x p = -[p]x w
    x, y, z = centred[..., 0], centred[..., 1], centred[..., 2]
    basis[..., 0, 4], basis[..., 0, 5] = z, -y
    basis[..., 1, 3], basis[..., 1, 5] = -z, x
    basis[..., 2, 3], basis[..., 2, 4] = y, -x
    design = basis.reshape(n, 3 * k, 6)
    return as_float_array(np.linalg.pinv(design) @ displacements.reshape(n, 3 * k, -1))


def rigid_part(displacements: FloatArray, points: FloatArray) -> FloatArray:
    """Each frame's point displacements projected on the rigid motions of its points.

    Parameters
    ----------
    displacements, points : numpy.ndarray, shape (N, K, 3), mm
        Per frame, the displacement of each of K points and where the point is.

    Returns
    -------
    numpy.ndarray, shape (N, K, 3), mm
        The displacements a small rigid motion (translation and rotation) of each frame's
        points explains best, by least squares.
    """
    motion = rigid_coordinates(displacements, points)[..., 0]
    rotation = motion[:, 3:]
    centred = points - points.mean(axis=1, keepdims=True)
    return motion[:, None, :3] + np.cross(rotation[:, None, :], centred)


def systematic_share_in_dh_span(
    model: RobotModel,
    joints_rad: FloatArray,
    obs: Observations,
    tracker_from_base: FloatArray,
    tcp_from_marker: FloatArray,
    white_power_mm2: float,
    frames: int = GEOMETRY_FRAMES,
    rigid_noise_covariance: FloatArray | None = None,
    rigid_noise_dof: float | None = None,
) -> dict[str, Any]:
    """How much of the systematic misfit has the shape of the arm's DH errors.

    Each frame's residual is reduced to the rigid motion of its spheres (:func:`rigid_part`),
    and the stacked result is split by its shape (as in :func:`white_noise_beyond_kinematics`):
    the part a least-squares fit of unit DH errors (:data:`UNIT_DH_SD`) explains beyond the
    pose, and the rest. White noise of known power has its expected share in each (its power
    per frame over the frame's degrees of freedom, per dimension of the subspace); what is
    left over in the DH span is the arm's error, what is left beyond it is a systematic error
    the arm's geometry cannot describe (a tracker's smooth bias field, a marker's geometry
    error). Only the first is scaled to the tip by the arm's geometry; scaling
    all of it overstated the error about 1.6 times where a tracker's bias dominated. A bias
    that happens to lie in the DH span counts as the arm's: the split errs towards the larger
    error.

    Parameters
    ----------
    model : RobotModel
    joints_rad : numpy.ndarray, shape (N, J)
        Joint angles at the used frames (NaN where unknown: those frames are left out).
    obs : Observations
    tracker_from_base, tcp_from_marker : numpy.ndarray, shape (4, 4)
        The fitted solution.
    white_power_mm2 : float
        The white noise's power per frame (sum over the spheres, mm^2).
    frames : int
        At most this many frames, evenly spread, are used.
    rigid_noise_covariance : numpy.ndarray, shape (6, 6), optional
        The white noise's covariance in a frame's rigid motion (``rigid_covariance_mm2`` of
        :func:`white_noise_power`). The DH-span test is then made on the residuals' rigid
        motions whitened by it: a noise that is large along one direction (a camera's depth)
        no longer hides an arm error that moves the marker across it. Measured on the
        simulated camera-grade pose tracker (depth noise three times the lateral), the test's
        statistic over its standard error rose from 2.0-18 (median 9.4) to 5.4-58 (median 27)
        over 20 seeds; on white noise both stay near 0 (-1.5 to 2.7).
    rigid_noise_dof : float, optional
        The degrees of freedom ``rigid_noise_covariance`` was estimated with.

    Returns
    -------
    dict
        ``dh_share`` in [0, 1] (1 when no systematic misfit is left in-sample), and the
        in-sample systematic powers per frame ``dh_power_mm2`` and ``other_power_mm2``;
        ``dh_detected_power_mm2``, the DH part less :data:`DETECTION_STANDARD_ERRORS` standard
        errors of the noise's share in it (a chi-square test on the DH span's few dimensions,
        far more sensitive to an arm's error than the held-out misfit of every coordinate), and
        ``unit_dh_power_mm2``, what unit-scale DH errors leave beyond the pose in-sample (both
        per frame).
    """
    if not np.all(np.isfinite(joints_rad), axis=1).any():
        return {
            "dh_share": 1.0,
            "dh_power_mm2": 0.0,
            "other_power_mm2": 0.0,
            "dh_detected_power_mm2": 0.0,
            "unit_dh_power_mm2": 0.0,
        }
    rows, seen, residual, pose, dh = residuals_and_shapes(
        model, joints_rad, obs, tracker_from_base, tcp_from_marker, frames
    )
    # Pose and DH errors move the marker rigidly: only each frame's rigid motion is compared,
    # the same whether the tracker sent spheres or a fitted pose (whose noise lives there only).
    stacked = rigid_part(residual, seen).reshape(-1)
    pose_design = pose.reshape(-1, 12)
    design = np.concatenate([pose, dh], axis=-1).reshape(-1, 12 + dh.shape[-1])
    # directions the data barely determine (DH columns nearly redundant with the pose, singular
    # values ~1e-12 of the largest) are cut: they would turn rounding into a different split
    beyond_pose, _, pose_rank, _ = np.linalg.lstsq(pose_design, stacked, rcond=RANK_RCOND)
    beyond_all, _, rank, _ = np.linalg.lstsq(design, stacked, rcond=RANK_RCOND)
    rss_pose = float(np.sum((stacked - pose_design @ beyond_pose) ** 2))
    rss_all = float(np.sum((stacked - design @ beyond_all) ** 2))
    # white noise per dimension of a frame's rigid motion (its power over its dof)
    per_dimension = white_power_mm2 / obs.dof_per_frame
    dh_dimensions = int(rank) - int(pose_rank)
    dh_excess = rss_pose - rss_all - per_dimension * dh_dimensions
    dh_power = max(dh_excess, 0.0) / len(rows)
    other_power = max(rss_all - per_dimension * (6 * len(rows) - int(rank)), 0.0) / len(rows)
    total = dh_power + other_power
    noise_standard_error = per_dimension * np.sqrt(2.0 * max(dh_dimensions, 1))
    if rigid_noise_covariance is not None:
        detected, unit_power = whitened_dh_span_test(
            residual, seen, pose, dh, rigid_noise_covariance, rigid_noise_dof
        )
    else:
        detected = max(dh_excess - DETECTION_STANDARD_ERRORS * noise_standard_error, 0.0)
        unit_power = _power_beyond_pose(pose_design, dh.reshape(-1, dh.shape[-1]))
    return {
        "dh_share": dh_power / total if total > 0 else 1.0,
        "dh_power_mm2": dh_power,
        "other_power_mm2": other_power,
        "dh_detected_power_mm2": detected / len(rows),
        "unit_dh_power_mm2": unit_power / len(rows),
    }


def whitened_dh_span_test(
    residual: FloatArray,
    seen: FloatArray,
    pose: FloatArray,
    dh: FloatArray,
    covariance: FloatArray,
    covariance_dof: float | None = None,
) -> tuple[float, float]:
    """The DH-span chi-square test of :func:`systematic_share_in_dh_span` on rigid motions
    whitened by the noise's covariance.

    Parameters
    ----------
    residual, seen : numpy.ndarray, shape (M, K, 3), mm
        The fit's sphere residuals and the predicted spheres (tracker frame).
    pose, dh : numpy.ndarray, shape (M, K, 3, 12) and (M, K, 3, D)
        The pose's Jacobian and the unit-scale DH errors' (:func:`residuals_and_shapes`).
    covariance : numpy.ndarray, shape (6, 6)
        The white noise's covariance in a frame's rigid motion (:func:`rigid_coordinates`).
    covariance_dof : float, optional
        The degrees of freedom ``covariance`` was estimated with (pairs of frames), None for a
        known one. Whitening by an estimate inflates the whitened noise: by ``n / (n - 7)`` on
        average for a 6 x 6 covariance from n degrees of freedom (the mean of an inverse
        Wishart matrix), 2.75 times from the 11 pairs of a 10 Hz camera's sweep, where taking
        it as one unit flagged an arm error on KinHEC's noise-only temporal sequences. With
        fewer than :data:`MINIMUM_WHITENING_DOF` nothing is detected.

    Returns
    -------
    detected : float
        What the DH columns explain beyond the pose, less the whitened noise's share (one unit
        per dimension of the DH span) and :data:`DETECTION_STANDARD_ERRORS` of its chi-square
        scatter; zero when not above it.
    unit_power : float
        What unit-scale DH errors leave beyond the pose, in the same whitened units, so that
        ``detected / unit_power`` is the arm's error scale squared.
    """
    try:
        whitening = np.linalg.inv(np.linalg.cholesky(covariance))
    except np.linalg.LinAlgError:
        return 0.0, 0.0
    motion = rigid_coordinates(residual, seen)[..., 0] @ whitening.T
    columns = np.einsum(
        "ij,njc->nic", whitening, rigid_coordinates(np.concatenate([pose, dh], axis=-1), seen)
    )
    stacked = motion.reshape(-1)
    design = columns.reshape(-1, columns.shape[-1])
    pose_design, dh_design = design[:, :12], design[:, 12:]
    beyond_pose, _, pose_rank, _ = np.linalg.lstsq(pose_design, stacked, rcond=RANK_RCOND)
    beyond_all, _, rank, _ = np.linalg.lstsq(design, stacked, rcond=RANK_RCOND)
    rss_pose = float(np.sum((stacked - pose_design @ beyond_pose) ** 2))
    rss_all = float(np.sum((stacked - design @ beyond_all) ** 2))
    unit_power = _power_beyond_pose(pose_design, dh_design)
    # whitened noise: one unit per dimension (times the inflation of an estimated covariance),
    # chi-square with the DH span's dimensions
    dimensions = max(int(rank) - int(pose_rank), 1)
    inflation, estimate_margin = 1.0, 0.0
    if covariance_dof is not None:
        if covariance_dof < MINIMUM_WHITENING_DOF:
            return 0.0, unit_power
        inflation = covariance_dof / (covariance_dof - 7.0)
        # One estimate whitens every frame, so its error does not average out over them: along
        # any direction the whitened power is n / chi^2(n - 5) times the truth (an inverse
        # Wishart's diagonal), a skewed factor; its upper quantile at the chi-square margin's
        # level is taken on the whole sum.
        level = float(norm.sf(DETECTION_STANDARD_ERRORS))
        estimate_margin = dimensions * (
            covariance_dof / chdtri(covariance_dof - 5.0, 1.0 - level) - inflation
        )
    excess = rss_pose - rss_all - dimensions * inflation
    margin = np.hypot(DETECTION_STANDARD_ERRORS * inflation * np.sqrt(2.0 * dimensions), estimate_margin)
    detected = max(excess - margin, 0.0)
    return detected, unit_power


def _power_beyond_pose(pose_design: FloatArray, dh_design: FloatArray) -> float:
    """What unit-scale DH errors (the columns of ``dh_design``) leave beyond the pose's columns,
    summed over every column and row."""
    fitted = pose_design @ np.linalg.lstsq(pose_design, dh_design, rcond=RANK_RCOND)[0]
    return float(np.sum((dh_design - fitted) ** 2))


def arm_and_other_parts(
    systematic_mm2: float, unit_sphere_power_mm2: float, split: dict[str, Any] | None, spheres: int
) -> tuple[float, float, float, bool]:
    """How a systematic held-out misfit divides between the arm's DH errors and the rest.

    Parameters
    ----------
    systematic_mm2 : float
        The held-out misfit beyond the noise's, per frame over all its spheres, mm^2.
    unit_sphere_power_mm2 : float
        The misfit a DH error scale of 1 mm leaves per frame (:func:`unseen_kinematic_error`).
    split : dict or None
        :func:`systematic_share_in_dh_span`'s split of the residuals, where the noise was
        measured apart from the misfit; None where the noise is what DH errors leave (all the
        misfit is then the arm's).
    spheres : int
        Spheres of the marker.

    Returns
    -------
    arm_scale_sq : float
        The arm's DH error scale, squared (mm^2).
    other_ms : float
        The mean square at the tip of the error beyond the arm's (a tracker's bias field), mm^2:
        as large as at one sphere of the marker, which is a point of the same chain.
    dh_share : float
        The share of the misfit in the DH span.
    detected_in_dh_span : bool
        True where the held-out misfit is within the noise's scatter yet the arm's errors show
        in the DH span's few dimensions in-sample (a noisy tracker): the scale is then theirs.
    """
    scale_sq = systematic_mm2 / unit_sphere_power_mm2 if unit_sphere_power_mm2 > 0 else 0.0
    if split is None:
        return scale_sq, 0.0, 1.0, False
    if systematic_mm2 > 0:
        share = float(split["dh_share"])
        return share * scale_sq, (1.0 - share) * systematic_mm2 / spheres, share, False
    if split["unit_dh_power_mm2"] > 0:
        arm_scale_sq = float(split["dh_detected_power_mm2"] / split["unit_dh_power_mm2"])
        return arm_scale_sq, 0.0, 1.0, arm_scale_sq > 0
    return 0.0, 0.0, 1.0, False


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
    site = near_site(obs.base_from_tcp_stack, SITE_RADIUS_MM, SITE_TILT_DEG)
    tip_in_marker = None if needle_tip is None else needle_tip.tip_in_marker
    # the marker's pose at each site frame (base frame): where a measured tip is, and how the
    # pivot's error, fixed in the marker frame, turns
    marker_in_base = obs.base_from_tcp_stack[site] @ tcp_from_marker
    if tip_in_marker is None:
        tip_in_base = obs.base_from_tcp_stack[site, :3, 3]
    else:
        tip_in_base = marker_in_base[:, :3, :3] @ tip_in_marker + marker_in_base[:, :3, 3]
    tre_ms = float(np.mean(predicted_tre_mm(tracker_from_base, covariance, tip_in_base) ** 2))
    # the noise-only error's covariance (tracker frame, mm^2), averaged over the site frames
    noise_covariance = np.mean(
        point_covariances(tracker_from_base, np.asarray(covariance)[:6, :6], tip_in_base), axis=0
    )
    rotation_noise_ms = float(np.trace(np.asarray(covariance)[3:6, 3:6]))
    ml_tracker_from_base, ml_tcp_from_marker = tracker_from_base, tcp_from_marker
    deviation_ms = rotation_deviation_ms = 0.0
    deviation_covariance = np.zeros((3, 3))
    if not likelihood_based:
        ml_tracker_from_base, ml_tcp_from_marker = refit(obs, tracker_from_base, tcp_from_marker)
        method_tip = tracker_from_base @ obs.base_from_tcp_stack[site]
        ml_tip = ml_tracker_from_base @ obs.base_from_tcp_stack[site]
        deviation = method_tip[:, :3, 3] - ml_tip[:, :3, 3]
        deviation_ms = float(np.mean(np.sum(deviation**2, axis=1)))
        # its second moment over the site frames, added like a covariance
        deviation_covariance = deviation.T @ deviation / len(deviation)
        rotation_deviation_ms = float(
            rotation_angle(tracker_from_base[:3, :3] @ ml_tracker_from_base[:3, :3].T) ** 2
        )
    has_model = robot_model is not None and joints_rad is not None and bool(np.all(np.isfinite(joints_rad)))
    if dh_error_scale_mm is not None and has_model:
        # the scale is given: the held-out refits would only be reported, not used
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
        misfit = held_out_misfit(obs, segments, ml_tracker_from_base, ml_tcp_from_marker, refit)
    sse = misfit["frame_sse_mm2"]
    computed = bool(np.isfinite(sse).any())
    held_out_ms = float(np.nanmean(sse)) if computed else 0.0
    scored = int(np.isfinite(sse).sum())
    mean_leverage = float(np.nanmean(misfit["frame_prediction_leverage"])) if computed else 0.0
    geometry: tuple[RobotModel, dict[str, Any], FloatArray] | None = None
    if has_model and robot_model is not None and joints_rad is not None:
        geometry = (
            robot_model,
            unseen_kinematic_error(
                robot_model,
                joints_rad,
                obs,
                ml_tracker_from_base,
                ml_tcp_from_marker,
                site,
                misfit["block_indices"],
                absorbed_dh,
                tip_in_marker=tip_in_marker,
            ),
            joints_rad,
        )
        scaled_by = "the robot's kinematic geometry"
    else:
        # no joint angles: solve them from the reported TCP poses, by the recording's robot
        # model or, without one, by the UR arm whose geometry hides the most of a given misfit
        # as many frames as with recorded joint angles: the DH-span test below needs them (on
        # 40, a camera-grade tracker's arm error went unseen on the bag and TUM paths, up to
        # 10.6 times the statement)
        rows = geometry_rows(len(obs.rows), GEOMETRY_FRAMES)
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
                misfit["block_indices"],
                tip_in_marker=tip_in_marker,
            )
            if unit["sphere_power_mm2"] > 0 and (
                geometry is None
                or unit["tip_position_ms_mm2"] / unit["sphere_power_mm2"]
                > geometry[1]["tip_position_ms_mm2"] / geometry[1]["sphere_power_mm2"]
            ):
                geometry = (arm, unit, joints)
        if geometry is not None and robot_model is not None:
            scaled_by = (
                f"the {robot_model.name}'s kinematic geometry at joint angles solved from the reported "
                "TCP poses (the recording has none)"
            )
        elif geometry is not None:
            scaled_by = (
                f"the kinematic geometry of a {geometry[0].name} with its flange at the marker, the UR arm "
                "that hides the most of it (the recording has no joint angles or robot model)"
            )
    # The white noise, from the residuals of consecutive frames where there are enough (the same
    # on every path, and every white source is in it as it is in the misfit); else from the
    # tracker's fit RMS; else unknown, and then all the misfit counts as systematic.
    # Beyond it, the misfit less DETECTION_STANDARD_ERRORS standard errors of the noise's is
    # systematic: frames of one recording cannot tell a smaller systematic misfit from a
    # misjudged noise level. The standard error has two parts, the held-out mean's own scatter
    # and that of the noise level it is compared with.
    shaped_noise_ms: float | None = None
    detection_standard_errors = DETECTION_STANDARD_ERRORS
    try:
        white: dict[str, Any] | None = white_noise_power(
            obs, segments, ml_tracker_from_base, ml_tcp_from_marker
        )
    except DegenerateDataError:
        white = None
    if white is not None:
        white_power = float(white["power_mm2"])
        noise_standard_error = float(
            np.sqrt(
                white["variance_mm4"] * (1.0 / max(scored, 1) + OVERLAPPING_PAIRS_VARIANCE / white["pairs"])
            )
        )
        beyond = "beyond the white noise of consecutive frames"
    elif obs.sigma_known:
        # chi-square scatter of the held-out mean (2 dof sigma^4 per frame), and the error of
        # the noise level, a median of the tracker's RMS values
        white_power = obs.dof_per_frame * obs.sigma_mm**2
        noise_standard_error = float(
            np.hypot(
                obs.sigma_mm**2 * np.sqrt(2.0 * obs.dof_per_frame / max(scored, 1)),
                white_power * noise_level_relative_error(len(obs.spheres_in_marker), len(obs.rows)),
            )
        )
        beyond = (
            "beyond the tracker's noise from its fit RMS (too few nearby frames to measure the white noise)"
        )
    else:
        beyond_dh = None
        if geometry is not None:
            try:
                beyond_dh = white_noise_beyond_kinematics(
                    geometry[0], geometry[2], obs, ml_tracker_from_base, ml_tcp_from_marker
                )
            except DegenerateDataError:
                beyond_dh = None
        if beyond_dh is not None:
            white_power = float(beyond_dh["power_mm2"])
            shape = np.asarray(beyond_dh["covariance_mm2"])
            # noise of this shape, not isotropic: the refits' prediction error and the
            # held-out mean's chi-square scatter (2 tr(Sigma^2) per frame) both follow it
            shaped_noise_ms = held_out_noise_power(misfit, shape) if computed else white_power
            scatter = (
                float(np.sqrt(2.0 * np.sum(shape * shape) / max(scored, 1))) / white_power
                if white_power > 0
                else 0.0
            )
            noise_standard_error = white_power * float(np.hypot(scatter, beyond_dh["relative_error"]))
            detection_standard_errors = DETECTION_STANDARD_ERRORS_BEYOND_DH
            beyond = (
                "beyond the white noise the residuals leave once the arm's DH errors are fitted too "
                "(one frame per pose and no tracker fit RMS; a systematic error DH errors cannot "
                "describe counts as noise there)"
            )
        else:
            white_power = noise_standard_error = 0.0
            beyond = "(all of it: neither nearby frames nor a tracker fit RMS measure the white noise)"
    noise_ms = (
        shaped_noise_ms
        if shaped_noise_ms is not None
        else white_power * (1.0 + mean_leverage / obs.dof_per_frame)
    )
    systematic = (
        max(held_out_ms - noise_ms - detection_standard_errors * noise_standard_error, 0.0)
        if computed
        else 0.0
    )
    spheres = len(obs.spheres_in_marker)
    components: dict[str, Any] = {
        "noise_tre_rms_mm": float(np.sqrt(tre_ms)),
        "held_out_sphere_rms_mm": float(np.sqrt(held_out_ms / spheres)) if computed else None,
        "noise_sphere_rms_mm": float(np.sqrt(noise_ms / spheres)) if computed else None,
        "white_noise_sphere_rms_mm": None if white is None else float(np.sqrt(white["power_mm2"] / spheres)),
        "tracker_noise_sphere_rms_mm": (
            float(np.sqrt(obs.dof_per_frame * obs.sigma_mm**2 / spheres)) if obs.sigma_known else None
        ),
        "noise_pairs": 0 if white is None else white["pairs"],
        "noise_pair_displacement_mm": None if white is None else white["displacement_mm"],
        "blocks": misfit["blocks"],
        "blocks_refitted": misfit["blocks_refitted"],
        "site_frames": int(site.sum()),
        "method_vs_ml_tip_rms_mm": float(np.sqrt(deviation_ms)),
    }
    refits = "ML refits" if not likelihood_based or absorbed_dh else "refits"
    blocks = f"{misfit['blocks_refitted']} held-out blocks ({refits})"
    if dh_error_scale_mm is not None and has_model:
        blocks = f"DH error scale {dh_error_scale_mm:.2f} mm from the ML start's held-out blocks"
    detected_in_dh_span = False
    # the systematic misfit one standard error lower and higher: how far the statement's own
    # estimate of it can be off on this many frames (its positive part errs upward where
    # there is none)
    systematic_range = [
        max(held_out_ms - noise_ms - (detection_standard_errors + step) * noise_standard_error, 0.0)
        if computed
        else 0.0
        for step in (1.0, -1.0)
    ]
    unseen_range: list[FloatArray] | None = None
    if geometry is not None:
        arm, unit, _ = geometry
        spheres_in_marker = len(obs.spheres_in_marker)

        def unseen_tip_covariance(arm_scale_sq: float, other_ms: float) -> FloatArray:
            """The tip's error the marker cannot see (tracker frame, mm^2): the arm's, shaped
            by its geometry, and the rest, isotropic."""
            return arm_scale_sq * np.asarray(unit["tip_position_covariance_mm2"]) + np.eye(3) * other_ms / 3.0

        if dh_error_scale_mm is not None:
            scale_sq = dh_error_scale_mm**2
            # kinematic identification: its corrections took the arm's part
            arm_scale_sq, other_ms, dh_share = scale_sq, 0.0, 1.0
        else:
            scale_sq = systematic / unit["sphere_power_mm2"] if unit["sphere_power_mm2"] > 0 else 0.0
            split = None
            # the noise measured apart from the misfit (pairs, fit RMS): split the misfit by its
            # shape; the noise taken as what DH errors leave has counted the rest as noise already
            if white is not None or obs.sigma_known:
                split = systematic_share_in_dh_span(
                    arm,
                    geometry[2],
                    obs,
                    ml_tracker_from_base,
                    ml_tcp_from_marker,
                    white_power,
                    rigid_noise_covariance=None if white is None else white["rigid_covariance_mm2"],
                    rigid_noise_dof=None if white is None else white["rigid_covariance_dof"],
                )
            arm_scale_sq, other_ms, dh_share, detected_in_dh_span = arm_and_other_parts(
                systematic, unit["sphere_power_mm2"], split, spheres_in_marker
            )
            unseen_range = [
                unseen_tip_covariance(
                    *arm_and_other_parts(value, unit["sphere_power_mm2"], split, spheres_in_marker)[:2]
                )
                for value in systematic_range
            ]
        unseen_ms = arm_scale_sq * unit["tip_position_ms_mm2"] + other_ms
        unseen_covariance = unseen_tip_covariance(arm_scale_sq, other_ms)
        unseen_rotation_ms = arm_scale_sq * unit["tip_rotation_ms_rad2"]
        # the whole misfit's scale: what kinematic identification takes as its DH prior
        components["dh_error_scale_mm"] = float(np.sqrt(scale_sq))
        components["systematic_dh_share"] = float(dh_share)
        components["unseen_tip_rms_mm"] = float(np.sqrt(unseen_ms))
        components["kinematic_geometry"] = arm.name
        basis = (
            f"{blocks}: systematic misfit {beyond}, scaled to the tip by {scaled_by} "
            "(errors the marker cannot see), plus the noise-only TRE"
        )
        if detected_in_dh_span:
            basis += (
                "; the held-out misfit is within the noise's scatter, so the arm's error scale comes "
                "from the part of the residuals with the DH errors' shape"
            )
    else:
        # no arm reaches the poses: the held-out power of a frame (over all its spheres) stands
        # for the tip's mean square, as a UR arm's geometry makes it on the paper's sweeps; a
        # measured tip is a point of the marker's chain, off by what one sphere is
        per_tip = 1.0 if tip_in_marker is None else 1.0 / len(obs.spheres_in_marker)
        unseen_ms = systematic * per_tip
        # the misfit says nothing of its direction at the tip: isotropic
        unseen_covariance = np.eye(3) * unseen_ms / 3.0
        unseen_range = [np.eye(3) * value * per_tip / 3.0 for value in systematic_range]
        unseen_rotation_ms = 0.0
        components["kinematic_geometry"] = None
        basis = (
            f"{blocks}: systematic misfit per frame {beyond}, plus the noise-only TRE; "
            "no joint angles and no UR arm reaches these poses, so the errors the marker cannot see are "
            "taken as large as the misfit it sees"
        )
    if not likelihood_based:
        basis += "; plus this method's distance from the ML solution"
    components["systematic_detected"] = bool(systematic > 0.0 or detected_in_dh_span)
    components["detected_in_dh_span_only"] = detected_in_dh_span
    tip_covariance = np.zeros((3, 3))
    if needle_tip is not None:
        # the pivot's error turned into the tracker frame at each site frame
        rotations = tracker_from_base[:3, :3] @ marker_in_base[:, :3, :3]
        tip_covariance = np.mean(rotations @ needle_tip.covariance_mm2 @ np.swapaxes(rotations, 1, 2), axis=0)
        components["needle_tip_sd_mm"] = needle_tip.sd_mm
        basis += (
            f"; the needle tip measured by a pivot ({needle_tip.frames} frames), its error "
            f"{needle_tip.sd_mm:.3f} mm per axis added"
        )
    position_covariance = noise_covariance + unseen_covariance + deviation_covariance + tip_covariance
    components["position_rms_mm"] = float(
        np.sqrt(tre_ms + unseen_ms + deviation_ms + np.trace(tip_covariance))
    )
    posture_rms = np.sqrt(rotation_noise_ms + unseen_rotation_ms + rotation_deviation_ms)
    position_mm = mean_gaussian_length(position_covariance)
    position_range = None
    if unseen_range is not None:
        # the statement lies within (an arm scale found in the DH span alone, where the misfit
        # is within the noise's scatter, need not grow with the misfit)
        known = noise_covariance + deviation_covariance + tip_covariance
        ends = [mean_gaussian_length(known + unseen) for unseen in unseen_range] + [position_mm]
        position_range = [min(ends), max(ends)]
    return {
        "position_mm": position_mm,
        "position_range_mm": position_range,
        "posture_deg": float(np.degrees(MEAN_OVER_RMS_3D * posture_rms)),
        "position_covariance_mm2": position_covariance.tolist(),
        "basis": basis,
        "components": components,
    }
