"""A fake OpenIGTLink sender: PLUS Server, 3D Slicer or an old sender streaming tool poses, written
from the OpenIGTLink specification (header v1, and v2 with the extended header and metadata)
and PLUS's server, independently of the adapter's reader.

Framing: a 58-byte big-endian header (u16 version, char[12] type, char[20] device name, u64
timestamp = seconds << 32 | fraction of a second * 2**32, u64 body size, u64 CRC-64 ECMA-182 of
the body), then the body. Header version 2 bodies start with the extended header (u16 its size
= 12, u16 metadata header size, u32 metadata body size, u32 message id), then the content, then
the metadata: u16 count, count x (u16 key size, u16 value encoding (3 = US-ASCII), u32 value
size), then the keys and values.

Contents: TRANSFORM = 12 float32 (R11 R21 R31 R12 R22 R32 R13 R23 R33 TX TY TZ, column by
column, mm); POSITION = 3 float32 position + 4 float32 quaternion (ox, oy, oz, w) (24 bytes:
the w-less form; 12 bytes: position only); TDATA = n x 70 bytes (char[20] name, u8 type
(2 = 6D), u8 reserved, 12 float32 as TRANSFORM); QTDATA = n x 50 bytes (name, type, reserved,
3 float32 position, 4 float32 quaternion qx, qy, qz, w).

Senders (``--igtl-sender``), as they behave for a tool that is not seen:

* ``plus``: PLUS Server with its default ``SendValidTransformsOnly="TRUE"``: header v2,
  ``TransformStatus=OK`` metadata, and *nothing* for an invalid tool, while the other
  transforms of the frame (``ReferenceToTracker``) keep coming (a TDATA leaves the invalid
  tool out, and is sent with none left). ``igtl send_invalid on`` is
  ``SendValidTransformsOnly="FALSE"``: the invalid tool comes as identity with
  ``TransformStatus=INVALID``.
* ``slicer``: 3D Slicer's OpenIGTLinkIF: header v2 without status metadata; a node that is not
  updated is not sent.
* ``old``: an old sender with header v1 and no status at all, which keeps sending a
  placeholder for an invalid tool (``igtl placeholder identity|zero|nan``).

What a client sends, and what PLUS Server answers (PlusLib ``vtkPlusOpenIGTLinkServer.cxx``,
``DataReceiverThread``, ``SendLatestFramesToClients``, ``KeepAlive``):

* GET_STATUS (header only, no body): ``plus`` answers at once with STATUS code 1 (OK), empty
  device name, in the client's header version (the stream's here); ``slicer`` and ``old`` do
  not answer (not known of them, so the fake assumes the worse);
* STATUS from a client is PLUS's keep-alive from the other side: read past, nothing answered;
* TRANSFORM: kept for ``received NAME`` (the calibration export); anything else is read past.

PLUS's keep-alive: its sender thread sends a STATUS (OK, header version 1, empty device name,
timestamp 0) to every client when it has had no *new tracker frame* for
:data:`KEEP_ALIVE_INTERVAL_S`. A frame whose transforms are all invalid is still a frame: an
occlusion is silence (with only the marker configured), not keep-alives; a tracker that stopped
(``unplug``) or repeats its last frame (``stale``: PLUS keeps no frame that is not newer) gives
keep-alives only.

Control (the world's ``igtl ...`` command): ``form transform|position|position24|position12|
tdata|qtdata``, ``header 1|2|3``, ``send_invalid on|off``, ``placeholder identity|zero|nan``,
``mute on|off`` (a hung sender: the connection kept, nothing sent, nothing answered),
``hang_up`` (close every connection), ``reference on|off`` (``ReferenceToTracker`` among the
transforms sent, or only the marker's), ``pointer on|off`` (``PointerToTracker`` likewise),
``stats`` (JSON: GET_STATUS received, keep-alives sent). Messages clients send (TRANSFORM) are
kept for ``received NAME``.

Further tools: PLUS names a tool's transform ``<Tool>To<Reference>`` (its ``Transform``
elements, ``From="Pointer" To="Tracker"``): the world's tracked pointer is ``PointerToTracker``
and the reference on the needle guide ``ReferenceToTracker``, each sent in the same frame (the
same timestamp) as the marker's transform and by the same rules when not seen (nothing from
PLUS by default, a placeholder from an old sender), one message per transform, or elements of
one TDATA/QTDATA.
"""

from __future__ import annotations

import functools
import json
import socket
import struct
import threading
import time

import numpy as np

from spacecal.core.errors import MissingExtraError
from spacecal.geometry.transforms import matrix_to_quaternion_wxyz
from spacecal.testing.fakes.net import accept_connections


@functools.cache
def _crc64_function():
    try:
        from crcmod import mkCrcFun
    except ImportError:
        raise MissingExtraError(
            "the OpenIGTLink fake needs crcmod, installed with the 'igtl' extra: pip install 'spacecal[igtl]'"
        ) from None
    return mkCrcFun(0x142F0E1EBA9EA3693, rev=False, initCrc=0, xorOut=0)


def crc64(data: bytes) -> int:
    """CRC-64 ECMA-182 of a message body, by crcmod (independent of the adapter's own table)."""
    return _crc64_function()(data)


HEADER = struct.Struct(">H12s20sQQQ")
ENCODING_US_ASCII = 3
TDATA_6D = 2
#: STATUS code 1: OK (OpenIGTLink status codes, ``igtlStatusMessage.h``).
STATUS_OK = 1
#: PlusServer's keep-alive interval: ``KeepAliveIntervalSec``, by default half its client socket
#: timeout of 0.5 s.
KEEP_ALIVE_INTERVAL_S = 0.25


def status_content(code: int = STATUS_OK) -> bytes:
    """A STATUS body: u16 code, i64 sub-code, char[20] error name, then the status message,
    NUL-terminated (``igtl::StatusMessage`` packs an empty one as a single NUL: 31 bytes)."""
    return struct.pack(">Hq20s", code, 0, b"") + b"\0"


def igtl_timestamp(seconds: float) -> int:
    whole = int(seconds)
    return whole << 32 | int((seconds - whole) * 2**32) & 0xFFFFFFFF


def pack_message(
    message_type: str, device_name: str, content: bytes, timestamp_s: float, version: int = 1, metadata=None
) -> bytes:
    """One OpenIGTLink message: header (+ extended header and metadata from version 2 on)."""
    body = content
    if version >= 2:
        items = [(k.encode(), str(v).encode()) for k, v in (metadata or {}).items()]
        meta_header = struct.pack(">H", len(items)) + b"".join(
            struct.pack(">HHI", len(k), ENCODING_US_ASCII, len(v)) for k, v in items
        )
        meta_body = b"".join(k + v for k, v in items)
        extended = struct.pack(">HHII", 12, len(meta_header), len(meta_body), 0)
        body = extended + content + meta_header + meta_body
    header = HEADER.pack(
        version,
        message_type.encode().ljust(12, b"\0"),
        device_name.encode().ljust(20, b"\0"),
        igtl_timestamp(timestamp_s),
        len(body),
        crc64(body),
    )
    return header + body


def transform_content(matrix) -> bytes:
    m = np.asarray(matrix, dtype=float)
    return struct.pack(">12f", *m[:3, :3].T.reshape(-1), *m[:3, 3])


def position_content(matrix, size: int = 28) -> bytes:
    m = np.asarray(matrix, dtype=float)
    if not np.all(np.isfinite(m)) or not np.any(m[:3, :3]):
        w, x, y, z = (np.nan,) * 4 if not np.all(np.isfinite(m)) else (0.0,) * 4
    else:
        w, x, y, z = matrix_to_quaternion_wxyz(m[:3, :3])
    if w < 0:  # the 3-element form assumes w >= 0
        w, x, y, z = -w, -x, -y, -z
    values = [*m[:3, 3], x, y, z, w]
    return struct.pack(f">{size // 4}f", *values[: size // 4])


def tdata_content(tools: list[tuple[str, np.ndarray]]) -> bytes:
    return b"".join(
        name.encode().ljust(20, b"\0") + struct.pack(">BB", TDATA_6D, 0) + transform_content(matrix)
        for name, matrix in tools
    )


def qtdata_content(tools: list[tuple[str, np.ndarray]]) -> bytes:
    out = b""
    for name, matrix in tools:
        w, x, y, z = matrix_to_quaternion_wxyz(np.asarray(matrix, dtype=float)[:3, :3])
        out += name.encode().ljust(20, b"\0") + struct.pack(">BB7f", TDATA_6D, 0, *matrix[:3, 3], x, y, z, w)
    return out


PLACEHOLDERS = {"identity": np.eye(4), "zero": np.zeros((4, 4)), "nan": np.full((4, 4), np.nan)}
#: The world's further tools and their PLUS transform names, in the order a frame sends them.
TOOL_DEVICE_NAMES = {"pointer": "PointerToTracker", "reference": "ReferenceToTracker"}


class FakeIGTLSender:
    """Streams the marker (and a reference) to every connected client at the tracker rate."""

    def __init__(self, fake_world, sender: str = "plus", marker_name: str = "MarkerToTracker"):
        self.world = fake_world
        self.sender = sender
        self.marker_name = marker_name
        self.lock = threading.Lock()
        self.clients: list[socket.socket] = []
        self.form = "transform"
        self.header = {"plus": 2, "slicer": 2, "old": 1}[sender]
        self.send_invalid = False
        self.placeholder = "identity"
        self.muted = False
        self.reference = True
        self.pointer = True
        self.received: dict[str, list] = {}
        #: PLUS answers GET_STATUS and sends keep-alives; of the others it is not known.
        self.answers_status = sender == "plus"
        #: GET_STATUS messages clients sent, and keep-alives sent (the tests' view).
        self.status_requests = 0
        self.keep_alives = 0

    def control(self, words: list[str]) -> str:
        if not words:
            return "ERROR igtl needs a switch"
        name, value = words[0], (words[1] if len(words) > 1 else "on")
        with self.lock:
            if name == "stats":
                return json.dumps({"status_requests": self.status_requests, "keep_alives": self.keep_alives})
            if name == "form" and value in (
                "transform",
                "position",
                "position24",
                "position12",
                "tdata",
                "qtdata",
            ):
                self.form = value
            elif name == "header" and value in ("1", "2", "3"):
                self.header = int(value)
            elif name in ("send_invalid", "mute", "reference", "pointer"):
                setattr(self, {"mute": "muted"}.get(name, name), value != "off")
            elif name == "placeholder" and value in PLACEHOLDERS:
                self.placeholder = value
            elif name == "hang_up":
                for client in self.clients:
                    try:
                        client.shutdown(socket.SHUT_RDWR)  # a FIN now, though a reader still waits
                    except OSError:
                        pass
                    client.close()
                self.clients.clear()
            else:
                return f"ERROR unknown igtl switch {' '.join(words)}"
        return "OK"

    def frame_messages(self, stamp: float, pose, further: dict | None = None) -> list[bytes]:
        """What this sender sends for one tracker frame: the marker's ``pose`` (or None) and
        the ``further`` tools' ({world tool name: pose or None}) that are switched on."""
        sent = [(self.marker_name, pose)]
        switched_on = {"pointer": self.pointer, "reference": self.reference}
        for name, device in TOOL_DEVICE_NAMES.items():
            if switched_on[name] and further is not None and name in further:
                sent.append((device, further[name]))
        tools: list[tuple[str, np.ndarray, bool]] = []
        for device, matrix in sent:
            if matrix is not None:
                tools.append((device, matrix, True))
            elif self.sender == "old" or (self.sender == "plus" and self.send_invalid):
                placeholder = PLACEHOLDERS["identity" if self.sender == "plus" else self.placeholder]
                tools.append((device, placeholder, False))
        version = self.header
        if self.form in ("tdata", "qtdata"):
            if not tools and self.sender != "plus":
                return []  # PLUS sends its TDATA without the invalid tools, even with none left
            pack = tdata_content if self.form == "tdata" else qtdata_content
            content = pack([(name, matrix) for name, matrix, _ in tools])
            return [pack_message(self.form.upper(), "Tracker", content, stamp, version)]
        messages = []
        for name, matrix, valid in tools:
            metadata = {"TransformStatus": "OK" if valid else "INVALID"} if self.sender == "plus" else None
            if self.form == "transform":
                content, kind = transform_content(matrix), "TRANSFORM"
            else:
                size = {"position": 28, "position24": 24, "position12": 12}[self.form]
                content, kind = position_content(matrix, size), "POSITION"
            messages.append(pack_message(kind, name, content, stamp, version, metadata))
        return messages

    def serve(self, server, stop: threading.Event, rate_hz: float) -> None:
        threading.Thread(target=self._accept, args=(server, stop), daemon=True).start()
        period = 1.0 / rate_hz
        next_time = time.monotonic()
        last_stamp = None
        quiet_since = time.monotonic()  # the last new tracker frame, or keep-alive
        while not stop.is_set():
            next_time += period
            time.sleep(max(next_time - time.monotonic(), 0.0))
            frame = None if self.world.unplugged else self.world.frame()
            # PLUS keeps a tracker frame only when it is newer than the last (a stale tracker
            # repeats its last one); the other senders send what the tracker gives them
            new = frame is not None and (frame[0] != last_stamp or self.sender != "plus")
            with self.lock:
                if self.muted:
                    continue
                if new:
                    assert frame is not None
                    stamp, pose, _, _, tools = frame
                    last_stamp = stamp
                    quiet_since = time.monotonic()
                    further = {name: tool for name, (tool, _) in tools.items()}
                    # the sender's clock, not the robot's
                    data = b"".join(self.frame_messages(stamp + self.world.igtl_epoch_s, pose, further))
                elif self.sender == "plus" and time.monotonic() - quiet_since > KEEP_ALIVE_INTERVAL_S:
                    quiet_since = time.monotonic()
                    self.keep_alives += 1
                    data = pack_message("STATUS", "", status_content(), 0.0, 1)
                else:
                    continue
                self._send_to_all(data)

    def _send_to_all(self, data: bytes) -> None:
        """Send ``data`` to every client (the lock held); a client that cannot take it is dropped."""
        if not data:
            return
        for client in list(self.clients):
            try:
                client.sendall(data)
            except OSError:
                self.clients.remove(client)

    def _accept(self, server, stop: threading.Event) -> None:
        for connection in accept_connections(server, stop):
            connection.settimeout(None)
            with self.lock:
                self.clients.append(connection)
            threading.Thread(target=self._read, args=(connection,), daemon=True).start()

    def _read(self, connection: socket.socket) -> None:
        """What a client sends: TRANSFORMs are kept (the calibration export), GET_STATUS is
        answered as PLUS answers it, everything else is read past."""
        buffer = b""
        try:
            while True:
                chunk = connection.recv(65536)
                if not chunk:
                    return
                buffer += chunk
                while len(buffer) >= HEADER.size:
                    version, kind, name, _, size, _ = HEADER.unpack(buffer[: HEADER.size])
                    if len(buffer) < HEADER.size + size:
                        break
                    body, buffer = buffer[HEADER.size : HEADER.size + size], buffer[HEADER.size + size :]
                    kind = kind.rstrip(b"\0")
                    if kind == b"TRANSFORM":
                        self._keep_transform(version, name, body)
                    elif kind == b"GET_STATUS":
                        self._answer_status(connection)
        except OSError:
            return

    def _keep_transform(self, version: int, name: bytes, body: bytes) -> None:
        start = struct.unpack(">H", body[:2])[0] if version >= 2 else 0
        values = struct.unpack(">12f", body[start : start + 48])
        matrix = np.eye(4)
        matrix[:3, :3] = np.array(values[:9]).reshape(3, 3).T
        matrix[:3, 3] = values[9:]
        self.received[name.rstrip(b"\0").decode()] = matrix.tolist()

    def _answer_status(self, connection: socket.socket) -> None:
        """PLUS's answer to GET_STATUS: STATUS OK in the client's header version, at once (a
        hung sender, ``mute``, answers nothing; senders not known to answer do not)."""
        with self.lock:
            self.status_requests += 1
            if self.muted or not self.answers_status:
                return
            reply = pack_message("STATUS", "", status_content(), 0.0, self.header)
            try:
                connection.sendall(reply)
            except OSError:
                pass
