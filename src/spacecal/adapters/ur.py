"""Universal Robots arms over RTDE through ``ur-rtde`` (extra ``ur``, pinned to 1.6.5).

* State: ``RTDEReceiveInterface`` with a short explicit recipe (the default one is about
  1.2 kB per packet, and the controller drops clients that do not drain it). The pose comes
  in metres with a rotation vector and is converted to mm here, at the boundary.
* Motion: ``RTDEControlInterface`` (it uploads its URScript and talks to it through
  registers): ``moveJ``, ``moveL`` (optionally asynchronous), ``stopL``.
* What stops the arm, from the receive recipe (RTDE guide): ``safety_status_bits`` (protective,
  safeguard and emergency stops, violation, fault, stopped by the safety system),
  ``robot_mode`` (anything but RUNNING = 7), ``runtime_state`` and ``robot_status_bits`` (our
  control program stopped or paused on the teach pendant). A lost connection
  (``isConnected()`` turns false, but the getters keep returning the last values forever) and
  a controller timestamp that stops advancing are device errors.
* A stop ends the control program through the dashboard server (``stop``): a safeguard stop
  only pauses a program, and the controller resumes the paused move when the safeguard is
  reset; a run spacecal gave up must never move again.
* ``movel``'s ``v`` and ``a`` are the TCP's linear speed (m/s) and acceleration (m/s^2); the
  rotation of the same move gets ``4 v`` rad/s and ``4 a`` rad/s^2, and the slower profile sets
  the duration (Universal Robots' answer on their forum, "MoveL: Tool Angular Speed"). A
  rotation about the TCP is therefore commanded with ``v = angular speed / 4``.
* The controller's own kinematics, read-only from the primary client interface (port 30001):
  the robot-state message's ``KinematicsInfo`` sub-package (the factory-calibrated DH
  parameters the controller computes ``actual_TCP_pose`` with) and ``CartesianInfo`` (the TCP
  set on the teach pendant).
* Read-only checks (:meth:`URRobot.preflight`): dashboard queries (version, robot mode, safety,
  remote control), an RTDE input-recipe probe for the registers the control script needs, the
  primary interface. Opening with ``control=False`` never uploads a program.
* Every controller state for the raw robot stream (:meth:`URRobot.drain_states`): a thread
  polls the receive interface every 0.5 ms (ur_rtde keeps only the newest packet) and keeps
  each new packet, read as one.
* The client constructor returns normally after about 2.5 s with ``isConnected() == False``
  when nothing answers, and ``disconnect()`` sleeps 500 ms per interface.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import re
import socket
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from spacecal.adapters import DeviceAddress, DeviceOptions, require
from spacecal.core.errors import DeviceError, InvalidInputError
from spacecal.core.ports import (
    FINDING_OK,
    FINDING_PROBLEM,
    FINDING_WARNING,
    SAFETY_EMERGENCY_STOP,
    SAFETY_FAULT,
    SAFETY_NORMAL,
    SAFETY_NOT_RUNNING,
    SAFETY_POWERED_OFF,
    SAFETY_PROGRAM_PAUSED,
    SAFETY_PROGRAM_STOPPED,
    SAFETY_PROTECTIVE_STOP,
    SAFETY_RECOVERY,
    SAFETY_SAFEGUARD_STOP,
    SAFETY_STOPPED_BY_SAFETY,
    SAFETY_VIOLATION,
    DeviceFinding,
    DeviceIdentity,
    RobotState,
)
from spacecal.core.units import metres_to_mm, mm_to_metres
from spacecal.geometry.rotations import rotation_angle
from spacecal.geometry.transforms import invert_transform, make_transform, matrix_to_rotvec, rotvec_to_matrix
from spacecal.models.kinematics import RobotModel, forward_kinematics
from spacecal.models.robot_kinds import robot_kind, ur_kind_names
from spacecal.planning.motion import MotionLimits, trapezoid_duration

RECEIVE_VARIABLES = [
    "timestamp",
    "actual_q",
    "actual_qd",
    "actual_TCP_pose",
    "safety_status_bits",
    "robot_mode",
    "runtime_state",
    "robot_status_bits",
]
RTDE_PORT, DASHBOARD_PORT, PRIMARY_PORT = 30004, 29999, 30001
#: safety_status_bits (RTDE guide), most severe first, and what each means for a run.
SAFETY_BITS = (
    (1 << 9, SAFETY_FAULT),
    (1 << 8, SAFETY_VIOLATION),
    ((1 << 5) | (1 << 6) | (1 << 7), SAFETY_EMERGENCY_STOP),
    (1 << 2, SAFETY_PROTECTIVE_STOP),
    (1 << 4, SAFETY_SAFEGUARD_STOP),
    (1 << 3, SAFETY_RECOVERY),
    (1 << 10, SAFETY_STOPPED_BY_SAFETY),
)
PROTECTIVE_STOP_BITS = 1 << 2
EMERGENCY_STOP_BITS = (1 << 5) | (1 << 6) | (1 << 7)
ROBOT_MODES = {
    -1: "NO_CONTROLLER",
    0: "DISCONNECTED",
    1: "CONFIRM_SAFETY",
    2: "BOOTING",
    3: "POWER_OFF",
    4: "POWER_ON",
    5: "IDLE",
    6: "BACKDRIVE",
    7: "RUNNING",
    8: "UPDATING_FIRMWARE",
}
ROBOT_MODE_RUNNING, ROBOT_MODE_POWER_OFF = 7, 3
RUNTIME_PLAYING, RUNTIME_PAUSING, RUNTIME_PAUSED = 2, 3, 4
#: The RTDE inputs ur_rtde 1.6.5's control script reads (lower register range).
CONTROL_INPUTS = [f"input_int_register_{i}" for i in range(8)] + [
    f"input_double_register_{i}" for i in range(18)
]
#: movel gives the rotation 4 rad/s per m/s of ``v`` (and 4 rad/s^2 per m/s^2 of ``a``).
MOVEL_RAD_PER_M = 4.0
#: Deceleration of stopL when a run is stopped, m/s^2.
STOP_DECEL_M_S2 = 2.0
#: How long spacecal's state stream may take to show the control program running after ur_rtde
#: started it (s): as long as a loaded computer may go without a new packet.
PROGRAM_SEEN_TIMEOUT_S = 1.0
#: A controller that sends no new state within this (s) is taken as gone: a live one streams at
#: 125 or 500 Hz, and a loaded computer has been seen to go 0.1 s without a packet.
ANSWER_WITHIN_S = 0.3
#: While a motion command is on its way, a controller whose state timestamp stands still this
#: long (s) is taken as gone and the command is given up: ur_rtde's ``moveL``/``moveJ`` sent
#: to a controller that vanished wait for ever (measured: over 60 s against the fake's
#: ``vanish``), with the GIL released. The receive interface's own C++ thread advances the
#: timestamp, so a loaded computer delays this check but does not trip it.
COMMAND_SILENCE_S = 1.0
#: Deadline of an asynchronous motion command (s): it returns once the controller's program
#: took it, in milliseconds; ur_rtde's own wait for a program ready for a command is 3 s.
ASYNC_COMMAND_DEADLINE_S = 5.0
#: On closing, how long a motion command still on its thread may take to end (s) before the
#: connection is treated as dropped (a stopped program ends a waiting command at once).
PENDING_COMMAND_GRACE_S = 1.0
#: How often the wait for a motion command looks at the controller's timestamp, s.
COMMAND_POLL_S = 0.02
#: A move counts as finished within these of its target, with the joints at rest.
ARRIVAL_MM, ARRIVAL_RAD, REST_RAD_S = 0.05, 1e-4, 1e-3
#: The controller's model must reproduce its reported TCP pose to this (mm).
MODEL_CHECK_MM = 0.1
#: What to do on the pendant, per safety state.
SAFETY_ADVICE = {
    SAFETY_PROTECTIVE_STOP: "protective stop: find what the arm hit, then unlock it on the teach pendant",
    SAFETY_SAFEGUARD_STOP: "safeguard stop: close the safeguard (door, light curtain, safety input) and "
    "reset it",
    SAFETY_EMERGENCY_STOP: "emergency stop: release the emergency-stop button and reset the robot on the "
    "teach pendant",
    SAFETY_VIOLATION: "safety violation: read the teach pendant's log, fix the cause and restart the robot",
    SAFETY_FAULT: "safety system fault: read the teach pendant's log and restart the robot",
    SAFETY_RECOVERY: "safety recovery mode: jog the arm back inside its safety limits on the teach pendant",
    SAFETY_STOPPED_BY_SAFETY: "stopped by the safety system: read the teach pendant's log and reset it",
}
ROBOT_MODE_ADVICE = {
    "POWER_OFF": "the arm is powered off: power it on and release the brakes on the teach pendant",
    "POWER_ON": "the arm is powering on: release the brakes on the teach pendant",
    "IDLE": "the arm is powered on with its brakes engaged: release the brakes on the teach pendant",
    "BOOTING": "the controller is still booting: wait for it, then power on the arm",
    "CONFIRM_SAFETY": "the safety configuration waits for confirmation on the teach pendant",
    "BACKDRIVE": "the arm is in backdrive mode: leave it on the teach pendant",
}


def pose_to_ur(base_from_tcp) -> list[float]:
    """Our 4x4 pose (mm) -> UR ``[x, y, z, rx, ry, rz]`` (m, rotation vector)."""
    pose = np.asarray(base_from_tcp, dtype=float)
    return [*mm_to_metres(pose[:3, 3]).tolist(), *matrix_to_rotvec(pose[:3, :3]).tolist()]


def pose_from_ur(ur_pose) -> np.ndarray:
    """UR ``[x, y, z, rx, ry, rz]`` (m, rotation vector) -> our 4x4 pose (mm)."""
    values = np.asarray(ur_pose, dtype=float)
    return make_transform(rotvec_to_matrix(values[3:6]), metres_to_mm(values[:3]))


def tcp_text(flange_from_tcp) -> str:
    """A TCP the way the teach pendant shows it: X, Y, Z in mm, RX, RY, RZ rotation vector in rad."""
    pose = np.asarray(flange_from_tcp, dtype=float)
    values = [*pose[:3, 3], *matrix_to_rotvec(pose[:3, :3])]
    return "X {:.1f} Y {:.1f} Z {:.1f} mm, RX {:.4f} RY {:.4f} RZ {:.4f} rad".format(*values)


def controller_condition(
    safety_bits: int, robot_mode: int, runtime_state: int, program_expected: bool
) -> str:
    """What stops the arm now (a ``SAFETY_*`` value), from the RTDE state fields."""
    for mask, name in SAFETY_BITS:
        if safety_bits & mask:
            return name
    if robot_mode == ROBOT_MODE_POWER_OFF:
        return SAFETY_POWERED_OFF
    if robot_mode != ROBOT_MODE_RUNNING:
        return f"{SAFETY_NOT_RUNNING}_(mode_{ROBOT_MODES.get(robot_mode, str(robot_mode))})"
    if program_expected and runtime_state != RUNTIME_PLAYING:
        return (
            SAFETY_PROGRAM_PAUSED
            if runtime_state in (RUNTIME_PAUSING, RUNTIME_PAUSED)
            else SAFETY_PROGRAM_STOPPED
        )
    return SAFETY_NORMAL


def movel_speed(
    start, end, speed_mm_s: float, accel_mm_s2: float, limits: MotionLimits
) -> tuple[float, float]:
    """``v`` (m/s) and ``a`` (m/s^2) for a movel so the controller takes the time our plan gives
    the move (:func:`spacecal.planning.motion.time_move`): the linear limits when translation
    sets the duration, the angular limits divided by :data:`MOVEL_RAD_PER_M` when rotation does."""
    start, end = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
    distance = float(np.linalg.norm(end[:3, 3] - start[:3, 3]))
    angle = float(rotation_angle(start[:3, :3].T @ end[:3, :3]))
    linear = trapezoid_duration(distance, speed_mm_s, accel_mm_s2)[0]
    angular = trapezoid_duration(angle, limits.angular_speed_rad_s, limits.angular_accel_rad_s2)[0]
    if angular > linear:
        return limits.angular_speed_rad_s / MOVEL_RAD_PER_M, limits.angular_accel_rad_s2 / MOVEL_RAD_PER_M
    return float(mm_to_metres(speed_mm_s)), float(mm_to_metres(accel_mm_s2))


# -- connecting -----------------------------------------------------------------------------
#: Deadline of the plain connection that finds whether anything listens on the RTDE port, s.
REACH_DEADLINE_S = 3.0


def _refuse_unreachable(host: str) -> None:
    """A DeviceError when nothing accepts a connection on the RTDE port, or what accepts it
    does not go through ur_rtde's handshake (protocol and controller versions, an output recipe,
    the start and a first data package) within :data:`REACH_DEADLINE_S`. Checked with sockets of
    spacecal's own before ur_rtde is asked: ur_rtde prints its own ``connect: Connection
    refused`` to the process's stderr before it raises, a line beside spacecal's own; and its
    interfaces' constructors wait for a silent server for ever, holding the interpreter (no
    thread of the process runs meanwhile, so no deadline of spacecal's could end the wait)."""
    try:
        with socket.create_connection((host, RTDE_PORT), timeout=REACH_DEADLINE_S):
            pass
    except OSError as exc:
        reason = exc.strerror or str(exc) or type(exc).__name__
        raise DeviceError(f"no UR controller answers RTDE on {host}:{RTDE_PORT} ({reason})") from None
    try:
        with _Exchange(
            host, RTDE_PORT, "RTDE interface", REACH_DEADLINE_S, REGISTER_CHECK_MAX_BYTES
        ) as exchange:
            # what ur_rtde's receive interface does before its constructor returns: the protocol
            # and controller versions, an output recipe, the start, and a first data package
            _rtde_request(exchange, "V", struct.pack(">H", 2))
            _rtde_request(exchange, "v", b"")
            _rtde_request(exchange, "O", struct.pack(">d", 10.0) + b"timestamp")
            _rtde_request(exchange, "S", b"")
            _rtde_answer(exchange, "U")
    except DeviceError as exc:
        raise DeviceError(f"no UR controller answers RTDE on {host}:{RTDE_PORT}: {exc}") from None


@contextlib.contextmanager
def _native_stderr_held():
    """Hold what native code writes to file descriptor 2 while ur_rtde connects: shown after
    a connection that succeeds, dropped when it fails (spacecal's one-line error says why)."""
    import os
    import sys
    import tempfile

    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no usable descriptor 2 (an embedding host): nothing to hold
        yield
        return
    with tempfile.TemporaryFile() as held:
        os.dup2(held.fileno(), 2)
        failed = True
        try:
            yield
            failed = False
        finally:
            with contextlib.suppress(OSError, ValueError):
                sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            if not failed:
                held.seek(0)
                text = held.read()
                if text:
                    with contextlib.suppress(OSError):
                        os.write(2, text)


# -- read-only conversations with the controller ---------------------------------------------
def _ur_nominal(name: str) -> RobotModel:
    """The nominal model of the UR kind ``name``; a kind of another vendor is refused in one
    line (a UR controller drives only UR arms)."""
    kind = robot_kind(name)
    if not kind.is_ur:
        raise InvalidInputError(
            f"--robot-model {name} is a {kind.vendor} arm; a UR controller drives one of "
            f"{', '.join(ur_kind_names())}"
        )
    return kind.model()


def _reported_model(version_text: str, model_text: str) -> str:
    """The model a controller names (``get robot model`` says ``UR10`` on an e-Series too; its
    PolyScope 5 version makes it a ``UR10e``)."""
    reported = model_text.strip()
    version = _version(version_text)
    if reported and version is not None and reported + "e" in ur_kind_names() and version[0] >= 5:
        reported += "e"
    return reported


#: Deadline of one whole dashboard-server conversation (port 29999), s: connecting, the greeting
#: and one reply line per command (``doctor`` sends four). The server answers a query within
#: milliseconds; this leaves room for a controller busy loading a program and a loaded computer,
#: and a port that sends one byte at a time cannot stretch it (the bound is on the whole
#: conversation, not on each read).
DASHBOARD_DEADLINE_S = 3.0
#: Deadline of the dashboard ``stop`` (s), run on every way out of a run, after a fault as well:
#: a controller that has not taken it within this is taken as gone, and the further stops of
#: this process skip it (see :func:`stop_program`), so a shutdown never waits on it twice.
STOP_DEADLINE_S = 1.0
#: Longest dashboard conversation read, bytes: replies are one short line each (the longest, a
#: program path or a PolyScope 5 error text, a few hundred bytes).
DASHBOARD_MAX_BYTES = 16 * 1024
#: Deadline of reading the kinematics from the primary interface (port 30001), s: the controller
#: sends its version message on connect and the robot state at 10 Hz, so this is 20 chances.
PRIMARY_DEADLINE_S = 2.0
#: Largest primary-interface message accepted, bytes: a robot-state message is about 1.1 kB (CB3)
#: to 1.5 kB (e-Series); a larger announced size is not the primary interface.
PRIMARY_MESSAGE_MAX_BYTES = 64 * 1024
#: Most bytes read from the primary interface in one check: 2 s of robot state at 10 Hz and the
#: controller's other messages are well under 100 kB.
PRIMARY_MAX_BYTES = 1024 * 1024
#: Deadline of the RTDE register check (port 30004), s: a protocol-version request and an input
#: recipe, each answered at once by the controller.
REGISTER_CHECK_DEADLINE_S = 2.0
#: Most bytes read in the RTDE register check: the two answers are a few hundred bytes (an RTDE
#: package is at most 64 kB, its size being 16 bits).
REGISTER_CHECK_MAX_BYTES = 256 * 1024


class _Exchange:
    """One short conversation with a controller port, bounded as a whole.

    Every read waits at most until one deadline, fixed when the conversation starts (a timeout
    per read would be renewed for ever by a port that sends one byte at a time), and at most
    ``max_bytes`` are read in all. Every failure is a :class:`DeviceError` naming the port.

    Parameters
    ----------
    host : str
    port : int
    what : str
        The port's name in messages (``"dashboard server"``).
    deadline_s : float
        Time for the whole conversation, from connecting to the last reply, s.
    max_bytes : int
        Most bytes read in the whole conversation.
    """

    def __init__(self, host: str, port: int, what: str, deadline_s: float, max_bytes: int):
        self.name = f"the {what} on {host}:{port}"
        self.deadline_s = deadline_s
        self._deadline = time.monotonic() + deadline_s
        self._left = max_bytes
        self._max_bytes = max_bytes
        self._buffer = bytearray()
        try:
            self._socket = socket.create_connection((host, port), timeout=deadline_s)
        except TimeoutError:
            raise DeviceError(f"{self.name} did not accept a connection within {deadline_s:g} s") from None
        except OSError as exc:
            raise DeviceError(f"{self.name} is not reachable ({exc.strerror or exc})") from None

    def __enter__(self) -> _Exchange:
        return self

    def __exit__(self, *_) -> None:
        self.close()

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self._socket.close()

    def _remaining_s(self) -> float:
        remaining = self._deadline - time.monotonic()
        if remaining <= 0:
            raise DeviceError(f"{self.name} did not answer in full within {self.deadline_s:g} s")
        return remaining

    def send(self, data: bytes) -> None:
        self._socket.settimeout(self._remaining_s())
        try:
            self._socket.sendall(data)
        except TimeoutError:
            raise DeviceError(f"{self.name} did not take a request within {self.deadline_s:g} s") from None
        except OSError as exc:
            raise DeviceError(f"{self.name} dropped the connection ({exc.strerror or exc})") from None

    def _fill(self) -> None:
        """Read what has come, waiting at most until the deadline."""
        if self._left <= 0:
            raise DeviceError(
                f"{self.name} sent more than {self._max_bytes} bytes: not a controller's answer"
            )
        self._socket.settimeout(self._remaining_s())
        try:
            chunk = self._socket.recv(min(self._left, 1 << 16))
        except TimeoutError:
            raise DeviceError(f"{self.name} did not answer in full within {self.deadline_s:g} s") from None
        except OSError as exc:
            raise DeviceError(f"{self.name} dropped the connection ({exc.strerror or exc})") from None
        if not chunk:
            raise DeviceError(f"{self.name} closed the connection in the middle of an answer")
        self._left -= len(chunk)
        self._buffer += chunk

    def read_exact(self, count: int) -> bytes:
        """Exactly ``count`` bytes."""
        if count > self._max_bytes:
            raise DeviceError(f"{self.name} announced a {count}-byte message: not a controller's answer")
        while len(self._buffer) < count:
            self._fill()
        data = bytes(self._buffer[:count])
        del self._buffer[:count]
        return data

    def read_line(self) -> str:
        """One line, without its end."""
        while b"\n" not in self._buffer:
            self._fill()
        line, _, rest = bytes(self._buffer).partition(b"\n")
        self._buffer[:] = rest
        return line.decode("utf-8", errors="replace").strip()


def dashboard(host: str, commands: list[str], deadline_s: float = DASHBOARD_DEADLINE_S) -> list[str]:
    """Send dashboard-server commands (port 29999), one reply line each.

    Parameters
    ----------
    host : str
    commands : list of str
    deadline_s : float
        Time for the whole conversation, s (:data:`DASHBOARD_DEADLINE_S`).

    Raises
    ------
    DeviceError
        Nothing listens, the conversation is not over by the deadline, the server closed the
        connection, or it sent more than :data:`DASHBOARD_MAX_BYTES`.
    """
    replies = []
    with _Exchange(host, DASHBOARD_PORT, "dashboard server", deadline_s, DASHBOARD_MAX_BYTES) as exchange:
        exchange.read_line()  # greeting
        for command in commands:
            exchange.send((command + "\n").encode())
            replies.append(exchange.read_line())
    return replies


#: Controllers whose dashboard server stayed silent in this process (switched off, cable pulled):
#: each further attempt would only wait out its deadline again.
_SILENT_HOSTS: set[str] = set()


def stop_program(host: str) -> None:
    """Stop the running program through the dashboard server (``stop``), unless this
    controller has already failed to take it once in this process; never raises, and returns
    within :data:`STOP_DEADLINE_S` (plus the time to set up a connection)."""
    if host in _SILENT_HOSTS:
        return
    try:
        dashboard(host, ["stop"], deadline_s=STOP_DEADLINE_S)
    except (OSError, ValueError):
        _SILENT_HOSTS.add(host)


def _rtde_answer(exchange: _Exchange, kind: str) -> bytes:
    """The body of the next RTDE package of type ``kind``, skipping any other."""
    while True:
        size, answer = struct.unpack(">HB", exchange.read_exact(3))
        if size < 3:
            raise DeviceError(f"{exchange.name} sent a {size}-byte package: not RTDE")
        body = exchange.read_exact(size - 3)
        if answer == ord(kind):
            return body


def _rtde_request(exchange: _Exchange, kind: str, payload: bytes) -> bytes:
    """Send one RTDE request (package type ``kind``) and return the body of its answer."""
    exchange.send(struct.pack(">HB", len(payload) + 3, ord(kind)) + payload)
    return _rtde_answer(exchange, kind)


def registers_in_use(
    host: str, names: list[str] = CONTROL_INPUTS, deadline_s: float = REGISTER_CHECK_DEADLINE_S
) -> list[str]:
    """RTDE inputs another client holds: set up an input recipe and read which fields answer
    ``IN_USE`` (nothing is written; the recipe ends with the connection). The whole check ends
    within ``deadline_s`` (:data:`REGISTER_CHECK_DEADLINE_S`) or raises :class:`DeviceError`."""

    with _Exchange(host, RTDE_PORT, "RTDE interface", deadline_s, REGISTER_CHECK_MAX_BYTES) as exchange:
        _rtde_request(exchange, "V", struct.pack(">H", 2))
        reply = _rtde_request(exchange, "I", ",".join(names).encode())
    types = reply[1:].decode(errors="replace").split(",")
    return [name for name, kind in zip(names, types) if kind == "IN_USE"]


@dataclass(frozen=True)
class ControllerKinematics:
    """The controller's kinematic model as its primary interface publishes it.

    Attributes
    ----------
    checksums : tuple of 6 int
        Per-joint calibration checksums (``KinematicsInfo``).
    theta_rad, a_mm, d_mm, alpha_rad : numpy.ndarray, shape (6,)
        The DH parameters the controller computes with: nominal plus factory-calibration deltas.
    calibration_status : int
    flange_from_tcp : numpy.ndarray, shape (4, 4), or None
        The TCP set on the teach pendant (``CartesianInfo``), mm; None if not sent.
    """

    checksums: tuple[int, ...]
    theta_rad: np.ndarray
    a_mm: np.ndarray
    d_mm: np.ndarray
    alpha_rad: np.ndarray
    calibration_status: int
    flange_from_tcp: np.ndarray | None

    def model(self, nominal: RobotModel, flange_from_tcp) -> RobotModel:
        """``nominal`` (name, limits) with these DH parameters and a TCP (4, 4), mm."""
        return dataclasses.replace(
            nominal,
            a_mm=self.a_mm.copy(),
            d_mm=self.d_mm.copy(),
            alpha_rad=self.alpha_rad.copy(),
            theta_offset_rad=self.theta_rad.copy(),
            flange_from_tcp=np.asarray(flange_from_tcp, dtype=float),
        )


class UnusableKinematics(ValueError):
    """The primary interface published kinematics that are not numbers a model can hold."""


def read_primary_interface(host: str, deadline_s: float = PRIMARY_DEADLINE_S) -> ControllerKinematics:
    """The ``KinematicsInfo`` and ``CartesianInfo`` of the primary interface's robot-state
    message (type 16; sub-packages 5 and 4), as Universal_Robots_Client_Library parses them.

    Raises
    ------
    DeviceError
        No robot state with kinematics within ``deadline_s`` (:data:`PRIMARY_DEADLINE_S`), a
        message announced larger than :data:`PRIMARY_MESSAGE_MAX_BYTES`, more than
        :data:`PRIMARY_MAX_BYTES` read, or the connection closed.
    UnusableKinematics
        DH parameters or a TCP that are not finite numbers (a controller fault).
    """
    with _Exchange(host, PRIMARY_PORT, "primary interface", deadline_s, PRIMARY_MAX_BYTES) as exchange:
        while True:
            size, kind = struct.unpack(">iB", exchange.read_exact(5))
            if not 5 <= size <= PRIMARY_MESSAGE_MAX_BYTES:
                raise DeviceError(
                    f"{exchange.name} announced a {size}-byte message (at most "
                    f"{PRIMARY_MESSAGE_MAX_BYTES} are accepted): not the primary interface"
                )
            body = exchange.read_exact(size - 5)
            if kind != 16:  # version and other robot messages
                continue
            found: dict[int, bytes] = {}
            offset = 0
            while offset + 5 <= len(body):
                sub_size, sub_kind = struct.unpack_from(">IB", body, offset)
                if sub_size < 5:
                    break
                found[sub_kind] = body[offset + 5 : offset + sub_size]
                offset += sub_size
            if 5 not in found:
                continue
            info = found[5]
            checksums = struct.unpack_from(">6I", info, 0)
            theta, a, d, alpha = (np.array(struct.unpack_from(">6d", info, 24 + 48 * k)) for k in range(4))
            status = struct.unpack_from(">I", info, 216)[0] if len(info) >= 220 else 0
            tcp = None
            cartesian = found.get(4, b"")
            if len(cartesian) >= 96:
                offset_values = np.array(struct.unpack_from(">6d", cartesian, 48))
                tcp = make_transform(rotvec_to_matrix(offset_values[3:]), metres_to_mm(offset_values[:3]))
            for name, values in (
                ("DH theta", theta),
                ("DH a", a),
                ("DH d", d),
                ("DH alpha", alpha),
                ("TCP", tcp),
            ):
                if values is not None and not np.all(np.isfinite(values)):
                    raise UnusableKinematics(
                        "the controller's primary interface published kinematics that are not finite "
                        f"numbers ({name}): a controller fault; spacecal cannot compute the TCP with "
                        "its model"
                    )
            return ControllerKinematics(
                tuple(int(c) for c in checksums),
                theta,
                metres_to_mm(a),
                metres_to_mm(d),
                alpha,
                int(status),
                tcp,
            )


#: The first PolyScope version whose dashboard server answers ``get serial number``.
SERIAL_NUMBER_SINCE = (5, 6)


def _version(text: str) -> tuple[int, ...] | None:
    match = re.search(r"(\d+)\.(\d+)\.(\d+)(?:\.(\d+))?", text)
    return tuple(int(v) for v in match.groups() if v is not None) if match else None


#: How often the state stream polls the receive interface for a new controller state, s (the
#: controller sends one every 8 ms on a CB3 and every 2 ms on an e-Series).
STREAM_POLL_S = 0.0005
#: The state stream keeps at most this many states between two drains (a minute at 500 Hz).
STREAM_CAPACITY = 30_000


class StateStream:
    """Every controller state as the controller sends it, for the raw robot stream.

    ur_rtde's receive interface keeps only the newest packet; a thread polls it at well above
    the controller's rate and keeps each new packet's timestamp, joints and TCP pose (read as
    one packet: see :meth:`URRobot._read_packet`). Started on first use, so a dry run and
    ``spacecal doctor`` never start it.
    """

    def __init__(self, read_packet: Callable[[], tuple]):
        self._read_packet = read_packet
        self._states: collections.deque[RobotState] = collections.deque(maxlen=STREAM_CAPACITY)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ur-state-stream", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        last = None
        while not self._stop.is_set():
            try:
                timestamp, joints, pose, *_ = self._read_packet()
            except (RuntimeError, OSError):
                return  # the connection is gone; state() reports it
            if timestamp != last:
                last = timestamp
                with self._lock:
                    self._states.append(RobotState(timestamp, joints, pose))
            time.sleep(STREAM_POLL_S)

    def drain(self) -> list[RobotState]:
        with self._lock:
            states = list(self._states)
            self._states.clear()
        return states

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)


class URRobot:
    """A UR arm behind the Robot protocol.

    Parameters
    ----------
    host : str
    control : bool
        Connect the control interface too (uploads the control program). Without it nothing
        is uploaded or written: a dry run and ``spacecal doctor`` use it so.
    stale_after_s : float
        A controller timestamp that does not advance for this long (wall time) is stale.
    robot_model : str or None
        The nominal model (``UR10``, ``UR10e``, ...) the controller's kinematics refine; None
        takes the one the controller names (dashboard ``get robot model``, with ``e`` for a
        PolyScope 5 controller). A model given that differs from the controller's is a
        preflight problem.
    limits : MotionLimits, optional
        The plan's rotation limits: rotation-led moves are commanded with them.
    """

    def __init__(
        self,
        host: str,
        control: bool = True,
        stale_after_s: float = 0.5,
        robot_model: str | None = None,
        limits: MotionLimits | None = None,
    ):
        rtde_receive = require("rtde_receive", "ur")
        self.host = host
        self.stale_after_s = stale_after_s
        self.limits = limits or MotionLimits()
        #: whether the model was given (--robot-model) or taken from the controller
        self.model_given = robot_model is not None
        given = _ur_nominal(robot_model) if robot_model is not None else None
        self._control = None
        self._program_expected = False
        #: whether the controller answered when the run was stopped (None: not stopped yet)
        self._answers: bool | None = None
        #: A motion command still on its worker thread, and the one the controller never
        #: answered (then nothing more is sent on the control connection).
        self._pending: threading.Thread | None = None
        self._stuck: str | None = None
        self._target: np.ndarray | None = None
        self._last_timestamp: float | None = None
        self._last_change = time.monotonic()
        self._stream: StateStream | None = None
        _refuse_unreachable(host)
        try:
            with _native_stderr_held():
                self._receive = rtde_receive.RTDEReceiveInterface(host, -1.0, RECEIVE_VARIABLES)
        except RuntimeError as exc:  # nothing listens: ur_rtde raises "Could not connect to ..."
            raise DeviceError(f"no UR controller answers RTDE on {host}:30004 ({exc})") from None
        if not self._receive.isConnected():
            raise DeviceError(f"no UR controller answers RTDE on {host}:30004")
        try:
            self.nominal = given if given is not None else _ur_nominal(self._controller_model_name())
        except BaseException:
            self.close()
            raise
        #: Why the controller's kinematics were refused, when they were (not when unread).
        self.kinematics_refused: str | None = None
        try:
            self.kinematics: ControllerKinematics | None = read_primary_interface(host)
        except UnusableKinematics as exc:
            self.kinematics, self.kinematics_refused = None, str(exc)
        except (OSError, ValueError, struct.error):
            self.kinematics = None
        if control:
            try:
                self.connect_control()
            except BaseException:
                self.close()
                raise

    def _controller_model_name(self) -> str:
        """The model the controller names, for a run without ``--robot-model``."""
        try:
            version_text, model_text = dashboard(self.host, ["PolyscopeVersion", "get robot model"])
        except OSError as exc:
            raise DeviceError(
                f"the UR controller on {self.host} did not say its model ({exc}); pass --robot-model"
            ) from None
        reported = _reported_model(version_text, model_text)
        if reported not in ur_kind_names():
            raise DeviceError(
                f"the UR controller on {self.host} names its model {model_text.strip()[:40]!r}, which "
                f"spacecal does not know ({', '.join(sorted(ur_kind_names()))}); pass --robot-model"
            )
        return reported

    def connect_control(self) -> None:
        """Upload the control program (after the read-only checks pass), so the arm can move."""
        if self._control is not None:
            return
        problems = [f for f in self.preflight() if f.level == FINDING_PROBLEM]
        if problems:
            raise DeviceError(
                f"the robot is not ready ({problems[0].subject}): {problems[0].text}; nothing moved"
            )
        rtde_control = require("rtde_control", "ur")
        try:
            with _native_stderr_held():
                control = rtde_control.RTDEControlInterface(self.host)
        except RuntimeError as exc:
            raise DeviceError(
                f"the UR controller on {self.host} did not start spacecal's control program ({exc}); "
                "check the teach pendant (remote control, robot running, no other program holding the RTDE "
                "registers); nothing moved"
            ) from None
        self._control = control
        if not control.isConnected():
            raise DeviceError(f"the UR control interface on {self.host} did not connect; nothing moved")
        # ur_rtde returns once its own RTDE connection shows the program running; ours is a second
        # connection read by its own thread, whose newest packet may be older (a busy computer, a
        # congested link) and would read as "program stopped on the teach pendant". A program
        # that really stopped still shows as stopped after this wait.
        deadline = time.monotonic() + PROGRAM_SEEN_TIMEOUT_S
        while int(self._receive.getRuntimeState()) != RUNTIME_PLAYING and time.monotonic() < deadline:
            time.sleep(0.004)
        self._program_expected = True
        if self._stream is None:  # states from before the first move: the first frames pair with them
            self._stream = StateStream(self._read_packet)

    # -- read-only checks --------------------------------------------------------------
    def identity(self) -> DeviceIdentity:
        """The controller's model, PolyScope version and, from PolyScope 5.6 on (the first that
        answers ``get serial number``), its serial number; from the dashboard server, each
        conversation within its deadline. A controller that does not answer has an identity of
        Nones."""
        try:
            version_text, model_text = dashboard(self.host, ["PolyscopeVersion", "get robot model"])
        except (OSError, ValueError):
            return DeviceIdentity()
        version = _version(version_text)
        serial = None
        if version is not None and version >= SERIAL_NUMBER_SINCE:
            try:
                (serial,) = dashboard(self.host, ["get serial number"])
            except (OSError, ValueError):
                serial = None
        return DeviceIdentity(
            model=_reported_model(version_text, model_text) or None,
            serial=serial,
            firmware=None if version is None else "PolyScope " + ".".join(map(str, version)),
        )

    def controller_model(self) -> tuple[RobotModel, str]:
        """The model the controller computes ``actual_TCP_pose`` with: its DH parameters
        (factory-calibrated where it is) and the TCP set on the teach pendant; and where it
        came from."""
        state = self._raw_state()
        if self.kinematics is not None:
            dh = self.kinematics.model(self.nominal, np.eye(4))
            source = "the controller's calibrated kinematics (primary interface)"
            if self.kinematics.flange_from_tcp is not None:
                return dh.with_tcp(self.kinematics.flange_from_tcp), source
        else:
            dh = self.nominal
            source = "the nominal kinematics (the controller's were not available)"
        # the TCP from where the controller reports it, relative to the flange by the model
        flange = forward_kinematics(dh, state[1], to_tcp=False)
        return dh.with_tcp(
            invert_transform(flange) @ state[2]
        ), source + ", TCP derived from the reported pose"

    def _raw_state(self) -> tuple[float, np.ndarray, np.ndarray]:
        timestamp, joints, pose, *_ = self._read_packet()
        return timestamp, joints, pose

    def preflight(self) -> list[DeviceFinding]:
        """Read-only checks of the controller: what a run needs, in a robot operator's words."""
        findings: list[DeviceFinding] = []

        def add(level: str, subject: str, text: str) -> None:
            findings.append(DeviceFinding(level, subject, text))

        version: tuple[int, ...] | None = None
        try:
            version_text, model_text, remote, program = dashboard(
                self.host, ["PolyscopeVersion", "get robot model", "is in remote control", "programState"]
            )
        except OSError as exc:
            add(FINDING_PROBLEM, "dashboard", f"no answer: {exc}")
            version_text = model_text = remote = program = ""
        else:
            version = _version(version_text)
            if version is None:
                add(FINDING_WARNING, "controller version", f"not understood: {version_text!r}")
            else:
                eseries = version[0] >= 5
                add(
                    FINDING_OK,
                    "controller version",
                    f"PolyScope {'.'.join(map(str, version))} ({'e-Series' if eseries else 'CB3'}), "
                    f"robot state at {500 if eseries else 125} Hz",
                )
                serial = self.identity().serial if version >= SERIAL_NUMBER_SINCE else None
                add(
                    FINDING_OK,
                    "serial number",
                    serial
                    if serial is not None
                    else "not given (PolyScope answers it from 5.6 on): calibrations name this robot by "
                    "its address",
                )
                if eseries and "true" not in remote.lower():
                    add(
                        FINDING_PROBLEM,
                        "remote control",
                        "the teach pendant is in Local control: switch it to Remote Control (the icon at the "
                        "top right of the pendant) so spacecal may move the robot",
                    )
                elif eseries:
                    add(FINDING_OK, "remote control", "on")
            reported = _reported_model(version_text, model_text)
            if reported in ur_kind_names() and reported == self.nominal.name and not self.model_given:
                add(FINDING_OK, "robot model", f"{reported}, as the controller names it")
            if reported in ur_kind_names() and reported != self.nominal.name:
                add(
                    FINDING_PROBLEM,
                    "robot model",
                    f"the controller says this is a {reported}, but --robot-model is {self.nominal.name}: "
                    f"pass --robot-model {reported}",
                )
            if program.startswith("PLAYING") and not self._program_expected:
                add(
                    FINDING_WARNING,
                    "program",
                    f"a program is running on the robot ({program}); "
                    "spacecal's control program will replace it",
                )
        timestamp, joints, pose = self._raw_state()
        mode = int(self._receive.getRobotMode())
        mode_name = ROBOT_MODES.get(mode, str(mode))
        if mode == ROBOT_MODE_RUNNING:
            add(FINDING_OK, "robot mode", "RUNNING (powered on, brakes released)")
        else:
            add(
                FINDING_PROBLEM,
                "robot mode",
                ROBOT_MODE_ADVICE.get(
                    mode_name, f"the arm is in mode {mode_name}: bring it to RUNNING on the teach pendant"
                ),
            )
        safety = controller_condition(
            int(self._receive.getSafetyStatusBits()), ROBOT_MODE_RUNNING, RUNTIME_PLAYING, False
        )
        if safety == SAFETY_NORMAL:
            add(FINDING_OK, "safety", "normal")
        else:
            add(FINDING_PROBLEM, "safety", SAFETY_ADVICE.get(safety, safety.replace("_", " ")))
        try:
            taken = registers_in_use(self.host) if not self._program_expected else []
        except (OSError, ValueError, struct.error) as exc:
            add(FINDING_WARNING, "RTDE registers", f"could not be checked ({exc})")
        else:
            if taken:
                add(
                    FINDING_PROBLEM,
                    "RTDE registers",
                    f"{len(taken)} RTDE input registers spacecal's control program needs ({taken[0]}, ...) "
                    "are held by another program: disable the URCap or fieldbus (EtherNet/IP, PROFINET) "
                    "using them "
                    "in the Installation tab, or close the other RTDE client",
                )
            else:
                add(FINDING_OK, "RTDE registers", "the input registers spacecal needs are free")
        model, _ = self.controller_model()
        predicted = forward_kinematics(model, joints)
        error_mm = float(np.linalg.norm(predicted[:3, 3] - pose[:3, 3]))
        nominal = forward_kinematics(self.nominal.with_tcp(model.flange_from_tcp), joints)
        from_nominal_mm = float(np.linalg.norm(nominal[:3, 3] - pose[:3, 3]))
        if self.kinematics_refused is not None:
            add(FINDING_PROBLEM, "kinematics", self.kinematics_refused)
        elif self.kinematics is None:
            add(
                FINDING_WARNING,
                "kinematics",
                f"the controller's kinematics could not be read from {self.host}:{PRIMARY_PORT}; "
                f"spacecal plans with the nominal {self.nominal.name} model "
                f"(the TCP is {from_nominal_mm:.1f} mm from it here)",
            )
        elif error_mm > MODEL_CHECK_MM:
            add(
                FINDING_PROBLEM,
                "kinematics",
                f"the controller's published kinematics put the TCP {error_mm:.2f} mm from where it "
                "reports it: "
                "its model cannot be used",
            )
        else:
            calibrated = from_nominal_mm > 0.01 or any(self.kinematics.checksums)
            add(
                FINDING_OK,
                "kinematics",
                (
                    f"factory-calibrated (checksums {' '.join(str(c) for c in self.kinematics.checksums)}); "
                    f"{from_nominal_mm:.1f} mm from the nominal {self.nominal.name} here"
                )
                if calibrated
                else f"the nominal {self.nominal.name} model (no factory calibration published)",
            )
        add(FINDING_OK, "tool (TCP)", f"set on the teach pendant: {tcp_text(model.flange_from_tcp)}")
        # a loaded computer may see no new packet for a while
        if not self._timestamp_advances(timestamp, within_s=1.0):
            add(FINDING_PROBLEM, "robot state", "the controller's RTDE timestamp does not advance")
        return findings

    # -- Robot protocol ----------------------------------------------------------------
    def _read_packet(self) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, int, int, int]:
        """One RTDE packet's fields. Each ur_rtde getter reads the newest packet on its own, so a
        packet arriving between two getters would pair one tick's joints with the next tick's
        pose (0.8 mm apart at 100 mm/s and 125 Hz): read until the timestamp is the same before
        and after."""
        receive = self._receive
        for _ in range(5):
            timestamp = float(receive.getTimestamp())
            fields = (
                np.asarray(receive.getActualQ(), dtype=float),
                pose_from_ur(receive.getActualTCPPose()),
                np.asarray(receive.getActualQd(), dtype=float),
                int(receive.getSafetyStatusBits()),
                int(receive.getRobotMode()),
                int(receive.getRuntimeState()),
            )
            if float(receive.getTimestamp()) == timestamp:
                break
        return (timestamp, *fields)

    def state(self) -> RobotState:
        if not self._receive.isConnected():
            raise DeviceError(f"lost the RTDE connection to {self.host}")
        timestamp, joints, pose, speeds, safety_bits, mode, runtime = self._read_packet()
        now = time.monotonic()
        if timestamp != self._last_timestamp:
            self._last_timestamp, self._last_change = timestamp, now
        elif now - self._last_change > self.stale_after_s:
            raise DeviceError(
                f"UR state is stale: its timestamp has not advanced for {now - self._last_change:.1f} s"
            )
        safety = controller_condition(safety_bits, mode, runtime, self._program_expected)
        moving = False
        if self._target is not None:
            arrived = (
                np.linalg.norm(pose[:3, 3] - self._target[:3, 3]) < ARRIVAL_MM
                and rotation_angle(pose[:3, :3] @ self._target[:3, :3].T) < ARRIVAL_RAD
                and np.max(np.abs(speeds)) < REST_RAD_S
            )
            moving = not arrived and safety == SAFETY_NORMAL
            if not moving:
                self._target = None
        return RobotState(timestamp, joints, pose, safety, moving)

    def drain_states(self) -> list[RobotState]:
        """Every controller state since the last call, oldest first (each with the controller's
        own timestamp, joints and TCP pose; safety and motion are :meth:`state`'s)."""
        if self._stream is None:
            self._stream = StateStream(self._read_packet)
        return self._stream.drain()

    def _require_control(self):
        if self._control is None:
            raise DeviceError("this UR connection was opened read-only")
        if not self._control.isConnected():
            raise DeviceError(f"lost the UR control connection to {self.host}")
        return self._control

    def _refused(self, command: str) -> DeviceError:
        """Why the controller did not take a command: a connection dropped at that moment is
        named as such (the stop's own state is read by the caller); else the refusal."""
        deadline = time.monotonic() + 0.3
        while time.monotonic() < deadline:
            if not self._receive.isConnected() or (
                self._control is not None and not self._control.isConnected()
            ):
                return DeviceError(f"lost the RTDE connection to {self.host}")
            time.sleep(0.02)
        return DeviceError(f"the UR controller refused or aborted {command}")

    def _commanded(self, what: str, call: Callable[[], bool], deadline_s: float | None) -> bool:
        """Run one ur_rtde motion command on a worker thread and wait for it while the
        controller keeps streaming its state, at most ``deadline_s`` (None: as long as it
        streams, for a synchronous move).

        A command that the controller stops answering is given up and left to its thread
        (ur_rtde offers no way to cancel it), and no further command is sent on this
        connection: the stop then goes through the dashboard server, which has deadlines.

        Raises
        ------
        DeviceError
            The controller fell silent (:data:`COMMAND_SILENCE_S`) or the deadline passed.
        """
        if self._stuck is not None:
            raise DeviceError(f"the UR controller on {self.host} did not answer {self._stuck}: lost")
        outcome: dict[str, object] = {}

        def send() -> None:
            try:
                outcome["value"] = call()
            except BaseException as exc:  # handed to the caller below
                outcome["error"] = exc

        worker = threading.Thread(target=send, name=f"ur {what}", daemon=True)
        started = last_advance = time.monotonic()
        stamp = float(self._receive.getTimestamp())
        self._pending = worker
        worker.start()
        while True:
            worker.join(COMMAND_POLL_S)
            if not worker.is_alive():
                break
            now = time.monotonic()
            latest = float(self._receive.getTimestamp())
            if latest != stamp:
                stamp, last_advance = latest, now
            silent = now - last_advance > COMMAND_SILENCE_S
            if silent or (deadline_s is not None and now - started > deadline_s):
                self._stuck = what
                self._answers = False
                why = (
                    f"its state stood still for {COMMAND_SILENCE_S:g} s"
                    if silent
                    else f"not within {deadline_s:g} s"
                )
                raise DeviceError(f"the UR controller on {self.host} did not answer {what} ({why}): lost")
        self._pending = None
        if "error" in outcome:
            raise outcome["error"]  # type: ignore[misc]
        return bool(outcome.get("value"))

    def move_joints(self, joints_rad, speed_rad_s: float, accel_rad_s2: float) -> None:
        control = self._require_control()
        joints = [float(v) for v in joints_rad]
        if not self._commanded("moveJ", lambda: control.moveJ(joints, speed_rad_s, accel_rad_s2), None):
            raise self._refused("moveJ")

    def move_linear(
        self, base_from_tcp, speed_mm_s: float, accel_mm_s2: float, asynchronous: bool = False
    ) -> None:
        control = self._require_control()
        target = np.asarray(base_from_tcp, dtype=float)
        here = pose_from_ur(self._receive.getActualTCPPose())
        speed_m_s, accel_m_s2 = movel_speed(here, target, speed_mm_s, accel_mm_s2, self.limits)
        pose = pose_to_ur(target)
        if not self._commanded(
            "moveL",
            lambda: control.moveL(pose, speed_m_s, accel_m_s2, asynchronous),
            ASYNC_COMMAND_DEADLINE_S if asynchronous else None,
        ):
            raise self._refused("moveL")
        self._target = target if asynchronous else None

    def _controller_answers(self) -> bool:
        """Whether the controller still streams its state (a new RTDE timestamp within
        :data:`ANSWER_WITHIN_S`). ur_rtde's ``isConnected()`` stays true while its thread tries
        to reconnect to a controller that is gone (switched off, its cable pulled) and its getters
        keep the last values, and a command sent then waits for an answer for ever, where no
        signal can end it (measured against the fake controller's ``vanish``)."""
        return self._receive.isConnected() and self._timestamp_advances(
            float(self._receive.getTimestamp()), ANSWER_WITHIN_S
        )

    def _timestamp_advances(self, since: float, within_s: float) -> bool:
        """Whether the RTDE timestamp moves on from ``since`` (s) within ``within_s`` (s)."""
        deadline = time.monotonic() + within_s
        while float(self._receive.getTimestamp()) == since:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.002)
        return True

    def stop(self) -> None:
        """Stop now and end the control program, so nothing (a safeguard reset, an unlocked
        protective stop, the pendant's play button) can resume a move spacecal gave up."""
        self._target = None
        if self._control is None:
            return  # read-only: nothing of ours runs on the controller
        self._program_expected = False
        # a command still on its thread (an interrupt while it was being sent) holds the
        # control connection: the stop then goes through the dashboard server alone
        pending = self._pending is not None and self._pending.is_alive()
        self._answers = self._stuck is None and self._controller_answers()
        with contextlib.suppress(RuntimeError, OSError):
            if (
                self._answers
                and not pending
                and self._control.isConnected()
                and int(self._receive.getRuntimeState()) == RUNTIME_PLAYING
                and int(self._receive.getSafetyStatusBits()) & ~0b11 == 0  # normal or reduced
            ):
                self._control.stopL(STOP_DECEL_M_S2)
        stop_program(self.host)

    def close(self) -> None:
        if self._stream is not None:
            self._stream.close()
        if self._pending is not None:
            self._pending.join(PENDING_COMMAND_GRACE_S)
            if self._pending.is_alive():  # never answered: the connection is as good as dropped
                self._answers = False
        answers = self._answers if self._answers is not None else self._controller_answers()
        dropped = not answers or (self._control is not None and not self._control.isConnected())
        if self._control is not None:
            with contextlib.suppress(RuntimeError):
                if not dropped:
                    self._control.stopScript()
            # after a drop this also ends ur_rtde's own reconnecting thread, which would upload
            # its control script again
            with contextlib.suppress(RuntimeError):
                self._control.disconnect()
            if dropped:
                _keep_forever(self._control, self.host)
            if not self._program_expected:
                # stopped: ur_rtde reconnects by itself after a dropped connection and uploads its
                # program again; end whatever it left running
                stop_program(self.host)
        if dropped:
            _keep_forever(self._receive, self.host)
        else:
            self._receive.disconnect()


#: Interfaces left alive after a dropped connection, with their controllers' hosts (see
#: :func:`_keep_forever`).
_KEPT_FOREVER: list[tuple[object, str]] = []


def _keep_forever(interface: object, host: str) -> None:
    """Never destroy ``interface``: ur_rtde 1.6.5's interfaces crash the process (segmentation
    fault) when they are destroyed, or disconnected, while their own thread reconnects after
    the controller closed the RTDE connection (measured against the fake controller), which
    would turn a clean "lost the RTDE connection" exit into a crash. Only the objects' memory
    stays; :func:`end_programs_left_running` ends what their thread may upload again."""
    import ctypes

    ctypes.pythonapi.Py_IncRef(ctypes.py_object(interface))
    _KEPT_FOREVER.append((interface, host))


def interfaces_left_running() -> bool:
    """Whether a dropped connection left ur_rtde interfaces alive in this process: their
    threads may still be reconnecting (and uploading their control script again), so the
    process should end with :func:`end_programs_left_running` and without the interpreter's
    teardown (which would run C++ destructors under those threads)."""
    return bool(_KEPT_FOREVER)


def end_programs_left_running() -> None:
    """Stop, through the dashboard, whatever program runs on the controllers whose interfaces
    were left alive: ur_rtde's reconnecting thread uploads its control script again when the
    controller answers, so this is the last thing a process does before it ends (the thread
    ends with it)."""
    for host in dict.fromkeys(host for _, host in _KEPT_FOREVER):
        stop_program(host)


def open_device(address: DeviceAddress, options: DeviceOptions) -> URRobot:
    """The ``ur://`` row of the URL table (:data:`spacecal.adapters.DEVICE_SCHEMES`)."""
    return URRobot(
        address.host, control=options.control, robot_model=options.robot_model, limits=options.limits
    )
