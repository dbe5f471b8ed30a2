"""Automatic acquisition (paper §4): run a motion plan on the robot while sampling the tracker.

Both devices' streams are written as they arrive, each on its own clock: every controller
state during the recorded moves (``STEM.robot.csv``, at the controller's rate where the robot
streams its states) and every sampled tracker frame (``STEM.tracker.csv``), flushed to disk,
so nothing recorded is lost. The paired recording (``STEM.csv``) is derived from them when
the run ends: each frame with the robot state interpolated at its time on the robot's clock,
at the estimated clock offset (:func:`spacecal.estimators.time_offset.pair_at_estimated_offset`).
A safety stop, a lost or stalled tracker, stale robot data, a move past its deadline, or
Ctrl-C stops the robot, keeps the files readable, records how far the plan got in a progress
file next to the recording, and raises with one line saying what happened; the run can then
be resumed where it stopped.
"""

from __future__ import annotations

import hashlib
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NoReturn, Protocol, runtime_checkable

import numpy as np

from spacecal.core.errors import DeviceError, InvalidInputError, SpacecalError
from spacecal.core.interrupts import raise_if_stop_requested
from spacecal.core.ports import FRAME_OK, SAFETY_NORMAL, Robot, RobotState, StreamingRobot, Tracker
from spacecal.io.acquisition_progress import progress_path, read_progress, write_progress
from spacecal.io.recordings import RawStreamWriter, open_path, raw_stem, raw_stream_paths, write_recording
from spacecal.planning.motion import MotionLimits, MotionPlan, TimedMove
from spacecal.records import AcquisitionProgress, StreamPairing
from spacecal.workflows.stations import average_stations

#: A robot state older than this, while moving, counts as stale (UR streams at 125–500 Hz).
STALE_ROBOT_S = 0.5
#: ... and only once it has stood still over this many tracker frames.
STALE_FRAMES = 3
#: Share of a sample period by which a frame may come before its due time and still count
#: for it (:class:`SampleGrid`).
EARLY_SHARE = 0.25


class SampleGrid:
    """Which tracker frames of one move are recorded: at most one in each sample period.

    The periods are a grid anchored at the move's first recorded frame; each runs from a
    quarter period (:data:`EARLY_SHARE`) before its grid point to three quarters after, and
    its first frame is recorded. A tracker's timestamps jitter by milliseconds around its
    frame rate (an OpenIGTLink sender stamps each frame when it takes it): a frame 49.9 ms
    after the last recorded one still counts for a 50 ms period, and one half a period
    after it does not. A first frame stamped late would set the grid late: the grid moves
    to a recorded frame stamped before its grid point, by at most a quarter period in all
    (so the move still records no more frames than it has periods, plus one).
    """

    def __init__(self, period_s: float):
        self.period_s = period_s
        self._first_s: float | None = None
        self._anchor_s = 0.0
        self._last_slot = 0

    def take(self, time_s: float) -> bool:
        """Whether to record a frame stamped ``time_s`` (called in the order frames come)."""
        if self.period_s <= 0:
            return False
        if self._first_s is None:
            self._first_s = self._anchor_s = time_s
            return True
        periods = (time_s - self._anchor_s) / self.period_s
        slot = int(np.floor(periods + EARLY_SHARE))
        if slot <= self._last_slot:
            return False
        self._last_slot = slot
        if periods < slot:  # stamped before its grid point: the grid moves to it, within bounds
            earliest = self._first_s - EARLY_SHARE * self.period_s
            self._anchor_s = max(time_s - slot * self.period_s, earliest)
        return True


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
        Frames in the first part of each move (robot clock) are not recorded. Not needed when
        the streams are paired by time (a frame delivered late, e.g. by a streamed OpenIGTLink
        source, is paired with the robot state when it was captured, and takes that state's
        segment), so 0 by default.
    deadline_factor, deadline_margin_s : float
        Every move must end within ``deadline_factor`` times its planned duration plus
        ``deadline_margin_s`` (robot clock); a move that does not ends the run.
    """

    linear_speed_mm_s: float = MotionLimits.linear_speed_mm_s
    linear_accel_mm_s2: float = MotionLimits.linear_accel_mm_s2
    frame_timeout_s: float = 1.0
    stale_robot_s: float = STALE_ROBOT_S
    move_start_guard_s: float = 0.0
    deadline_factor: float = 1.5
    deadline_margin_s: float = 2.0


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
    raw_paths: tuple[Path, Path] | None = None
    pairing: StreamPairing | None = None
    #: Why no paired recording could be derived from the raw streams (None when it was).
    unpaired_because: str | None = None

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


def _write_progress(path: Path, plan: MotionPlan, completed: int, stopped_because: str | None) -> None:
    write_progress(
        AcquisitionProgress(
            plan_fingerprint(plan),
            completed,
            len(plan.moves),
            stopped_because,
            np.asarray(plan.home_joints_rad),
        ),
        path,
    )


def is_hold(move: TimedMove) -> bool:
    """True for a move that holds still (a station): same start and end pose, some duration."""
    return move.duration_s > 0 and bool(np.allclose(move.start, move.end, atol=1e-9))


class SampleSink(Protocol):
    """Where acquired samples go: the recording CSV writer, or memory for experiments."""

    def append(
        self,
        time_s: float,
        segment: str,
        joints_rad: np.ndarray,
        base_from_tcp: np.ndarray,
        tracker_from_marker: np.ndarray | None = None,
        marker_rms_mm: float = float("nan"),
        spheres_in_tracker: np.ndarray | None = None,
        robot_time_s: float = float("nan"),
        *,
        status: str = FRAME_OK,
    ) -> None:
        """Keep one sample: the tracker frame (``time_s`` on the tracker's clock, ``status`` its
        frame status, kept with any pose the tracker reported) with the newest robot state when
        it arrived (``robot_time_s`` on the robot's clock)."""


@runtime_checkable
class RobotStreamSink(Protocol):
    """A sink that also keeps the robot's own state stream (every controller tick)."""

    def add_robot_states(self, states: list[RobotState], segment: str) -> None:
        """Keep controller states received during a recorded move."""


class RunFault(DeviceError):
    """A fault that ends a run; the message says what happened in a robot operator's words."""


#: ``observer(time_s, segment, tracker_from_marker, base_from_tcp, recorded)``, called for every
#: tracker frame of a run (recorded or not): the frame time (s), the move's label, the marker
#: pose (4, 4) in mm or None when not seen, the robot's TCP pose (4, 4) in mm, and whether the
#: frame was recorded as a sample. It runs in the acquisition loop, so it must return at once
#: (a live view puts the frame on a bounded queue); an exception in it detaches it with one
#: warning on stderr and the run goes on.
FrameObserver = Callable[[float, str, "np.ndarray | None", np.ndarray, bool], None]

#: ``on_sample(samples, visible, move_index, label)``, called after every sample a run records
#: (an acquisition's or a check's): the samples and the visible ones so far, the move's index
#: in the plan and its label.
SampleCallback = Callable[[int, int, int, str], None]


def _notify(observer: FrameObserver, *frame: Any) -> FrameObserver | None:
    """Call ``observer``; on an exception warn once and return None (detach it)."""
    try:
        observer(*frame)
    except Exception as exc:  # a failed view must never stop the robot's run
        print(
            f"warning: the acquisition's frame observer failed ({type(exc).__name__}: {exc}); "
            "the run continues without it",
            file=sys.stderr,
            flush=True,
        )
        return None
    return observer


def run_plan(
    plan: MotionPlan,
    robot: Robot,
    tracker: Tracker,
    sink: SampleSink,
    settings: AcquisitionSettings,
    progress: AcquisitionResult,
    approach_first_move: bool = False,
    on_sample: SampleCallback | None = None,
    on_move_done: Callable[[int], None] | None = None,
    observer: FrameObserver | None = None,
) -> None:
    """The acquisition loop (paper §4): run the moves of ``plan`` from
    ``progress.moves_completed`` on, sampling the tracker, and hand each sample to ``sink``.

    This one loop drives real devices (:func:`acquire`) and simulated ones (the simulator's
    recordings are made by it, in simulated time). It stops nothing by itself: a fault
    raises :class:`RunFault` and the caller stops the robot.

    Parameters
    ----------
    plan : MotionPlan
        Moves with ``sample_period_s > 0`` are recorded (at most one frame per period,
        :class:`SampleGrid`); others are transit.
    robot, tracker : Robot, Tracker
    sink : SampleSink
        Receives each sample; if it has ``add_robot_states`` it also receives the robot's
        states during recorded moves: every controller state where the robot streams them
        (``drain_states``), else the state read at each frame.
    settings : AcquisitionSettings
    progress : AcquisitionResult
        Updated in place (samples, moves completed).
    approach_first_move : bool
        Move to the first move's start pose first (resuming an interrupted run).
    on_sample : callable, optional
        Called as ``on_sample(samples, visible, move_index, label)`` after each sample.
    on_move_done : callable, optional
        Called with the number of moves completed after each move.
    observer : FrameObserver, optional
        Called with every tracker frame (see :data:`FrameObserver`); costs one comparison
        per frame when None.
    """
    stream_sink = sink if isinstance(sink, RobotStreamSink) else None
    streaming_robot = robot if isinstance(robot, StreamingRobot) else None
    first_move = progress.moves_completed
    for index in range(first_move, len(plan.moves)):
        move = plan.moves[index]
        if index == first_move and approach_first_move and not _at_pose(robot, move.start):
            _approach(robot, tracker, move.start, settings)
        # A hold (start = end) is a station: the arm rests while frames are taken for the
        # move's duration (stop-and-go sampling); there is nothing to command.
        hold = is_hold(move)
        if not hold:
            robot.move_linear(
                move.end, settings.linear_speed_mm_s, settings.linear_accel_mm_s2, asynchronous=True
            )
        grid = SampleGrid(move.sample_period_s)
        robot_time: float | None = None
        robot_time_seen_at = 0.0
        frames_since_robot_update = 0
        move_started_at = None
        while True:
            # a stop whose KeyboardInterrupt Python lost on the way (core.interrupts)
            raise_if_stop_requested()
            try:
                frame = tracker.next_frame(settings.frame_timeout_s)
            except DeviceError as exc:
                raise RunFault(f"tracker lost ({exc})") from exc
            state = robot.state()
            if stream_sink is not None:
                # The stream since the last frame, through every move and the moments between
                # them (a frame delivered late pairs with the state it was captured at, and no
                # gap opens at a move's start); or, for a robot that keeps no stream, the state
                # just read. The sink skips a state not newer than the last it kept.
                states = streaming_robot.drain_states() if streaming_robot is not None else []
                stream_sink.add_robot_states(states or [state], move.label)
            if state.safety != SAFETY_NORMAL:
                raise RunFault(f"robot {state.safety.replace('_', ' ')}")
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
                    raise RunFault(
                        f"robot data stale: no new robot state for {frame.time_s - robot_time_seen_at:.2f} s"
                    )
            if move_started_at is None:
                move_started_at = state.time_s
            settled = state.time_s - move_started_at >= settings.move_start_guard_s
            recorded = False
            if settled and grid.take(frame.time_s):
                recorded = True
                seen = frame.status == FRAME_OK
                sink.append(
                    frame.time_s,
                    move.label,
                    state.joints_rad,
                    state.base_from_tcp,
                    frame.tracker_from_marker,
                    frame.rms_mm,
                    frame.spheres_in_tracker,
                    robot_time_s=state.time_s,
                    status=frame.status,
                )
                progress.samples_written += 1
                progress.visible_written += int(seen)
                if on_sample:
                    on_sample(progress.samples_written, progress.visible_written, index, move.label)
            if observer is not None:
                observer = _notify(
                    observer,
                    frame.time_s,
                    move.label,
                    frame.tracker_from_marker if frame.status == FRAME_OK else None,
                    state.base_from_tcp,
                    recorded,
                )
            elapsed = state.time_s - move_started_at
            if hold and elapsed >= move.duration_s:
                break
            # A robot that has arrived has finished its move, however late this loop looks: a
            # loop held up (a slow disk's fsync, a busy computer) must not take an arm at rest
            # at its target for one that is late. Only an arm still moving past the deadline is.
            if not hold and not state.moving:
                break
            deadline = settings.deadline_factor * move.duration_s + settings.deadline_margin_s
            if elapsed > deadline:
                raise RunFault(
                    f"move {index + 1}/{len(plan.moves)} ({move.label}) did not finish within its deadline "
                    f"of {deadline:.1f} s (planned {move.duration_s:.1f} s); the robot was stopped"
                )
        progress.moves_completed = index + 1
        if on_move_done:
            on_move_done(progress.moves_completed)


class _RawSink:
    """The acquisition's sink on disk: both raw streams, as they arrive."""

    def __init__(self, writer: RawStreamWriter):
        self.writer = writer

    def append(
        self,
        time_s: float,
        segment: str,
        joints_rad: np.ndarray,
        base_from_tcp: np.ndarray,
        tracker_from_marker: np.ndarray | None = None,
        marker_rms_mm: float = float("nan"),
        spheres_in_tracker: np.ndarray | None = None,
        robot_time_s: float = float("nan"),
        *,
        status: str = FRAME_OK,
    ) -> None:
        self.writer.add_tracker_frame(
            time_s, tracker_from_marker, marker_rms_mm, robot_time_s, spheres_in_tracker, status
        )

    def add_robot_states(self, states: list[RobotState], segment: str) -> None:
        self.writer.add_robot_states(states, segment)


def acquire(
    plan: MotionPlan,
    robot: Robot,
    tracker: Tracker,
    recording_path: str | Path,
    metadata: dict,
    settings: AcquisitionSettings | None = None,
    resume: bool = False,
    on_sample: SampleCallback | None = None,
    observer: FrameObserver | None = None,
) -> AcquisitionResult:
    """Run ``plan`` on ``robot`` while sampling ``tracker``; write the raw streams as they
    arrive and the paired recording derived from them.

    Parameters
    ----------
    plan : MotionPlan
        Moves with ``sample_period_s > 0`` are recorded (at most one frame per period,
        :class:`SampleGrid`); others are transit.
    robot, tracker : Robot, Tracker
    recording_path : str or Path
        The paired recording CSV, ``STEM.csv``; the raw streams, their metadata file and the
        progress file go next to it (named by :mod:`spacecal.io.recording_files`).
    metadata : dict
        Written to the recording's metadata file.
    settings : AcquisitionSettings, optional
    resume : bool
        Continue a stopped run of the same plan: append to the streams and start from the
        move that was interrupted (from its start pose).
    on_sample : callable, optional
        Called as ``on_sample(samples, visible, move_index, label)`` after each sample
        (progress display).
    observer : FrameObserver, optional
        Called with every tracker frame (a live view); see :data:`FrameObserver`.

    Raises
    ------
    AcquisitionStopped
        On a fault or Ctrl-C, after stopping the robot; the streams keep every sample and the
        paired recording is derived from what was recorded.
    """
    settings = settings or AcquisitionSettings()
    recording_path = Path(recording_path)
    progress_file = progress_path(recording_path)
    raw_paths = raw_stream_paths(recording_path)
    first_move = 0
    if resume:
        if not progress_file.is_file():
            raise InvalidInputError(f"nothing to resume: {progress_file} is missing")
        progress = read_progress(recording_path)
        if progress is None or progress.plan_fingerprint != plan_fingerprint(plan):
            raise InvalidInputError(f"{recording_path} was recorded with a different plan; cannot resume it")
        first_move = progress.moves_completed
    else:
        for path in (recording_path, *raw_paths):
            if path.exists():
                raise InvalidInputError(f"{path} exists; choose another file or pass --resume")

    # progress first: an interruption before the first sample leaves a run --resume can start
    _write_progress(progress_file, plan, first_move, None)
    sphere_count = len(metadata.get("marker", {}).get("spheres_in_marker_mm", []))
    writer = RawStreamWriter(
        raw_stem(recording_path),
        metadata,
        sphere_count,
        append=resume,
        durable=not metadata.get("simulated", False),
    )
    result = AcquisitionResult(recording_path, 0, 0, first_move, len(plan.moves), raw_paths=raw_paths)

    def fail(reason: str) -> NoReturn:
        robot.stop()
        result.stopped_because = reason
        _write_progress(progress_file, plan, result.moves_completed, reason)
        writer.close()
        _derive_recording(result, metadata)
        kept = (
            f"{recording_path}"
            if result.unpaired_because is None
            else f"the raw streams {raw_paths[0].name} and {raw_paths[1].name} ({result.unpaired_because})"
        )
        raise AcquisitionStopped(
            f"acquisition stopped: {reason}; {result.samples_written} samples kept in {kept}; "
            "resume with --resume",
            result,
        )

    try:
        run_plan(
            plan,
            robot,
            tracker,
            _RawSink(writer),
            settings,
            result,
            approach_first_move=resume,
            on_sample=on_sample,
            on_move_done=lambda done: _write_progress(progress_file, plan, done, None),
            observer=observer,
        )
    except KeyboardInterrupt:
        fail("interrupted by the user (Ctrl-C)")
    except RunFault as exc:
        fail(str(exc))
    except SpacecalError as exc:
        if isinstance(exc, AcquisitionStopped):
            raise
        fail(_cause(robot, exc))
    finally:
        writer.close()
    _derive_recording(result, metadata)
    if result.unpaired_because is not None:
        raise InvalidInputError(
            f"the raw streams {raw_paths[0]} and {raw_paths[1]} were recorded, but no paired recording "
            f"could be derived from them: {result.unpaired_because}"
        )
    return result


def _derive_recording(result: AcquisitionResult, metadata: dict) -> None:
    """Pair the raw streams into ``result.recording_path`` (atomically), at the estimated clock
    offset, one averaged sample per station for a stop-and-go run (``metadata["sampling"]``);
    a failure leaves the streams as they are and says why in ``result``."""
    assert result.raw_paths is not None
    sampling = metadata.get("sampling") or {}
    try:
        opened = open_path(*result.raw_paths, fall_back_to_link=True)
        recording, result.pairing = opened.recording, opened.source.pairing
        if sampling.get("mode") == "stop-and-go":
            recording = average_stations(recording, float(sampling["frame_period_s"]))
        write_recording(recording, result.recording_path)
    except SpacecalError as exc:
        result.unpaired_because = str(exc)


def _approach(
    robot: Robot, tracker: Tracker, base_from_tcp: np.ndarray, settings: AcquisitionSettings
) -> None:
    """Move to where an interrupted move started, watching the robot at the tracker's pace as
    during a recorded move (so a safety stop or a lost tracker ends the run the same way, and
    a simulated arm follows the path instead of jumping to its end)."""
    robot.move_linear(
        base_from_tcp, settings.linear_speed_mm_s, settings.linear_accel_mm_s2, asynchronous=True
    )
    while True:
        raise_if_stop_requested()
        try:
            tracker.next_frame(settings.frame_timeout_s)
        except DeviceError as exc:
            raise RunFault(f"tracker lost ({exc})") from exc
        state = robot.state()
        if state.safety != SAFETY_NORMAL:
            raise RunFault(f"robot {state.safety.replace('_', ' ')}")
        if not state.moving:
            return


def _at_pose(robot: Robot, base_from_tcp: np.ndarray) -> bool:
    """True when the TCP is already at ``base_from_tcp`` (to a micrometre and a microradian)."""
    here = robot.state().base_from_tcp
    return bool(
        np.allclose(here[:3, 3], base_from_tcp[:3, 3], atol=1e-3)
        and np.allclose(here[:3, :3], base_from_tcp[:3, :3], atol=1e-6)
    )


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
