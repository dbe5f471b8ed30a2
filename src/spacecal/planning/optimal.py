"""Calibration motions planned for the error they leave at the surgical site.

Candidates are static stations drawn around the site (position in a cube, orientation tilted
from home), each feasible: reachable within joint limits and with the marker predicted
visible. The predicted error of a set of stations is the expected error of the needle tip
at configurations around the site after a joint maximum-likelihood fit of the calibration
*and* the robot's DH corrections (with their prior): from the Fisher information

    I = sum over stations, frames, spheres of J^T J / sigma^2 + prior^-1,   Sigma = I^-1,

with J the derivative of the predicted sphere positions with respect to the 12 pose and 24 DH
parameters, and the tip error at a site configuration g^T Sigma g. Stations are added
greedily by error reduction per second of motion (transit at the speed limits plus the hold
for the frames) until the time budget is spent; the final plan is timed exactly.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from spacecal.core.errors import DegenerateDataError, UnreachableError
from spacecal.geometry.rotations import rotation_angle
from spacecal.geometry.transforms import axis_angle_transform
from spacecal.models.kinematics import (
    RobotModel,
    dh_point_jacobian,
    forward_kinematics,
    inverse_kinematics,
    pose_point_jacobian,
)
from spacecal.planning.motion import MotionLimits, MotionPlan, TimedMove, time_move, trapezoid_duration
from spacecal.planning.needle import needle_pose
from spacecal.planning.stations import random_station
from spacecal.planning.visibility import VisibilityModel


@dataclass(frozen=True)
class PlannerSettings:
    """Budget, candidates and noise model of :func:`plan_for_site`.

    Attributes
    ----------
    budget_s : float
        Largest total motion time (transit plus holds).
    candidates : int
    cube_mm, tilt_deg : float
        Where candidate stations are drawn.
    frames_per_station : int
    frame_period_s : float
    sphere_sigma_mm : float
        Per-axis sphere noise of the tracker.
    prior_length_sd_mm, prior_angle_sd_rad : float
        Prior of the DH corrections (as in the kinematic estimator).
    pose_prior_mm, pose_prior_rad : float
        How well the set-up is known before calibrating (it is, roughly: the planner itself
        needs it to predict visibility); keeps the first greedy steps well conditioned.
    limits : MotionLimits
    """

    budget_s: float = 30.0
    candidates: int = 120
    cube_mm: float = 250.0
    tilt_deg: float = 45.0
    frames_per_station: int = 5
    frame_period_s: float = 0.05
    sphere_sigma_mm: float = 0.15
    prior_length_sd_mm: float = 1.0
    prior_angle_sd_rad: float = 0.002
    pose_prior_mm: float = 50.0
    pose_prior_rad: float = 0.05
    limits: MotionLimits = field(default_factory=MotionLimits)


def parameter_jacobian(model, joints, tracker_from_base, tcp_from_marker, points_in_marker, dh_step=1e-6):
    """d(points in tracker)/d(36 parameters) for configurations (N, 6): shape (N, K, 3, 36).

    Parameters: the 12 pose perturbations of the estimators
    (:func:`~spacecal.models.kinematics.apply_pose_step`; analytic), then the 24 DH
    corrections (central differences with ``dh_step``).
    """
    base_from_tcp_stack = forward_kinematics(model, np.atleast_2d(joints))
    pose = pose_point_jacobian(base_from_tcp_stack, tracker_from_base, tcp_from_marker, points_in_marker)
    dh = dh_point_jacobian(model, joints, tracker_from_base, tcp_from_marker, points_in_marker, dh_step)
    return np.concatenate([pose, dh], axis=-1)


@dataclass
class SitePlan:
    """A planned calibration motion and its predicted error."""

    plan: MotionPlan
    station_joints_rad: np.ndarray
    predicted_error_mm: float
    motion_time_s: float


def _prior_sd(s: PlannerSettings) -> np.ndarray:
    """Prior s.d. of the 36 parameters: pose (translation, rotation, twice), DH lengths, DH angles."""
    pose = [s.pose_prior_mm] * 3 + [s.pose_prior_rad] * 3
    return np.array(pose * 2 + [s.prior_length_sd_mm] * 12 + [s.prior_angle_sd_rad] * 12)


def predicted_site_error(information, site_gradients) -> float:
    """RMS predicted tip error (mm) over site configurations for an information matrix (36, 36)."""
    # scale to unit diagonal before inverting: the parameters span mm and rad over many decades
    scale = 1.0 / np.sqrt(np.diag(information))
    covariance = scale[:, None] * np.linalg.inv(information * np.outer(scale, scale)) * scale[None, :]
    variances = np.einsum("mia,ab,mib->m", site_gradients, covariance, site_gradients)
    return float(np.sqrt(np.mean(np.clip(variances, 0.0, None))))


def site_configurations(
    model: RobotModel, home_joints_rad, site_in_base=None
) -> tuple[np.ndarray, np.ndarray]:
    """The needle at the site: its pose, and the joints (5, 6) with the tool at the site and
    tilted by 15 degrees about four axes (where the error is predicted).

    Parameters
    ----------
    model : RobotModel
    home_joints_rad : array_like, shape (6,)
    site_in_base : array_like, shape (3,) or (4, 4), optional
        The tip's working point, mm in base, with the tool in its home orientation; or the
        needle's pose there (``base_from_tcp``, e.g. at the target of a planned path,
        :func:`needle_site`). Default: the TCP at home.

    Raises
    ------
    DegenerateDataError
        When the site cannot be reached.
    """
    home_joints = np.asarray(home_joints_rad, dtype=float)
    site = forward_kinematics(model, home_joints)
    try:
        if site_in_base is not None:
            given = np.asarray(site_in_base, dtype=float)
            if given.shape == (4, 4):
                site = given.copy()
            else:
                site[:3, 3] = given
            home_joints = inverse_kinematics(model, site, home_joints)
        tilted = [
            inverse_kinematics(model, site @ axis_angle_transform(axis, np.radians(15)), home_joints)
            for axis in ([1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0])
        ]
    except UnreachableError:
        raise DegenerateDataError(
            "the site cannot be reached with the tool in that orientation (or tilted 15 degrees); "
            "choose a site nearer home"
        ) from None
    return site, np.array([home_joints, *tilted])


def needle_site(model: RobotModel, home_joints_rad, entry_in_base, target_in_base) -> np.ndarray:
    """The needle (the TCP) at the target of a planned path: ``base_from_tcp`` (4, 4), mm, with
    its z axis from the entry to the target and its roll nearest the tool's at home."""
    home = forward_kinematics(model, np.asarray(home_joints_rad, dtype=float))
    entry, target = np.asarray(entry_in_base, dtype=float), np.asarray(target_in_base, dtype=float)
    if np.linalg.norm(target - entry) < 1.0:
        raise DegenerateDataError("the needle path's entry and target are less than 1 mm apart")
    return needle_pose(target, target - entry, roll_reference=home[:3, 0])


def plan_for_site(
    model: RobotModel,
    home_joints_rad,
    visibility: VisibilityModel,
    rng: np.random.Generator,
    settings: PlannerSettings | None = None,
    site_in_base: np.ndarray | None = None,
) -> SitePlan:
    """Choose stations that minimise the predicted tip error at the site within the time budget.

    The site is where the needle tip will work: ``site_in_base`` (3,), mm, or the needle's
    pose there (4, 4) (see :func:`site_configurations`); by default the TCP at home. Stations
    are drawn around it (a cube, tilted by up to the settings' tilt) with its orientation, and
    the error is predicted for the tip there and tilted by 15 degrees about four axes. The
    tour starts and ends at home.
    """
    s = settings or PlannerSettings()
    home_joints = np.asarray(home_joints_rad, dtype=float)
    home = forward_kinematics(model, home_joints)
    site, site_joints = site_configurations(model, home_joints, site_in_base)
    spheres = visibility.marker.spheres_in_marker
    t_prior, x_prior = visibility.tracker_from_base, visibility.tcp_from_marker

    feasible_poses: list[np.ndarray] = []
    feasible_joints: list[np.ndarray] = []
    for _ in range(s.candidates * 10):
        if len(feasible_poses) >= s.candidates:
            break
        pose = random_station(site, rng, s.cube_mm, s.tilt_deg)
        if not visibility.visible(pose[None])[0]:
            continue
        try:
            q = inverse_kinematics(model, pose, home_joints)
        except UnreachableError:
            continue
        feasible_poses.append(pose)
        feasible_joints.append(q)
    if len(feasible_poses) < 6:
        raise DegenerateDataError(
            f"only {len(feasible_poses)} feasible stations around the site; widen the cube or tilt"
        )
    poses, joints = np.array(feasible_poses), np.array(feasible_joints)

    # information per candidate (frames at a station repeat the same geometry)
    jac = parameter_jacobian(model, joints, t_prior, x_prior, spheres).reshape(len(joints), -1, 36)
    info_each = np.einsum("nka,nkb->nab", jac, jac) * s.frames_per_station / s.sphere_sigma_mm**2
    prior_sd = _prior_sd(s)
    # site: the needle tip at home and at tilted configurations around it
    site_gradients = parameter_jacobian(model, site_joints, t_prior, np.eye(4), np.zeros((1, 3)))[:, 0]

    hold = s.frames_per_station * s.frame_period_s

    def transit_estimate(q_from, q_to, pose_from, pose_to):
        distance = float(np.linalg.norm(pose_to[:3, 3] - pose_from[:3, 3]))
        angle = float(rotation_angle(pose_to[:3, :3] @ pose_from[:3, :3].T))
        joint = float(np.max(np.abs(q_to - q_from)))
        return max(
            trapezoid_duration(distance, s.limits.linear_speed_mm_s, s.limits.linear_accel_mm_s2)[0],
            trapezoid_duration(angle, s.limits.angular_speed_rad_s, s.limits.angular_accel_rad_s2)[0],
            joint / s.limits.joint_speed_rad_s,
        )

    information = np.diag(1.0 / prior_sd**2)
    chosen: list[int] = []
    q_last, pose_last, elapsed = home_joints, home, 0.0
    current = predicted_site_error(information, site_gradients)
    while True:
        best, best_score, best_time = None, 0.0, 0.0
        for index in range(len(joints)):
            if index in chosen:
                continue
            extra = transit_estimate(q_last, joints[index], pose_last, poses[index]) + hold
            if (
                elapsed + extra + transit_estimate(joints[index], home_joints, poses[index], home)
                > s.budget_s
            ):
                continue
            error = predicted_site_error(information + info_each[index], site_gradients)
            score = (current - error) / extra
            if score > best_score:
                best, best_score, best_time = index, score, extra
        if best is None:
            break
        chosen.append(best)
        information = information + info_each[best]
        current = predicted_site_error(information, site_gradients)
        q_last, pose_last, elapsed = joints[best], poses[best], elapsed + best_time
    if len(chosen) < 3:
        raise DegenerateDataError(f"a {s.budget_s:.0f} s budget buys only {len(chosen)} stations; raise it")

    # time the chosen tour exactly; drop stations from the end until it fits the budget
    while True:
        plan = _timed_tour(model, home_joints, home, poses[chosen], s, hold)
        if plan.motion_time_s <= s.budget_s or len(chosen) <= 3:
            break
        chosen.pop()
    information = np.diag(1.0 / prior_sd**2) + info_each[chosen].sum(axis=0)
    return SitePlan(
        plan, joints[chosen], predicted_site_error(information, site_gradients), plan.motion_time_s
    )


def _timed_tour(model, home_joints, home, station_poses, s: PlannerSettings, hold: float) -> MotionPlan:
    moves: list[TimedMove] = []
    q, pose = home_joints, home
    for station in station_poses:
        # the tracker samples during transits too (the paper samples while moving)
        move, q_end = time_move(model, "transit", pose, station, q, s.limits, s.frame_period_s)
        moves.append(move)
        moves.append(TimedMove("station", station, station, hold, 0.0, s.frame_period_s))
        q, pose = q_end, station
    move, _ = time_move(model, "transit", pose, home, q, s.limits, 0.0)
    moves.append(move)
    return MotionPlan(home_joints, home, moves, {"stations": len(station_poses)}, [])


def paper_sweep_site_error(
    model: RobotModel,
    plan: MotionPlan,
    visibility: VisibilityModel,
    settings: PlannerSettings | None = None,
    site_in_base: np.ndarray | None = None,
) -> float:
    """The same predicted site error for an existing plan (e.g. the paper's sweeps), for comparison."""
    s = settings or PlannerSettings()
    from spacecal.planning.motion import track_path

    paths: list[np.ndarray] = []
    q = plan.home_joints_rad
    for move in plan.moves:
        if move.sample_period_s > 0:
            t = np.arange(0.0, move.duration_s, move.sample_period_s)
            path = track_path(model, move.poses_at(t), q)
            paths.append(path)
            q = path[-1]
        q = track_path(model, move.end[None], q)[0]
    joints = np.concatenate(paths)
    seen = visibility.visible(forward_kinematics(model, joints))
    jac = parameter_jacobian(
        model,
        joints[seen],
        visibility.tracker_from_base,
        visibility.tcp_from_marker,
        visibility.marker.spheres_in_marker,
    ).reshape(int(seen.sum()), -1, 36)
    information = np.einsum("nka,nkb->ab", jac, jac) / s.sphere_sigma_mm**2
    prior_sd = _prior_sd(s)
    _, site_joints = site_configurations(model, plan.home_joints_rad, site_in_base)
    site_gradients = parameter_jacobian(
        model, site_joints, visibility.tracker_from_base, np.eye(4), np.zeros((1, 3))
    )[:, 0]
    return predicted_site_error(information + np.diag(1.0 / prior_sd**2), site_gradients)
