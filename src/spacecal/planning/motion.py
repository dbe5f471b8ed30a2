"""Straight-line Cartesian moves (like a UR ``movel``) timed under speed and acceleration limits.

A move interpolates the TCP pose from ``start`` to ``end``: position linearly, orientation
along the geodesic (slerp). The path parameter s in [0, 1] follows a trapezoidal velocity
profile whose duration respects the TCP's linear and angular limits and every joint's
speed limit along the path.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spacecal.core.errors import InvalidInputError, UnreachableError
from spacecal.geometry.transforms import interpolate_transforms, matrix_to_rotvec
from spacecal.models.kinematics import (
    RobotModel,
    inverse_kinematics,
    inverse_kinematics_gauss_newton,
    linearised_joints,
)
from spacecal.records.plan import PlannedMove, PlanRecord


@dataclass(frozen=True)
class MotionLimits:
    """Speed and acceleration limits for calibration motions (conservative defaults).

    Attributes
    ----------
    linear_speed_mm_s, linear_accel_mm_s2 : float
        TCP translation limits.
    angular_speed_rad_s, angular_accel_rad_s2 : float
        TCP rotation limits.
    joint_speed_rad_s : float
        Limit on every joint's speed.
    """

    linear_speed_mm_s: float = 100.0
    linear_accel_mm_s2: float = 400.0
    angular_speed_rad_s: float = np.radians(45.0)
    angular_accel_rad_s2: float = np.radians(180.0)
    joint_speed_rad_s: float = 1.0


def trapezoid_duration(distance: float, speed: float, accel: float) -> tuple[float, float]:
    """Duration and acceleration time of a rest-to-rest trapezoidal move over ``distance``."""
    if distance <= 0:
        return 0.0, 0.0
    if distance >= speed**2 / accel:
        accel_time = speed / accel
        return distance / speed + accel_time, accel_time
    accel_time = np.sqrt(distance / accel)
    return 2.0 * accel_time, accel_time


def trapezoid_progress(t, duration: float, accel_time: float) -> np.ndarray:
    """Path parameter s(t) in [0, 1] of a trapezoidal profile; t is clipped to [0, duration]."""
    t = np.clip(np.asarray(t, dtype=float), 0.0, duration)
    if duration == 0:
        return np.ones_like(t)
    if accel_time == 0:  # a hold (start == end) or an instantaneous profile
        return t / duration
    peak_rate = 1.0 / (duration - accel_time)
    accel = peak_rate / accel_time
    return np.where(
        t < accel_time,
        0.5 * accel * t**2,
        np.where(
            t > duration - accel_time,
            1.0 - 0.5 * accel * (duration - t) ** 2,
            peak_rate * (t - 0.5 * accel_time),
        ),
    )


#: Poses of a dense path solved together by :func:`follow_path`.
PATH_CHUNK = 16
#: Largest joint step (rad) between neighbouring poses of a chunk solved together; a larger one
#: is taken for a jump to another IK branch, and the chunk is followed pose by pose instead.
BRANCH_JUMP_RAD = 0.2
#: Position tolerance (mm) of the joints :func:`track_path` finds; rotations to 1e-3 of it, rad.
PATH_TOL_MM = 1e-9


def follow_path(
    model: RobotModel, poses_base_from_tcp, start_joints_rad, tolerance_mm: float = PATH_TOL_MM
) -> tuple[np.ndarray, int]:
    """Joint angles following a dense pose path continuously from ``start_joints_rad``, as a
    controller follows a ``movel``: on the IK branch it starts on, never a jump to another.

    The path is solved in chunks of :data:`PATH_CHUNK` poses: Gauss–Newton
    (:func:`~spacecal.models.kinematics.inverse_kinematics_gauss_newton`) on the whole chunk at
    once, each pose from the linearised step from the last solution
    (:func:`~spacecal.models.kinematics.linearised_joints`). A chunk whose solutions do not all
    converge, or step by more than :data:`BRANCH_JUMP_RAD` from their neighbour or from that
    start, is followed pose by pose instead, each from the previous solution's linear
    continuation. Both reach the same joints on the same branch (to the tolerance); the chunks
    cost about a tenth.

    Parameters
    ----------
    model : RobotModel
    poses_base_from_tcp : array_like, shape (M, 4, 4)
        ``base_from_tcp`` along the path, mm, closely spaced.
    start_joints_rad : array_like, shape (6,)
        The configuration at the first pose (or near it).
    tolerance_mm : float
        Every position error below this (mm), every rotation error below 1e-3 of it (rad).

    Returns
    -------
    joints : numpy.ndarray, shape (M, 6)
        NaN from the first pose that could not be followed on.
    followed : int
        Poses followed (M when all).
    """
    poses = np.asarray(poses_base_from_tcp, dtype=float)
    joints = np.full((len(poses), 6), np.nan)
    q = np.asarray(start_joints_rad, dtype=float).copy()
    previous = None
    for first in range(0, len(poses), PATH_CHUNK):
        chunk = poses[first : first + PATH_CHUNK]
        solved = _solve_chunk(model, chunk, q, tolerance_mm)
        if solved is None:
            solved, done = _follow_pose_by_pose(model, chunk, q, previous, tolerance_mm)
            if done < len(chunk):
                joints[first : first + done] = solved[:done]
                return joints, first + done
        joints[first : first + len(chunk)] = solved
        previous = solved[-2] if len(solved) > 1 else q
        q = solved[-1]
    return joints, len(poses)


def track_path(model: RobotModel, poses_base_from_tcp, start_joints_rad) -> np.ndarray:
    """Joint angles (M, 6) following a dense pose path continuously from ``start_joints_rad``
    (:func:`follow_path`, to :data:`PATH_TOL_MM`).

    Raises
    ------
    UnreachableError
        If a pose cannot be tracked (workspace edge or singularity).
    """
    joints, followed = follow_path(model, poses_base_from_tcp, start_joints_rad)
    if followed < len(joints):
        raise UnreachableError(f"path pose {followed} cannot be tracked (workspace edge or singularity)")
    return joints


def _solve(model: RobotModel, targets: np.ndarray, starts: np.ndarray, tolerance_mm: float):
    return inverse_kinematics_gauss_newton(
        model,
        targets,
        starts,
        max_iterations=30,
        position_tol_mm=tolerance_mm,
        rotation_tol_rad=tolerance_mm * 1e-3,
    )


def _solve_chunk(
    model: RobotModel, chunk: np.ndarray, q: np.ndarray, tolerance_mm: float
) -> np.ndarray | None:
    """The chunk's joints (K, 6) solved together from ``q``, or None where they may have left
    its branch."""
    guess = linearised_joints(model, q, chunk)
    solved, converged = _solve(model, chunk, guess, tolerance_mm)
    if not converged:
        return None
    steps = np.abs(np.diff(np.vstack([q, solved]), axis=0))
    if steps.max() > BRANCH_JUMP_RAD or np.abs(solved - guess).max() > BRANCH_JUMP_RAD:
        return None
    return solved


def _follow_pose_by_pose(
    model: RobotModel, chunk: np.ndarray, q: np.ndarray, previous: np.ndarray | None, tolerance_mm: float
) -> tuple[np.ndarray, int]:
    """The chunk's joints (K, 6) one pose at a time, and how many were followed."""
    joints = np.full((len(chunk), 6), np.nan)
    for k, target in enumerate(chunk):
        # start from the path's own continuation (linear in the last two solutions), which
        # is closer than the last solution and saves an iteration; from the last solution
        # again if that fails
        starts = [q] if previous is None else [2.0 * q - previous, q]
        for start in starts:
            solved, converged = _solve(model, target[None], start[None], tolerance_mm)
            if converged:
                break
        if not converged:
            return joints, k
        previous, q = q, solved[0]
        joints[k] = q
    return joints, len(chunk)


@dataclass
class TimedMove:
    """A Cartesian move with its timing.

    Attributes
    ----------
    label : str
        Segment label written into recordings (``rot_x``, ``lin_y``, ``transit``...).
    start, end : numpy.ndarray, shape (4, 4)
        ``base_from_tcp`` at the ends, mm.
    duration_s, accel_time_s : float
    sample_period_s : float
        How often the tracker is sampled during this move.
    """

    label: str
    start: np.ndarray
    end: np.ndarray
    duration_s: float
    accel_time_s: float
    sample_period_s: float

    def poses_at(self, t_s) -> np.ndarray:
        """Commanded ``base_from_tcp`` (M, 4, 4) at times (M,) since the move started."""
        progress = trapezoid_progress(t_s, self.duration_s, self.accel_time_s)
        return interpolate_transforms(self.start, self.end, np.atleast_1d(progress))


def time_move(
    model: RobotModel,
    label: str,
    start,
    end,
    start_joints_rad,
    limits: MotionLimits,
    sample_period_s: float,
    path_points: int = 41,
) -> tuple[TimedMove, np.ndarray]:
    """Time a Cartesian move under ``limits`` and return it with the joint angles at its end.

    The duration is the longest of the linear, angular and joint-speed bounds; the joint
    bound uses the peak path speed of the trapezoid and ``max |dq/ds|`` on a dense path.
    """
    start = np.asarray(start, dtype=float)
    end = np.asarray(end, dtype=float)
    distance = float(np.linalg.norm(end[:3, 3] - start[:3, 3]))
    angle = float(np.linalg.norm(matrix_to_rotvec(start[:3, :3].T @ end[:3, :3])))
    candidates = [
        trapezoid_duration(distance, limits.linear_speed_mm_s, limits.linear_accel_mm_s2),
        trapezoid_duration(angle, limits.angular_speed_rad_s, limits.angular_accel_rad_s2),
    ]
    duration, accel_time = max(candidates)
    s = np.linspace(0.0, 1.0, path_points)
    joints = track_path(model, interpolate_transforms(start, end, s), start_joints_rad)
    if duration > 0:
        dq_ds = np.max(np.abs(np.diff(joints, axis=0)), axis=0).max() / (s[1] - s[0])
        peak_rate = 1.0 / (duration - accel_time)
        joint_speed = dq_ds * peak_rate
        if joint_speed > limits.joint_speed_rad_s:
            stretch = joint_speed / limits.joint_speed_rad_s
            duration, accel_time = duration * stretch, accel_time * stretch
    move = TimedMove(label, start, end, duration, accel_time, sample_period_s)
    return move, joints[-1]


def reachable_joints(model: RobotModel, poses_base_from_tcp, reference_joints_rad) -> np.ndarray:
    """Boolean (M,): each pose has an IK solution within the joint limits."""
    ok = np.zeros(len(poses_base_from_tcp), dtype=bool)
    for k, pose in enumerate(poses_base_from_tcp):
        try:
            inverse_kinematics(model, pose, reference_joints_rad)
            ok[k] = True
        except UnreachableError:
            pass
    return ok


@dataclass
class MotionPlan:
    """A planned calibration motion.

    Attributes
    ----------
    home_joints_rad : numpy.ndarray, shape (6,)
    home_base_from_tcp : numpy.ndarray, shape (4, 4), mm
    moves : list of TimedMove
        In execution order; moves with ``sample_period_s == 0`` are not sampled.
    extents : dict
        Per segment the range actually planned, e.g. for the paper's sweeps
        ``{"rot_x": [lo_deg, hi_deg], "lin_x": [lo_mm, hi_mm], ...}``.
    messages : list of str
        What was shrunk and why.
    workspace_box_mm : numpy.ndarray, shape (6,), or None
        ``xmin, xmax, ymin, ymax, zmin, zmax`` (base frame, mm) the plan keeps the TCP in, when
        it states one (a plan file's ``workspace_box_mm``).
    """

    home_joints_rad: np.ndarray
    home_base_from_tcp: np.ndarray
    moves: list[TimedMove]
    extents: dict
    messages: list[str]
    workspace_box_mm: np.ndarray | None = None

    @property
    def motion_time_s(self) -> float:
        """Total planned motion time, s."""
        return float(sum(m.duration_s for m in self.moves))

    def summary(self) -> dict:
        """Plain-data description for result files and CLI output."""
        return {
            "motion_time_s": self.motion_time_s,
            "extents": self.extents,
            "messages": self.messages,
            "moves": [{"label": m.label, "duration_s": m.duration_s} for m in self.moves],
        }


def planned_moves(plan: MotionPlan) -> list[PlannedMove]:
    """The plan's moves as the plan file's records."""
    return [
        PlannedMove(m.label, m.start, m.end, m.duration_s, m.accel_time_s, m.sample_period_s)
        for m in plan.moves
    ]


def motion_plan_from_record(record: PlanRecord) -> MotionPlan:
    """The runnable plan a plan file describes.

    Raises
    ------
    InvalidInputError
        For a version-1 file, which kept only a summary of each move.
    """
    if not record.runnable:
        raise InvalidInputError(
            "this plan file was written by an older spacecal and holds no move poses; "
            "run 'spacecal plan' again"
        )
    moves = [
        TimedMove(m.label, m.start, m.end, m.duration_s, m.accel_time_s, m.sample_period_s)
        for m in record.moves
    ]
    extents = {"stations": len(record.station_joints_rad)} if record.kind == "site-optimal" else {}
    return MotionPlan(
        record.home_joints_rad, record.home_base_from_tcp, moves, extents, [], record.workspace_box_mm
    )
