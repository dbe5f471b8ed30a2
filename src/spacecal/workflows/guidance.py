"""Needle guidance on the robot (paper §5.3): the needle poses of each stage along a planned
path, and the errors of a measured needle against the plan.

Every pose and point here is in the tracker frame (mm): the plan was brought there by the image
registration, and the needle is measured there. The needle frame has its origin at the tip and
its z axis along the needle, from entry to target (:func:`spacecal.planning.needle.needle_pose`).

Stages, with ``s`` the tip's planned place along the axis, measured from the entry towards the
target (mm)::

    standoff   s = -standoff_mm          the tip before the entry, on the axis
    insert     s = depth ("advance")     the tip at the target
               s = 0     ("hold")        the guide at the entry, for a manual insertion

Errors of a measured needle (tip ``p``, unit axis ``a``) at a stage with place ``s`` (the paper
§5.3 measures the needle's tip and its entry on a second CT; here the tracker measures the
needle, and the axis carries the measured tip to the entry's and the target's depth)::

    entry_error  = | p + (0 - s) a - entry |
    target_error = | p + (depth - s) a - target |
    direction    = angle(a, (target - entry) / depth)

For "advance" this is the tip against the target and the axis' crossing at the entry depth
against the entry; for "hold", the tip against the entry and the axis at the planned depth
against the target (as :mod:`spacecal.experiments.phantom` scores its cases).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spacecal.core.errors import DegenerateDataError, InvalidInputError
from spacecal.models.kinematics import RobotModel, forward_kinematics
from spacecal.planning.held_poses import SETTLE_S
from spacecal.planning.motion import MotionLimits, MotionPlan, TimedMove, time_move
from spacecal.planning.needle import needle_pose

#: The stages of a guidance, in order, and the insertion modes.
STAGES = ("standoff", "insert")
INSERTIONS = ("advance", "hold")
#: The robot stands at a plan's standoff when its needle is this close to it (mm, deg): the
#: robot's repeatability and the tracker's noise are tenths of a millimetre, a different plan or
#: a moved robot is millimetres away.
AT_STANDOFF_MM = 2.0
AT_STANDOFF_DEG = 2.0


@dataclass(frozen=True)
class NeedleAxis:
    """A planned path in the tracker frame.

    Attributes
    ----------
    entry, target : numpy.ndarray, shape (3,)
        mm, tracker frame.
    """

    entry: np.ndarray
    target: np.ndarray

    def __post_init__(self) -> None:
        if self.depth_mm < 1.0:
            raise DegenerateDataError("entry and target are less than 1 mm apart: no needle direction")

    @property
    def depth_mm(self) -> float:
        """The path's length, entry to target, mm."""
        return float(np.linalg.norm(np.asarray(self.target) - np.asarray(self.entry)))

    @property
    def direction(self) -> np.ndarray:
        """Unit vector (3,), entry to target."""
        return (np.asarray(self.target) - np.asarray(self.entry)) / self.depth_mm

    def point_at(self, s_mm: float) -> np.ndarray:
        """The point (3,) ``s_mm`` along the axis from the entry (negative: before it), mm."""
        return np.asarray(self.entry, dtype=float) + s_mm * self.direction


def stage_place_mm(stage: str, axis: NeedleAxis, insertion: str, standoff_mm: float) -> float:
    """Where the tip is planned along the axis at the end of ``stage``, mm from the entry."""
    if insertion not in INSERTIONS:
        raise InvalidInputError(f"insertion must be one of {', '.join(INSERTIONS)}, got {insertion!r}")
    if stage == "standoff":
        return -float(standoff_mm)
    if stage == "insert":
        return axis.depth_mm if insertion == "advance" else 0.0
    raise InvalidInputError(f"stage must be one of {', '.join(STAGES)}, got {stage!r}")


def stage_pose(
    stage: str, axis: NeedleAxis, insertion: str, standoff_mm: float, roll_reference: np.ndarray
) -> np.ndarray:
    """``tracker_from_needle`` (4, 4) planned at the end of ``stage``: the tip on the axis at
    :func:`stage_place_mm`, z along entry to target, the roll about the needle nearest
    ``roll_reference`` (3,) (the needle's x axis where it stands: the marker keeps facing the
    tracker as it did)."""
    tip = axis.point_at(stage_place_mm(stage, axis, insertion, standoff_mm))
    return needle_pose(tip, axis.direction, roll_reference)


@dataclass(frozen=True)
class NeedleErrors:
    """The errors of one measured needle against the plan (tracker frame).

    Attributes
    ----------
    tip_error_mm : float
        The measured tip against the stage's planned tip.
    entry_error_mm, target_error_mm : float
        The measured axis at the entry's and the target's depth against them (module docstring).
    direction_error_deg : float
        The measured axis against the planned one.
    """

    tip_error_mm: float
    entry_error_mm: float
    target_error_mm: float
    direction_error_deg: float


def needle_errors(
    measured_tracker_from_needle: np.ndarray, axis: NeedleAxis, place_mm: float
) -> NeedleErrors:
    """The errors of a needle measured at a stage whose tip is planned ``place_mm`` along the
    axis (:func:`stage_place_mm`); the definitions are the module docstring's (paper §5.3)."""
    measured = np.asarray(measured_tracker_from_needle, dtype=float)
    tip, along = measured[:3, 3], measured[:3, 2] / np.linalg.norm(measured[:3, 2])
    entry_seen = tip + (0.0 - place_mm) * along
    target_seen = tip + (axis.depth_mm - place_mm) * along
    cosine = float(np.clip(along @ axis.direction, -1.0, 1.0))
    return NeedleErrors(
        tip_error_mm=float(np.linalg.norm(tip - axis.point_at(place_mm))),
        entry_error_mm=float(np.linalg.norm(entry_seen - axis.entry)),
        target_error_mm=float(np.linalg.norm(target_seen - axis.target)),
        direction_error_deg=float(np.degrees(np.arccos(cosine))),
    )


def at_pose(
    measured: np.ndarray,
    planned: np.ndarray,
    tolerance_mm: float = AT_STANDOFF_MM,
    tolerance_deg: float = AT_STANDOFF_DEG,
) -> tuple[bool, float, float]:
    """Whether the needle ``measured`` (4, 4) stands at ``planned`` (4, 4): its tip within
    ``tolerance_mm`` and its axis within ``tolerance_deg`` (the roll about the needle is free).

    Returns
    -------
    at : bool
    distance_mm, angle_deg : float
    """
    distance = float(np.linalg.norm(measured[:3, 3] - planned[:3, 3]))
    cosine = float(np.clip(measured[:3, 2] @ planned[:3, 2], -1.0, 1.0))
    angle = float(np.degrees(np.arccos(cosine)))
    return distance <= tolerance_mm and angle <= tolerance_deg, distance, angle


def stage_plan(
    model: RobotModel,
    start_joints_rad: np.ndarray,
    targets_base_from_tcp: np.ndarray,
    stages: tuple[str, ...],
    limits: MotionLimits,
    frame_period_s: float,
    frames_per_pose: int,
) -> MotionPlan:
    """The motion of guidance stages: from where the robot stands a straight move to each
    stage's TCP pose (labelled ``to-<stage>``, not recorded: the standoff's is the approach,
    the insertion's runs along the needle's axis), then a hold there (labelled with the stage)
    while the tracker takes ``frames_per_pose`` frames. Unlike a check's plan it does not
    return: the robot stays at the last stage, as guidance needs it.

    Parameters
    ----------
    model : RobotModel
        The controller's model: the targets are TCP poses in its base frame.
    start_joints_rad : numpy.ndarray, shape (6,)
        Where the robot stands (the plan's home).
    targets_base_from_tcp : numpy.ndarray, shape (N, 4, 4)
        One per stage, mm.
    stages : tuple of str
    limits : MotionLimits
    frame_period_s : float
    frames_per_pose : int
    """
    targets = np.asarray(targets_base_from_tcp, dtype=float).reshape(-1, 4, 4)
    if len(targets) != len(stages):
        raise InvalidInputError(f"{len(targets)} stage poses for {len(stages)} stages")
    start = np.asarray(start_joints_rad, dtype=float)
    q, home = start, forward_kinematics(model, start)
    pose, moves = home, []
    for stage, target in zip(stages, targets):
        if not np.allclose(target, pose, atol=1e-9):
            move, q = time_move(model, f"to-{stage}", pose, target, q, limits, 0.0)
            moves.append(move)
        moves.append(
            TimedMove(stage, target, target, SETTLE_S + frames_per_pose * frame_period_s, 0.0, frame_period_s)
        )
        pose = target
    return MotionPlan(start, home, moves, {"guidance_stages": list(stages)}, [])


__all__ = [
    "AT_STANDOFF_DEG",
    "AT_STANDOFF_MM",
    "INSERTIONS",
    "STAGES",
    "NeedleAxis",
    "NeedleErrors",
    "at_pose",
    "needle_errors",
    "stage_place_mm",
    "stage_plan",
    "stage_pose",
]
