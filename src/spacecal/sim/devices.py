"""Simulated devices behind the interfaces of :mod:`spacecal.core.ports`, in simulated time.

A :class:`SimClock` is shared by the robot and the tracker: waiting for a tracker frame
advances it, and the robot's motion follows it, so workflows run the same loop against the
simulation as against hardware, only faster than real time.
"""

from __future__ import annotations

import dataclasses
import threading
from collections import deque
from collections.abc import Sequence
from typing import Any

import numpy as np

from spacecal.core.errors import DeviceError, UnreachableError
from spacecal.core.ports import (
    FRAME_MISSING,
    FRAME_OK,
    SAFETY_NORMAL,
    SAFETY_PROTECTIVE_STOP,
    RobotState,
    TrackerFrame,
)
from spacecal.models.kinematics import forward_kinematics, inverse_kinematics_gauss_newton
from spacecal.planning.motion import MotionLimits, time_move, track_path, trapezoid_duration
from spacecal.sim.world import World


class SimClock:
    """Simulated time, s."""

    def __init__(self, start_s: float = 0.0):
        self._now_s = start_s

    @property
    def now_s(self) -> float:
        return self._now_s

    def advance_to(self, time_s: float) -> None:
        self._now_s = max(self._now_s, time_s)


class RealClock(SimClock):
    """Wall-clock time, optionally sped up, for running the simulation as devices would run
    (behind protocol fakes, or at a training station where the motion should take as long as
    on the robot).

    ``now_s`` counts seconds since construction (from ``start_s``), ``speed`` simulated seconds
    per real second; ``advance_to`` sleeps until then.
    """

    def __init__(self, start_s: float = 0.0, speed: float = 1.0):
        import time

        if not speed > 0:
            raise ValueError(f"a clock's speed must be positive, got {speed}")
        self._time = time
        self._origin_s = start_s
        self._speed = speed
        self._start = time.monotonic()

    @property
    def now_s(self) -> float:
        return self._origin_s + (self._time.monotonic() - self._start) * self._speed

    def advance_to(self, time_s: float) -> None:
        delay = (time_s - self.now_s) / self._speed
        if delay > 0:
            self._time.sleep(delay)


class SimulatedRobot:
    """The world's robot: moves by its true kinematics, reports and plans its moves by its
    controller's model (:attr:`World.controller_model`: nominal or factory-calibrated).

    Linear moves follow the planner's trapezoidal Cartesian profile; joint moves a
    trapezoid on the largest joint distance. States are stamped at controller ticks. Where
    the arm really is carries the world's repeatability scatter, a fresh draw of
    :meth:`World.repeatability_offsets` each time it is measured (the simulator's one
    repeatability model).

    Parameters
    ----------
    world : World
    clock : SimClock, optional
    joints_rad : array_like, shape (6,), optional
        Start configuration (default: the world's home).
    protective_stop_at_s : float, optional
        Fault injection: the controller enters a protective stop at this simulated time.
    limits : MotionLimits, optional
        Rotation and joint limits of linear moves (each move command sets the linear ones).
    stream_states : bool
        Keep every controller state (one per tick, as RTDE streams them) for
        :meth:`drain_states`.
    """

    def __init__(
        self,
        world: World,
        clock: SimClock | None = None,
        joints_rad=None,
        protective_stop_at_s: float | None = None,
        limits: MotionLimits | None = None,
        stream_states: bool = False,
    ):
        self.world = world
        self.clock = clock or SimClock()
        self.limits = limits or MotionLimits()
        self._joints = np.array(world.home_joints_rad if joints_rad is None else joints_rad, dtype=float)
        # ("linear", TimedMove, start), ("joint", (q0, q1, start, duration), start) or
        # ("points", (times since start (P+1,), joints (P+1, 6)), start)
        self._motion: tuple[Any, ...] | None = None
        self.protective_stop_at_s = protective_stop_at_s
        self._safety = SAFETY_NORMAL
        self.commands: list[str] = []
        self._tick_s = 1.0 / world.controller_model.controller_hz
        self._stream: list[RobotState] | None = [] if stream_states else None
        self._streamed_to_s = np.floor(self.clock.now_s / self._tick_s) * self._tick_s
        self._newest_tick: tuple[float, np.ndarray] = (float(self._streamed_to_s), self._joints.copy())
        self._updated_at_s = -np.inf
        self._followed: tuple[Any, np.ndarray, np.ndarray] | None = None
        self._lock = threading.RLock()

    #: Time step (s) of the path a linear move's joints are followed along when it is commanded:
    #: a controller tracks its path continuously, so the joints at any later instant are solved
    #: from the followed path's joints there, on the same branch.
    PATH_STEP_S = 0.02

    def _follow(self, move) -> None:
        """Follow a commanded linear move's path from the current joints (once per move; the
        path depends on progress alone, so later looks only refine from it)."""
        steps = max(2, int(np.ceil(move.duration_s / self.PATH_STEP_S)) + 1)
        times = np.linspace(0.0, move.duration_s, steps)
        self._followed = (
            move,
            times,
            track_path(self.world.controller_model, move.poses_at(times), self._joints),
        )

    def _joints_at(self, motion: tuple, times_s: np.ndarray) -> np.ndarray:
        """Joint angles (M, 6) of ``motion`` at times (M,) since the clock's origin."""
        kind, move, start = motion
        if kind == "linear":
            if self._followed is None or self._followed[0] is not move:
                raise RuntimeError("a linear move's path is followed when it is commanded")
            _, path_s, path = self._followed
            since = np.clip(times_s - start, 0.0, move.duration_s)
            # each instant is solved from where the followed path was at its time: the same
            # branch, all instants together
            guess = np.stack([np.interp(since, path_s, joint) for joint in path.T], axis=1)
            joints, converged = inverse_kinematics_gauss_newton(
                self.world.controller_model,
                move.poses_at(since),
                guess,
                max_iterations=30,
                position_tol_mm=1e-9,
                rotation_tol_rad=1e-12,
            )
            if not converged:
                raise UnreachableError("the simulated arm cannot follow its path (a workspace edge)")
            return joints
        if kind == "points":
            times, points = move
            since = times_s - start
            return np.stack([np.interp(since, times, points[:, k]) for k in range(points.shape[1])], axis=1)
        q0, q1, _, duration = move
        fraction = np.ones_like(times_s) if duration == 0 else np.clip((times_s - start) / duration, 0.0, 1.0)
        return q0 + fraction[:, None] * (q1 - q0)

    @staticmethod
    def _motion_end_s(motion: tuple) -> float:
        kind, move, start = motion
        if kind == "points":
            return start + float(move[0][-1])
        return start + (move.duration_s if kind == "linear" else move[3])

    def _update(self) -> None:
        # the protocol fakes call in from several threads: one look at a time
        with self._lock:
            self._advance()

    def _advance(self) -> None:
        now = self.clock.now_s
        if now == self._updated_at_s:
            return  # nothing has happened since the last look
        self._updated_at_s = now
        if self.protective_stop_at_s is not None and now >= self.protective_stop_at_s:
            self._safety = SAFETY_PROTECTIVE_STOP
        ticks = np.arange(self._streamed_to_s + self._tick_s, now + 1e-12, self._tick_s)
        if self._stream is None:
            ticks = ticks[-1:]  # nobody keeps the stream: only the newest tick matters
        motion = self._motion
        if motion is None or self._safety != SAFETY_NORMAL:
            self._stream_ticks(ticks, np.tile(self._joints, (len(ticks), 1)), moving=False)
            if motion is not None:
                self._finish()
            return
        path = self._joints_at(motion, np.append(ticks, now))
        end = self._motion_end_s(motion)
        self._stream_ticks(ticks, path[:-1], moving=ticks < end)
        self._joints = path[-1]
        if now >= end:
            self._finish()

    def _stream_ticks(self, ticks: np.ndarray, joints: np.ndarray, moving) -> None:
        if len(ticks):
            self._streamed_to_s = float(ticks[-1])
            self._newest_tick = (float(ticks[-1]), joints[-1].copy())
        if self._stream is None or not len(ticks):
            return
        poses = forward_kinematics(self.world.controller_model, joints)
        moving = np.broadcast_to(moving, ticks.shape)
        self._stream.extend(
            RobotState(float(t), q.copy(), pose, self._safety, bool(m))
            for t, q, pose, m in zip(ticks, joints, poses, moving)
        )

    def _finish(self) -> None:
        self._motion = None

    # -- Robot protocol ----------------------------------------------------------------
    def state(self) -> RobotState:
        self._update()
        return RobotState(
            time_s=float(np.floor(self.clock.now_s / self._tick_s) * self._tick_s),
            joints_rad=self._joints.copy(),
            base_from_tcp=forward_kinematics(self.world.controller_model, self._joints),
            safety=self._safety,
            moving=self._motion is not None,
        )

    def tick_state(self) -> RobotState:
        """The newest controller tick as a controller's packet holds it: the joints at the tick's
        own time (:meth:`state` gives the joints now, stamped with the tick before)."""
        self._update()
        time_s, joints = self._newest_tick
        return RobotState(
            time_s=time_s,
            joints_rad=joints.copy(),
            base_from_tcp=forward_kinematics(self.world.controller_model, joints),
            safety=self._safety,
            moving=self._motion is not None,
        )

    def drain_states(self) -> list[RobotState]:
        """Every controller state since the last call, one per tick (``stream_states``)."""
        return self.drain_states_and_now()[0]

    def drain_states_and_now(self) -> tuple[list[RobotState], float, np.ndarray]:
        """:meth:`drain_states`, and the time (s) and joints (6,) of the arm at that same look,
        taken together: the ticks and the present instant bound where the arm really went, for
        instruments that see it at their own instants (a tracker's frame)."""
        with self._lock:
            self._advance()
            states, self._stream = self._stream or [], [] if self._stream is not None else None
            return states, float(self._updated_at_s), self._joints.copy()

    def move_linear(
        self, base_from_tcp, speed_mm_s: float, accel_mm_s2: float, asynchronous: bool = False
    ) -> None:
        self._update()
        self._require_normal()
        self.commands.append("movel")
        start_pose = forward_kinematics(self.world.controller_model, self._joints)
        limits = dataclasses.replace(
            self.limits, linear_speed_mm_s=speed_mm_s, linear_accel_mm_s2=accel_mm_s2
        )
        move, _ = time_move(
            self.world.controller_model,
            "move",
            start_pose,
            np.asarray(base_from_tcp),
            self._joints,
            limits,
            0.0,
        )
        self._follow(move)
        self._motion = ("linear", move, self.clock.now_s)
        self._updated_at_s = -np.inf
        if not asynchronous:
            self.clock.advance_to(self.clock.now_s + move.duration_s)
            self._update()

    def start_joint_move(self, joints_rad, speed_rad_s: float, accel_rad_s2: float) -> float:
        """Start a joint move (trapezoid on the largest joint distance) and return its duration, s."""
        self._update()
        self._require_normal()
        self.commands.append("movej")
        target = np.asarray(joints_rad, dtype=float)
        with self._lock:
            duration, _ = trapezoid_duration(
                float(np.max(np.abs(target - self._joints))), speed_rad_s, accel_rad_s2
            )
            now = self.clock.now_s
            self._motion = ("joint", (self._joints.copy(), target, now, duration), now)
            self._updated_at_s = -np.inf
        return duration

    def start_trajectory(self, times_s, joints_rad) -> float:
        """Start following joint positions (P, 6) due at ``times_s`` (P,) from now, linearly
        between them from where the arm is (a trajectory controller's goal); its duration, s."""
        self._update()
        self._require_normal()
        self.commands.append("trajectory")
        times = np.concatenate([[0.0], np.asarray(times_s, dtype=float)])
        with self._lock:
            points = np.vstack([self._joints, np.asarray(joints_rad, dtype=float)])
            now = self.clock.now_s
            self._motion = ("points", (times, points), now)
            self._updated_at_s = -np.inf
        return float(times[-1])

    def move_joints(self, joints_rad, speed_rad_s: float, accel_rad_s2: float) -> None:
        duration = self.start_joint_move(joints_rad, speed_rad_s, accel_rad_s2)
        self.clock.advance_to(self.clock.now_s + duration)
        self._update()

    def stop(self) -> None:
        self.commands.append("stop")
        self._update()
        if self._motion is not None:
            self._finish()

    def _require_normal(self) -> None:
        if self._safety != SAFETY_NORMAL:
            raise DeviceError(f"robot is in {self._safety.replace('_', ' ')}; clear it on the teach pendant")

    # -- ground truth for simulated instruments ----------------------------------------
    def true_base_from_tcp(self) -> np.ndarray:
        """Where the TCP really is now (truth; for simulated instruments only)."""
        return self.true_base_from_tcp_and_time()[0]

    def true_base_from_tcp_and_time(self) -> tuple[np.ndarray, float]:
        """Where the TCP really is (4, 4), and the simulated instant (s) it is there: one look."""
        with self._lock:
            self._advance()
            joints, time_s = self._joints.copy(), float(self._updated_at_s)
        return self.world.true_base_from_tcp(joints)[0], time_s


class SimulatedTracker:
    """The world's optical tracker following the marker on the simulated robot.

    Parameters
    ----------
    unplug_after_frames : int, optional
        Fault injection: after this many frames the tracker stops answering.
    tools : sequence of str
        The world's further tools this tracker follows as well (``pointer``, ``reference``:
        :attr:`World.tools`), reported in :attr:`TrackerFrame.tools` under those names, each
        measured with the tracker's noise model; none by default (the marker only).

    Attributes
    ----------
    truth : dict
        Frame time (s) -> ``(true tracker_from_marker (4, 4), outlier kind)`` of every frame
        delivered: the ground truth experiments score against.
    tool_truth : dict
        Frame time (s) -> {tool name: its true pose (4, 4), or None while not in the world's
        view (a pointer put away)} of every frame delivered with tools.
    """

    #: True poses kept for stale-frame outliers (the scenario's stale frames are 2-8 old).
    HISTORY_FRAMES = 8

    def __init__(
        self,
        world: World,
        robot: SimulatedRobot,
        unplug_after_frames: int | None = None,
        tools: Sequence[str] = (),
    ):
        for name in tools:
            world.tool_geometry(name)  # an unknown tool is one line now, not at the first frame
        self.tools = tuple(tools)
        self.tool_truth: dict[float, dict[str, np.ndarray | None]] = {}
        self.world = world
        self.robot = robot
        self.clock = robot.clock
        self.period_s = 1.0 / world.tracker.rate_hz
        self._frame_number = int(np.ceil(self.clock.now_s / self.period_s))
        self.unplug_after_frames = unplug_after_frames
        self._delivered = 0
        self._history: deque[np.ndarray] = deque(maxlen=self.HISTORY_FRAMES)
        self.truth: dict[float, tuple[np.ndarray, str]] = {}

    def next_frame(self, timeout_s: float) -> TrackerFrame:
        if self.unplug_after_frames is not None and self._delivered >= self.unplug_after_frames:
            self.clock.advance_to(self.clock.now_s + timeout_s)
            raise DeviceError(f"no tracker frame for {timeout_s:.1f} s: tracker unplugged or stalled")
        self._frame_number = max(self._frame_number + 1, int(np.floor(self.clock.now_s / self.period_s)) + 1)
        self.clock.advance_to(self._frame_number * self.period_s)
        # the frame shows the marker where it is at the frame's time stamp: on a real-time clock
        # a busy machine wakes the tracker late, and the frame is then stamped when it was taken
        base_from_tcp, taken_s = self.robot.true_base_from_tcp_and_time()
        truth = self.world.tracker_from_base @ base_from_tcp @ self.world.tcp_from_marker
        earlier = np.array(self._history) if self._history else None
        tracked = self.world.track_marker(truth[None], earlier)
        self._history.append(truth)
        self._delivered += 1
        pose = tracked.tracker_from_marker[0]
        seen = bool(np.all(np.isfinite(pose)))
        time_s = max(self._frame_number * self.period_s, taken_s)
        self.truth[time_s] = (truth, str(tracked.outlier_kind[0]))
        return TrackerFrame(
            time_s=time_s,
            frame_number=self._frame_number,
            status=FRAME_OK if seen else FRAME_MISSING,
            tracker_from_marker=pose if seen else None,
            rms_mm=float(tracked.rms_mm[0]),
            spheres_in_tracker=tracked.spheres_in_tracker[0] if seen else None,
            tools=self._tool_poses(base_from_tcp, time_s),
        )

    def _tool_poses(self, base_from_tcp: np.ndarray, time_s: float) -> dict[str, np.ndarray | None]:
        """The further tools as the tracker sees them in this frame (their noise from the
        world's tool stream, so that the marker's frames are those it had without them)."""
        poses: dict[str, np.ndarray | None] = {}
        truths: dict[str, np.ndarray | None] = {}
        for name in self.tools:
            truth = self.world.true_tool_pose(name, base_from_tcp, time_s)
            truths[name] = truth
            if truth is None:
                poses[name] = None
                continue
            pose = self.world.track_tool(name, truth[None]).tracker_from_marker[0]
            poses[name] = pose if bool(np.all(np.isfinite(pose))) else None
        if self.tools:
            self.tool_truth[time_s] = truths
        return poses


class SimulatedLaserTracker:
    """The paper's laser tracker: measures the needle pose exactly, in the tracker frame."""

    def __init__(self, world: World, robot: SimulatedRobot, tcp_from_needle=None):
        self.world = world
        self.robot = robot
        self.tcp_from_needle = np.eye(4) if tcp_from_needle is None else np.asarray(tcp_from_needle)

    def measure_tracker_from_needle(self) -> np.ndarray:
        return self.world.tracker_from_base @ self.robot.true_base_from_tcp() @ self.tcp_from_needle
