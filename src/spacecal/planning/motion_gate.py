"""The one gate every motion passes before the robot moves.

Whatever produced a motion (the paper's sweeps planned where the robot stands, a plan file,
the check poses, stop-and-go stations), :func:`gate_motion` checks the path the robot will
really take (the acquisition loop commands a straight ``movel`` from wherever the arm is to
each move's end) against the controller's kinematic model, and returns a
:class:`MotionGateReport`: what was checked, with counts, and the first refusal if any.

Checks, in the order a move meets them (the first failure in execution order is reported):

* plan: at least one move, at most :data:`MAX_MOVES` moves and :data:`MAX_POINTS` check
  points, finite numbers; the commanded TCP limits within what the robot permits; the start
  configuration within the joint limits.
* continuity: each move starts where the previous one ended, the first where the robot stands
  (and at the plan's home), within :data:`CONTINUITY_MM` and :data:`CONTINUITY_RAD`.
* speeds: the TCP speed and acceleration each move's timing states are within the commanded
  limits (else the run misses the move's deadline part-way and stops), and those within what
  the robot permits (:class:`RobotPermits`).
* workspace: every sample of the TCP inside the box, and the TCP and flange above the base
  plane and outside the base cylinder.
* reach: inverse kinematics on one continuous branch at every sample, followed from the
  start configuration as a controller follows a ``movel``.
* joint limits: every sample within the model's limits.
* singularities: every sample at least :data:`WRIST_MARGIN_RAD`, :data:`ELBOW_MARGIN_RAD`
  and :data:`SHOULDER_MARGIN_MM` from the UR's wrist, elbow and shoulder singularities.
* joint speeds: between adjacent samples no joint turns more than :data:`FLIP_RAD` (a branch
  flip), nor faster than the robot's joint speed limit at the commanded timing.
* visibility: where a prior set-up is known, the marker predicted visible on most of each
  recorded move (:data:`MIN_VISIBLE_FRACTION`).

Samples are :data:`POSITION_STEP_MM` and :data:`ROTATION_STEP_RAD` apart along each line
(whichever gives more), ends included; ``docs/workflow.md`` explains every tolerance.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.geometry.arrays import ArrayLike, FloatArray
from spacecal.geometry.transforms import interpolate_transforms, invert_transform, matrix_to_rotvec
from spacecal.models.kinematics import (
    RobotModel,
    forward_kinematics,
)
from spacecal.models.robot_kinds import ROBOT_KINDS
from spacecal.planning.motion import MotionLimits, follow_path, trapezoid_duration
from spacecal.planning.visibility import VisibilityModel

# -- sampling -------------------------------------------------------------------------------
#: Largest TCP travel between two samples of a line, mm.
POSITION_STEP_MM = 2.0
#: Largest TCP rotation between two samples of a line, rad (1 degree).
ROTATION_STEP_RAD = math.radians(1.0)

# -- continuity -----------------------------------------------------------------------------
#: Largest gap between a move's start and where the arm is when it starts, mm and rad. They are
#: the tolerances spacecal already accepts elsewhere: 1 mm between its kinematic model and the
#: TCP the controller reports (``app.acquisition.TCP_MISMATCH_MM``) and between the robot and a
#: plan's home (``PLAN_HOME_MM``); 0.01 rad, the joint offset a robot may stand from a plan's
#: home (``PLAN_HOME_RAD``), which turns the TCP by about as much. A plan written with the
#: nominal model and run on a calibrated controller starts that far from the arm (0.2 mm and
#: 0.1 deg in the paper-realistic scenario); beyond them the arm would take a path nobody
#: planned. The gate samples the path the arm really takes (from where it is), so a gap within
#: the tolerance is checked too. 0.01 rad turns a point 100 mm from the TCP (the marker) by 1 mm.
CONTINUITY_MM = 1.0
CONTINUITY_RAD = 0.01

# -- singularities and branch flips -----------------------------------------------------------
#: Closest approach of joint 5 to 0 or 180 degrees (wrist singularity: joints 4 and 6 align).
WRIST_MARGIN_RAD = math.radians(5.0)
#: Closest approach of joint 3 to 0 or 180 degrees (elbow singularity: the arm stretched out
#: or folded).
ELBOW_MARGIN_RAD = math.radians(5.0)
#: Closest approach of the wrist to the base axis, mm (shoulder singularity:
#: ``a2 cos q2 + a3 cos(q2+q3) + d5 sin(q2+q3+q4) = 0``).
SHOULDER_MARGIN_MM = 20.0
#: A joint turning more than this between adjacent samples has left the branch it was on.
#: At the margins above, a step of one sample (1 degree of TCP rotation, 2 mm of travel)
#: turns a joint at most 1 deg / sin(5 deg) = 11.5 deg (wrist) or 2 mm / 20 mm = 5.7 deg
#: (shoulder); a flip between branches turns one by at least twice a margin and usually
#: by far more (joints 4 and 6 by 180 degrees through the wrist singularity).
FLIP_RAD = math.radians(30.0)

# -- plan size --------------------------------------------------------------------------------
#: Most moves a plan may hold (spacecal's own plans hold under 300, stop-and-go included).
MAX_MOVES = 5000
#: Most check points a plan may need (about 400 m of travel at 2 mm): beyond it the gate
#: would take minutes, and no calibration motion is that long.
MAX_POINTS = 200_000

# -- workspace ------------------------------------------------------------------------------
#: Half side of the default workspace box around the home TCP, mm: the paper's whole 500 mm
#: stroke to each side (its sweeps go 250 mm), far beyond the planner's 150 mm station cube.
DEFAULT_BOX_HALF_MM = 500.0
#: Radius of the cylinder about the base axis the TCP and flange keep out of, mm: the largest
#: UR base (190 mm across: UR10, UR10e, UR16e) plus 55 mm for the tool's and marker's bodies.
BASE_CYLINDER_RADIUS_MM = 150.0
#: Height of that cylinder above the shoulder joint's axis (``d1``), mm: the shoulder's
#: housing (75 mm radius on the largest UR) and the same clearance.
BASE_CYLINDER_ABOVE_SHOULDER_MM = 130.0

# -- visibility ------------------------------------------------------------------------------
#: Smallest fraction of a recorded move's samples where the marker must be predicted visible.
#: The planners keep every recorded pose they chose visible; the samples between them, near a
#: sweep's end, may leave the predicted volume. Below half, the move records mostly nothing.
MIN_VISIBLE_FRACTION = 0.5

# -- speeds ---------------------------------------------------------------------------------
#: How much faster than the commanded limits a move's stated timing may be (relative). A plan
#: timed by spacecal states them exactly; one whose durations were written to a few digits, or
#: timed from poses within the continuity tolerance, states up to a fraction of a percent more.
#: The run's move deadline (1.5 times the planned duration plus 2 s) absorbs far more; a plan
#: 1% faster than commanded was timed for other limits.
SPEED_SLACK = 0.01
#: Relative rounding allowed against what the robot permits (none to speak of).
PERMIT_SLACK = 1e-9

#: Names of the checks, in the order the report lists them.
CHECKS = (
    "plan",
    "continuity",
    "speeds",
    "workspace",
    "reach",
    "joint limits",
    "singularities",
    "joint speeds",
    "visibility",
)


@dataclass(frozen=True)
class RobotPermits:
    """What the robot permits, whatever a plan or the command line asks.

    Attributes
    ----------
    tcp_speed_mm_s : float
        TCP linear speed (UR data sheets: typical TCP speed 1 m/s).
    tcp_accel_mm_s2 : float
        TCP linear acceleration (UR publishes none; the largest ``acquire`` accepts).
    tcp_angular_speed_rad_s : float
        TCP rotation speed (180 deg/s, a UR arm's fastest wrist).
    joint_speed_rad_s : numpy.ndarray, shape (J,)
        Each joint's largest speed (default: six joints at the slowest speed of any
        registered kind).
    """

    tcp_speed_mm_s: float = 1000.0
    tcp_accel_mm_s2: float = 10_000.0
    tcp_angular_speed_rad_s: float = math.pi
    joint_speed_rad_s: FloatArray = field(default_factory=lambda: _slowest_joint_speeds_rad_s(6))


def _slowest_joint_speeds_rad_s(joints: int) -> FloatArray:
    """``joints`` joint speeds (rad/s), each the slowest joint speed of any registered kind."""
    slowest = min(min(kind.joint_speed_deg_s) for kind in ROBOT_KINDS.values())
    return np.radians(np.full(joints, slowest))


def robot_permits(model_name: str, joints: int = 6) -> RobotPermits:
    """The permits of the robot kind ``model_name`` (its datasheet joint speeds); a name not
    registered gets, on each of its ``joints`` joints, the slowest speed of any kind."""
    kind = ROBOT_KINDS.get(model_name)
    if kind is None or kind.n_joints != joints:
        return RobotPermits(joint_speed_rad_s=_slowest_joint_speeds_rad_s(joints))
    return RobotPermits(joint_speed_rad_s=kind.joint_speed_rad_s)


class GateMove(Protocol):
    """What the gate reads of a move (:class:`~spacecal.planning.motion.TimedMove` and
    :class:`~spacecal.records.plan.PlannedMove` both have it)."""

    @property
    def label(self) -> str: ...
    @property
    def start(self) -> np.ndarray: ...
    @property
    def end(self) -> np.ndarray: ...
    @property
    def duration_s(self) -> float: ...
    @property
    def accel_time_s(self) -> float: ...
    @property
    def sample_period_s(self) -> float: ...


@dataclass(frozen=True)
class Workspace:
    """Where the TCP may go, in the robot base frame.

    Attributes
    ----------
    box_mm : numpy.ndarray, shape (6,)
        ``xmin, xmax, ymin, ymax, zmin, zmax`` the TCP stays in, mm.
    source : str
        Where the box came from (``--workspace-box``, the plan file, the default).
    base_radius_mm, base_height_mm : float
        The cylinder about the base axis (z from 0 to ``base_height_mm``) the TCP and flange
        keep out of; the base plane z = 0 they stay above.
    """

    box_mm: FloatArray
    source: str
    base_radius_mm: float = BASE_CYLINDER_RADIUS_MM
    base_height_mm: float = 0.0


def workspace_around(
    model: RobotModel,
    home_base_from_tcp: ArrayLike,
    box_mm: ArrayLike | None = None,
    source: str = "",
    half_mm: float = DEFAULT_BOX_HALF_MM,
) -> Workspace:
    """The workspace of a motion: ``box_mm`` when given, else a cube of half side ``half_mm``
    around the home TCP; the base cylinder from the model's shoulder height."""
    height = float(model.d_mm[0]) + BASE_CYLINDER_ABOVE_SHOULDER_MM
    if box_mm is not None:
        box = np.asarray(box_mm, dtype=float)
        if box.shape != (6,) or not np.all(np.isfinite(box)) or np.any(box[0::2] >= box[1::2]):
            raise InvalidInputError("a workspace box is xmin,xmax,ymin,ymax,zmin,zmax in mm, each min < max")
        return Workspace(box, source or "given", base_height_mm=height)
    centre = np.asarray(home_base_from_tcp, dtype=float)[:3, 3]
    box = np.column_stack([centre - half_mm, centre + half_mm]).ravel()
    return Workspace(box, f"default: {half_mm:.0f} mm around home", base_height_mm=height)


@dataclass(frozen=True)
class GateCheck:
    """One line of the report: a check, whether it passed, and what it covered.

    ``status`` is ``passed``, ``refused``, ``not checked`` (the gate stopped before it) or
    ``not known`` (nothing to check it with, e.g. visibility without a tracker pose).
    """

    name: str
    status: str
    summary: str

    def line(self) -> str:
        return (
            f"{self.name}: {self.status}: {self.summary}" if self.summary else f"{self.name}: {self.status}"
        )


@dataclass(frozen=True)
class GateRefusal:
    """The first failure in execution order.

    Attributes
    ----------
    move : int
        1-based index of the move in the plan; 0 for the plan as a whole.
    label : str
        The move's label ("" for the plan).
    check : str
        One of :data:`CHECKS`.
    detail : str
        What failed, where along the move, by how much.
    """

    move: int
    label: str
    check: str
    detail: str
    moves: int = 0

    def line(self) -> str:
        where = "" if self.move == 0 else f"move {self.move}/{self.moves} ({self.label}): "
        return f"motion refused, nothing moved: {where}{self.check}: {self.detail}"


@dataclass(frozen=True)
class MotionGateReport:
    """What the gate checked and what it found.

    Attributes
    ----------
    moves : int
        Moves in the plan (those checked: from ``first_move`` on).
    points : int
        Samples whose pose was checked (IK, limits, singularities, workspace).
    checks : tuple of GateCheck
        One per name in :data:`CHECKS`.
    refusal : GateRefusal or None
    stats : dict
        The numbers behind the summaries (closest approaches, largest speeds), plain values.
    """

    moves: int
    points: int
    checks: tuple[GateCheck, ...]
    refusal: GateRefusal | None = None
    stats: dict[str, Any] = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        return self.refusal is None

    def lines(self) -> list[str]:
        """The report as an operator reads it: a heading, then one line per check."""
        head = (
            f"motion gate: {self.points} points along {self.moves} moves checked "
            f"(every {POSITION_STEP_MM:g} mm and {math.degrees(ROTATION_STEP_RAD):g} deg)"
        )
        return [head] + ["  " + check.line() for check in self.checks]

    def summary(self) -> str:
        """One line: the verdict and what it covered."""
        if self.refusal is not None:
            return self.refusal.line()
        unknown = [c.name for c in self.checks if c.status == "not known"]
        return (
            f"motion gate: passed: {self.points} points along {self.moves} moves checked for "
            + ", ".join(c.name for c in self.checks if c.status == "passed")
            + (f" ({', '.join(unknown)}: not known)" if unknown else "")
        )

    def check(self, name: str) -> GateCheck:
        return next(c for c in self.checks if c.name == name)

    def to_dict(self) -> dict[str, Any]:
        return {
            "passed": self.passed,
            "moves": self.moves,
            "points": self.points,
            "checks": [{"name": c.name, "status": c.status, "summary": c.summary} for c in self.checks],
            "refusal": None if self.refusal is None else self.refusal.line(),
            "stats": self.stats,
        }

    def raise_if_refused(self) -> None:
        """Raise :class:`MotionRefusedError` (one line) when the gate refused the motion."""
        if self.refusal is not None:
            raise MotionRefusedError(self)


class MotionRefusedError(InvalidInputError):
    """The motion gate refused a motion; ``report`` holds what it checked."""

    def __init__(self, report: MotionGateReport):
        assert report.refusal is not None
        super().__init__(report.refusal.line())
        self.report = report


# -- following a line -----------------------------------------------------------------------
#: A line is followed when every position error is below this (mm) and every rotation error
#: below 1e-3 of it (rad).
IK_TOL_MM = 1e-6


def _rotation_between(a: FloatArray, b: FloatArray) -> float:
    return float(np.linalg.norm(matrix_to_rotvec(a[:3, :3].T @ b[:3, :3])))


def _sample_count(start: FloatArray, end: FloatArray) -> int:
    """Samples of the straight move from ``start`` to ``end``, both ends included."""
    distance = float(np.linalg.norm(end[:3, 3] - start[:3, 3]))
    angle = _rotation_between(start, end)
    intervals = max(math.ceil(distance / POSITION_STEP_MM), math.ceil(angle / ROTATION_STEP_RAD), 1)
    return intervals + 1


def singularity_distances(
    model: RobotModel, joints_rad: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Distances of configurations (N, 6) from the UR's three singularities.

    The Jacobian determinant of a UR arm factors as
    ``a2 a3 sin(q3) sin(q5) (a2 cos q2 + a3 cos(q2+q3) + d5 sin(q2+q3+q4))`` (with the joint
    offsets added to q; a tool offset does not change it), so each factor measures one.

    Returns
    -------
    wrist_rad, elbow_rad : numpy.ndarray, shape (N,)
        Angle of joint 5 (wrist) and joint 3 (elbow) from 0 or 180 degrees.
    shoulder_mm : numpy.ndarray, shape (N,)
        ``|a2 cos q2 + a3 cos(q2+q3) + d5 sin(q2+q3+q4)|``: how far the wrist is from the
        position where joint 1 cannot move it sideways, mm.
    """
    theta = np.atleast_2d(np.asarray(joints_rad, dtype=float)) + model.theta_offset_rad
    wrist = np.abs(np.mod(theta[:, 4] + np.pi / 2, np.pi) - np.pi / 2)
    elbow = np.abs(np.mod(theta[:, 2] + np.pi / 2, np.pi) - np.pi / 2)
    a2, a3, d5 = model.a_mm[1], model.a_mm[2], model.d_mm[4]
    q2, q23 = theta[:, 1], theta[:, 1] + theta[:, 2]
    shoulder = np.abs(a2 * np.cos(q2) + a3 * np.cos(q23) + d5 * np.sin(q23 + theta[:, 3]))
    return wrist, elbow, shoulder


def max_reach_mm(model: RobotModel) -> float:
    """An upper bound on the TCP's distance from the shoulder (joint 2 at height ``d1``), mm:
    every link length and offset after it, and the tool, laid end to end."""
    tool = float(np.linalg.norm(model.flange_from_tcp[:3, 3]))
    return float(np.sum(np.abs(model.a_mm)) + np.sum(np.abs(model.d_mm[1:])) + tool)


# -- the gate -----------------------------------------------------------------------------------
class _Refused(Exception):
    def __init__(self, move: int, label: str, check: str, detail: str):
        super().__init__(detail)
        self.refusal = (move, label, check, detail)


#: A failure found along a move: sample index, check name, what failed.
_Failure = tuple[int, str, str]


@dataclass
class _Tally:
    """What the checks covered so far (the report's summaries and stats)."""

    points: int = 0
    moves_checked: int = 0
    largest_gap_mm: float = 0.0
    largest_gap_rad: float = 0.0
    first_gap_mm: float = 0.0
    first_gap_rad: float = 0.0
    stated_speed_mm_s: float = 0.0
    stated_accel_mm_s2: float = 0.0
    stated_angular_rad_s: float = 0.0
    joint_low_rad: float = 0.0
    joint_high_rad: float = 0.0
    wrist_rad: float = math.inf
    elbow_rad: float = math.inf
    shoulder_mm: float = math.inf
    joint_speed_fraction: float = 0.0
    largest_step_rad: float = 0.0
    lowest_z_mm: float = math.inf
    nearest_axis_mm: float = math.inf
    recorded_points: int = 0
    visible_points: int = 0
    worst_visible_fraction: float = 1.0


def _where(k: int, count: int) -> str:
    if k == 0:
        return "at its start"
    return "at its end" if k == count - 1 else f"at {100 * k / (count - 1):.0f}% of it"


def _xyz(p: FloatArray) -> str:
    return "({:.0f}, {:.0f}, {:.0f}) mm".format(*p)


def _deg_range(low: float, high: float) -> str:
    return f"{np.degrees(low):.0f}..{np.degrees(high):.0f} deg"


def gate_motion(
    model: RobotModel,
    moves: Sequence[GateMove],
    start_joints_rad: ArrayLike,
    commanded: MotionLimits,
    workspace: Workspace,
    *,
    start_base_from_tcp: ArrayLike | None = None,
    home_base_from_tcp: ArrayLike | None = None,
    visibility: VisibilityModel | None = None,
    visibility_note: str = "no tracker pose known",
    permits: RobotPermits | None = None,
    first_move: int = 0,
    commanded_by: str = "",
) -> MotionGateReport:
    """Check a motion before anything moves: every move, all along the path it will take.

    Pure: the model, the moves and where the arm stands in, a report out; nothing is moved
    and no device is asked.

    Parameters
    ----------
    model : RobotModel
        The controller's kinematic model (what the acquisition plans and records with), with
        its TCP.
    moves : sequence of GateMove
        In execution order (a plan's moves).
    start_joints_rad : array_like, shape (6,)
        Where the robot stands now.
    commanded : MotionLimits
        The TCP limits the run commands (``--speed-mm-s`` ...; a scenario's in simulation).
    workspace : Workspace
    start_base_from_tcp : array_like, shape (4, 4), optional
        The TCP where the controller reports it, mm; default the model's at the start joints.
    home_base_from_tcp : array_like, shape (4, 4), optional
        The plan's home: the first move must start there too.
    visibility : VisibilityModel, optional
        Predicts where the tracker sees the marker; None: visibility is "not known" (why:
        ``visibility_note``).
    permits : RobotPermits, optional
        Default: :func:`robot_permits` of the model's name.
    first_move : int
        Resume: the moves before it are done; the arm goes in a straight line from where it
        stands to this move's start first (checked as the move "approach").
    commanded_by : str
        Where the commanded limits come from (named in a refusal, e.g. the options to change).

    Returns
    -------
    MotionGateReport
        ``refusal`` is the first failure in execution order (None: every check passed).
    """
    permits = permits or robot_permits(model.name, model.n_joints)
    tally = _Tally()
    count = len(moves)
    joints = np.asarray(start_joints_rad, dtype=float)
    pose = (
        forward_kinematics(model, joints)
        if start_base_from_tcp is None
        else np.asarray(start_base_from_tcp, dtype=float)
    )
    refusal = None
    try:
        _check_plan(model, moves, joints, pose, commanded, permits, first_move)
        steps: list[tuple[int, GateMove | None]] = [(k, moves[k]) for k in range(first_move, count)]
        if first_move > 0:
            steps.insert(0, (first_move, None))  # the straight approach to the interrupted move
        for index, move in steps:
            if move is None:
                label, target = "approach", np.asarray(moves[index].start, dtype=float)
            else:
                label, target = move.label, np.asarray(move.end, dtype=float)
                first = index == 0
                _check_continuity(index + 1, move, pose, tally, first, home_base_from_tcp)
                _check_speeds(index + 1, move, commanded, tally, commanded_by)
            failures, joints = _check_line(
                model, pose, target, joints, move, commanded, permits, workspace, visibility, tally
            )
            if failures:
                k, check, detail = min(failures, key=lambda f: (f[0], CHECKS.index(f[1])))
                raise _Refused(index + 1, label, check, detail)
            pose = target
            tally.moves_checked += 1
    except _Refused as stop:
        refusal = GateRefusal(*stop.refusal, moves=count)
    return MotionGateReport(
        moves=max(count - first_move, 0),
        points=tally.points,
        checks=_summaries(tally, refusal, workspace, visibility, visibility_note, commanded, permits, model),
        refusal=refusal,
        stats=_stats(tally),
    )


def _check_plan(
    model: RobotModel,
    moves: Sequence[GateMove],
    joints: FloatArray,
    pose: FloatArray,
    commanded: MotionLimits,
    permits: RobotPermits,
    first_move: int,
) -> None:
    """The checks of the plan as a whole: size, numbers, commanded limits, where the arm stands."""
    count = len(moves)
    if count == 0:
        raise _Refused(0, "", "plan", "it holds no moves")
    if count > MAX_MOVES:
        raise _Refused(
            MAX_MOVES + 1,
            moves[MAX_MOVES].label,
            "plan",
            f"{count} moves is more than any calibration motion needs (at most {MAX_MOVES})",
        )
    if not 0 <= first_move < count:
        raise _Refused(0, "", "plan", f"nothing left to run from move {first_move + 1} of {count}")
    for k, move in enumerate(moves):
        timing = (move.duration_s, move.accel_time_s, move.sample_period_s)
        if not (
            np.all(np.isfinite(np.asarray(move.start, dtype=float)))
            and np.all(np.isfinite(np.asarray(move.end, dtype=float)))
            and all(isinstance(v, (int, float)) and math.isfinite(v) for v in timing)
        ):
            raise _Refused(k + 1, move.label, "plan", "NaN or infinite values in its poses or timing")
        if not 0 <= move.accel_time_s <= move.duration_s / 2 + 1e-9 or move.sample_period_s < 0:
            raise _Refused(
                k + 1,
                move.label,
                "plan",
                "needs 0 <= accel_time_s <= duration_s/2 and sample_period_s >= 0",
            )
    # the size of the check, before any of it: every move's samples (as stated)
    starts = np.array([np.asarray(m.start, dtype=float) for m in moves[first_move:]])
    ends = np.array([np.asarray(m.end, dtype=float) for m in moves[first_move:]])
    relative = np.swapaxes(starts[:, :3, :3], 1, 2) @ ends[:, :3, :3]
    angle = np.linalg.norm(np.atleast_2d(matrix_to_rotvec(relative)), axis=1)
    distance = np.linalg.norm(ends[:, :3, 3] - starts[:, :3, 3], axis=1)
    samples = np.maximum(np.ceil(distance / POSITION_STEP_MM), np.ceil(angle / ROTATION_STEP_RAD)) + 2
    over = np.cumsum(samples) > MAX_POINTS
    if over.any():
        k = first_move + int(np.argmax(over))
        raise _Refused(
            k + 1,
            moves[k].label,
            "plan",
            f"the motion up to this move needs more than {MAX_POINTS} check points (every "
            f"{POSITION_STEP_MM:g} mm and {math.degrees(ROTATION_STEP_RAD):g} deg): longer than any "
            "calibration motion",
        )
    if not (np.all(np.isfinite(joints)) and np.all(np.isfinite(pose))):
        raise _Refused(0, "", "plan", "the robot's current joints or TCP pose are not finite")
    to_deg = 180 / np.pi
    for name, value, allowed, unit, scale in (
        ("TCP speed", commanded.linear_speed_mm_s, permits.tcp_speed_mm_s, "mm/s", 1.0),
        ("TCP acceleration", commanded.linear_accel_mm_s2, permits.tcp_accel_mm_s2, "mm/s^2", 1.0),
        (
            "TCP rotation speed",
            commanded.angular_speed_rad_s,
            permits.tcp_angular_speed_rad_s,
            "deg/s",
            to_deg,
        ),
    ):
        if not (math.isfinite(value) and 0 < value <= allowed * (1 + PERMIT_SLACK)):
            raise _Refused(
                0,
                "",
                "speeds",
                f"the commanded {name} {value * scale:g} {unit} is not within what the robot permits "
                f"(0..{allowed * scale:g} {unit})",
            )
    outside = (joints < model.joint_lower_rad) | (joints > model.joint_upper_rad)
    if outside.any():
        j = int(np.argmax(outside))
        limits = _deg_range(model.joint_lower_rad[j], model.joint_upper_rad[j])
        raise _Refused(
            0,
            "",
            "joint limits",
            f"the robot stands with joint {j + 1} at {np.degrees(joints[j]):.1f} deg, outside {limits}",
        )


def _gap(a: ArrayLike, b: ArrayLike) -> tuple[float, float]:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return float(np.linalg.norm(a[:3, 3] - b[:3, 3])), _rotation_between(a, b)


def _check_continuity(
    number: int, move: GateMove, pose: FloatArray, tally: _Tally, first: bool, home: ArrayLike | None
) -> None:
    """The move starts where the arm is (and the first one at the plan's home)."""
    references = [(pose, "where the robot stands" if first else "where the previous move ended")]
    if first and home is not None:
        references.append((np.asarray(home, dtype=float), "the plan's home"))
    for reference, what in references:
        gap_mm, gap_rad = _gap(move.start, reference)
        if first:
            tally.first_gap_mm = max(tally.first_gap_mm, gap_mm)
            tally.first_gap_rad = max(tally.first_gap_rad, gap_rad)
        else:
            tally.largest_gap_mm = max(tally.largest_gap_mm, gap_mm)
            tally.largest_gap_rad = max(tally.largest_gap_rad, gap_rad)
        if gap_mm > CONTINUITY_MM or gap_rad > CONTINUITY_RAD:
            raise _Refused(
                number,
                move.label,
                "continuity",
                f"it starts {gap_mm:.1f} mm and {np.degrees(gap_rad):.2f} deg from {what} (tolerance "
                f"{CONTINUITY_MM:g} mm, {np.degrees(CONTINUITY_RAD):.2f} deg): the arm would take a path "
                "nobody planned",
            )


def _is_hold(move: GateMove) -> bool:
    return move.duration_s > 0 and bool(np.allclose(move.start, move.end, atol=1e-9))


def _stated_profile(move: GateMove) -> tuple[float, float, float, float]:
    """Peak linear speed (mm/s) and acceleration (mm/s^2), angular speed (rad/s) and
    acceleration (rad/s^2) of a move's stated trapezoid; inf where its timing leaves no time."""
    distance, angle = _gap(move.end, move.start)
    cruise = move.duration_s - move.accel_time_s

    def peak(amount: float) -> tuple[float, float]:
        if amount <= 0:
            return 0.0, 0.0
        if cruise <= 0:
            return math.inf, math.inf
        speed = amount / cruise
        return speed, (speed / move.accel_time_s if move.accel_time_s > 0 else math.inf)

    return (*peak(distance), *peak(angle))


def _check_speeds(
    number: int, move: GateMove, commanded: MotionLimits, tally: _Tally, commanded_by: str
) -> None:
    """The speeds the move's timing states are within the commanded ones (which the plan-wide
    check holds within what the robot permits)."""
    if _is_hold(move):
        return  # the arm rests
    speed, accel, angular, angular_accel = _stated_profile(move)
    tally.stated_speed_mm_s = max(tally.stated_speed_mm_s, speed)
    tally.stated_accel_mm_s2 = max(tally.stated_accel_mm_s2, accel)
    tally.stated_angular_rad_s = max(tally.stated_angular_rad_s, angular)
    to_deg = 180 / np.pi
    for name, value, limit, unit, scale in (
        ("TCP speed", speed, commanded.linear_speed_mm_s, "mm/s", 1.0),
        ("TCP acceleration", accel, commanded.linear_accel_mm_s2, "mm/s^2", 1.0),
        ("TCP rotation speed", angular, commanded.angular_speed_rad_s, "deg/s", to_deg),
        ("TCP rotation acceleration", angular_accel, commanded.angular_accel_rad_s2, "deg/s^2", to_deg),
    ):
        if value > limit * (1 + SPEED_SLACK):
            needs = "an instantaneous step" if math.isinf(value) else f"{value * scale:.4g} {unit}"
            by = f" ({commanded_by})" if commanded_by else ""
            raise _Refused(
                number,
                move.label,
                "speeds",
                f"its timing needs a {name} of {needs}, above the commanded {limit * scale:.4g} {unit}{by}: "
                "the run would miss the move's deadline and stop part-way",
            )


def _check_line(
    model: RobotModel,
    start: FloatArray,
    end: FloatArray,
    joints_start: FloatArray,
    move: GateMove | None,
    commanded: MotionLimits,
    permits: RobotPermits,
    workspace: Workspace,
    visibility: VisibilityModel | None,
    tally: _Tally,
) -> tuple[list[_Failure], FloatArray]:
    """Check the straight move the arm takes from ``start`` (where it is) to ``end``: the
    failures found along it and the joints at its end."""
    count = _sample_count(start, end)
    poses = np.asarray(interpolate_transforms(start, end, np.linspace(0.0, 1.0, count)), dtype=float)
    poses = poses.reshape(-1, 4, 4)
    failures = _workspace_failures(model, poses, workspace, tally)
    # IK only up to the first workspace failure: the arm never gets further
    limit = min((k for k, _, _ in failures), default=count - 1) + 1
    reach, joints, solved = _reach(model, poses[:limit], joints_start, count)
    failures += reach
    tally.points += solved
    if solved > 0:
        failures += _joint_failures(
            model, joints[:solved], start, end, move, commanded, permits, tally, count
        )
    if failures:
        return failures, joints_start
    if visibility is not None and move is not None and move.sample_period_s > 0:
        failures += _visibility_failures(poses, visibility, tally)
    return failures, joints[-1]


def _workspace_failures(
    model: RobotModel, poses: FloatArray, workspace: Workspace, tally: _Tally
) -> list[_Failure]:
    """The box (TCP), the base plane and the base cylinder (TCP and flange)."""
    count = len(poses)
    tcp = poses[:, :3, 3]
    points = np.stack([tcp, (poses @ invert_transform(model.flange_from_tcp))[:, :3, 3]], axis=1)
    radius = np.hypot(points[..., 0], points[..., 1])
    tally.lowest_z_mm = min(tally.lowest_z_mm, float(points[..., 2].min()))
    tally.nearest_axis_mm = min(tally.nearest_axis_mm, float(radius.min()))
    box = workspace.box_mm.reshape(3, 2)
    below = np.any(points[..., 2] < 0.0, axis=1)
    inside = np.any((radius < workspace.base_radius_mm) & (points[..., 2] < workspace.base_height_mm), axis=1)
    outside = np.any((tcp < box[:, 0]) | (tcp > box[:, 1]), axis=1)
    failures: list[_Failure] = []
    if below.any():
        k = int(np.argmax(below))
        which = "TCP" if points[k, 0, 2] < 0 else "flange"
        failures.append(
            (
                k,
                "workspace",
                f"the {which} goes below the base plane {_where(k, count)} (down to z = "
                f"{points[..., 2].min():.0f} mm)",
            )
        )
    if inside.any():
        k = int(np.argmax(inside))
        failures.append(
            (
                k,
                "workspace",
                f"the TCP or flange enters the base cylinder ({radius[k].min():.0f} mm from the "
                f"base axis, keep-out radius {workspace.base_radius_mm:.0f} mm) {_where(k, count)}",
            )
        )
    if outside.any():
        k = int(np.argmax(outside))
        failures.append(
            (
                k,
                "workspace",
                f"the TCP leaves the workspace box ({workspace.source}) at {_xyz(tcp[k])} {_where(k, count)}",
            )
        )
    return failures


def _reach(
    model: RobotModel, poses: FloatArray, joints_start: FloatArray, count: int
) -> tuple[list[_Failure], FloatArray, int]:
    """IK all along on one branch (a distance bound first: no IK reaches past it)."""
    shoulder = np.array([0.0, 0.0, model.d_mm[0]])
    distance = np.linalg.norm(poses[:, :3, 3] - shoulder, axis=1)
    far = distance > max_reach_mm(model)
    failures: list[_Failure] = []
    limit = len(poses)
    if far.any():
        k = int(np.argmax(far))
        failures.append(
            (
                k,
                "reach",
                f"the TCP at {_xyz(poses[k, :3, 3])} is {distance[k]:.0f} mm from the shoulder, beyond "
                f"the {model.name}'s reach ({max_reach_mm(model):.0f} mm with this tool) {_where(k, count)}",
            )
        )
        limit = k
    joints = np.full((limit, 6), np.nan)
    solved = 0
    if limit > 0:
        joints, solved = follow_path(model, poses[:limit], joints_start, IK_TOL_MM)
        if solved < limit:
            failures.append(
                (
                    solved,
                    "reach",
                    f"no inverse kinematics on the arm's branch at {_xyz(poses[solved, :3, 3])} "
                    f"{_where(solved, count)} (out of reach, or through a singularity)",
                )
            )
    return failures, joints, solved


def _joint_failures(
    model: RobotModel,
    joints: FloatArray,
    start: FloatArray,
    end: FloatArray,
    move: GateMove | None,
    commanded: MotionLimits,
    permits: RobotPermits,
    tally: _Tally,
    count: int,
) -> list[_Failure]:
    """Joint limits, singularities, branch flips and joint speeds along a followed line."""
    failures: list[_Failure] = []
    low, high = joints < model.joint_lower_rad, joints > model.joint_upper_rad
    tally.joint_low_rad = min(tally.joint_low_rad, float(joints.min()))
    tally.joint_high_rad = max(tally.joint_high_rad, float(joints.max()))
    bad = np.any(low | high, axis=1)
    if bad.any():
        k = int(np.argmax(bad))
        j = int(np.argmax(low[k] | high[k]))
        limits = _deg_range(model.joint_lower_rad[j], model.joint_upper_rad[j])
        failures.append(
            (
                k,
                "joint limits",
                f"joint {j + 1} reaches {np.degrees(joints[k, j]):.1f} deg, outside {limits}, "
                f"{_where(k, count)}",
            )
        )
    wrist, elbow, shoulder = singularity_distances(model, joints)
    tally.wrist_rad = min(tally.wrist_rad, float(wrist.min()))
    tally.elbow_rad = min(tally.elbow_rad, float(elbow.min()))
    tally.shoulder_mm = min(tally.shoulder_mm, float(shoulder.min()))
    for values, margin, name, what, unit in (
        (np.degrees(wrist), np.degrees(WRIST_MARGIN_RAD), "wrist", "joint 5 is {:.1f} deg from 0/180", "deg"),
        (np.degrees(elbow), np.degrees(ELBOW_MARGIN_RAD), "elbow", "joint 3 is {:.1f} deg from 0/180", "deg"),
        (shoulder, SHOULDER_MARGIN_MM, "shoulder", "the wrist is {:.0f} mm from the base axis", "mm"),
    ):
        near = values < margin
        if near.any():
            k = int(np.argmax(near))
            failures.append(
                (
                    k,
                    "singularities",
                    f"{what.format(values[k])} {_where(k, count)}: near the {name} "
                    f"singularity (margin {margin:.0f} {unit})",
                )
            )
    if len(joints) < 2:
        return failures
    steps = np.abs(np.diff(joints, axis=0))  # (M-1, 6)
    tally.largest_step_rad = max(tally.largest_step_rad, float(steps.max()))
    flips = np.any(steps > FLIP_RAD, axis=1)
    if flips.any():
        k = int(np.argmax(flips))
        j = int(np.argmax(steps[k]))
        failures.append(
            (
                k + 1,
                "joint speeds",
                f"joint {j + 1} turns {np.degrees(steps[k, j]):.0f} deg between two samples "
                f"{_where(k + 1, count)}: the IK branch flips (through a singularity)",
            )
        )
    speeds = steps * (count - 1) * _peak_path_rate(start, end, commanded, move)  # |dq/ds| ds/dt
    fraction = speeds / permits.joint_speed_rad_s
    tally.joint_speed_fraction = max(tally.joint_speed_fraction, float(fraction.max()))
    fast = np.any(fraction > 1.0 + PERMIT_SLACK, axis=1)
    if fast.any():
        k = int(np.argmax(fast))
        j = int(np.argmax(fraction[k]))
        failures.append(
            (
                k + 1,
                "joint speeds",
                f"joint {j + 1} would turn at {np.degrees(speeds[k, j]):.0f} deg/s {_where(k + 1, count)}, "
                f"above the {model.name}'s {np.degrees(permits.joint_speed_rad_s[j]):.0f} deg/s",
            )
        )
    return failures


def _peak_path_rate(
    start: FloatArray, end: FloatArray, commanded: MotionLimits, move: GateMove | None
) -> float:
    """Largest ds/dt (1/s) of a move as it runs: a controller runs a ``movel`` at the commanded
    limits, whatever the plan's timing; at the stated timing where that is faster."""
    distance, angle = _gap(end, start)
    duration, accel_time = max(
        trapezoid_duration(distance, commanded.linear_speed_mm_s, commanded.linear_accel_mm_s2),
        trapezoid_duration(angle, commanded.angular_speed_rad_s, commanded.angular_accel_rad_s2),
    )
    rate = 1.0 / (duration - accel_time) if duration > accel_time else 0.0
    if move is not None and move.duration_s > move.accel_time_s:
        rate = max(rate, 1.0 / (move.duration_s - move.accel_time_s))
    return rate


def _visibility_failures(poses: FloatArray, visibility: VisibilityModel, tally: _Tally) -> list[_Failure]:
    """A recorded move must be predicted visible on most of its samples."""
    seen = np.asarray(visibility.visible(poses), dtype=bool)
    tally.recorded_points += len(seen)
    tally.visible_points += int(seen.sum())
    fraction = float(seen.mean())
    tally.worst_visible_fraction = min(tally.worst_visible_fraction, fraction)
    if fraction >= MIN_VISIBLE_FRACTION:
        return []
    first_unseen = int(np.argmin(seen))
    return [
        (
            first_unseen,
            "visibility",
            f"the marker is predicted visible at only {100 * fraction:.0f}% of this "
            f"recorded move (need {100 * MIN_VISIBLE_FRACTION:.0f}%)",
        )
    ]


def _summaries(
    tally: _Tally,
    refusal: GateRefusal | None,
    workspace: Workspace,
    visibility: VisibilityModel | None,
    visibility_note: str,
    commanded: MotionLimits,
    permits: RobotPermits,
    model: RobotModel,
) -> tuple[GateCheck, ...]:
    deg = math.degrees
    moves = tally.moves_checked
    box = ", ".join(f"{v:.0f}" for v in workspace.box_mm)
    text = {
        "plan": f"{moves} moves in order; the commanded limits within what the {model.name} permits",
        "continuity": (
            f"each move starts where the last ended (largest gap {tally.largest_gap_mm:.3f} mm, "
            f"{deg(tally.largest_gap_rad):.3f} deg), the first {tally.first_gap_mm:.2f} mm and "
            f"{deg(tally.first_gap_rad):.3f} deg from where the robot stands and the plan's home "
            f"(tolerance {CONTINUITY_MM:g} mm, {deg(CONTINUITY_RAD):.2f} deg)"
        ),
        "speeds": (
            f"planned TCP up to {tally.stated_speed_mm_s:.0f} mm/s, {tally.stated_accel_mm_s2:.0f} mm/s^2, "
            f"{deg(tally.stated_angular_rad_s):.1f} deg/s; commanded {commanded.linear_speed_mm_s:g} mm/s, "
            f"{commanded.linear_accel_mm_s2:g} mm/s^2, {deg(commanded.angular_speed_rad_s):.1f} deg/s; the "
            f"robot permits {permits.tcp_speed_mm_s:g} mm/s"
        ),
        "workspace": (
            f"{tally.points} TCP points in the box [{box}] mm ({workspace.source}); TCP and flange at "
            f"least {tally.lowest_z_mm:.0f} mm above the base plane and {tally.nearest_axis_mm:.0f} mm "
            f"from the base axis (keep-out cylinder {workspace.base_radius_mm:.0f} mm to z = "
            f"{workspace.base_height_mm:.0f} mm)"
        ),
        "reach": f"{tally.points} points along {moves} moves solved by the {model.name}'s IK on one branch",
        "joint limits": (
            f"joints within {deg(tally.joint_low_rad):.0f}..{deg(tally.joint_high_rad):.0f} deg (limits "
            f"{_deg_range(float(model.joint_lower_rad.min()), float(model.joint_upper_rad.max()))})"
        ),
        "singularities": (
            f"closest: wrist {deg(tally.wrist_rad):.1f} deg, elbow {deg(tally.elbow_rad):.1f} deg, "
            f"shoulder {tally.shoulder_mm:.0f} mm (margins {deg(WRIST_MARGIN_RAD):.0f} deg, "
            f"{deg(ELBOW_MARGIN_RAD):.0f} deg, {SHOULDER_MARGIN_MM:.0f} mm)"
        ),
        "joint speeds": (
            f"largest joint step between samples {deg(tally.largest_step_rad):.2f} deg (a flip: "
            f"{deg(FLIP_RAD):.0f} deg); at the commanded speeds up to "
            f"{100 * tally.joint_speed_fraction:.0f}% of the {model.name}'s joint speed limits"
        ),
        "visibility": (
            f"marker predicted visible at {tally.visible_points} of {tally.recorded_points} recorded "
            f"points (worst recorded move {100 * tally.worst_visible_fraction:.0f}%, need "
            f"{100 * MIN_VISIBLE_FRACTION:.0f}%)"
        ),
    }
    checks = []
    for name in CHECKS:
        if refusal is not None and name == refusal.check:
            checks.append(GateCheck(name, "refused", refusal.detail))
        elif name == "visibility" and visibility is None:
            checks.append(GateCheck(name, "not known", visibility_note))
        elif refusal is None:
            checks.append(GateCheck(name, "passed", text[name]))
        elif moves == 0:
            checks.append(GateCheck(name, "not checked", ""))
        else:
            checks.append(GateCheck(name, f"passed before move {refusal.move}", text[name]))
    return tuple(checks)


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def _stats(tally: _Tally) -> dict[str, Any]:
    return {
        "points": tally.points,
        "moves_checked": tally.moves_checked,
        "largest_gap_mm": tally.largest_gap_mm,
        "largest_gap_deg": math.degrees(tally.largest_gap_rad),
        "first_gap_mm": tally.first_gap_mm,
        "first_gap_deg": math.degrees(tally.first_gap_rad),
        "stated_speed_mm_s": _finite(tally.stated_speed_mm_s),
        "stated_angular_speed_deg_s": _finite(math.degrees(tally.stated_angular_rad_s)),
        "closest_wrist_deg": _finite(math.degrees(tally.wrist_rad)),
        "closest_elbow_deg": _finite(math.degrees(tally.elbow_rad)),
        "closest_shoulder_mm": _finite(tally.shoulder_mm),
        "largest_joint_step_deg": math.degrees(tally.largest_step_rad),
        "joint_speed_fraction": tally.joint_speed_fraction,
        "lowest_z_mm": _finite(tally.lowest_z_mm),
        "nearest_base_axis_mm": _finite(tally.nearest_axis_mm),
        "recorded_points": tally.recorded_points,
        "visible_points": tally.visible_points,
    }
