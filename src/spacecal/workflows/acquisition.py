"""Automatic acquisition (paper §4): run a motion plan on the robot while sampling the tracker.

Each sample is written and flushed to the recording as it arrives, so nothing recorded is
lost. A protective or emergency stop, a lost or stalled tracker, stale robot data, or
Ctrl-C stops the robot, keeps the file readable, records how far the plan got in a
progress file next to the recording, and raises with one line saying what happened; the
run can then be resumed where it stopped.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spacecal.core.ports import FRAME_OK, SAFETY_NORMAL, Robot, Tracker
from spacecal.core.errors import DeviceError, InvalidInputError, SpacecalError
from spacecal.io.recording_csv import RecordingWriter
from spacecal.planning.motion import MotionPlan

#: A robot state older than this, while moving, counts as stale (UR streams at 125–500 Hz).
STALE_ROBOT_S = 0.5
#: ... and only once it has stood still over this many tracker frames.
STALE_FRAMES = 3


@dataclass
class AcquisitionSettings:
    """How to run a plan.

    Attributes
    ----------
    linear_speed_mm_s, linear_accel_mm_s2 : float
        Conservative TCP limits for every move.
    frame_timeout_s : float
        Longest wait for a tracker frame before the tracker counts as lost.
    stale_robot_s : float
        Longest age of the robot state while moving before it counts as stale.
    move_start_guard_s : float
        Frames in the first part of each move (robot clock) are not recorded: a tracker that
        delivers frames late (a streamed OpenIGTLink source) would otherwise label the last
        frames of one move with the next move's segment.
    """

    linear_speed_mm_s: float = 100.0
    linear_accel_mm_s2: float = 400.0
    frame_timeout_s: float = 1.0
    stale_robot_s: float = STALE_ROBOT_S
    move_start_guard_s: float = 0.1


@dataclass
class AcquisitionResult:
    """What an acquisition produced."""

    recording_path: Path
    samples_written: int
    visible_written: int
    moves_completed: int
    moves_total: int
    stopped_because: str | None = None
    progress: list = field(default_factory=list)

    @property
    def complete(self) -> bool:
        return self.moves_completed == self.moves_total


class AcquisitionStopped(DeviceError):
    """The acquisition stopped on a fault; ``result`` says how far it got."""

    def __init__(self, message: str, result: AcquisitionResult):
        super().__init__(message)
        self.result = result


def plan_fingerprint(plan: MotionPlan) -> str:
    """A short hash identifying a plan, so a resume cannot continue a different plan."""
    data = np.concatenate(
        [np.concatenate([m.start.ravel(), m.end.ravel(), [m.sample_period_s]]) for m in plan.moves]
    )
    return hashlib.sha256(np.round(data, 6).tobytes()).hexdigest()[:16]


def progress_path(recording_path: str | Path) -> Path:
    """``rec.csv`` -> ``rec.progress.json``."""
    path = Path(recording_path)
    return path.with_name(path.stem + ".progress.json")


def _write_progress(path: Path, plan: MotionPlan, completed: int, stopped_because: str | None) -> None:
    path.write_text(
        json.dumps(
            {
                "plan": plan_fingerprint(plan),
                "moves_completed": completed,
                "moves_total": len(plan.moves),
                "stopped_because": stopped_because,
                "home_joints_rad": np.asarray(plan.home_joints_rad).tolist(),
            },
            indent=2,
        )
    )


def resume_home_joints(recording_path: str | Path) -> np.ndarray | None:
    """The home configuration a stopped acquisition was planned from (to re-plan it on resume)."""
    path = progress_path(recording_path)
    if not path.is_file():
        return None
    return np.asarray(json.loads(path.read_text())["home_joints_rad"], dtype=float)


def acquire(
    plan: MotionPlan,
    robot: Robot,
    tracker: Tracker,
    recording_path: str | Path,
    metadata: dict,
    settings: AcquisitionSettings | None = None,
    resume: bool = False,
    on_sample: Callable[[int, int, int, str], None] | None = None,
) -> AcquisitionResult:
    """Run ``plan`` on ``robot`` while sampling ``tracker``; write the recording as it goes.

    Parameters
    ----------
    plan : MotionPlan
        Moves with ``sample_period_s > 0`` are recorded (at most one frame per period);
        others are transit.
    robot, tracker : Robot, Tracker
    recording_path : str or Path
        The recording CSV; its metadata and progress files go next to it.
    metadata : dict
        Written to ``<stem>.meta.json``.
    settings : AcquisitionSettings, optional
    resume : bool
        Continue a stopped run of the same plan: append to the recording and start from
        the move that was interrupted (from its start pose).
    on_sample : callable, optional
        Called as ``on_sample(samples, visible, move_index, label)`` after each sample
        (progress display).

    Raises
    ------
    AcquisitionStopped
        On a fault or Ctrl-C, after stopping the robot; the recording keeps every sample.
    """
    settings = settings or AcquisitionSettings()
    recording_path = Path(recording_path)
    progress_file = progress_path(recording_path)
    first_move = 0
    if resume:
        if not progress_file.is_file() or not recording_path.is_file():
            raise InvalidInputError(f"nothing to resume: {progress_file} or {recording_path} is missing")
        progress = json.loads(progress_file.read_text())
        if progress.get("plan") != plan_fingerprint(plan):
            raise InvalidInputError(f"{recording_path} was recorded with a different plan; cannot resume it")
        first_move = int(progress["moves_completed"])
    elif recording_path.exists():
        raise InvalidInputError(f"{recording_path} exists; choose another file or pass --resume")

    writer = RecordingWriter(recording_path, metadata, append=resume)
    result = AcquisitionResult(recording_path, 0, 0, first_move, len(plan.moves))
    _write_progress(progress_file, plan, first_move, None)

    def fail(reason: str) -> None:
        robot.stop()
        result.stopped_because = reason
        _write_progress(progress_file, plan, result.moves_completed, reason)
        raise AcquisitionStopped(
            f"acquisition stopped: {reason}; {result.samples_written} samples kept in {recording_path}; "
            f"resume with --resume",
            result,
        )

    try:
        for index in range(first_move, len(plan.moves)):
            move = plan.moves[index]
            if index == first_move and resume:
                robot.move_linear(move.start, settings.linear_speed_mm_s, settings.linear_accel_mm_s2)
            robot.move_linear(
                move.end, settings.linear_speed_mm_s, settings.linear_accel_mm_s2, asynchronous=True
            )
            last_recorded = -np.inf
            robot_time, robot_time_seen_at, frames_since_robot_update = None, None, 0
            move_started_at = None
            while True:
                try:
                    frame = tracker.next_frame(settings.frame_timeout_s)
                except DeviceError as exc:
                    fail(f"tracker lost ({exc})")
                state = robot.state()
                if state.safety != SAFETY_NORMAL:
                    fail(f"robot {state.safety.replace('_', ' ')}")
                # Stale robot data: its timestamp stands still while the tracker's advances. Each
                # device is compared only with its own clock, so unrelated clocks are fine.
                # Several frames are required: two reads a few ms apart may share a robot timestamp
                # even when one tracker frame arrives late.
                if state.time_s != robot_time:
                    robot_time, robot_time_seen_at, frames_since_robot_update = state.time_s, frame.time_s, 0
                else:
                    frames_since_robot_update += 1
                    if (
                        state.moving
                        and frames_since_robot_update >= STALE_FRAMES
                        and frame.time_s - robot_time_seen_at > settings.stale_robot_s
                    ):
                        fail(
                            f"robot data stale: no new robot state for {frame.time_s - robot_time_seen_at:.2f} s"
                        )
                if move_started_at is None:
                    move_started_at = state.time_s
                settled = state.time_s - move_started_at >= settings.move_start_guard_s
                if (
                    settled
                    and move.sample_period_s > 0
                    and frame.time_s - last_recorded >= move.sample_period_s - 1e-6
                ):
                    seen = frame.status == FRAME_OK
                    writer.append(
                        frame.time_s,
                        move.label,
                        state.joints_rad,
                        state.base_from_tcp,
                        frame.tracker_from_marker if seen else None,
                        frame.rms_mm,
                        frame.spheres_in_tracker if seen else None,
                    )
                    last_recorded = frame.time_s
                    result.samples_written += 1
                    result.visible_written += int(seen)
                    if on_sample:
                        on_sample(result.samples_written, result.visible_written, index, move.label)
                if not state.moving:
                    break
            result.moves_completed = index + 1
            _write_progress(progress_file, plan, result.moves_completed, None)
    except KeyboardInterrupt:
        fail("interrupted by the user (Ctrl-C)")
    except SpacecalError as exc:
        if isinstance(exc, AcquisitionStopped):
            raise
        fail(_cause(robot, exc))
    finally:
        writer.close()
    return result


def _cause(robot: Robot, error: Exception) -> str:
    """What stopped the run: a safety stop can land while a command is being issued, and the
    command's own error ("refused") then hides it; the robot's safety state says what happened."""
    try:
        safety = robot.state().safety
    except SpacecalError:
        return str(error)
    if safety != SAFETY_NORMAL:
        return f"robot {safety.replace('_', ' ')} ({error})"
    return str(error)
