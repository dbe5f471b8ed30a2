"""A first look at a rosbridge server with spacecal's own socket, before roslibpy connects.

roslibpy (over autobahn and Twisted) retries a failed WebSocket upgrade for ever and logs a
message it cannot parse without telling its caller, so a plain HTTP server or a WebSocket
server that is no rosbridge would only show as a timeout. This probe opens the WebSocket
itself (RFC 6455 client handshake), subscribes to the joint-state topic (rosbridge v2
``subscribe``) and reads until the first ``publish`` on it, the whole conversation within one
deadline; anything else it is sent decides what the server is, in one line.
"""

from __future__ import annotations

import base64
import contextlib
import hashlib
import json
import os
import socket
import struct
import time

from spacecal.core.errors import DeviceError
from spacecal.core.text import sanitize_for_terminal

_WEBSOCKET_GUID = b"258EAFA5-E914-47DA-95CA-C5AB0DC85B11"
#: Largest frame the probe reads, bytes (a JointState of a few dozen joints is a few kB).
MAX_FRAME_BYTES = 1 << 20
#: Messages the probe reads before it gives up on a server that sends only other things.
MAX_MESSAGES = 200


class _Reader:
    """Reads from a socket until one deadline for the whole conversation."""

    def __init__(self, sock: socket.socket, deadline: float, name: str, deadline_s: float):
        self.sock, self.deadline, self.name, self.deadline_s = sock, deadline, name, deadline_s
        self.buffer = bytearray()

    def _fill(self) -> None:
        remaining = self.deadline - time.monotonic()
        if remaining <= 0:
            raise TimeoutError
        self.sock.settimeout(remaining)
        chunk = self.sock.recv(1 << 16)
        if not chunk:
            raise DeviceError(f"{self.name} closed the connection")
        self.buffer += chunk

    def exact(self, count: int) -> bytes:
        while len(self.buffer) < count:
            self._fill()
        data = bytes(self.buffer[:count])
        del self.buffer[:count]
        return data

    def until(self, marker: bytes, limit: int) -> bytes:
        while marker not in self.buffer:
            if len(self.buffer) > limit:
                raise DeviceError(f"{self.name} sent {limit} bytes without ending its HTTP header")
            self._fill()
        head, _, rest = bytes(self.buffer).partition(marker)
        self.buffer[:] = rest
        return head


def _frame(payload: bytes, opcode: int = 0x1) -> bytes:
    """One masked client frame (RFC 6455 5.2)."""
    mask = os.urandom(4)
    size = len(payload)
    head = bytes([0x80 | opcode])
    if size < 126:
        head += bytes([0x80 | size])
    elif size < 1 << 16:
        head += bytes([0x80 | 126]) + struct.pack(">H", size)
    else:
        head += bytes([0x80 | 127]) + struct.pack(">Q", size)
    return head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(payload))


def _read_message(reader: _Reader) -> tuple[int, bytes]:
    """(opcode, payload) of the next whole message (fragments joined)."""
    parts, first_opcode = [], None
    while True:
        b0, b1 = reader.exact(2)
        opcode, size = b0 & 0x0F, b1 & 0x7F
        if size == 126:
            size = struct.unpack(">H", reader.exact(2))[0]
        elif size == 127:
            size = struct.unpack(">Q", reader.exact(8))[0]
        if size > MAX_FRAME_BYTES:
            raise DeviceError(
                f"{reader.name} announced a {size}-byte WebSocket frame: not a rosbridge message"
            )
        mask = reader.exact(4) if b1 & 0x80 else None
        payload = reader.exact(size)
        if mask is not None:
            payload = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
        if opcode >= 0x8:  # control frames: close, ping, pong
            if opcode == 0x8:
                raise DeviceError(f"{reader.name} closed the WebSocket")
            if opcode == 0x9:
                reader.sock.sendall(_frame(payload, 0xA))
            continue
        first_opcode = opcode if first_opcode is None else first_opcode
        parts.append(payload)
        if b0 & 0x80:
            return first_opcode, b"".join(parts)


def _shown(data: bytes) -> str:
    text = data[:40].decode("utf-8", errors="replace")
    return "".join(c if c.isprintable() else "?" for c in text)


def probe_rosbridge(host: str, port: int, topic: str, message_type: str, deadline_s: float) -> dict:
    """The first message rosbridge publishes on ``topic``, within ``deadline_s`` in all.

    Returns
    -------
    dict
        The ROS message (``msg`` of the first ``publish`` on ``topic``).

    Raises
    ------
    DeviceError
        Nothing listens; what listens does not upgrade to a WebSocket (a plain HTTP server);
        it sends what is not a rosbridge message; or no message on ``topic`` within the
        deadline. One line each.
    """
    name = f"ws://{host}:{port}"
    deadline = time.monotonic() + deadline_s
    try:
        sock = socket.create_connection((host, port), timeout=deadline_s)
    except TimeoutError:
        raise DeviceError(f"no rosbridge at {name}: no connection within {deadline_s:g} s") from None
    except OSError as exc:
        raise DeviceError(f"no rosbridge at {name} ({exc.strerror or exc})") from None
    with contextlib.closing(sock):
        reader = _Reader(sock, deadline, f"the server at {name}", deadline_s)
        key = base64.b64encode(os.urandom(16))
        try:
            sock.sendall(
                b"GET / HTTP/1.1\r\nHost: %s:%d\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                b"Sec-WebSocket-Key: %s\r\nSec-WebSocket-Version: 13\r\n\r\n" % (host.encode(), port, key)
            )
            try:
                head = reader.until(b"\r\n\r\n", 16 * 1024)
            except TimeoutError:
                raise DeviceError(
                    f"{name} is not a rosbridge server: it did not answer a WebSocket upgrade "
                    f"within {deadline_s:g} s"
                ) from None
            status = head.split(b"\r\n", 1)[0]
            accept = base64.b64encode(hashlib.sha1(key + _WEBSOCKET_GUID).digest())
            headers = {
                k.strip().lower(): v.strip()
                for k, _, v in (line.partition(b":") for line in head.split(b"\r\n")[1:])
            }
            if not status.startswith(b"HTTP/1.1 101") or headers.get(b"sec-websocket-accept") != accept:
                raise DeviceError(
                    f"{name} is not a rosbridge server: it answered {_shown(status)!r} to a WebSocket upgrade"
                )
            request = {"op": "subscribe", "id": "spacecal-probe", "topic": topic, "type": message_type}
            sock.sendall(_frame(json.dumps(request).encode()))
            for _ in range(MAX_MESSAGES):
                opcode, payload = _read_message(reader)
                try:
                    message = json.loads(payload)
                    op = message["op"]
                except (ValueError, KeyError, TypeError):
                    raise DeviceError(
                        f"{name} is not a rosbridge server: it sent {_shown(payload)!r}, "
                        "not a rosbridge message"
                    ) from None
                if op == "publish" and message.get("topic") == topic and isinstance(message.get("msg"), dict):
                    with contextlib.suppress(OSError):
                        sock.sendall(_frame(struct.pack(">H", 1000), 0x8))
                    return message["msg"]
                if op == "status" and message.get("level") == "error":
                    raise DeviceError(
                        f"rosbridge at {name} refused to subscribe to {topic}: "
                        f"{sanitize_for_terminal(message.get('msg'), 120)}"
                    )
            raise DeviceError(f"rosbridge at {name} sent {MAX_MESSAGES} messages, none on {topic}")
        except TimeoutError:
            raise DeviceError(
                f"rosbridge at {name} published no {message_type} on {topic} within {deadline_s:g} s "
                "(is the robot driver running, and the topic's name right?)"
            ) from None
        except OSError as exc:
            if isinstance(exc, DeviceError):
                raise
            raise DeviceError(f"the connection to {name} failed ({exc.strerror or exc})") from None
