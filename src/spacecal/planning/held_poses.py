"""Plans of holds: from home, a transit to each target pose, a hold there while the tracker
takes its frames, and back home. The pre-operative check, the verification on the robot
(paper §5.2) and guidance each send the robot to poses this way."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.models.kinematics import RobotModel, forward_kinematics
from spacecal.planning.motion import MotionLimits, MotionPlan, TimedMove, time_move

#: Rest before a hold's frames count, s (the arm settles after the move).
SETTLE_S = 0.3


def hold_plan(
    model: RobotModel,
    home_joints_rad: np.ndarray,
    targets_base_from_tcp: np.ndarray,
    labels: Sequence[str],
    limits: MotionLimits,
    frame_period_s: float,
    frames_per_pose: int = 10,
    settle_s: float = SETTLE_S,
    via_home: bool = False,
    summary: dict | None = None,
) -> MotionPlan:
    """A plan that holds the TCP at each target for ``frames_per_pose`` frames.

    Parameters
    ----------
    model : RobotModel
        The controller's model: the targets are TCP poses in its base frame.
    home_joints_rad : numpy.ndarray, shape (6,)
        Where the robot stands; the plan starts and ends there.
    targets_base_from_tcp : numpy.ndarray, shape (N, 4, 4)
        ``base_from_tcp`` of each hold, mm.
    labels : sequence of str
        One per target, each its own: the segment label of its hold.
    limits : MotionLimits
        Commanded limits of the transits.
    frame_period_s : float
        Tracker frame period, s.
    frames_per_pose : int
    settle_s : float
        Rest before frames count, s.
    via_home : bool
        Return home between targets (the paper reaches each needle pose "from another place"),
        else go straight from one target to the next.
    summary : dict, optional
        The plan's summary entries (kept with its recordings).

    Returns
    -------
    MotionPlan
        Transits are labelled ``transit`` and not recorded; the joint angles each transit ends
        at are solved by IK near the previous ones (``time_move``).

    Raises
    ------
    InvalidInputError
        Targets and labels disagree in number, or labels repeat.
    UnreachableError
        A target has no IK solution near the path (the motion gate checks the plan again).
    """
    targets = np.asarray(targets_base_from_tcp, dtype=float).reshape(-1, 4, 4)
    if len(targets) != len(labels) or len(set(labels)) != len(labels):
        raise InvalidInputError(f"{len(targets)} hold poses need as many labels, each its own")
    home_joints = np.asarray(home_joints_rad, dtype=float)
    home = forward_kinematics(model, home_joints)
    moves: list[TimedMove] = []
    q, pose = home_joints, home
    hold_s = settle_s + frames_per_pose * frame_period_s
    for label, target in zip(labels, targets):
        if via_home and not np.allclose(pose, home, atol=1e-9):
            move, q = time_move(model, "transit", pose, home, q, limits, 0.0)
            moves.append(move)
            pose = home
        if not np.allclose(target, pose, atol=1e-9):
            move, q = time_move(model, "transit", pose, target, q, limits, 0.0)
            moves.append(move)
        moves.append(TimedMove(label, target, target, hold_s, 0.0, frame_period_s))
        pose = target
    if not np.allclose(pose, home, atol=1e-9):
        move, _ = time_move(model, "transit", pose, home, q, limits, 0.0)
        moves.append(move)
    return MotionPlan(home_joints, home, moves, dict(summary or {}), [])
