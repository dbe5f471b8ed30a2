"""The white noise of the residuals: from consecutive frames, or what is left beyond the DH errors."""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.special import chdtri, gammaln

from spacecal.core.errors import DegenerateDataError
from spacecal.estimators.assessment.residual_noise import (
    frame_noise_covariance,
)
from spacecal.estimators.assessment.rigid_motion import rigid_coordinates
from spacecal.estimators.assessment.unseen_kinematics import GEOMETRY_FRAMES, geometry_rows, unit_dh_sd
from spacecal.estimators.methods.ml import (
    predict_spheres,
)
from spacecal.estimators.methods.observations import Observations
from spacecal.geometry.arrays import FloatArray, IntArray
from spacecal.models.kinematics import (
    RobotModel,
    dh_point_jacobian,
    pose_point_jacobian,
)

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
