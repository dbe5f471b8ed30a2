"""A fake NDI tracker speaking the Combined API (the framing ndicapi implements), over TCP
(Vega-style) or a pseudo-terminal (the Vicra's USB-serial path).

Framing: a command is ASCII, followed (when it contains ':') by a 4-hex CRC, then CR.
ASCII replies are text + 4-hex CRC + CR; errors are ``ERRORxx``. The BX reply is binary:
``C4 A5`` + LE u16 body length + LE u16 CRC of those 4 bytes + body + LE u16 CRC of body.
CRC-16: polynomial x^16 + x^15 + x^2 + 1, reflected (0xA001), initial value 0.
"""

from __future__ import annotations

import os
import struct
import sys
import threading
import tty

import numpy as np

try:  # imported as part of the tests package, or as a module of the world process
    from .net import accept_connections
except ImportError:
    from net import accept_connections

from spacecal.geometry.transforms import matrix_to_quaternion_wxyz

PORT_STATUS_OK = 0x00000031  # occupied, initialised, enabled
ERROR_INVALID_COMMAND = "ERROR01"


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


class FakeNDI:
    """Command handling of one tracker; ``frame_source()`` gives (frame_number, pose or None, rms)."""

    def __init__(self, frame_source, log=None):
        self.frame_source = frame_source
        self.handles: dict[int, dict] = {}
        self.next_handle = 0x0A
        self.tracking = False
        self.log = log

    def handle(self, command: str) -> bytes:
        if self.log:
            print(f"ndi <- {command}", file=self.log, flush=True)
        name, _, args = command.partition(":")
        if " " in name:
            name, _, args = command.partition(" ")
        handler = getattr(self, f"cmd_{name.upper()}", None)
        if handler is None:
            return ascii_reply(ERROR_INVALID_COMMAND)
        return handler(args)

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
        text = (
            "Polaris Vicra Control Firmware\nNDI S/N: P6-00042\nCharacterization Date: 01/01/10\n"
            "Freeze Tag: Polaris Vicra Rev 007.000\nFreeze Date: 01/01/10\n"
            "(C) Northern Digital Inc.\n"
        )
        return ascii_reply(text)

    def cmd_GETINFO(self, args):
        return ascii_reply("ERROR01")  # old Vicra firmware: the client falls back to VER

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
    def _tools(self):
        """(handle, pose or None, rms, frame) for every enabled handle: the first is the marker on
        the robot; any others are static reference markers somewhere in the volume."""
        frame, pose, rms = self.frame_source()
        enabled = sorted(h for h, s in self.handles.items() if s["enabled"])
        tools = []
        for i, handle in enumerate(enabled):
            if i == 0:
                tools.append((handle, pose, rms, frame))
            else:
                reference = np.eye(4)
                reference[:3, 3] = [100.0 * i, 0.0, -1000.0]
                tools.append((handle, reference, 0.1, frame))
        return tools

    def cmd_BX(self, args):
        if not self.tracking:
            return ascii_reply("ERROR0C")
        body = bytearray([len(self._tools())])
        for handle, pose, rms, frame in self._tools():
            if pose is None:
                body += struct.pack("<BBII", handle, 0x02, PORT_STATUS_OK, frame)
            else:
                q = matrix_to_quaternion_wxyz(pose[:3, :3])
                body += struct.pack("<BB8fII", handle, 0x01, *q, *pose[:3, 3], rms, PORT_STATUS_OK, frame)
        body += struct.pack("<H", 0)
        header = struct.pack("<HH", 0xA5C4, len(body))
        return header + struct.pack("<H", crc16(header)) + bytes(body) + struct.pack("<H", crc16(bytes(body)))

    def cmd_TX(self, args):
        if not self.tracking:
            return ascii_reply("ERROR0C")
        tools = self._tools()
        text = f"{len(tools):02X}"
        for handle, pose, rms, frame in tools:
            text += f"{handle:02X}"
            if pose is None:
                text += "MISSING"
            else:
                q = matrix_to_quaternion_wxyz(pose[:3, :3])
                # fixed widths: sign + 5 digits (q x 1e4, rms x 1e4), sign + 6 digits (mm x 100)
                text += "".join(f"{int(round(v * 1e4)):+06d}" for v in q)
                text += "".join(f"{int(round(v * 100)):+07d}" for v in pose[:3, 3])
                text += f"{int(round(rms * 1e4)):+06d}"
            text += f"{PORT_STATUS_OK:08X}{frame:08X}\n"
        text += "0000"
        return ascii_reply(text)


def _read_commands(read, write, device: FakeNDI, stop: threading.Event):
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
            try:
                write(device.handle(split_command(line)))
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

        _read_commands(read, connection.sendall, device, stop)
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

    _read_commands(read, write, device, stop)


if __name__ == "__main__":  # CRC check values from the protocol description
    for text, expected in (("OKAY", 0xA896), ("RESET", 0xBE6F), ("INIT:", 0xE3A5)):
        print(text, f"{crc16(text.encode()):04X}", "ok" if crc16(text.encode()) == expected else "WRONG")
    sys.exit(0)
