"""Simulated devices behind the interfaces of :mod:`spacecal.core.ports`, in simulated time.

A :class:`SimClock` is shared by the robot and the tracker: waiting for a tracker frame
advances it, and the robot's motion follows it, so workflows run the same loop against the
simulation as against hardware, only faster than real time.
"""

from __future__ import annotations

import numpy as np

from spacecal.core.ports import FRAME_MISSING, FRAME_OK, SAFETY_NORMAL, SAFETY_PROTECTIVE_STOP, RobotState, TrackerFrame
from spacecal.core.errors import DeviceError
from spacecal.models.kinematics import forward_kinematics
from spacecal.models.robot_errors import REPEATABILITY_TO_AXIS_SD
from spacecal.planning.motion import MotionLimits, time_move, track_path, trapezoid_duration
from spacecal.sim.world import World


class SimClock:
    """Simulated time, s."""

    def __init__(self, start_s: float = 0.0):
        self.now_s = start_s

    def advance_to(self, time_s: float) -> None:
        self.now_s = max(self.now_s, time_s)


class RealClock(SimClock):
    """Wall-clock time for running the simulation in real time (behind protocol fakes).

    ``now_s`` counts seconds since construction; ``advance_to`` sleeps until then.
    """

    def __init__(self):
        import time

        self._time = time
        self._start = time.monotonic()

    @property
    def now_s(self) -> float:
        return self._time.monotonic() - self._start

    def advance_to(self, time_s: float) -> None:
        delay = time_s - self.now_s
        if delay > 0:
            self._time.sleep(delay)


class SimulatedRobot:
    """The world's robot: moves by its true kinematics, reports by its nominal model.

    Linear moves follow the planner's trapezoidal Cartesian profile; joint moves a
    trapezoid on the largest joint distance. States are stamped at controller ticks. A
    resting arm carries one repeatability offset per stop; a moving one scatters per query.

    Parameters
    ----------
    protective_stop_at_s : float, optional
        Fault injection: the controller enters a protective stop at this simulated time.
    """

    def __init__(
        self,
        world: World,
        clock: SimClock | None = None,
        joints_rad=None,
        protective_stop_at_s: float | None = None,
    ):
        self.world = world
        self.clock = clock or SimClock()
        self._joints = np.array(world.home_joints_rad if joints_rad is None else joints_rad, dtype=float)
        self._motion = None  # (TimedMove, start time) of a linear move, or (q0, q1, start, duration)
        self._rest_offset = self._draw_offset()
        self.protective_stop_at_s = protective_stop_at_s
        self._safety = SAFETY_NORMAL
        self.commands: list[str] = []

    def _draw_offset(self) -> np.ndarray:
        sd = self.world.scenario.repeatability_mm * REPEATABILITY_TO_AXIS_SD
        return self.world.noise_rng.normal(scale=sd, size=3) if sd > 0 else np.zeros(3)

    def _update(self) -> None:
        now = self.clock.now_s
        if self.protective_stop_at_s is not None and now >= self.protective_stop_at_s:
            self._safety = SAFETY_PROTECTIVE_STOP
        if self._motion is None:
            return
        if self._safety != SAFETY_NORMAL:
            self._finish()
            return
        kind, move, start = self._motion
        elapsed = min(now - start, move.duration_s if kind == "linear" else move[3])
        if kind == "linear":
            self._joints = track_path(
                self.world.nominal_model, move.poses_at(np.array([elapsed])), self._joints
            )[0]
            done = now - start >= move.duration_s
        else:
            q0, q1, _, duration = move
            fraction = 1.0 if duration == 0 else np.clip(elapsed / duration, 0.0, 1.0)
            self._joints = q0 + fraction * (q1 - q0)
            done = fraction >= 1.0
        if done:
            self._finish()

    def _finish(self) -> None:
        self._motion = None
        self._rest_offset = self._draw_offset()

    # -- Robot protocol ----------------------------------------------------------------
    def state(self) -> RobotState:
        self._update()
        tick = 1.0 / self.world.nominal_model.controller_hz
        return RobotState(
            time_s=float(np.floor(self.clock.now_s / tick) * tick),
            joints_rad=self._joints.copy(),
            base_from_tcp=forward_kinematics(self.world.nominal_model, self._joints),
            safety=self._safety,
            moving=self._motion is not None,
        )

    def move_linear(
        self, base_from_tcp, speed_mm_s: float, accel_mm_s2: float, asynchronous: bool = False
    ) -> None:
        self._update()
        self._require_normal()
        self.commands.append("movel")
        start_pose = forward_kinematics(self.world.nominal_model, self._joints)
        limits = MotionLimits(linear_speed_mm_s=speed_mm_s, linear_accel_mm_s2=accel_mm_s2)
        move, _ = time_move(
            self.world.nominal_model, "move", start_pose, np.asarray(base_from_tcp), self._joints, limits, 0.0
        )
        self._motion = ("linear", move, self.clock.now_s)
        if not asynchronous:
            self.clock.advance_to(self.clock.now_s + move.duration_s)
            self._update()

    def move_joints(self, joints_rad, speed_rad_s: float, accel_rad_s2: float) -> None:
        self._update()
        self._require_normal()
        self.commands.append("movej")
        target = np.asarray(joints_rad, dtype=float)
        duration, _ = trapezoid_duration(
            float(np.max(np.abs(target - self._joints))), speed_rad_s, accel_rad_s2
        )
        self._motion = ("joint", (self._joints.copy(), target, self.clock.now_s, duration), self.clock.now_s)
        self.clock.advance_to(self.clock.now_s + duration)
        self._update()

    def stop(self) -> None:
        self.commands.append("stop")
        self._update()
        self._motion = None

    def _require_normal(self) -> None:
        if self._safety != SAFETY_NORMAL:
            raise DeviceError(f"robot is in {self._safety.replace('_', ' ')}; clear it on the teach pendant")

    # -- ground truth for simulated instruments ----------------------------------------
    def true_base_from_tcp(self) -> np.ndarray:
        """Where the TCP really is now (truth; for simulated instruments only)."""
        self._update()
        pose = forward_kinematics(self.world.true_model, self._joints)
        offset = self._draw_offset() if self._motion is not None else self._rest_offset
        pose[:3, 3] += offset
        return pose


class SimulatedTracker:
    """The world's optical tracker following the marker on the simulated robot.

    Parameters
    ----------
    unplug_after_frames : int, optional
        Fault injection: after this many frames the tracker stops answering.
    """

    def __init__(self, world: World, robot: SimulatedRobot, unplug_after_frames: int | None = None):
        self.world = world
        self.robot = robot
        self.clock = robot.clock
        self.period_s = 1.0 / world.tracker.rate_hz
        self._frame_number = int(np.ceil(self.clock.now_s / self.period_s))
        self.unplug_after_frames = unplug_after_frames
        self._delivered = 0

    def next_frame(self, timeout_s: float) -> TrackerFrame:
        if self.unplug_after_frames is not None and self._delivered >= self.unplug_after_frames:
            self.clock.advance_to(self.clock.now_s + timeout_s)
            raise DeviceError(f"no tracker frame for {timeout_s:.1f} s: tracker unplugged or stalled")
        self._frame_number = max(self._frame_number + 1, int(np.floor(self.clock.now_s / self.period_s)) + 1)
        self.clock.advance_to(self._frame_number * self.period_s)
        truth = self.world.tracker_from_base @ self.robot.true_base_from_tcp() @ self.world.tcp_from_marker
        tracked = self.world.track_marker(truth[None])
        self._delivered += 1
        pose = tracked.tracker_from_marker[0]
        seen = bool(np.all(np.isfinite(pose)))
        return TrackerFrame(
            time_s=self._frame_number * self.period_s,
            frame_number=self._frame_number,
            status=FRAME_OK if seen else FRAME_MISSING,
            tracker_from_marker=pose if seen else None,
            rms_mm=float(tracked.rms_mm[0]),
            spheres_in_tracker=tracked.spheres_in_tracker[0] if seen else None,
        )


class SimulatedLaserTracker:
    """The paper's laser tracker: measures the needle pose exactly, in the tracker frame."""

    def __init__(self, world: World, robot: SimulatedRobot, tcp_from_needle=None):
        self.world = world
        self.robot = robot
        self.tcp_from_needle = np.eye(4) if tcp_from_needle is None else np.asarray(tcp_from_needle)

    def measure_tracker_from_needle(self) -> np.ndarray:
        return self.world.tracker_from_base @ self.robot.true_base_from_tcp() @ self.tcp_from_needle
