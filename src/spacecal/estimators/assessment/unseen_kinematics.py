"""What the marker cannot see: the tip error DH errors of unit scale cause beyond what the fit absorbs."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from spacecal.core.errors import UnreachableError
from spacecal.estimators.methods.observations import Observations
from spacecal.geometry.arrays import FloatArray, IntArray, as_float_array
from spacecal.geometry.rotations import rotation_angle
from spacecal.geometry.transforms import invert_transform, make_transform
from spacecal.models.kinematics import (
    N_JOINTS,
    RobotModel,
    dh_point_jacobian,
    forward_kinematics,
    inverse_kinematics,
    inverse_kinematics_gauss_newton,
    pose_point_jacobian,
)
from spacecal.models.robot_kinds import robot_kind, ur_kind_names


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
    registered UR kind (:func:`~spacecal.models.robot_kinds.ur_kind_names`: six-joint arms,
    whose joint angles their poses set), with its flange at the marker (the tool
    offset is unknown too: the TCP is placed where the calibration puts it from the marker,
    with the TCP's orientation).
    """
    if robot_model is not None:
        return [robot_model]
    flange_from_tcp = make_transform(np.eye(3), -np.asarray(tcp_from_marker, dtype=float)[:3, 3])
    return [robot_kind(name).model(flange_from_tcp) for name in ur_kind_names()]


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
