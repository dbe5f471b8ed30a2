"""Holding the robot still at poses and keeping what the tracker saw there: the measuring step
of the pre-operative check, of the verification on the robot (paper §5.2) and of guidance.

A plan of holds (:func:`spacecal.planning.held_poses.hold_plan`) runs through the acquisition
loop (:func:`~spacecal.workflows.acquisition.run_plan`), so it has the same safety as a
calibration run: a safety stop, a lost tracker or a move past its deadline stops the robot and
ends the run with one line.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spacecal.core.errors import DegenerateDataError, DeviceError, SpacecalError
from spacecal.core.ports import Robot, RobotState, Tracker
from spacecal.planning.motion import MotionPlan
from spacecal.workflows.acquisition import (
    AcquisitionResult,
    AcquisitionSettings,
    FrameObserver,
    RunFault,
    SampleCallback,
    run_plan,
)


class _HoldSink:
    """Keeps the frames and robot states of each hold."""

    def __init__(self) -> None:
        self.frames: dict[str, list[np.ndarray]] = defaultdict(list)
        self.states: dict[str, list[RobotState]] = defaultdict(list)

    def append(self, time_s, segment, joints_rad, base_from_tcp, tracker_from_marker=None, *_, **__) -> None:
        if tracker_from_marker is not None:
            self.frames[segment].append(np.asarray(tracker_from_marker, dtype=float))

    def add_robot_states(self, states: list[RobotState], segment: str) -> None:
        self.states[segment].extend(states)


@dataclass(frozen=True)
class HeldPose:
    """What a hold gave: the frames the tracker saw and where the robot rested.

    Attributes
    ----------
    label : str
    tracker_from_marker_stack : numpy.ndarray, shape (F, 4, 4)
        The frames the marker was seen in, mm.
    at_rest : RobotState
        The robot's last state of the hold.
    tools : mapping of str to numpy.ndarray, shape (G, 4, 4)
        Further tools the tracker saw during the hold (``tracker_from_<tool>``, mm), by name.
    """

    label: str
    tracker_from_marker_stack: np.ndarray
    at_rest: RobotState
    tools: Mapping[str, np.ndarray] = field(default_factory=dict)


def hold_poses(
    robot: Robot,
    tracker: Tracker,
    plan: MotionPlan,
    settings: AcquisitionSettings,
    frames_per_pose: int = 10,
    on_sample: SampleCallback | None = None,
    what: str = "check",
    observer: FrameObserver | None = None,
) -> list[HeldPose]:
    """Run a plan of holds and keep the frames held at each; ``on_sample(samples, visible,
    move_index, label)`` follows it as it follows an acquisition.

    Parameters
    ----------
    robot, tracker
    plan : MotionPlan
        Holds are the moves with a sample period; transits are not recorded.
    settings : AcquisitionSettings
    frames_per_pose : int
        Frames each hold should give; fewer than half of them seen refuses it.
    on_sample : callable, optional
    what : str
        The run's name in its messages (``check``, ``verification``, ``guidance``).
    observer : FrameObserver, optional
        Called with every tracker frame, moving and holding (a live view).

    Raises
    ------
    DegenerateDataError
        When the marker was seen in fewer than half the frames at a hold.
    DeviceError
        On a device fault or Ctrl-C (the robot was stopped).
    """
    sink = _HoldSink()
    progress = AcquisitionResult(Path(what), 0, 0, 0, len(plan.moves))
    try:
        run_plan(plan, robot, tracker, sink, settings, progress, on_sample=on_sample, observer=observer)
    except (RunFault, SpacecalError, KeyboardInterrupt) as exc:
        robot.stop()
        reason = "interrupted by the user (Ctrl-C)" if isinstance(exc, KeyboardInterrupt) else str(exc)
        raise DeviceError(f"{what} stopped: {reason}; the robot was stopped and nothing was logged") from None
    held = []
    for label in dict.fromkeys(move.label for move in plan.moves if move.sample_period_s > 0):
        seen, states = sink.frames.get(label, []), sink.states.get(label, [])
        if len(seen) < max(3, frames_per_pose // 2) or not states:
            raise DegenerateDataError(
                f"{what} {label}: the marker was seen in {len(seen)} frames; make sure the tracker sees it"
            )
        held.append(HeldPose(label, np.array(seen), states[-1]))
    return held
