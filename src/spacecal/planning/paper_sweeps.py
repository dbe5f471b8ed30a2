"""The paper's calibration motion (§4): rotations about, and translations along, the TCP axes.

From a home pose the TCP rotates -90 ... +90 degrees about each of its own axes, keeping
its origin fixed (sampled every 100 ms), then translates 500 mm along each of its axes
(sampled every 50 ms). Every waypoint is checked for reachability, joint limits and
predicted marker visibility; a sweep that cannot be done in full is shrunk to the part
that can, and the plan says so.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from spacecal.core.errors import DegenerateDataError, UnreachableError
from spacecal.geometry.transforms import axis_angle_transform, make_transform
from spacecal.models.kinematics import RobotModel, forward_kinematics, within_joint_limits
from spacecal.planning.motion import MotionLimits, MotionPlan, TimedMove, time_move, track_path
from spacecal.planning.visibility import VisibilityModel

AXES = {"x": np.array([1.0, 0.0, 0.0]), "y": np.array([0.0, 1.0, 0.0]), "z": np.array([0.0, 0.0, 1.0])}


#: Largest rotation commanded in one straight move; larger sweeps pass through home.
MAX_SINGLE_ROTATION_DEG = 175.0


@dataclass(frozen=True)
class PaperSweepSettings:
    """Parameters of the paper's sweeps (defaults are the paper's values).

    These defaults, with those of :class:`~spacecal.planning.motion.MotionLimits`, are the
    one place the paper's sweep values are written; read them from here
    (``PaperSweepSettings().rotation_each_way_deg``) rather than repeating them.

    Attributes
    ----------
    rotation_each_way_deg : float
        Rotation to each side of home about each TCP axis (paper: 90, i.e. 180 in all).
    translation_stroke_mm : float
        Total stroke along each TCP axis, centred on home, so half of it to each side
        (paper: 500).
    rotation_sample_period_s, translation_sample_period_s : float
        Tracker sampling during the sweeps (paper: 0.1 and 0.05).
    limits : MotionLimits
    minimum_rotation_span_deg, minimum_translation_stroke_mm : float
        A sweep shrunk below these totals (both sides together) is refused: the estimator
        could not use it.
    """

    rotation_each_way_deg: float = 90.0
    translation_stroke_mm: float = 500.0
    rotation_sample_period_s: float = 0.1
    translation_sample_period_s: float = 0.05
    limits: MotionLimits = field(default_factory=MotionLimits)
    minimum_rotation_span_deg: float = 20.0
    minimum_translation_stroke_mm: float = 100.0


def _feasible_extent(model, home_joints, offsets, make_pose, visibility) -> tuple[float, str]:
    """Largest |offset| reachable continuously from home along ``offsets`` (0 first).

    Returns the extent and, if it falls short, what stopped it first.
    """
    poses = np.array([make_pose(o) for o in offsets])
    reached = np.zeros(len(poses), dtype=bool)
    in_limits = np.zeros(len(poses), dtype=bool)
    q = home_joints
    for k, pose in enumerate(poses):
        try:
            q = track_path(model, pose[None], q)[0]
        except UnreachableError:
            break
        reached[k] = True
        in_limits[k] = within_joint_limits(model, q[None])[0]
    seen = visibility.visible(poses) if visibility is not None else np.ones(len(poses), dtype=bool)
    checks = (("reach", reached), ("joint limits", in_limits), ("marker visibility", seen))
    ok = reached & in_limits & seen
    bad = np.flatnonzero(~ok)
    if len(bad) == 0:
        return float(abs(offsets[-1])), ""
    first = bad[0]
    reason = next(name for name, passed in checks if not passed[first])
    return (float(abs(offsets[first - 1])) if first > 0 else 0.0), reason


def _reasons(why: dict) -> str:
    parts = [f"{'+' if sign > 0 else '-'} side: {reason}" for sign, reason in why.items() if reason]
    return "; ".join(parts)


def plan_paper_sweeps(
    model: RobotModel,
    home_joints_rad,
    settings: PaperSweepSettings | None = None,
    visibility: VisibilityModel | None = None,
) -> MotionPlan:
    """Plan the paper's rotation and translation sweeps from a home configuration.

    Parameters
    ----------
    model : RobotModel
        The controller's kinematic model (with its TCP).
    home_joints_rad : array_like, shape (6,)
        Home configuration near the surgical site.
    settings : PaperSweepSettings, optional
    visibility : VisibilityModel, optional
        Predicts where the marker is seen; without it only reachability is checked.

    Returns
    -------
    MotionPlan

    Raises
    ------
    UnreachableError
        If the home pose itself is infeasible.
    DegenerateDataError
        If a sweep must shrink below the usable minimum.
    """
    settings = settings or PaperSweepSettings()
    home_joints = np.asarray(home_joints_rad, dtype=float)
    home = forward_kinematics(model, home_joints)
    if not within_joint_limits(model, home_joints[None])[0]:
        raise UnreachableError("the home configuration is outside the joint limits")
    if visibility is not None and not visibility.visible(home[None])[0]:
        raise UnreachableError("the marker is not visible to the tracker at the home pose")

    extents: dict = {}
    messages: list[str] = []
    moves: list[TimedMove] = []
    q = home_joints
    limits = settings.limits

    def add(label, start, end, period):
        nonlocal q
        move, q = time_move(model, label, start, end, q, limits, period)
        moves.append(move)

    def sweep_extent(label, requested, step, unit, minimum, make_pose):
        """Feasible [-lo, +hi] of a sweep about/along one axis, shrunk and reported as needed."""
        span, why = {}, {}
        for sign in (1, -1):
            offsets = sign * np.arange(0.0, requested + 1e-9, step)
            span[sign], why[sign] = _feasible_extent(model, home_joints, offsets, make_pose, visibility)
        hi, lo = span[1], span[-1]
        if min(hi, lo) < requested:
            messages.append(
                f"{label}: shrunk to -{lo:.0f}..+{hi:.0f} {unit} of the requested "
                f"+-{requested:.0f} {unit} ({_reasons(why)})"
            )
        if hi + lo < minimum:
            raise DegenerateDataError(
                f"{label}: only {hi + lo:.0f} {unit} of {'rotation' if unit == 'deg' else 'travel'} is "
                f"feasible from this home pose (need {minimum:.0f}); choose another home pose"
            )
        extents[label] = [-lo, hi]
        return lo, hi

    for name, axis in AXES.items():
        label = f"rot_{name}"
        lo, hi = sweep_extent(
            label,
            settings.rotation_each_way_deg,
            1.0,
            "deg",
            settings.minimum_rotation_span_deg,
            lambda a, axis=axis: home @ axis_angle_transform(axis, np.radians(a)),
        )
        plus = home @ axis_angle_transform(axis, np.radians(hi))
        minus = home @ axis_angle_transform(axis, -np.radians(lo))
        period = settings.rotation_sample_period_s
        add(label, home, plus, period)
        if hi + lo > MAX_SINGLE_ROTATION_DEG:
            # A straight move between orientations about 180 deg apart has no unique shortest
            # rotation: the controller may turn the tool the other way round. Pass home.
            add(label, plus, home, period)
            add(label, home, minus, period)
        else:
            add(label, plus, minus, period)
        add(label, minus, home, period)

    for name, axis in AXES.items():
        label = f"lin_{name}"
        lo, hi = sweep_extent(
            label,
            settings.translation_stroke_mm / 2.0,
            5.0,
            "mm",
            settings.minimum_translation_stroke_mm,
            lambda d, axis=axis: home @ make_transform(np.eye(3), d * axis),
        )
        start = home @ make_transform(np.eye(3), -lo * axis)
        end = home @ make_transform(np.eye(3), hi * axis)
        add("transit", home, start, 0.0)
        add(label, start, end, settings.translation_sample_period_s)
        add("transit", end, home, 0.0)

    return MotionPlan(home_joints, home, moves, extents, messages)
