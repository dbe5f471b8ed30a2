"""A fake Universal Robots controller: RTDE (30004), dashboard (29999), script (30003) and the
primary/secondary client interfaces (30001/30002) on one loopback address, driving the world's
simulated robot. It behaves as a CB3 (software 3.x, 125 Hz) or an e-Series (5.x, 500 Hz)
controller (:data:`GENERATIONS`).

What a real controller does and this fake models (``control()`` injects each):

* safety stops by ``safety_status_bits`` (RTDE guide: 0 normal, 1 reduced, 2 protective,
  3 recovery, 4 safeguard, 5 system emergency, 6 robot emergency, 7 emergency, 8 violation,
  9 fault, 10 stopped due to safety) and ``safety_mode``; a **safeguard stop pauses the program
  and the program continues its move when the safeguard is reset**, unless it was stopped;
* ``robot_mode`` (7 RUNNING, 3 POWER_OFF, 5 IDLE, 2 BOOTING ...), ``runtime_state`` (1 stopped,
  2 playing, 4 paused) and ``robot_status_bits`` (bit 0 power on, bit 1 program running): a
  program stopped or paused on the pendant stops the robot and answers no more commands;
* two RTDE connections see the same ticks at different moments: a busy client thread or a
  congested link delivers one stream late (``lag_read_only S`` delays the packets of the
  clients without an input recipe, the read-only ones, by S seconds);
* a controller switched off or cut from the network (``vanish``): every connection falls silent
  (no data, no replies, no close) and new ones are accepted but never answered;
* e-Series in local control: ``is in remote control`` answers false and the script port
  refuses programs; RTDE input registers owned by another client: the input setup answers
  ``IN_USE`` for them;
* ``movel``: ``v``/``a`` limit the TCP's linear motion in m/s, m/s^2; the rotation of the
  same move is limited to ``4 v`` rad/s and ``4 a`` rad/s^2 and the slower of the two profiles
  sets the duration (UR's answer on the UR forum, "MoveL: Tool Angular Speed");
* the controller's own (factory-calibrated) DH parameters and the pendant's TCP: the robot
  reports ``actual_TCP_pose`` through them, and the primary interface's robot-state message
  carries them (``KinematicsInfo`` sub-package 5: checksums, DH theta, a, d, alpha, calibration
  status, as parsed by Universal_Robots_Client_Library; ``CartesianInfo`` sub-package 4: TCP
  pose then TCP offset, m and rotation vector).

RTDE framing: big-endian ``uint16 size`` (including the 3-byte header) + ``uint8 type``.
The real ur_rtde client decodes data packets with its own name->type table, so ours must
agree (TYPES below). The control interface uploads a URScript and then talks to it through
registers: it writes a command id to ``input_int_register_0`` and arguments to
``input_double_register_*``; the script answers on ``output_int_register_0`` (1 = ready,
2 = done) and reports asynchronous progress on ``output_int_register_2`` (< 0 idle).
"""

from __future__ import annotations

import collections
import dataclasses
import json
import re
import socket
import struct
import sys
import threading
import time
from dataclasses import dataclass

import numpy as np

from spacecal.geometry.transforms import (
    invert_transform,
    make_transform,
    matrix_to_rotvec,
    rotvec_to_matrix,
)
from spacecal.testing.fakes.net import accept_connections, listen

RTDE_PORT, DASHBOARD_PORT, SCRIPT_PORT = 30004, 29999, 30003
PRIMARY_PORT, SECONDARY_PORT = 30001, 30002


@dataclass(frozen=True)
class Generation:
    """What differs between controller generations, as clients see it."""

    version: tuple[int, int, int, int]
    max_hz: float
    polyscope: str
    serial: str
    robot_model: str


GENERATIONS = {
    "cb3": Generation(
        (3, 15, 7, 106331), 125.0, "URSoftware 3.15.7.106331 (Sep 06 2021)", "2018300000", "UR10"
    ),
    "eseries": Generation(
        (5, 11, 1, 108318), 500.0, "URSoftware 5.11.1.108318 (Jul 08 2021)", "20195500000", "UR10e"
    ),
}
#: safety state -> (safety_status_bits, safety_mode, dashboard ``safetystatus`` word)
SAFETY = {
    "normal": (1 << 0, 1, "NORMAL"),
    "protective_stop": (1 << 2, 3, "PROTECTIVE_STOP"),
    "safeguard_stop": (1 << 4, 5, "SAFEGUARD_STOP"),
    "system_emergency_stop": ((1 << 5) | (1 << 7), 6, "SYSTEM_EMERGENCY_STOP"),
    "emergency_stop": ((1 << 6) | (1 << 7), 7, "ROBOT_EMERGENCY_STOP"),
    "violation": ((1 << 8) | (1 << 10), 8, "VIOLATION"),
    "fault": ((1 << 9) | (1 << 10), 9, "FAULT"),
}
ROBOT_MODES = {
    "NO_CONTROLLER": -1,
    "DISCONNECTED": 0,
    "CONFIRM_SAFETY": 1,
    "BOOTING": 2,
    "POWER_OFF": 3,
    "POWER_ON": 4,
    "IDLE": 5,
    "BACKDRIVE": 6,
    "RUNNING": 7,
}
RUNTIME_STOPPED, RUNTIME_PLAYING, RUNTIME_PAUSED = 1, 2, 4
#: movel: rotation speed (rad/s) and acceleration (rad/s^2) per unit of v (m/s) and a (m/s^2).
MOVEL_RAD_PER_M = 4.0

FORMATS = {
    "DOUBLE": "d",
    "UINT32": "I",
    "INT32": "i",
    "UINT64": "Q",
    "UINT8": "B",
    "BOOL": "?",
    "VECTOR6D": "6d",
    "VECTOR3D": "3d",
    "VECTOR6INT32": "6i",
    "VECTOR6UINT32": "6I",
}
TYPES = {
    "timestamp": "DOUBLE",
    "target_q": "VECTOR6D",
    "target_qd": "VECTOR6D",
    "target_qdd": "VECTOR6D",
    "target_current": "VECTOR6D",
    "target_moment": "VECTOR6D",
    "actual_q": "VECTOR6D",
    "actual_qd": "VECTOR6D",
    "actual_current": "VECTOR6D",
    "joint_control_output": "VECTOR6D",
    "actual_TCP_pose": "VECTOR6D",
    "actual_TCP_speed": "VECTOR6D",
    "actual_TCP_force": "VECTOR6D",
    "target_TCP_pose": "VECTOR6D",
    "target_TCP_speed": "VECTOR6D",
    "actual_digital_input_bits": "UINT64",
    "joint_temperatures": "VECTOR6D",
    "actual_execution_time": "DOUBLE",
    "robot_mode": "INT32",
    "joint_mode": "VECTOR6INT32",
    "safety_mode": "INT32",
    "safety_status": "INT32",
    "actual_tool_accelerometer": "VECTOR3D",
    "speed_scaling": "DOUBLE",
    "target_speed_fraction": "DOUBLE",
    "actual_momentum": "DOUBLE",
    "actual_main_voltage": "DOUBLE",
    "actual_robot_voltage": "DOUBLE",
    "actual_robot_current": "DOUBLE",
    "actual_joint_voltage": "VECTOR6D",
    "actual_digital_output_bits": "UINT64",
    "runtime_state": "UINT32",
    "robot_status_bits": "UINT32",
    "safety_status_bits": "UINT32",
    "standard_analog_input0": "DOUBLE",
    "standard_analog_input1": "DOUBLE",
    "standard_analog_output0": "DOUBLE",
    "standard_analog_output1": "DOUBLE",
    "analog_io_types": "UINT32",
    "io_current": "DOUBLE",
    "tool_mode": "UINT32",
    "tool_analog_input_types": "UINT32",
    "tool_analog_input0": "DOUBLE",
    "tool_analog_input1": "DOUBLE",
    "tool_output_voltage": "INT32",
    "tool_output_current": "DOUBLE",
    "tool_temperature": "DOUBLE",
    "tcp_force_scalar": "DOUBLE",
    "output_bit_registers0_to_31": "UINT32",
    "output_bit_registers32_to_63": "UINT32",
    "payload": "DOUBLE",
    "payload_cog": "VECTOR3D",
    "ft_raw_wrench": "VECTOR6D",
    "euromap67_input_bits": "UINT32",
    "euromap67_output_bits": "UINT32",
    "euromap67_24V_voltage": "DOUBLE",
    "euromap67_24V_current": "DOUBLE",
    "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32",
    "standard_digital_output_mask": "UINT8",
    "standard_digital_output": "UINT8",
    "configurable_digital_output_mask": "UINT8",
    "configurable_digital_output": "UINT8",
    "tool_digital_output_mask": "UINT8",
    "tool_digital_output": "UINT8",
    "speed_slider_mask": "UINT32",
    "speed_slider_fraction": "DOUBLE",
    "external_force_torque": "VECTOR6D",
}


def type_of(name: str) -> str | None:
    if name in TYPES:
        return TYPES[name]
    match = re.fullmatch(r"(input|output)_(int|double|bit)_register_(\d+)", name)
    if match:
        return {"int": "INT32", "double": "DOUBLE", "bit": "BOOL"}[match.group(2)]
    return None


def pack(kind: int, payload: bytes) -> bytes:
    return struct.pack(">HB", len(payload) + 3, kind) + payload


def calibrated_deltas(seed: int) -> dict[str, np.ndarray]:
    """A robot's factory-calibration deltas from its nominal DH table (deterministic per seed):
    a few mm and a few mrad, as real arms show."""
    rng = np.random.default_rng([seed, 30004])
    return {
        "delta_a_mm": rng.normal(scale=1.5, size=6) * [0, 1, 1, 1, 1, 0],
        "delta_d_mm": rng.normal(scale=1.5, size=6) * [1, 1, 1, 1, 1, 1],
        "delta_alpha_rad": rng.normal(scale=0.002, size=6) * [1, 1, 1, 1, 1, 0],
        "delta_theta_rad": rng.normal(scale=0.002, size=6),
    }


def configure_world(fake_world, generation: str = "cb3", calibrated: bool = False, pendant_tcp=None) -> None:
    """Make the world's robot the controller of ``generation``, with factory-calibrated DH
    parameters and/or a TCP set on the pendant (x, y, z mm; rx, ry, rz rotation vector, rad).

    The marker stays where it is on the flange; the truth's ``tcp_from_marker`` then refers to
    the pendant's TCP, which is what ``actual_TCP_pose`` reports."""
    from spacecal.sim.devices import SimulatedRobot
    from spacecal.sim.scenario import load_scenario
    from spacecal.sim.world import build_world

    spec = GENERATIONS[generation]
    world = fake_world.world
    if world.nominal_model.name != spec.robot_model:
        world = build_world(
            dataclasses.replace(load_scenario(fake_world.scenario_name), robot_model=spec.robot_model)
        )
    flange_from_marker = world.nominal_model.flange_from_tcp @ world.tcp_from_marker
    tcp = world.nominal_model.flange_from_tcp
    if pendant_tcp is not None:
        values = np.asarray(pendant_tcp, dtype=float)
        tcp = make_transform(rotvec_to_matrix(values[3:6]), values[:3])
    controller_model = dataclasses.replace(world.nominal_model.with_tcp(tcp), controller_hz=spec.max_hz)
    true_model = dataclasses.replace(world.true_model.with_tcp(tcp), controller_hz=spec.max_hz)
    if calibrated:  # the controller knows its arm: it reports and plans through the true DH
        controller_model = controller_model.with_dh_errors(**calibrated_deltas(world.scenario.seed))
        true_model = controller_model
    fake_world.nominal_dh = world.nominal_model
    fake_world.world = dataclasses.replace(
        world,
        nominal_model=controller_model,
        controller_model=controller_model,
        true_model=true_model,
        tcp_from_marker=invert_transform(tcp) @ flange_from_marker,
    )
    fake_world.robot = SimulatedRobot(fake_world.world, fake_world.clock, stream_states=True)
    fake_world.generation = generation
    fake_world.calibrated = calibrated


class FakeController:
    """The controller state shared by the servers."""

    def __init__(self, fake_world, log=None):
        self.fake = fake_world
        self.log = log
        self.generation = GENERATIONS[getattr(fake_world, "generation", "cb3")]
        self.registers: dict[str, float] = {"output_int_register_0": 1, "output_int_register_2": -1}
        self.script: str = ""
        self.scripts_uploaded = 0
        self.program_running = False
        self.paused = False
        self.robot_mode = "RUNNING"
        self.remote_control = True
        self.registers_taken = False
        self.primary_enabled = True
        self.primary_sends_nan = False
        self.read_only_lag_s = 0.0
        self.vanished = False  # switched off or its cable pulled: every connection falls silent
        self.silent_connections: list = []
        self.last_command = 0
        self.pending_done = False
        self.async_running = False
        self.lock = threading.RLock()
        self.commands: list[int] = []
        self.last_motion: tuple | None = None  # (kind, target, speed, accel, asynchronous)
        self.interrupted: tuple | None = None  # the move a safeguard stop paused
        self.connections = {"rtde": 0, "dashboard": 0, "script": 0, "primary": 0}
        self.rtde_sockets: set = set()
        self.fault_at: float | None = None
        self._snapshot: tuple | None = None
        self._snapshot_lock = threading.Lock()
        # motion monitor: when the joints last changed (monotonic), for "time to still"
        self.last_motion_at = time.monotonic()
        self._monitor_joints: np.ndarray | None = None

    @property
    def robot(self):
        return self.fake.robot

    @property
    def safety(self) -> str:
        return self.fake.robot._safety

    def start_script(self, script: str) -> None:
        """A (re)uploaded control script starts afresh: nothing pending, ready for a command.

        Without this a resumed client's first command could equal the interrupted client's last
        one and be taken for a repeat, and the client would wait for ever. A controller in local
        control (e-Series), powered off or in a safety stop does not start it."""
        with self.lock:
            if self.vanished:
                return
            if not self.can_run_programs():
                self.say("script refused: the controller cannot run programs now")
                return
            self.script = script
            self.scripts_uploaded += 1
            self.program_running = True
            self.paused = False
            self.interrupted = None
            self.last_command = 0
            self.pending_done = False
            self.async_running = False
            self.registers["output_int_register_0"] = 1
            self.registers["output_int_register_2"] = -1
            self.registers["input_int_register_0"] = 0

    def can_run_programs(self) -> bool:
        return (
            self.robot_mode == "RUNNING"
            and self.safety == "normal"
            and (self.remote_control or self.generation.version[0] < 5)
        )

    def say(self, text: str) -> None:
        if self.log:
            print(f"ur <- {text}", file=self.log, flush=True)

    # -- state -------------------------------------------------------------------------
    def snapshot(self):
        """(state, joint speeds) now; one computation per controller tick for every client."""
        with self._snapshot_lock:
            now = time.monotonic()
            tick = 1.0 / self.generation.max_hz
            if self._snapshot is not None and now - self._snapshot[0] < tick / 2:
                return self._snapshot[1], self._snapshot[2]
            state = self.robot.tick_state()  # a packet holds one tick: its time and its joints
            speeds = np.zeros(6)
            if self._snapshot is not None and state.time_s > self._snapshot[1].time_s:
                previous = self._snapshot[1]
                speeds = (state.joints_rad - previous.joints_rad) / (state.time_s - previous.time_s)
            elif self._snapshot is not None:
                speeds = self._snapshot[2]
            self._snapshot = (now, state, speeds)
            return state, speeds

    def runtime_state(self) -> int:
        if not self.program_running:
            return RUNTIME_STOPPED
        return RUNTIME_PAUSED if self.paused else RUNTIME_PLAYING

    def playing(self) -> bool:
        return self.runtime_state() == RUNTIME_PLAYING

    def value(self, name: str, snapshot=None):
        """One output field; every field of one packet comes from one ``snapshot`` (one tick)."""
        state, speeds = snapshot if snapshot is not None else self.snapshot()
        safety = self.safety
        if name == "timestamp":
            return state.time_s
        if name in ("actual_q", "target_q"):
            return tuple(state.joints_rad)
        if name in ("actual_qd", "target_qd"):
            return tuple(speeds)
        if name in ("actual_TCP_pose", "target_TCP_pose"):
            pose = state.base_from_tcp
            return (*(pose[:3, 3] / 1000.0), *matrix_to_rotvec(pose[:3, :3]))
        if name == "robot_mode":
            return ROBOT_MODES[self.robot_mode]
        if name in ("safety_mode", "safety_status"):
            return SAFETY[safety][1]
        if name == "safety_status_bits":
            return SAFETY[safety][0]
        if name == "robot_status_bits":
            powered = ROBOT_MODES[self.robot_mode] >= ROBOT_MODES["POWER_ON"]
            return (1 if powered else 0) | (2 if self.playing() else 0)
        if name == "runtime_state":
            return self.runtime_state()
        if name == "speed_scaling" or name == "target_speed_fraction":
            return 1.0
        kind = type_of(name)
        default = self.registers.get(name, 0)
        counts = {"VECTOR6D": 6, "VECTOR3D": 3, "VECTOR6INT32": 6, "VECTOR6UINT32": 6}
        count = counts.get(kind) if kind is not None else None
        return (0,) * count if count else default

    def monitor(self, stop: threading.Event) -> None:
        """Watch the joints (200 Hz) so a test can ask how long the robot took to stand still."""
        while not stop.is_set():
            state, _ = self.snapshot()
            with self.lock:
                if self._monitor_joints is not None and np.any(
                    np.abs(state.joints_rad - self._monitor_joints) > 1e-9
                ):
                    self.last_motion_at = time.monotonic()
                self._monitor_joints = state.joints_rad
            time.sleep(0.005)

    def update(self) -> None:
        """Advance the script's side of the register handshake."""
        with self.lock:
            if not self.playing():
                return  # a stopped or paused program answers nothing
            moving = self.robot.state().moving
            if self.pending_done and not moving:
                self.registers["output_int_register_0"] = 2
                self.pending_done = False
            if self.async_running and not moving:
                self.async_running = False
                self.registers["output_int_register_2"] = -1
            elif self.async_running:
                self.registers["output_int_register_2"] = (
                    int(self.registers.get("output_int_register_2", 0)) + 1
                )

    # -- inputs ------------------------------------------------------------------------
    def on_inputs(self, values: dict) -> None:
        with self.lock:
            self.registers.update(values)
            if not self.playing():
                return  # the script is not running: nobody reads the registers
            command = int(self.registers.get("input_int_register_0", 0))
            if command == self.last_command:
                return
            self.last_command = command
            if command == 0:
                self.registers["output_int_register_0"] = 1
                return
            self.commands.append(command)
            doubles = [self.registers.get(f"input_double_register_{i}", 0.0) for i in range(16)]
            asynchronous = int(self.registers.get("input_int_register_1", 0)) == 1
            self.say(f"command {command} doubles {np.round(doubles[:9], 4).tolist()} async {asynchronous}")
            self.execute(command, doubles, asynchronous)

    def execute(self, command: int, doubles, asynchronous: bool) -> None:
        if self.safety != "normal":
            self.registers["output_int_register_0"] = 2  # the script is stopped; nothing moves
            return
        if command == 1:  # MOVEJ: q[6], speed, acceleration
            self.last_motion = ("joint", list(doubles[:6]), doubles[6], doubles[7], asynchronous)
            self._start(
                lambda: self.robot.start_joint_move(doubles[:6], doubles[6], doubles[7]), asynchronous
            )
        elif command == 3:  # MOVEL: pose (m, rotation vector), speed m/s, acceleration m/s^2
            pose = make_transform(rotvec_to_matrix(doubles[3:6]), np.array(doubles[:3]) * 1000.0)
            self.last_motion = ("linear", pose, doubles[6], doubles[7], asynchronous)
            self._start(lambda: self._movel(pose, doubles[6], doubles[7]), asynchronous)
        elif command == 255:  # STOP_SCRIPT
            self.robot.stop()
            self.program_running = False
            self.registers["output_int_register_0"] = 2
        else:  # stopL, stopJ and the rest: stop any motion, done
            self.robot.stop()
            self.async_running = False
            self.registers["output_int_register_2"] = -1
            self.registers["output_int_register_0"] = 2

    def _movel(self, pose, speed_m_s: float, accel_m_s2: float) -> None:
        """URScript movel: v, a limit the linear path; the rotation gets 4 v rad/s, 4 a rad/s^2."""
        self.robot.limits = dataclasses.replace(
            self.robot.limits,
            angular_speed_rad_s=MOVEL_RAD_PER_M * speed_m_s,
            angular_accel_rad_s2=MOVEL_RAD_PER_M * accel_m_s2,
        )
        self.robot.move_linear(pose, speed_m_s * 1000.0, accel_m_s2 * 1000.0, asynchronous=True)
        motion = self.robot._motion
        self.last_move_s = motion[1].duration_s if motion is not None else 0.0

    def _start(self, begin, asynchronous: bool) -> None:
        begin()
        if asynchronous:
            self.async_running = True
            self.registers["output_int_register_2"] = 0
            self.registers["output_int_register_0"] = 2
        else:
            self.pending_done = True

    # -- what happens on the pendant, the safety system and the network ----------------
    def _halt(self, stop_program: bool) -> None:
        self.robot.stop()
        self.pending_done = False
        if stop_program:
            self.program_running = False
            self.paused = False
            self.interrupted = None

    def set_safety(self, name: str) -> None:
        with self.lock:
            moving = self.robot.state().moving
            if name == "safeguard_stop":  # the program pauses; it continues on reset
                self.interrupted = self.last_motion if moving and self.program_running else None
                self.robot._safety = name
                self._halt(stop_program=False)
                self.paused = self.program_running
            elif name == "protective_stop":
                self.robot._safety = name
                self._halt(stop_program=False)
                self.paused = self.program_running
            else:  # emergency stops, violation, fault: the program is stopped
                self.robot._safety = name
                self._halt(stop_program=True)

    def safeguard_reset(self) -> None:
        """The safeguard is reset: a paused program resumes its move, as on a real controller."""
        with self.lock:
            if self.safety != "safeguard_stop":
                return
            self.robot._safety = "normal"
            if self.program_running and self.paused:
                self.paused = False
                motion, self.interrupted = self.interrupted, None
                if motion is not None:
                    kind, target, speed, accel, _ = motion
                    if kind == "linear":
                        self._movel(target, speed, accel)
                    else:
                        self.robot.start_joint_move(target, speed, accel)

    def drop_rtde(self) -> None:
        for connection in list(self.rtde_sockets):
            try:
                connection.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    def stats(self) -> dict:
        state, speeds = self.snapshot()
        now = time.monotonic()
        return {
            "connections": dict(self.connections),
            "program_running": self.program_running,
            "runtime_state": self.runtime_state(),
            "safety": self.safety,
            "robot_mode": self.robot_mode,
            "moving": bool(state.moving),
            "max_joint_speed_rad_s": float(np.max(np.abs(speeds))),
            "still_for_s": now - self.last_motion_at,
            "fault_to_still_s": None
            if self.fault_at is None
            else max(0.0, self.last_motion_at - self.fault_at),
            "scripts_uploaded": self.scripts_uploaded,
            "last_movel_s": getattr(self, "last_move_s", None),
            "tracker_tracking": any(device.tracking for device in getattr(self.fake, "ndi_devices", ())),
            "commands": list(self.commands),
        }

    def control(self, words: list[str]) -> str:
        """World control-port commands ``ur ...`` (see ``world.py``)."""
        if not words:
            return "ERROR ur needs a command"
        command, arguments = words[0], words[1:]
        with self.lock:
            if command in SAFETY and command != "normal":
                self.fault_at = time.monotonic()
                self.set_safety(command)
            elif command == "safeguard_reset":
                self.safeguard_reset()
            elif command == "clear":  # unlock a protective stop / reset an emergency stop on the pendant
                self.robot._safety = "normal"
            elif command == "program_stop":
                self.fault_at = time.monotonic()
                self._halt(stop_program=True)
            elif command == "program_pause":
                self.fault_at = time.monotonic()
                self._halt(stop_program=False)
                self.paused = self.program_running
            elif command == "program_play":
                self.paused = False
            elif command == "power_off":
                self.fault_at = time.monotonic()
                self.robot_mode = "POWER_OFF"
                self._halt(stop_program=True)
            elif command == "mode":
                if not arguments or arguments[0].upper() not in ROBOT_MODES:
                    return "ERROR mode takes one of " + ", ".join(ROBOT_MODES)
                self.fault_at = time.monotonic()
                self.robot_mode = arguments[0].upper()
                if self.robot_mode != "RUNNING":
                    self._halt(stop_program=True)
            elif command == "drop_rtde":
                self.fault_at = time.monotonic()
                self.drop_rtde()
            elif command == "remote_control":
                self.remote_control = arguments != ["off"]
            elif command == "registers_taken":
                self.registers_taken = arguments != ["off"]
            elif command == "vanish":  # the controller is switched off or its network cable pulled
                self.fault_at = time.monotonic()
                self.vanished = True
            elif command == "lag_read_only":  # read-only clients' packets arrive S s late
                self.read_only_lag_s = float(arguments[0]) if arguments else 0.0
            elif command == "primary":  # the primary interface answers (on), closes at once (off)
                self.primary_enabled = arguments != ["off"]  # or publishes a NaN DH length (nan)
                self.primary_sends_nan = arguments == ["nan"]
            elif command == "mark":  # the test is about to stop the run another way (a signal)
                self.fault_at = time.monotonic()
            elif command == "stats":
                return json.dumps(self.stats())
            else:
                return f"ERROR unknown ur command {command}"
        return "OK"


def _recv_exact(connection, count: int) -> bytes:
    data = b""
    while len(data) < count:
        chunk = connection.recv(count - len(data))
        if not chunk:
            raise ConnectionError("closed")
        data += chunk
    return data


#: Fields of the RTDE inputs another client (a URCap, a fieldbus) can hold.
REGISTER_INPUT = re.compile(r"input_(int|double|bit)_register_\d+")


def serve_rtde_connection(controller: FakeController, connection, stop: threading.Event) -> None:
    output = {"names": [], "types": [], "hz": controller.generation.max_hz}
    inputs: list[tuple[list[str], list[str]]] = []
    streaming = threading.Event()
    send_lock = threading.Lock()
    controller.rtde_sockets.add(connection)

    def stream():
        next_time = time.monotonic()
        late: collections.deque = collections.deque()  # (send at, packet) of a lagging stream
        while not stop.is_set() and streaming.is_set():
            if controller.vanished:
                time.sleep(0.01)
                continue
            controller.update()
            snapshot = controller.snapshot()
            values = b"".join(
                struct.pack(">" + FORMATS[t], *np.atleast_1d(controller.value(n, snapshot)))
                for n, t in zip(output["names"], output["types"])
            )
            packet = pack(ord("U"), struct.pack(">B", 1) + values)
            if controller.read_only_lag_s > 0 and not inputs:  # a read-only client's stream
                late.append((time.monotonic() + controller.read_only_lag_s, packet))
                packet = b""
                while late and late[0][0] <= time.monotonic():
                    packet += late.popleft()[1]
            try:
                with send_lock:
                    connection.sendall(packet)
            except OSError:
                return
            next_time += 1.0 / output["hz"]
            delay = next_time - time.monotonic()
            if delay < -0.1:  # fell behind (a loaded machine): keep the rate, drop the backlog
                next_time = time.monotonic()
            time.sleep(max(delay, 0.0))

    try:
        while not stop.is_set():
            size, kind = struct.unpack(">HB", _recv_exact(connection, 3))
            payload = _recv_exact(connection, size - 3)
            if controller.vanished:
                continue  # nobody is there to read it
            kind = chr(kind)
            if kind == "V":
                reply = pack(ord("V"), struct.pack(">B", 1))
            elif kind == "v":
                reply = pack(ord("v"), struct.pack(">4I", *controller.generation.version))
            elif kind == "O":
                (hz,) = struct.unpack(">d", payload[:8])
                names = [n for n in payload[8:].decode().split(",") if n]
                types = [type_of(n) or "NOT_FOUND" for n in names]
                controller.say(f"output setup {hz} Hz {names}")
                rate = min(hz, controller.generation.max_hz) if hz > 0 else controller.generation.max_hz
                output.update(names=names, types=types, hz=rate)
                reply = pack(ord("O"), struct.pack(">B", 1) + ",".join(types).encode())
            elif kind == "I":
                names = [n for n in payload.decode().split(",") if n]
                types = [
                    "IN_USE"
                    if controller.registers_taken and REGISTER_INPUT.fullmatch(n)
                    else type_of(n) or "NOT_FOUND"
                    for n in names
                ]
                recipe_id = 0 if "IN_USE" in types else len(inputs) + 1
                if recipe_id:
                    inputs.append((names, types))
                controller.say(f"input recipe {recipe_id} {names} -> {types}")
                reply = pack(ord("I"), struct.pack(">B", recipe_id) + ",".join(types).encode())
            elif kind == "S":
                with send_lock:  # acknowledge before the first data packet
                    connection.sendall(pack(ord("S"), struct.pack(">B", 1)))
                streaming.set()
                threading.Thread(target=stream, daemon=True).start()
                continue
            elif kind == "P":
                streaming.clear()
                reply = pack(ord("P"), struct.pack(">B", 1))
            elif kind == "U":
                recipe = payload[0]
                if not 1 <= recipe <= len(inputs):
                    continue
                names, types = inputs[recipe - 1]
                values, offset = {}, 1
                for name, type_name in zip(names, types):
                    fmt = ">" + FORMATS[type_name]
                    unpacked = struct.unpack_from(fmt, payload, offset)
                    offset += struct.calcsize(fmt)
                    values[name] = unpacked[0] if len(unpacked) == 1 else unpacked
                controller.on_inputs(values)
                continue
            else:
                controller.say(f"unknown packet {kind!r}")
                continue
            with send_lock:
                connection.sendall(reply)
    except (ConnectionError, OSError):
        pass
    finally:
        streaming.clear()
        controller.rtde_sockets.discard(connection)
        connection.close()


def dashboard_reply(controller: FakeController, command: str) -> str:
    """The dashboard server's answer to one command line."""
    generation = controller.generation
    eseries = generation.version[0] >= 5
    if command == "PolyscopeVersion":
        return generation.polyscope
    if command == "get serial number":
        return generation.serial
    if command == "get robot model":
        return generation.robot_model.rstrip("e")
    if command == "is in remote control" and eseries:
        return "true" if controller.remote_control else "false"
    if command == "stop":
        if eseries and not controller.remote_control:
            return "Failed to execute: stop"
        with controller.lock:
            controller._halt(stop_program=True)
        return "Stopped"
    if command == "pause":
        with controller.lock:
            controller._halt(stop_program=False)
            controller.paused = controller.program_running
        return "Pausing program"
    if command == "robotmode":
        return f"Robotmode: {controller.robot_mode}"
    if command in ("safetystatus", "safetymode"):
        word = SAFETY[controller.safety][2]
        if command == "safetymode" and word.endswith("EMERGENCY_STOP"):
            word = word.replace("SYSTEM_", "").replace("ROBOT_", "")
        return ("Safetystatus: " if command == "safetystatus" else "Safetymode: ") + word
    if command == "programState":
        states = {RUNTIME_STOPPED: "STOPPED", RUNTIME_PLAYING: "PLAYING", RUNTIME_PAUSED: "PAUSED"}
        return f"{states[controller.runtime_state()]} rtde_control"
    if command == "running":
        return f"Program running: {'true' if controller.playing() else 'false'}"
    if command == "unlock protective stop":
        if controller.safety == "protective_stop":
            controller.robot._safety = "normal"
        return "Protective stop releasing"
    if command == "close safety popup":
        return "closing safety popup"
    return f"could not understand: '{command}'"


def serve_dashboard_connection(controller: FakeController, connection, stop) -> None:
    stream = connection.makefile("rw")
    controller.connections["dashboard"] += 1
    try:
        stream.write("Connected: Universal Robots Dashboard Server\n")
        stream.flush()
        for line in stream:
            if controller.vanished:
                continue
            command = line.strip()
            controller.say(f"dashboard {command}")
            if command == "quit":
                stream.write("Disconnected\n")
                stream.flush()
                break
            stream.write(dashboard_reply(controller, command) + "\n")
            stream.flush()
    except OSError:
        pass
    finally:
        controller.connections["dashboard"] -= 1
        connection.close()


def serve_script_connection(controller: FakeController, connection, stop) -> None:
    connection.settimeout(0.2)
    received = b""
    while not stop.is_set():
        try:
            chunk = connection.recv(65536)
        except TimeoutError:
            if received:
                controller.start_script(received.decode(errors="replace"))
                controller.say(f"script uploaded ({len(received)} bytes)")
                received = b""
            continue
        except OSError:
            break
        if not chunk:
            break
        received += chunk
    if received:
        controller.start_script(received.decode(errors="replace"))
    connection.close()


# -- primary / secondary client interface (30001 / 30002) -------------------------------
ROBOT_STATE, ROBOT_MESSAGE = 16, 20
CARTESIAN_INFO, KINEMATICS_INFO = 4, 5


def version_message(controller: FakeController) -> bytes:
    """The primary interface's first message: a robot message of kind VERSION (3)."""
    major, minor, bugfix, build = controller.generation.version
    name = b"URControl"
    body = (
        struct.pack(">QbB", 0, -2, 3)
        + struct.pack(">b", len(name))
        + name
        + struct.pack(">BBii", major, minor, bugfix, build)
        + b"01-01-2021, 00:00:00"
    )
    return struct.pack(">iB", len(body) + 5, ROBOT_MESSAGE) + body


def kinematics_checksums(controller: FakeController) -> list[int]:
    if not getattr(controller.fake, "calibrated", False):
        return [0] * 6
    return [
        int(v) for v in np.random.default_rng([controller.fake.world.scenario.seed, 5]).integers(1, 2**31, 6)
    ]


def robot_state_message(controller: FakeController) -> bytes:
    """A robot-state message with the CartesianInfo and KinematicsInfo sub-packages."""
    model = controller.fake.world.nominal_model
    state, _ = controller.snapshot()
    pose = state.base_from_tcp
    tcp = model.flange_from_tcp
    cartesian = struct.pack(
        ">12d",
        *(pose[:3, 3] / 1000.0),
        *matrix_to_rotvec(pose[:3, :3]),
        *(tcp[:3, 3] / 1000.0),
        *matrix_to_rotvec(tcp[:3, :3]),
    )
    a_m = model.a_mm / 1000.0
    if controller.primary_sends_nan:  # a controller fault: spacecal must not compute with it
        a_m = np.where(np.arange(6) == 2, np.nan, a_m)
    kinematics = (
        struct.pack(">6I", *kinematics_checksums(controller))
        + struct.pack(">6d", *model.theta_offset_rad)
        + struct.pack(">6d", *a_m)
        + struct.pack(">6d", *(model.d_mm / 1000.0))
        + struct.pack(">6d", *model.alpha_rad)
        + struct.pack(">I", 1 if getattr(controller.fake, "calibrated", False) else 0)
    )
    body = b"".join(
        struct.pack(">iB", len(payload) + 5, kind) + payload
        for kind, payload in ((CARTESIAN_INFO, cartesian), (KINEMATICS_INFO, kinematics))
    )
    return struct.pack(">iB", len(body) + 5, ROBOT_STATE) + body


def serve_primary_connection(controller: FakeController, connection, stop) -> None:
    """Version message on connect, then robot-state messages at 10 Hz (what clients parse)."""
    controller.connections["primary"] += 1
    try:
        if not controller.primary_enabled:
            return
        connection.sendall(version_message(controller))
        while not stop.is_set():
            if not controller.vanished:
                connection.sendall(robot_state_message(controller))
            time.sleep(0.1)
    except OSError:
        pass
    finally:
        controller.connections["primary"] -= 1
        connection.close()


def serve(server, handler, controller: FakeController, stop: threading.Event) -> None:
    for connection in accept_connections(server, stop):
        if controller.vanished:  # nothing answers: the connection is held open, silent
            controller.silent_connections.append(connection)
            continue
        threading.Thread(target=handler, args=(controller, connection, stop), daemon=True).start()


def _counted(name: str, handler):
    def run(controller, connection, stop):
        controller.connections[name] += 1
        try:
            handler(controller, connection, stop)
        finally:
            controller.connections[name] -= 1

    return run


def start_controller(fake_world, host: str, stop: threading.Event, log=None) -> FakeController:
    controller = FakeController(fake_world, log)
    for port, handler in (
        (RTDE_PORT, _counted("rtde", serve_rtde_connection)),
        (DASHBOARD_PORT, serve_dashboard_connection),
        (SCRIPT_PORT, _counted("script", serve_script_connection)),
        (PRIMARY_PORT, serve_primary_connection),
        (SECONDARY_PORT, serve_primary_connection),
    ):
        server = listen(host, port)  # bound here: a busy port is an error before READY
        threading.Thread(target=serve, args=(server, handler, controller, stop), daemon=True).start()
    threading.Thread(target=controller.monitor, args=(stop,), daemon=True).start()
    return controller


if __name__ == "__main__":
    sys.exit(0)
