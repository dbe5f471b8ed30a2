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
from spacecal.models.kinematics import RobotModel, inverse_kinematics, inverse_kinematics_gauss_newton
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


def track_path(model: RobotModel, poses_base_from_tcp, start_joints_rad) -> np.ndarray:
    """Joint angles (M, 6) following a dense pose path continuously from ``start_joints_rad``.

    Each pose is solved by Gauss–Newton (:func:`~spacecal.models.kinematics.inverse_kinematics_gauss_newton`)
    from the previous solution, so the arm never jumps between IK branches mid-move (as a UR
    controller behaves on ``movel``).

    Raises
    ------
    UnreachableError
        If a pose cannot be tracked (workspace edge or singularity).
    """
    poses = np.asarray(poses_base_from_tcp, dtype=float)
    joints = np.empty((len(poses), 6))
    q = np.asarray(start_joints_rad, dtype=float).copy()
    previous = None
    for k, target in enumerate(poses):
        # start from the path's own continuation (linear in the last two solutions), which
        # is closer than the last solution and saves an iteration; from the last solution
        # again if that fails
        starts = [q] if previous is None else [2.0 * q - previous, q]
        for start in starts:
            solved, converged = inverse_kinematics_gauss_newton(
                model,
                target[None],
                start[None],
                max_iterations=30,
                position_tol_mm=1e-9,
                rotation_tol_rad=1e-12,
            )
            if converged:
                break
        if not converged:
            raise UnreachableError(f"path pose {k} cannot be tracked (workspace edge or singularity)")
        previous, q = q, solved[0]
        joints[k] = q
    return joints


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
