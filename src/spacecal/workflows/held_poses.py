"""Holding the robot still at poses and keeping what the tracker saw there: the measuring step
of the pre-operative check, of the verification on the robot (paper §5.2) and of guidance.

A plan of holds (:func:`spacecal.planning.held_poses.hold_plan`) runs through the acquisition
loop (:func:`~spacecal.workflows.acquisition.run_plan`), so it has the same safety as a
calibration run: a safety stop, a lost tracker or a move past its deadline stops the robot and
ends the run with one line. The holds completed before a stop are kept in the error
(:class:`HoldsStopped`), so a caller can keep what was measured.

The further tools of each frame (:attr:`~spacecal.core.ports.TrackerFrame.tools`, e.g. a
reference tool on the needle guide) are kept with the marker's frames: the acquisition loop
hands its sink the marker only, so the tracker is read through :class:`_ToolKeepingTracker`,
which keeps the tools of the frame it last delivered.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spacecal.core.errors import DegenerateDataError, DeviceError, SpacecalError
from spacecal.core.ports import Robot, RobotState, Tracker, TrackerFrame
from spacecal.planning.motion import MotionPlan
from spacecal.workflows.acquisition import (
    AcquisitionResult,
    AcquisitionSettings,
    FrameObserver,
    RunFault,
    SampleCallback,
    run_plan,
)


class _ToolKeepingTracker:
    """A tracker read through (the acquisition loop only asks for frames): the further tools of
    the frame :meth:`next_frame` last delivered are kept (with its time, s) for the sink."""

    def __init__(self, tracker: Tracker) -> None:
        self._tracker = tracker
        self.last: TrackerFrame | None = None

    def next_frame(self, timeout_s: float) -> TrackerFrame:
        self.last = self._tracker.next_frame(timeout_s)
        return self.last


class _HoldSink:
    """Keeps the frames, the further tools' poses and the robot states of each hold."""

    def __init__(self, tracker: _ToolKeepingTracker) -> None:
        self.tracker = tracker
        self.frames: dict[str, list[np.ndarray]] = defaultdict(list)
        self.tools: dict[str, dict[str, list[np.ndarray]]] = defaultdict(lambda: defaultdict(list))
        self.states: dict[str, list[RobotState]] = defaultdict(list)

    def append(self, time_s, segment, joints_rad, base_from_tcp, tracker_from_marker=None, *_, **__) -> None:
        if tracker_from_marker is not None:
            self.frames[segment].append(np.asarray(tracker_from_marker, dtype=float))
        frame = self.tracker.last
        if frame is not None and frame.time_s == time_s:  # the frame this sample is of
            for name, pose in frame.tools.items():
                if pose is not None:
                    self.tools[segment][name].append(np.asarray(pose, dtype=float))

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


class HoldsStopped(DeviceError):
    """A run of holds stopped (a device fault, Ctrl-C, a stop request): the robot was stopped.

    Attributes
    ----------
    held : list of HeldPose
        The holds completed before the stop, in the plan's order (each with enough frames).
    total : int
        The holds the plan had.
    reason : str
        Why it stopped, in an operator's words.
    """

    def __init__(self, message: str, held: list[HeldPose], total: int, reason: str):
        super().__init__(message)
        self.held, self.total, self.reason = held, total, reason


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
    HoldsStopped
        On a device fault, Ctrl-C or a stop request (the robot was stopped); it carries the
        holds completed before it.
    """
    reading = _ToolKeepingTracker(tracker)
    sink = _HoldSink(reading)
    progress = AcquisitionResult(Path(what), 0, 0, 0, len(plan.moves))
    labels = list(dict.fromkeys(move.label for move in plan.moves if move.sample_period_s > 0))
    try:
        run_plan(plan, robot, reading, sink, settings, progress, on_sample=on_sample, observer=observer)
    except (RunFault, SpacecalError, KeyboardInterrupt) as exc:
        robot.stop()
        reason = _stop_reason(exc)
        # the holds whose every move completed before the stop, and had their frames
        done = {move.label for move in plan.moves[: progress.moves_completed] if move.sample_period_s > 0}
        done -= {move.label for move in plan.moves[progress.moves_completed :] if move.sample_period_s > 0}
        complete = [
            _held(sink, label)
            for label in labels
            if label in done and len(sink.frames.get(label, [])) >= max(3, frames_per_pose // 2)
        ]
        kept = [pose for pose in complete if pose is not None]
        raise HoldsStopped(
            f"{what} stopped: {reason}; the robot was stopped and nothing was logged",
            kept,
            len(labels),
            reason,
        ) from None
    held = []
    for label in labels:
        seen = sink.frames.get(label, [])
        pose = _held(sink, label) if len(seen) >= max(3, frames_per_pose // 2) else None
        if pose is None:
            raise DegenerateDataError(
                f"{what} {label}: the marker was seen in {len(seen)} frames; make sure the tracker sees it"
            )
        held.append(pose)
    return held


def _stop_reason(exc: BaseException) -> str:
    """Why a run of holds stopped, in an operator's words."""
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted by the user (Ctrl-C)"
    return str(exc)


def _held(sink: _HoldSink, label: str) -> HeldPose | None:
    """The hold ``label`` as the sink kept it, or None without a robot state."""
    states = sink.states.get(label, [])
    if not states:
        return None
    tools = {name: np.array(poses) for name, poses in sink.tools.get(label, {}).items()}
    return HeldPose(label, np.array(sink.frames.get(label, [])), states[-1], tools)
