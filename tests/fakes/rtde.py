"""A fake Universal Robots controller: RTDE (30004), dashboard (29999) and script (30003)
servers on one loopback address, driving the world's simulated robot.

RTDE framing: big-endian ``uint16 size`` (including the 3-byte header) + ``uint8 type``.
The real ur_rtde client decodes data packets with its own name->type table, so ours must
agree (TYPES below). The control interface uploads a URScript and then talks to it through
registers: it writes a command id to ``input_int_register_0`` and arguments to
``input_double_register_*``; the script answers on ``output_int_register_0`` (1 = ready,
2 = done) and reports asynchronous progress on ``output_int_register_2`` (< 0 idle).
"""

from __future__ import annotations

import re
import struct
import sys
import threading
import time

import numpy as np

try:  # imported as part of the tests package, or as a module of the world process
    from .net import accept_connections, listen
except ImportError:
    from net import accept_connections, listen

from spacecal.geometry.transforms import make_transform, matrix_to_rotvec, rotvec_to_matrix

RTDE_PORT, DASHBOARD_PORT, SCRIPT_PORT = 30004, 29999, 30003
CONTROLLER_VERSION = (3, 15, 7, 106331)  # CB3 (the paper's UR10): 125 Hz by default

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
SAFETY_MODES = {"normal": 1, "protective_stop": 3, "emergency_stop": 7}
SAFETY_BITS = {"normal": 1 << 0, "protective_stop": 1 << 2, "emergency_stop": 1 << 7}


def type_of(name: str) -> str | None:
    if name in TYPES:
        return TYPES[name]
    match = re.fullmatch(r"(input|output)_(int|double|bit)_register_(\d+)", name)
    if match:
        return {"int": "INT32", "double": "DOUBLE", "bit": "BOOL"}[match.group(2)]
    return None


def pack(kind: int, payload: bytes) -> bytes:
    return struct.pack(">HB", len(payload) + 3, kind) + payload


class FakeController:
    """The controller state shared by the three servers."""

    def __init__(self, fake_world, log=None):
        self.fake = fake_world
        self.robot = fake_world.robot
        self.log = log
        self.registers: dict[str, float] = {"output_int_register_0": 1, "output_int_register_2": -1}
        self.script: str = ""
        self.program_running = False
        self.last_command = 0
        self.pending_done = False
        self.async_running = False
        self.lock = threading.RLock()
        self.commands: list[int] = []

    def start_script(self, script: str) -> None:
        """A (re)uploaded control script starts afresh: nothing pending, ready for a command.

        Without this a resumed client's first command could equal the interrupted client's last
        one and be taken for a repeat, and the client would wait for ever."""
        with self.lock:
            self.script = script
            self.program_running = True
            self.last_command = 0
            self.pending_done = False
            self.async_running = False
            self.registers["output_int_register_0"] = 1
            self.registers["output_int_register_2"] = -1
            self.registers["input_int_register_0"] = 0

    def say(self, text: str) -> None:
        if self.log:
            print(f"ur <- {text}", file=self.log, flush=True)

    # -- outputs -----------------------------------------------------------------------
    def value(self, name: str):
        state = self.robot.state()
        safety = self.fake.robot._safety
        if name == "timestamp":
            return state.time_s
        if name in ("actual_q", "target_q"):
            return tuple(state.joints_rad)
        if name in ("actual_qd", "target_qd"):
            return tuple(self._joint_speeds(state))
        if name in ("actual_TCP_pose", "target_TCP_pose"):
            pose = state.base_from_tcp
            return (*(pose[:3, 3] / 1000.0), *matrix_to_rotvec(pose[:3, :3]))
        if name == "robot_mode":
            return 7  # RUNNING
        if name in ("safety_mode", "safety_status"):
            return SAFETY_MODES[safety]
        if name == "safety_status_bits":
            return SAFETY_BITS[safety]
        if name == "robot_status_bits":
            return 1 | (2 if self.program_running else 0)
        if name == "runtime_state":
            return 2 if self.program_running else 1
        if name == "speed_scaling" or name == "target_speed_fraction":
            return 1.0
        kind = type_of(name)
        default = self.registers.get(name, 0)
        count = {"VECTOR6D": 6, "VECTOR3D": 3, "VECTOR6INT32": 6, "VECTOR6UINT32": 6}.get(kind)
        return (0,) * count if count else default

    def _joint_speeds(self, state) -> np.ndarray:
        """Finite-difference joint speeds, rad/s (the simulated robot has positions only)."""
        previous = getattr(self, "_previous_state", None)
        self._previous_state = state
        if previous is None or state.time_s <= previous.time_s:
            return getattr(self, "_speeds", np.zeros(6))
        self._speeds = (state.joints_rad - previous.joints_rad) / (state.time_s - previous.time_s)
        return self._speeds

    def update(self) -> None:
        """Advance the script's side of the register handshake."""
        with self.lock:
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
        if self.fake.robot._safety != "normal":
            self.registers["output_int_register_0"] = 2  # the script is stopped; nothing moves
            return
        if command == 1:  # MOVEJ: q[6], speed, acceleration
            self._start(lambda: self._move_joints(doubles[:6], doubles[6], doubles[7]), asynchronous)
        elif command == 3:  # MOVEL: pose (m, rotation vector), speed m/s, acceleration m/s^2
            pose = make_transform(rotvec_to_matrix(doubles[3:6]), np.array(doubles[:3]) * 1000.0)
            self._start(
                lambda: self.robot.move_linear(
                    pose, doubles[6] * 1000.0, doubles[7] * 1000.0, asynchronous=True
                ),
                asynchronous,
            )
        elif command == 255:  # STOP_SCRIPT
            self.robot.stop()
            self.program_running = False
            self.registers["output_int_register_0"] = 2
        else:  # stopL, stopJ and the rest: stop any motion, done
            self.robot.stop()
            self.async_running = False
            self.registers["output_int_register_2"] = -1
            self.registers["output_int_register_0"] = 2

    def _move_joints(self, q, speed, accel):
        # a joint move in real time: start it without blocking the server thread
        self.robot.start_joint_move(q, speed, accel)

    def _start(self, begin, asynchronous: bool) -> None:
        begin()
        if asynchronous:
            self.async_running = True
            self.registers["output_int_register_2"] = 0
            self.registers["output_int_register_0"] = 2
        else:
            self.pending_done = True


def _recv_exact(connection, count: int) -> bytes:
    data = b""
    while len(data) < count:
        chunk = connection.recv(count - len(data))
        if not chunk:
            raise ConnectionError("closed")
        data += chunk
    return data


def serve_rtde_connection(controller: FakeController, connection, stop: threading.Event) -> None:
    output = {"names": [], "types": [], "hz": 125.0}
    inputs: list[tuple[list[str], list[str]]] = []
    streaming = threading.Event()
    send_lock = threading.Lock()

    def stream():
        next_time = time.monotonic()
        while not stop.is_set() and streaming.is_set():
            controller.update()
            values = b"".join(
                struct.pack(">" + FORMATS[t], *np.atleast_1d(controller.value(n)))
                for n, t in zip(output["names"], output["types"])
            )
            try:
                with send_lock:
                    connection.sendall(pack(ord("U"), struct.pack(">B", 1) + values))
            except OSError:
                return
            next_time += 1.0 / output["hz"]
            time.sleep(max(next_time - time.monotonic(), 0.0))

    streamer = None
    try:
        while not stop.is_set():
            size, kind = struct.unpack(">HB", _recv_exact(connection, 3))
            payload = _recv_exact(connection, size - 3)
            kind = chr(kind)
            if kind == "V":
                reply = pack(ord("V"), struct.pack(">B", 1))
            elif kind == "v":
                reply = pack(ord("v"), struct.pack(">4I", *CONTROLLER_VERSION))
            elif kind == "O":
                (hz,) = struct.unpack(">d", payload[:8])
                names = [n for n in payload[8:].decode().split(",") if n]
                types = [type_of(n) or "NOT_FOUND" for n in names]
                controller.say(f"output setup {hz} Hz {names}")
                output.update(names=names, types=types, hz=hz or 125.0)
                reply = pack(ord("O"), struct.pack(">B", 1) + ",".join(types).encode())
            elif kind == "I":
                names = [n for n in payload.decode().split(",") if n]
                types = [type_of(n) or "NOT_FOUND" for n in names]
                inputs.append((names, types))
                controller.say(f"input recipe {len(inputs)} {names}")
                reply = pack(ord("I"), struct.pack(">B", len(inputs)) + ",".join(types).encode())
            elif kind == "S":
                with send_lock:  # acknowledge before the first data packet
                    connection.sendall(pack(ord("S"), struct.pack(">B", 1)))
                streaming.set()
                streamer = threading.Thread(target=stream, daemon=True)
                streamer.start()
                continue
            elif kind == "P":
                streaming.clear()
                reply = pack(ord("P"), struct.pack(">B", 1))
            elif kind == "U":
                recipe = payload[0]
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
        connection.close()


def serve_dashboard_connection(controller: FakeController, connection, stop) -> None:
    stream = connection.makefile("rw")
    try:
        stream.write("Connected: Universal Robots Dashboard Server\n")
        stream.flush()
        for line in stream:
            command = line.strip()
            controller.say(f"dashboard {command}")
            if command == "PolyscopeVersion":
                reply = "URSoftware 3.15.7.106331 (Sep 06 2021)"
            elif command == "get serial number":
                reply = "2018300000"
            elif command == "is in remote control":
                reply = "true"
            elif command == "stop":
                controller.program_running = False
                reply = "Stopped"
            elif command == "robotmode":
                reply = "Robotmode: RUNNING"
            elif command == "safetystatus" or command == "safetymode":
                reply = (
                    "Safetystatus: "
                    + {
                        "normal": "NORMAL",
                        "protective_stop": "PROTECTIVE_STOP",
                        "emergency_stop": "ROBOT_EMERGENCY_STOP",
                    }[controller.fake.robot._safety]
                )
            elif command == "programState":
                reply = ("PLAYING" if controller.program_running else "STOPPED") + " <unnamed>"
            elif command == "unlock protective stop":
                controller.fake.robot._safety = "normal"
                reply = "Protective stop releasing"
            else:
                reply = f"could not understand: '{command}'"
            stream.write(reply + "\n")
            stream.flush()
    except OSError:
        pass
    finally:
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


def serve(server, handler, controller: FakeController, stop: threading.Event) -> None:
    for connection in accept_connections(server, stop):
        threading.Thread(target=handler, args=(controller, connection, stop), daemon=True).start()


def start_controller(fake_world, host: str, stop: threading.Event, log=None) -> FakeController:
    controller = FakeController(fake_world, log)
    for port, handler in (
        (RTDE_PORT, serve_rtde_connection),
        (DASHBOARD_PORT, serve_dashboard_connection),
        (SCRIPT_PORT, serve_script_connection),
    ):
        server = listen(host, port)  # bound here: a busy port is an error before READY
        threading.Thread(target=serve, args=(server, handler, controller, stop), daemon=True).start()
    return controller


if __name__ == "__main__":
    sys.exit(0)
