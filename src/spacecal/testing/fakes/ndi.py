"""A fake NDI tracker speaking the Combined API (the framing ndicapi implements), over TCP
(Vega-style) or a pseudo-terminal (the Vicra's USB-serial path).

Framing: a command is ASCII, followed (when it contains ':') by a 4-hex CRC, then CR.
ASCII replies are text + 4-hex CRC + CR; errors are ``ERRORxx``. The BX reply is binary:
``C4 A5`` + LE u16 body length + LE u16 CRC of those 4 bytes + body + LE u16 CRC of body.
CRC-16: polynomial x^16 + x^15 + x^2 + 1, reflected (0xA001), initial value 0.

Generations (``--ndi-generation``) differ in what they answer, as the devices do (an
unsupported command is ``ERROR01``, "invalid command"):

* ``polaris-old``: early Polaris firmware (API G.001.002): no ``BX`` (ASCII ``TX`` only), no
  ``GET``/``GETINFO``, no ``BX2``.
* ``vicra``: Polaris Vicra (API G.001.004): ``BX``, ``TX``, ``APIREV``, ``VER``; no ``GET``/
  ``GETINFO``/``BX2`` (PLUS reads firmware < 3 with ``BX``).
* ``spectra``: Polaris Spectra (API G.002.005): as the Vicra.
* ``vega``: Polaris Vega (API G.003.005): also ``GET``/``GETINFO``; ``BX2`` exists on the device,
  but this fake does not model its payload and says so (``ERROR01``), as nothing we test uses it.

Frames follow the reply option: 0x0001 transforms and status, 0x0800 also the transforms "not
normally reported": an out-of-volume tool comes with its pose and port-status bit 0x40 when
0x0800 is asked for, and as plainly missing (handle status 0x02) otherwise. A partially
out-of-volume tool (bit 0x80) is always reported with its pose. Faults (:class:`NDIFaults`,
driven from the world's control port) corrupt or drop replies and set status bits.
"""

from __future__ import annotations

import os
import struct
import sys
import threading
import tty

import numpy as np

from spacecal.geometry.transforms import matrix_to_quaternion_wxyz
from spacecal.testing.fakes.net import accept_connections

PORT_STATUS_OK = 0x00000031  # occupied, initialised, enabled
PORT_OUT_OF_VOLUME, PORT_PARTIALLY_OUT_OF_VOLUME = 0x40, 0x80
PORT_IR_INTERFERENCE, PORT_PROCESSING_EXCEPTION = 0x200, 0x1000
SYSTEM_TOO_MUCH_INFRARED = 0x0002
HANDLE_VALID, HANDLE_MISSING, HANDLE_DISABLED = 0x01, 0x02, 0x04
REPLY_NOT_NORMALLY_REPORTED = 0x0800
ERROR_INVALID_COMMAND = "ERROR01"

#: What each generation answers: its VER text, API revision and optional commands.
GENERATIONS = {
    "polaris-old": {"model": "Polaris Control Firmware", "apirev": "G.001.002", "bx": False, "get": False},
    "vicra": {"model": "Polaris Vicra Control Firmware", "apirev": "G.001.004", "bx": True, "get": False},
    "spectra": {"model": "Polaris Spectra Control Firmware", "apirev": "G.002.005", "bx": True, "get": False},
    "vega": {"model": "Polaris Vega Control Firmware", "apirev": "G.003.005", "bx": True, "get": True},
}


class NDIFaults:
    """Fault switches shared by the serial and the TCP fake (set from the control port).

    ``crc_error``, ``short_reply`` and ``drop`` count down tracking replies (BX/TX) to spoil:
    a wrong CRC, a reply cut short, no reply at all (a timeout on the client's side). The
    flags set status bits of the marker (the first enabled tool) or of the whole frame.
    """

    def __init__(self):
        self.lock = threading.Lock()
        self.crc_error = 0
        self.short_reply = 0
        self.drop = 0
        self.out_of_volume = False
        self.partial_volume = False
        self.processing_exception = False
        self.interference = False
        self.disabled = False
        self.spoiled = 0  # replies spoiled so far

    def control(self, words: list[str]) -> str:
        """``crc_error N``, ``short_reply N``, ``drop N``, ``<flag> on|off``, ``spoiled``."""
        if not words:
            return "ERROR ndi needs a fault"
        name = words[0]
        with self.lock:
            if name == "spoiled":
                return str(self.spoiled)
            if name in ("crc_error", "short_reply", "drop"):
                setattr(self, name, int(words[1]) if len(words) > 1 else 1)
            elif name in (
                "out_of_volume",
                "partial_volume",
                "processing_exception",
                "interference",
                "disabled",
            ):
                setattr(self, name, words[1:] != ["off"])
            else:
                return f"ERROR unknown ndi fault {name}"
        return "OK"

    def spoil(self) -> str | None:
        """Which transport fault the next tracking reply gets, if any."""
        with self.lock:
            for name in ("drop", "crc_error", "short_reply"):
                if getattr(self, name) > 0:
                    setattr(self, name, getattr(self, name) - 1)
                    self.spoiled += 1
                    return name
        return None


def crc16(data: bytes) -> int:
    """The Combined API's CRC-16 (reflected 0xA001, init 0)."""
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def ascii_reply(text: str) -> bytes:
    return f"{text}{crc16(text.encode()):04X}\r".encode()


def split_command(raw: bytes) -> str:
    """The command text without its CRC (the CRC is checked when present)."""
    text = raw.decode("ascii", errors="replace").strip("\r")
    if ":" in text and len(text) >= 4:
        body, crc = text[:-4], text[-4:]
        try:
            if int(crc, 16) == crc16(body.encode()):
                return body
        except ValueError:
            pass
    return text


#: Where a passive tool definition holds its sphere count and positions (the 752-byte SROM
#: image NDI's tools write: the count at byte 28, then 20 x 3 little-endian float32 from 72).
ROM_COUNT_OFFSET, ROM_POSITIONS_OFFSET, ROM_MAX_SPHERES = 28, 72, 20
#: Sphere distances (mm) within which a tool definition is a tool of the world.
ROM_MATCH_MM = 0.5


def rom_spheres(rom: bytes) -> np.ndarray | None:
    """The sphere positions (K, 3), mm, of a passive tool definition image; None if it holds none."""
    if len(rom) < ROM_POSITIONS_OFFSET + 12 * ROM_MAX_SPHERES or not rom.startswith(b"NDI"):
        return None
    count = rom[ROM_COUNT_OFFSET]
    if not 3 <= count <= ROM_MAX_SPHERES:
        return None
    return np.array(struct.unpack_from(f"<{3 * count}f", rom, ROM_POSITIONS_OFFSET)).reshape(-1, 3)


def _distances(spheres: np.ndarray) -> np.ndarray:
    return np.sort(np.linalg.norm(spheres[:, None] - spheres[None], axis=2)[np.triu_indices(len(spheres), 1)])


class FakeNDI:
    """Command handling of one tracker.

    ``frame_source()`` gives (frame_number, marker pose or None, rms), or with a fourth item the
    world's further tools: {name: (pose or None, rms)}. ``geometries`` ({name: spheres (K, 3),
    mm}, the marker's named ``marker``) are the tools in the world: a port handle follows the
    tool whose sphere distances its tool definition holds, as a tracker identifies a passive
    tool by its geometry, and sees nothing for a definition of no tool there. Without them the
    first enabled handle follows the marker and any other sees nothing.
    """

    def __init__(
        self,
        frame_source,
        log=None,
        generation: str = "vicra",
        faults: NDIFaults | None = None,
        geometries: dict[str, np.ndarray] | None = None,
    ):
        self.frame_source = frame_source
        self.geometries = geometries
        self.handles: dict[int, dict] = {}
        self.next_handle = 0x0A
        self.tracking = False
        self.log = log
        self.generation = GENERATIONS[generation]
        self.faults = faults or NDIFaults()

    def handle(self, command: str) -> bytes | None:
        """The reply to one command; None when a fault swallows it."""
        if self.log:
            print(f"ndi <- {command}", file=self.log, flush=True)
        name, _, args = command.partition(":")
        if " " in name:
            name, _, args = command.partition(" ")
        name = name.upper()
        supported = {
            "BX": self.generation["bx"],
            "GET": self.generation["get"],
            "GETINFO": self.generation["get"],
        }
        handler = getattr(self, f"cmd_{name}", None)
        if handler is None or not supported.get(name, True):
            return ascii_reply(ERROR_INVALID_COMMAND)
        reply = handler(args)
        if name in ("BX", "TX") and self.tracking and not reply.startswith(b"ERROR"):
            fault = self.faults.spoil()
            if fault == "drop":
                return None
            if fault == "crc_error":  # flip the last CRC byte (binary) or digit (ASCII)
                return reply[:-2] + bytes([reply[-2] ^ 0x5A]) + reply[-1:]
            if fault == "short_reply":  # cut off mid-reply; the ASCII end mark still comes
                return reply[: len(reply) // 2] + (b"\r" if name == "TX" else b"")
        return reply

    # -- set-up commands ---------------------------------------------------------------
    def cmd_INIT(self, args):
        self.handles.clear()
        self.tracking = False
        return ascii_reply("OKAY")

    def cmd_COMM(self, args):
        return ascii_reply("OKAY")

    def cmd_BEEP(self, args):
        return ascii_reply("1")

    def cmd_VER(self, args):
        model = self.generation["model"]
        text = (
            f"{model}\nNDI S/N: P6-00042\nCharacterization Date: 01/01/10\n"
            f"Freeze Tag: {model.split(' Control')[0]} Rev 007.000\nFreeze Date: 01/01/10\n"
            "(C) Northern Digital Inc.\n"
        )
        return ascii_reply(text)

    def cmd_APIREV(self, args):
        return ascii_reply(self.generation["apirev"])

    def cmd_GET(self, args):  # Vega's user parameters: answer the ones PLUS asks for
        if "API Revision" in args:
            return ascii_reply(f"Features.Firmware.API Revision={self.generation['apirev']}")
        return ascii_reply("ERROR35")

    def cmd_GETINFO(self, args):
        return self.cmd_GET(args)

    def cmd_PHSR(self, args):
        which = int(args or "00", 16)
        selected = []
        for handle, state in self.handles.items():
            if (
                which == 0x00
                or (which == 0x02 and not state["initialised"])
                or (which == 0x03 and state["initialised"] and not state["enabled"])
                or (which == 0x04 and state["enabled"])
            ):
                selected.append(f"{handle:02X}{0x31 if state['enabled'] else 0x01:03X}")
        return ascii_reply(f"{len(selected):02X}" + "".join(selected))

    def cmd_PHRQ(self, args):
        handle = self.next_handle
        self.next_handle += 1
        self.handles[handle] = {"rom": b"", "initialised": False, "enabled": False}
        return ascii_reply(f"{handle:02X}")

    def cmd_PHF(self, args):
        self.handles.pop(int(args[:2], 16), None)
        return ascii_reply("OKAY")

    def cmd_PVWR(self, args):
        handle = int(args[:2], 16)
        if handle not in self.handles:
            return ascii_reply("ERROR0A")
        self.handles[handle]["rom"] += bytes.fromhex(args[6:])
        self.handles[handle].pop("tool", None)  # identified again from the whole definition
        return ascii_reply("OKAY")

    def cmd_PINIT(self, args):
        handle = int(args[:2], 16)
        if handle not in self.handles:
            return ascii_reply("ERROR0A")
        self.handles[handle]["initialised"] = True
        return ascii_reply("OKAY")

    def cmd_PENA(self, args):
        handle = int(args[:2], 16)
        if handle not in self.handles or not self.handles[handle]["initialised"]:
            return ascii_reply("ERROR0A")
        self.handles[handle]["enabled"] = True
        return ascii_reply("OKAY")

    def cmd_TSTART(self, args):
        self.tracking = True
        return ascii_reply("OKAY")

    def cmd_TSTOP(self, args):
        self.tracking = False
        return ascii_reply("OKAY")

    # -- tracking replies --------------------------------------------------------------
    def _tool_of(self, handle: int, first: bool) -> str | None:
        """The world's tool a port handle follows (by its definition's geometry), or None."""
        if self.geometries is None:
            return "marker" if first else None
        state = self.handles[handle]
        if "tool" not in state:
            spheres = rom_spheres(state["rom"])
            state["tool"] = None
            for name, geometry in self.geometries.items():
                if (
                    spheres is not None
                    and len(spheres) == len(geometry)
                    and np.allclose(_distances(spheres), _distances(np.asarray(geometry)), atol=ROM_MATCH_MM)
                ):
                    state["tool"] = name
                    break
        return state["tool"]

    def _tools(self):
        """(handle, pose or None, rms, frame) for every enabled handle, in handle order: each
        the pose of the tool its definition describes (None: no such tool in view)."""
        source = self.frame_source()
        frame, pose, rms = source[:3]
        further = source[3] if len(source) > 3 else {}
        enabled = sorted(h for h, s in self.handles.items() if s["enabled"])
        tools = []
        for i, handle in enumerate(enabled):
            name = self._tool_of(handle, first=i == 0)
            if name == "marker":
                tools.append((handle, pose, rms, frame))
            elif name in further:
                tool_pose, tool_rms = further[name]
                tools.append((handle, tool_pose, tool_rms, frame))
            else:
                tools.append((handle, None, 0.0, frame))
        return tools

    def _states(self, option: int):
        """(handle, handle status, pose or None, rms, port status, frame) per tool, and the
        system status, with the fault flags applied to the marker (the first tool)."""
        faults = self.faults
        states = []
        for i, (handle, pose, rms, frame) in enumerate(self._tools()):
            port, status = PORT_STATUS_OK, HANDLE_VALID if pose is not None else HANDLE_MISSING
            if i == 0 and pose is not None:
                if faults.out_of_volume:
                    port |= PORT_OUT_OF_VOLUME
                    if not option & REPLY_NOT_NORMALLY_REPORTED:
                        status, pose = HANDLE_MISSING, None
                elif faults.partial_volume:
                    port |= PORT_PARTIALLY_OUT_OF_VOLUME
                if faults.processing_exception:
                    port |= PORT_PROCESSING_EXCEPTION
            if i == 0 and faults.disabled:
                status, pose = HANDLE_DISABLED, None
            states.append((handle, status, pose, rms, port, frame))
        return states, SYSTEM_TOO_MUCH_INFRARED if faults.interference else 0

    def cmd_BX(self, args):
        if not self.tracking:
            return ascii_reply("ERROR0C")
        states, system = self._states(int(args[:4] or "0001", 16))
        body = bytearray([len(states)])
        for handle, status, pose, rms, port, frame in states:
            if status == HANDLE_DISABLED:  # no data follows a disabled handle
                body += struct.pack("<BB", handle, status)
            elif pose is None:
                body += struct.pack("<BBII", handle, status, port, frame)
            else:
                q = matrix_to_quaternion_wxyz(pose[:3, :3])
                body += struct.pack("<BB8fII", handle, status, *q, *pose[:3, 3], rms, port, frame)
        body += struct.pack("<H", system)
        header = struct.pack("<HH", 0xA5C4, len(body))
        return header + struct.pack("<H", crc16(header)) + bytes(body) + struct.pack("<H", crc16(bytes(body)))

    def cmd_TX(self, args):
        if not self.tracking:
            return ascii_reply("ERROR0C")
        states, system = self._states(int(args[:4] or "0001", 16))
        text = f"{len(states):02X}"
        for handle, status, pose, rms, port, frame in states:
            text += f"{handle:02X}"
            if status == HANDLE_DISABLED:
                text += "DISABLED\n"
                continue
            if pose is None:
                text += "MISSING"
            else:
                q = matrix_to_quaternion_wxyz(pose[:3, :3])
                # fixed widths: sign + 5 digits (q x 1e4, rms x 1e4), sign + 6 digits (mm x 100)
                text += "".join(f"{int(round(v * 1e4)):+06d}" for v in q)
                text += "".join(f"{int(round(v * 100)):+07d}" for v in pose[:3, 3])
                text += f"{int(round(rms * 1e4)):+06d}"
            text += f"{port:08X}{frame:08X}\n"
        text += f"{system:04X}"
        return ascii_reply(text)


def serve_commands(read, write, device: FakeNDI, stop: threading.Event) -> None:
    """Answer the commands ``read()`` gives (bytes; b"" or an OSError ends it) with ``device``'s
    replies through ``write``, until ``stop`` is set: the Combined API over any byte stream."""
    buffer = b""
    while not stop.is_set():
        try:
            chunk = read()
        except OSError:
            return
        if not chunk:
            return
        buffer += chunk
        while b"\r" in buffer:
            line, buffer = buffer.split(b"\r", 1)
            if not line.strip():
                continue
            reply = device.handle(split_command(line))
            if reply is None:
                continue
            try:
                write(reply)
            except OSError:
                return


def serve_tcp(device: FakeNDI, server, stop: threading.Event, unplugged: threading.Event):
    """Serve one client at a time over TCP (a listening socket); closing the connection is 'unplugging'."""
    for connection in accept_connections(server, stop):
        connection.settimeout(0.2)

        def read(connection=connection):
            while not stop.is_set():
                if unplugged.is_set():
                    return b""
                try:
                    return connection.recv(4096)
                except TimeoutError:
                    continue
            return b""

        serve_commands(read, connection.sendall, device, stop)
        connection.close()


def open_pty() -> tuple[int, str]:
    """A raw pseudo-terminal pair: (master fd the fake serves, slave path the client opens)."""
    master, slave = os.openpty()
    tty.setraw(slave)
    return master, os.ttyname(slave)


def serve_pty(device: FakeNDI, master: int, stop: threading.Event, unplugged: threading.Event):
    """Serve commands on a pty master (the Vicra's serial path)."""
    import select

    def read():
        while not stop.is_set():
            if unplugged.is_set():
                return b""
            ready, _, _ = select.select([master], [], [], 0.2)
            if ready:
                return os.read(master, 4096)
        return b""

    def write(data):
        os.write(master, data)

    serve_commands(read, write, device, stop)


if __name__ == "__main__":  # CRC check values from the protocol description
    for text, expected in (("OKAY", 0xA896), ("RESET", 0xBE6F), ("INIT:", 0xE3A5)):
        print(text, f"{crc16(text.encode()):04X}", "ok" if crc16(text.encode()) == expected else "WRONG")
    sys.exit(0)
