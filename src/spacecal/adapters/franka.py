"""Franka Robotics arms (FR3) over the Franka Control Interface through libfranka's Python
bindings ``pylibfranka`` (extra ``franka``).

* Connection: libfranka's command connection (TCP port 1337) and the robot's 1 kHz state
  stream (UDP). libfranka has no port to choose: a ``franka://HOST`` URL is a host only. The
  command port is first checked with spacecal's own socket and the protocol's ``Connect``
  message within :data:`REACH_DEADLINE_S` (libfranka's own connect waits longer for a host
  that does not answer), which also gives the robot's server version for :meth:`identity`.
* State: ``q`` (rad) and ``O_T_EE`` (metres, column-major, base to the end effector set in
  Desk) converted to mm here, at the boundary; ``time`` is the robot's own clock. libfranka
  raises after 1 s without a state packet (``UDP receive: Timeout``): that is the deadline of
  every read, and a robot that fell silent is a :class:`DeviceError`.
* Motion: a joint-position (``move_joints``) or Cartesian-pose (``move_linear``) motion
  generator fed one set-point per 1 ms cycle by a loop on a thread of its own
  (``readOnce``/``writeOnce``), along minimum-jerk paths (:mod:`spacecal.adapters.franka_motion`)
  the robot's discontinuity checks accept. The caller waits with a deadline of the path's
  duration plus :data:`MOTION_MARGIN_S` on the robot's clock.
* What stops the arm, from ``robot_mode`` (``kReflex``, ``kUserStopped``, ``kGuiding``,
  ``kAutomaticErrorRecovery``, ``kOther``) and ``current_errors``: a motion is refused before
  it starts, in one line, and a motion the robot aborted ends with libfranka's reason.
* A stop slows the running path to rest (:data:`STOP_DECEL_RAD_S2`) and ends the motion
  generator; afterwards nothing more is commanded on this connection. A Franka arm holds its
  pose between motions and moves only when a client commands it, so nothing can resume a
  move spacecal gave up.
"""

from __future__ import annotations

import contextlib
import socket
import struct
import threading
import time
from collections.abc import Callable

import numpy as np

from spacecal.adapters import DeviceAddress, DeviceOptions, require
from spacecal.adapters.franka_motion import (
    PEAK_SPEED,
    PathClock,
    interpolate_pose,
    path_duration,
    stop_duration,
)
from spacecal.core.errors import DeviceError, InvalidInputError
from spacecal.core.ports import (
    FINDING_OK,
    FINDING_PROBLEM,
    FINDING_WARNING,
    SAFETY_NORMAL,
    SAFETY_NOT_RUNNING,
    DeviceFinding,
    DeviceIdentity,
    RobotState,
    plausible_tracked_pose,
)
from spacecal.core.units import metres_to_mm, mm_to_metres
from spacecal.geometry.rotations import rotation_angle
from spacecal.geometry.transforms import matrix_to_rotvec
from spacecal.models.kinematics import RobotModel, forward_kinematics
from spacecal.models.robot_kinds import ROBOT_KINDS, robot_kind
from spacecal.planning.motion import MotionLimits

#: libfranka's command port (fixed: libfranka takes a host only).
COMMAND_PORT = 1337
#: The robot kind a ``franka://`` URL opens unless ``--robot-model`` names another, and the
#: vendor of the kinds it may name (:mod:`spacecal.models.robot_kinds`).
DEFAULT_KIND, FRANKA_VENDOR = "FR3", "Franka Robotics"
#: Deadline of spacecal's own ``Connect`` exchange on the command port, s.
REACH_DEADLINE_S = 3.0
#: The libfranka protocol's Connect command (research_interface::robot::Command::kConnect) and
#: the Connect response status meaning success.
CONNECT_COMMAND, CONNECT_SUCCESS = 0, 0
#: Extra time a motion may take beyond its path (and stop), s of the robot's clock: the
#: robot's own start and the answer to the finished motion, on a loaded machine.
MOTION_MARGIN_S = 3.0
#: The same deadline in wall time is this many times longer: a real robot's clock is real time,
#: so the deadline on its clock is the one that binds; a simulator on a loaded computer runs
#: slower than real time (measured: a third of it at a load of 12 on 2 cores) and its
#: motions take as much longer. The wall-time bound ends a motion that never starts.
WALL_DEADLINE_FACTOR = 4.0
#: Deceleration of a stop, per joint, rad/s^2 (an FR3 joint is allowed 10 rad/s^2 and more).
STOP_DECEL_RAD_S2 = 5.0
#: Deceleration of a stop of a straight-line move, mm/s^2.
STOP_DECEL_MM_S2 = 1000.0
#: A state older than this (s) is stale: the robot sends one every millisecond.
STALE_AFTER_S = 0.5
#: A robot's last commanded pose farther than this (mm) from its measured one is not the start
#: of a straight-line path (a robot that has not yet streamed a pose command reports none).
START_POSE_MM = 5.0
#: How often the caller of a move looks at its loop, s.
WAIT_POLL_S = 0.01
#: Beyond this distance (mm) between the nominal kinematics' end effector and the reported
#: one, the preflight warns.
MODEL_CHECK_MM = 1.0
#: Joint-space arrival, rad. Measured on the simulator once the arm stood still: joints 1-6
#: within 3e-4 rad of a finished path's end; joint 7 (low gain, friction) then creeps while
#: the robot holds the pose, 2.3e-3 rad at most seen. A sanity bound, not the calibration's:
#: the joints a recording keeps are the reported ones.
ARRIVAL_RAD = 5e-3
#: After the path's last set-point, how long a joint move waits at most for the arm to stand
#: still (no joint moving more than :data:`SETTLED_RAD` over :data:`SETTLED_OVER_S`), s,
#: before it judges the arrival with :data:`ARRIVAL_RAD`.
SETTLE_S, SETTLED_RAD, SETTLED_OVER_S = 1.0, 2e-5, 0.05

#: ``robot_mode`` name -> (the ``RobotState.safety`` it is, what to do about it). Idle and Move
#: are a robot ready to be commanded.
MODE_CONDITIONS = {
    "Reflex": (
        "stopped_by_a_reflex",
        "the arm stopped in a reflex ({errors}): find the cause, then clear it (Desk, or "
        "automatic error recovery) before spacecal moves it",
    ),
    "UserStopped": (
        "user_stop_pressed",
        "the user stop (external activation device) is pressed: release it",
    ),
    "Guiding": (
        "in_guiding_mode",
        "the arm is being guided by hand: release the guiding button",
    ),
    "AutomaticErrorRecovery": (
        "in_error_recovery",
        "the robot is recovering from an error: wait for it, then check Desk",
    ),
    "Other": (
        f"{SAFETY_NOT_RUNNING}_(mode_Other)",
        "the robot is not ready for commands: unlock the joints and activate FCI in Desk",
    ),
}
READY_MODES = ("Idle", "Move")


def _matrix(column_major) -> np.ndarray:
    """A libfranka 16-vector (column-major) as a 4x4 matrix."""
    return np.asarray(column_major, dtype=float).reshape(4, 4, order="F")


def pose_from_franka(column_major) -> np.ndarray:
    """libfranka's ``O_T_EE`` (metres, column-major) -> our 4x4 pose (mm)."""
    pose = _matrix(column_major).copy()
    pose[:3, 3] = metres_to_mm(pose[:3, 3])
    return pose


def pose_to_franka(pose_mm) -> list[float]:
    """Our 4x4 pose (mm) -> libfranka's 16-vector (metres, column-major)."""
    pose = np.array(pose_mm, dtype=float)
    pose[:3, 3] = mm_to_metres(pose[:3, 3])
    pose[3] = (0.0, 0.0, 0.0, 1.0)
    return [float(v) for v in pose.reshape(16, order="F")]


def ee_text(flange_from_ee) -> str:
    """An end effector as Desk gives it: X, Y, Z in mm and the rotation vector in rad."""
    pose = np.asarray(flange_from_ee, dtype=float)
    values = [*pose[:3, 3], *matrix_to_rotvec(pose[:3, :3])]
    return "X {:.1f} Y {:.1f} Z {:.1f} mm, RX {:.4f} RY {:.4f} RZ {:.4f} rad".format(*values)


def error_names(errors) -> list[str]:
    """The set flags of a libfranka ``Errors`` (its ``str`` is ``["name", ...]``)."""
    text = str(errors).strip().strip("[]")
    return [name.strip().strip('"') for name in text.split(",") if name.strip().strip('"')]


def mode_name(mode) -> str:
    """``RobotMode.Reflex`` -> ``Reflex``."""
    return str(getattr(mode, "name", mode)).rsplit(".", 1)[-1]


def condition(mode: str, errors: list[str]) -> str:
    """What stops the arm now (a ``RobotState.safety`` value), from ``robot_mode`` and
    ``current_errors``."""
    if mode in MODE_CONDITIONS:
        return MODE_CONDITIONS[mode][0]
    if mode not in READY_MODES:
        return f"{SAFETY_NOT_RUNNING}_(mode_{mode})"
    return "stopped_by_an_error" if errors else SAFETY_NORMAL


def advice(mode: str, errors: list[str]) -> str:
    """What the operator does about a robot that is not ready, one phrase."""
    if mode in MODE_CONDITIONS:
        return MODE_CONDITIONS[mode][1].format(errors=", ".join(errors) or "no error named")
    if mode not in READY_MODES:
        return f"the robot is in mode {mode}: bring it to Idle in Desk"
    return f"the robot reports errors ({', '.join(errors)}): clear them in Desk"


def server_version(host: str, deadline_s: float = REACH_DEADLINE_S) -> int:
    """The robot's command-server version, from the protocol's ``Connect`` exchange on port
    1337 (a 12-byte header, then version and UDP port; the answer a status byte and the
    server's version), all within ``deadline_s``. The connection is closed at once; nothing
    is commanded.

    Raises
    ------
    DeviceError
        Nothing accepts the connection, or what does gives no Connect answer in time.
    """
    deadline = time.monotonic() + deadline_s
    name = f"no Franka robot answers on {host}:{COMMAND_PORT}"
    try:
        with socket.create_connection((host, COMMAND_PORT), timeout=deadline_s) as connection:
            request = struct.pack("<HH", 0, 0)  # version 0 is no library's: only its answer is read
            connection.sendall(struct.pack("<III", CONNECT_COMMAND, 1, 12 + len(request)) + request)
            answer = b""
            while len(answer) < 15:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise DeviceError(f"{name} (no Connect answer within {deadline_s:g} s)")
                connection.settimeout(remaining)
                chunk = connection.recv(15 - len(answer))
                if not chunk:
                    raise DeviceError(f"{name} (it closed the connection before answering)")
                answer += chunk
    except TimeoutError:
        raise DeviceError(f"{name} (no answer within {deadline_s:g} s)") from None
    except OSError as exc:
        if isinstance(exc, DeviceError):
            raise
        raise DeviceError(f"{name} ({exc.strerror or exc})") from None
    command, _, size = struct.unpack_from("<III", answer)
    if command != CONNECT_COMMAND or size < 15:
        raise DeviceError(f"{name}: what answers is not a Franka robot's command server")
    return struct.unpack_from("<H", answer, 13)[0]


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text.removeprefix("libfranka: ").removeprefix("libfranka robot: ")


class _Motion:
    """One motion generator's run: the loop on its own thread, the latest state it read."""

    def __init__(self, name: str, duration_s: float, stop_s: float):
        self.name = name
        self.clock = PathClock(duration_s, stop_s)
        self.done = threading.Event()
        self.error: BaseException | None = None
        self.thread: threading.Thread | None = None

    @property
    def deadline_s(self) -> float:
        return self.clock.duration_s + self.clock.stop_s + MOTION_MARGIN_S


class FrankaRobot:
    """A Franka arm behind the Robot protocol.

    Parameters
    ----------
    host : str
    control : bool
        Allow motion now (after the read-only checks pass); else only after
        :meth:`connect_control`. A dry run and ``spacecal doctor`` open it without.
    robot_model : str or None
        The robot kind (default :data:`DEFAULT_KIND`).
    limits : MotionLimits, optional
        Rotation limits for straight-line moves.
    """

    def __init__(
        self,
        host: str,
        control: bool = False,
        robot_model: str | None = None,
        limits: MotionLimits | None = None,
    ):
        self._franka = require("pylibfranka", "franka")
        self.host = host
        self.kind_name = robot_model or DEFAULT_KIND
        self.model_given = robot_model is not None
        self.limits = limits or MotionLimits()
        self.kinematics = None  # libfranka publishes no calibrated kinematics
        self._server_version = server_version(host)
        try:
            self._robot = self._franka.Robot(host, self._franka.RealtimeConfig.kIgnore)
        except Exception as exc:  # pylibfranka's exceptions are RuntimeErrors of its own
            raise DeviceError(f"could not connect to the Franka robot on {host}: {_one_line(exc)}") from None
        self._lock = threading.Lock()  # one libfranka operation at a time on this connection
        self._motion: _Motion | None = None
        self._latest: tuple[object, float] | None = None  # (libfranka state, monotonic time read)
        self._stopped = False
        self._control = False
        self._lost: str | None = None
        try:
            self.nominal = self._nominal_model()
        except BaseException:
            self.close()
            raise
        if control:
            try:
                self.connect_control()
            except BaseException:
                self.close()
                raise

    # -- model ---------------------------------------------------------------------------------
    def _nominal_model(self) -> RobotModel:
        """The nominal model of the robot kind, with the end effector set in Desk (``F_T_EE``);
        a kind of another vendor is refused in one line."""
        kind = robot_kind(self.kind_name)
        if kind.vendor != FRANKA_VENDOR:
            franka_kinds = sorted(k.name for k in ROBOT_KINDS.values() if k.vendor == FRANKA_VENDOR)
            raise InvalidInputError(
                f"--robot-model {self.kind_name} is a {kind.vendor} arm; a Franka robot is one of "
                f"{', '.join(franka_kinds)}"
            )
        return kind.model(pose_from_franka(self._raw_state().F_T_EE))

    def controller_model(self) -> tuple[RobotModel, str]:
        """The model the robot computes ``O_T_EE`` with, and where it came from: libfranka
        publishes no calibrated kinematics, so the nominal model of the robot kind with the
        end effector (``F_T_EE``) set in Desk."""
        return self.nominal, f"the nominal {self.kind_name} kinematics, end effector as set in Desk"

    # -- reading -------------------------------------------------------------------------------
    def _lost_error(self, exc: BaseException | None = None) -> DeviceError:
        if exc is not None and self._lost is None:
            self._lost = _one_line(exc)
        return DeviceError(f"lost the connection to the Franka robot on {self.host} ({self._lost})")

    def _raw_state(self):
        """The newest libfranka state: the running motion's, else one read now (at most
        libfranka's 1 s UDP timeout)."""
        if self._lost is not None:
            raise self._lost_error()
        motion = self._motion
        if motion is not None and not motion.done.is_set() and self._latest is not None:
            state, read_at = self._latest
            if time.monotonic() - read_at > STALE_AFTER_S:
                raise DeviceError(
                    f"Franka state is stale: no new state for {time.monotonic() - read_at:.1f} s"
                )
            return state
        with self._lock:
            try:
                state = self._robot.read_once()
            except Exception as exc:
                raise self._lost_error(exc) from None
        self._latest = (state, time.monotonic())
        return state

    def state(self) -> RobotState:
        raw = self._raw_state()
        mode, errors = mode_name(raw.robot_mode), error_names(raw.current_errors)
        joints = np.asarray(raw.q, dtype=float)
        motion = self._motion
        moving = motion is not None and not motion.done.is_set()
        return RobotState(
            float(raw.time.to_sec()),
            joints,
            pose_from_franka(raw.O_T_EE),
            condition(mode, errors),
            moving,
        )

    # -- checks --------------------------------------------------------------------------------
    def identity(self) -> DeviceIdentity:
        """The robot's command-server version (its answer to ``Connect``). libfranka reports
        neither the model nor a serial number: the recording names the robot kind it was
        opened as, and calibrations name this robot by its address."""
        return DeviceIdentity(firmware=f"FCI server version {self._server_version}")

    def preflight(self) -> list[DeviceFinding]:
        """Read-only checks: server version, robot mode and errors, the state stream, the
        nominal kinematics against the reported pose."""
        findings: list[DeviceFinding] = []

        def add(level: str, subject: str, text: str) -> None:
            findings.append(DeviceFinding(level, subject, text))

        add(
            FINDING_OK,
            "controller version",
            f"FCI server version {self._server_version}, libfranka {self._franka.__version__}",
        )
        add(
            FINDING_OK,
            "serial number",
            "not given by libfranka: calibrations name this robot by its address",
        )
        first = self._raw_state()
        mode, errors = mode_name(first.robot_mode), error_names(first.current_errors)
        if condition(mode, errors) == SAFETY_NORMAL:
            add(FINDING_OK, "robot mode", f"{mode} (ready for commands)")
        else:
            add(FINDING_PROBLEM, "robot mode", advice(mode, errors))
        later = self._raw_state()
        if float(later.time.to_sec()) <= float(first.time.to_sec()):
            add(FINDING_PROBLEM, "robot state", "the robot's state time does not advance")
        else:
            add(FINDING_OK, "robot state", "streaming at 1 kHz")
        add(FINDING_OK, "end effector", f"set in Desk (F_T_EE): {ee_text(pose_from_franka(later.F_T_EE))}")
        joints = np.asarray(later.q, dtype=float)
        predicted = forward_kinematics(self.nominal, joints)
        error_mm = float(np.linalg.norm(predicted[:3, 3] - pose_from_franka(later.O_T_EE)[:3, 3]))
        if error_mm > MODEL_CHECK_MM:
            # a warning here, as a UR's nominal fallback: whether the run can go on is the
            # model check of the workflows (spacecal.app.devices.hardware_model), which a
            # mismatch fails
            add(
                FINDING_WARNING,
                "kinematics",
                f"the nominal {self.kind_name} model puts the end effector {error_mm:.2f} mm from where "
                "the robot reports it: check --robot-model and the end effector set in Desk",
            )
        else:
            add(
                FINDING_OK,
                "kinematics",
                f"the nominal {self.kind_name} model ({error_mm:.3f} mm from the reported pose here)",
            )
        return findings

    def connect_control(self) -> None:
        """Allow motion, after every read-only check has passed; nothing moves."""
        if self._control:
            return
        problems = [f for f in self.preflight() if f.level == FINDING_PROBLEM]
        if problems:
            raise DeviceError(
                f"the robot is not ready ({problems[0].subject}): {problems[0].text}; nothing moved"
            )
        self._control = True

    # -- motion --------------------------------------------------------------------------------
    def _refuse_motion(self) -> None:
        if not self._control:
            raise DeviceError("this Franka connection was opened read-only")
        if self._stopped:
            raise DeviceError("the Franka robot was stopped: nothing more is commanded on this connection")
        if self._motion is not None and not self._motion.done.is_set():
            raise DeviceError("the Franka robot is still moving")
        raw = self._raw_state()
        mode, errors = mode_name(raw.robot_mode), error_names(raw.current_errors)
        if condition(mode, errors) != SAFETY_NORMAL:
            raise DeviceError(f"the robot is not ready (robot mode): {advice(mode, errors)}; nothing moved")

    def _run(self, motion: _Motion, start: Callable, command: Callable) -> None:
        """The control loop: start the motion generator, then one set-point per state until
        the path is at its end (or at rest after a stop)."""
        franka = self._franka
        try:
            with self._lock:
                control = start()
                try:
                    first = True
                    while True:
                        state, period = control.readOnce()
                        self._latest = (state, time.monotonic())
                        if self._stopped:
                            motion.clock.stop()
                        s = motion.clock.advance(0.0 if first else period.to_sec())
                        finished = motion.clock.finished
                        set_point = command(state, s, first)
                        first = False
                        set_point.motion_finished = finished
                        control.writeOnce(set_point)
                        if finished:
                            break
                finally:
                    del control  # an unfinished motion is cancelled by libfranka here
        except franka.NetworkException as exc:
            motion.error = self._lost_error(exc)
        except (franka.FrankaException, RuntimeError) as exc:  # a reflex, a refused command
            motion.error = DeviceError(f"the Franka robot aborted {motion.name}: {_one_line(exc)}")
        except BaseException as exc:  # handed to the caller
            motion.error = exc
        finally:
            motion.done.set()

    def _start(self, motion: _Motion, start: Callable, command: Callable, wait: bool) -> None:
        motion.thread = threading.Thread(
            target=self._run, args=(motion, start, command), name=f"franka {motion.name}", daemon=True
        )
        self._motion = motion
        motion.thread.start()
        if wait:
            self._wait(motion)

    def _wait(self, motion: _Motion) -> None:
        """Wait for a motion to end, at most its deadline on the robot's clock (and
        :data:`WALL_DEADLINE_FACTOR` times that in wall time); a KeyboardInterrupt stops it
        first."""
        wall_deadline = time.monotonic() + WALL_DEADLINE_FACTOR * motion.deadline_s
        try:
            while not motion.done.wait(WAIT_POLL_S):
                if motion.clock.elapsed_s > motion.deadline_s or time.monotonic() > wall_deadline:
                    self._stopped = True
                    raise DeviceError(
                        f"the Franka robot did not finish {motion.name} within {motion.deadline_s:.1f} s"
                    )
        except KeyboardInterrupt:
            self.stop()
            raise
        if motion.error is not None:
            raise motion.error

    def _refuse_beyond_limits(self, target: np.ndarray) -> None:
        """One line before anything is commanded for a target outside the kind's joint limits
        (the robot would abort the motion at the limit with a reflex)."""
        lower, upper = self.nominal.joint_lower_rad, self.nominal.joint_upper_rad
        outside = np.flatnonzero((target < lower) | (target > upper))
        if outside.size:
            j = int(outside[0])
            raise InvalidInputError(
                f"joint {j + 1} target {target[j]:.4f} rad is outside the {self.kind_name}'s limits "
                f"[{lower[j]:.4f}, {upper[j]:.4f}] rad; nothing moved"
            )

    def move_joints(self, joints_rad, speed_rad_s: float, accel_rad_s2: float) -> None:
        """Move to joint angles (7,), rad, along a minimum-jerk path whose fastest joint keeps
        within ``speed_rad_s`` and ``accel_rad_s2``; return when there."""
        target = np.asarray(joints_rad, dtype=float)
        self._refuse_motion()
        start_q = np.asarray(self._raw_state().q, dtype=float)
        if target.shape != start_q.shape or not np.all(np.isfinite(target)):
            raise InvalidInputError(
                f"a Franka joint move needs {start_q.size} finite joint angles, got {target.tolist()}"
            )
        self._refuse_beyond_limits(target)
        distance = float(np.max(np.abs(target - start_q)))
        duration = path_duration(distance, speed_rad_s, accel_rad_s2)
        peak = PEAK_SPEED * distance / duration if duration > 0 else 0.0
        motion = _Motion("the joint move", duration, stop_duration(peak, STOP_DECEL_RAD_S2))
        franka = self._franka
        origin: list[np.ndarray] = []

        def command(state, s, first):
            if first:  # the path starts where the robot's own command is now
                origin.append(np.asarray(state.q_d, dtype=float))
            q0 = origin[0]
            return franka.JointPositions([float(v) for v in q0 + (target - q0) * s])

        self._start(
            motion,
            lambda: self._robot.start_joint_position_control(franka.ControllerMode.JointImpedance),
            command,
            wait=True,
        )
        if self._stopped:
            return
        settle_until = time.monotonic() + SETTLE_S
        before = np.asarray(self._raw_state().q, dtype=float)
        while True:
            time.sleep(SETTLED_OVER_S)
            reached = np.asarray(self._raw_state().q, dtype=float)
            if np.max(np.abs(reached - before)) < SETTLED_RAD or time.monotonic() > settle_until:
                break
            before = reached
        off_rad = float(np.max(np.abs(reached - target)))
        if off_rad > ARRIVAL_RAD:
            raise DeviceError(
                f"the Franka robot ended the joint move {np.degrees(off_rad):.2f} deg from its target"
            )

    def move_linear(
        self, base_from_tcp, speed_mm_s: float, accel_mm_s2: float, asynchronous: bool = False
    ) -> None:
        """Straight-line move of the end effector to a pose (4, 4), mm, along a minimum-jerk
        path within the linear limits given and the rotation limits of ``limits``; return at
        once when ``asynchronous`` (:meth:`state` says ``moving`` until it ends)."""
        target = np.asarray(base_from_tcp, dtype=float)
        if target.shape != (4, 4) or not np.all(np.isfinite(target)):
            raise InvalidInputError("a Franka straight-line move needs a finite 4x4 target pose")
        self._refuse_motion()
        here = pose_from_franka(self._raw_state().O_T_EE)
        distance = float(np.linalg.norm(target[:3, 3] - here[:3, 3]))
        angle = float(rotation_angle(here[:3, :3].T @ target[:3, :3]))
        duration = max(
            path_duration(distance, speed_mm_s, accel_mm_s2),
            path_duration(angle, self.limits.angular_speed_rad_s, self.limits.angular_accel_rad_s2),
        )
        peak = PEAK_SPEED * distance / duration if duration > 0 else 0.0
        motion = _Motion("the straight-line move", duration, stop_duration(peak, STOP_DECEL_MM_S2))
        franka = self._franka
        origin: list[np.ndarray] = []

        def command(state, s, first):
            if first:  # the path starts at the robot's own last commanded pose (libfranka's advice)
                commanded, measured = pose_from_franka(state.O_T_EE_c), pose_from_franka(state.O_T_EE)
                near = np.linalg.norm(commanded[:3, 3] - measured[:3, 3]) < START_POSE_MM
                origin.append(commanded if near and plausible_tracked_pose(commanded) else measured)
            return franka.CartesianPose(pose_to_franka(interpolate_pose(origin[0], target, s)))

        self._start(
            motion,
            lambda: self._robot.start_cartesian_pose_control(franka.ControllerMode.CartesianImpedance),
            command,
            wait=not asynchronous,
        )

    def stop(self) -> None:
        """Slow the running motion to rest and end its motion generator; nothing more is
        commanded on this connection. Returns within the stop's duration plus
        :data:`MOTION_MARGIN_S`; never raises for a robot already gone."""
        self._stopped = True
        motion = self._motion
        if motion is None or motion.thread is None:
            return
        motion.thread.join(motion.clock.stop_s + MOTION_MARGIN_S)

    def close(self) -> None:
        """Stop, then release the connection (libfranka closes its sockets with the object)."""
        self.stop()
        motion = self._motion
        if motion is not None and motion.thread is not None and motion.thread.is_alive():
            return  # the loop still holds the connection; it ends with libfranka's 1 s timeout
        with contextlib.suppress(Exception):
            del self._robot


def open_device(address: DeviceAddress, options: DeviceOptions) -> FrankaRobot:
    """The ``franka://`` row of the URL table (:data:`spacecal.adapters.DEVICE_SCHEMES`)."""
    return FrankaRobot(
        address.host, control=options.control, robot_model=options.robot_model, limits=options.limits
    )
