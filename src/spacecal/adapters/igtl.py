"""OpenIGTLink trackers (PLUS Server, 3D Slicer, any OpenIGTLink sender): a small reader of the
OpenIGTLink framing of our own; ``pyigtl`` (extra ``igtl``) only sends the calibration.

Why our own reader: pyigtl 0.3.4 parses only IMAGE, TRANSFORM, STRING and POINT (POSITION, TDATA
and QTDATA are dropped as unknown), never checks the CRC, and keeps only the newest message per
device name, so it cannot tell the silence of one tool from the silence of the stream. The
framing is small: a 58-byte big-endian header (u16 version, char[12] type, char[20] device
name, u64 timestamp = seconds << 32 | fraction * 2**32, u64 body size, u64 CRC-64 ECMA-182 of
the body), then the body; from header version 2 on the body starts with an extended header
(u16 its size, u16 metadata header size, u32 metadata body size, u32 message id) and ends with
the metadata (u16 count, count x (u16 key size, u16 encoding, u32 value size), keys and values).

Poses we read (mm), for the marker's device name (PLUS naming, ``MarkerToTracker`` maps marker
coordinates into the tracker frame, i.e. our ``tracker_from_marker``):

* TRANSFORM: 12 float32, the rotation column by column, then the translation;
* POSITION: position + quaternion (ox, oy, oz, w), or the 24-byte form without w (w >= 0); the
  12-byte position-only form has no orientation and is refused with one line;
* TDATA (several tools per message, 12 float32 each) and QTDATA (position + quaternion): the
  element whose name is the marker's; a message without it means the marker was not seen.

Status: ``TransformStatus`` metadata (PLUS, header v2) OK -> ``ok``; anything else -> ``invalid``
with the pose kept, unless the pose is a placeholder. A placeholder (identity, all-zero, NaN,
or not a rigid transform) is never a pose: it is ``missing``. PLUS by default
(``SendValidTransformsOnly``) sends nothing at all for an invalid tool while the other
transforms of the frame keep coming: a tracker frame (a sender timestamp seen on a message of
the stream, STATUS aside) that passes without the marker is a ``missing`` frame.

Silence: with the marker the only transform PLUS is configured to send, an occlusion is silence.
When no message of the stream has come for :data:`PROBE_AFTER_S`, the reader asks GET_STATUS
(a header-only message, protocol v1 on) every :data:`PROBE_INTERVAL_S`; PlusServer answers each
with STATUS (OK) while it runs (PlusLib ``vtkPlusOpenIGTLinkServer::DataReceiverThread``). A
STATUS proves the frames due before it were not sent (one TCP stream keeps the server's order):
each frame period that passed before the answer, by :func:`frame_late_s`, is a ``missing``
frame, stamped on the sender's clock one period after the last. The run ends only when the
server is gone: the connection closed or reset, no answer to GET_STATUS (nor any message) for
the frame timeout, or STATUS messages beyond those asked for, which PlusServer sends as its
keep-alive only while its tracker delivers no frames at all (``KeepAliveIntervalSec``, 0.25 s).
A sender that does not answer GET_STATUS (not known of 3D Slicer) ends the run after the frame
timeout of silence, as before. STATUS timestamps are never frame times (PLUS leaves them
unset). A message with a bad CRC is dropped and counted.

Bounds, against a sender that is not what it claims: a pose message announcing a body larger
than :data:`POSE_BODY_MAX_BYTES`, or any message larger than :data:`MAX_BODY_BYTES`, ends the
connection with one :class:`DeviceError` line; other messages above
:data:`POSE_BODY_MAX_BYTES` (images) are read past without being kept. Waiting is bounded by
``connect_timeout_s`` on connecting and by each ``next_frame`` timeout after that, which only
whole messages renew. The calibration is sent with our own socket (pyigtl packs the message):
pyigtl's client waits without a deadline for a message the server is still sending, before it
sends, and its ``stop`` waits for that; see :func:`publish_transform`.
"""

from __future__ import annotations

import collections
import socket
import struct
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from spacecal.adapters import IGTL_DEFAULT_PORT, DeviceAddress, DeviceOptions, require
from spacecal.core.errors import DeviceError, InvalidInputError
from spacecal.core.ports import (
    FINDING_OK,
    FINDING_PROBLEM,
    FINDING_WARNING,
    FRAME_INVALID,
    FRAME_MISSING,
    FRAME_OK,
    DeviceFinding,
    TrackerFrame,
    refused_poses_finding,
)
from spacecal.core.text import one_line_ascii
from spacecal.geometry.transforms import is_rigid_transform, transform_from_position_quaternion

#: Time the connection stays open after publishing, so the server reads the message.
PUBLISH_LINGER_S = 0.3
#: Deadline of publishing (s): connecting and handing one 106-byte TRANSFORM to the server, which
#: takes milliseconds on a local network; the linger (:data:`PUBLISH_LINGER_S`) follows.
PUBLISH_DEADLINE_S = 5.0
#: Time given to a server's backlog of old messages on connect before frames are read.
BACKLOG_DRAIN_S = 0.3
#: How long connecting and the marker's first message may take, s (a sender streams at 10-60 Hz).
CONNECT_DEADLINE_S = 5.0

#: Frames lagging the newest by more than this (sender time, s) are skipped, never returned.
MAX_LAG_S = 0.25

HEADER = struct.Struct(">H12s20sQQQ")
EXTENDED_HEADER = struct.Struct(">HHII")
#: Largest body of any message accepted, bytes: an OpenIGTLink sender's largest messages are
#: images (an ultrasound frame is under 1 MB, a 512 x 512 x 100 16-bit volume 50 MB); a larger
#: announced size (a length field of another protocol, 612 MB) is not an OpenIGTLink stream.
MAX_BODY_BYTES = 64 * 1024 * 1024
#: Largest body of a pose message (TRANSFORM, POSITION, TDATA, QTDATA) accepted, bytes: a
#: TRANSFORM is 48 bytes, a TDATA 70 per tool, and header v2 metadata a few hundred more; 64 kB
#: is a TDATA of 900 tools. Other messages larger than this are read past, never kept.
POSE_BODY_MAX_BYTES = 64 * 1024
TDATA_ELEMENT, QTDATA_ELEMENT = 70, 50
#: Message types that carry tool poses.
POSE_TYPES = ("TRANSFORM", "POSITION", "TDATA", "QTDATA")
#: Message types about the link, not a tracker frame (their timestamps are no frame times).
LINK_TYPES = ("STATUS",)

#: Silence (no message of the stream) after which GET_STATUS is asked, and the interval it is
#: asked at while the silence lasts, s: two frames of a 20 Hz tracker, and a 58-byte message
#: ten times a second, which PlusServer answers at once from its receiving thread.
PROBE_AFTER_S = 0.1
PROBE_INTERVAL_S = 0.1
#: A frame this much later than its period (s) counts as not sent (see :func:`frame_late_s`):
#: the jitter of a sender's frames on a busy computer and its network.
FRAME_LATE_S = 0.05
#: STATUS messages beyond the GET_STATUS asked during one silence that show a sender with no
#: tracker frames: PlusServer's keep-alive, every 0.25 s only then (two: not one answer late).
KEEP_ALIVES_WITHOUT_FRAMES = 2


def frame_late_s(period_s: float) -> float:
    """How long after its due time (the last frame's arrival plus whole periods) a frame that
    has not come counts as not sent, s: one period and :data:`FRAME_LATE_S`."""
    return period_s + FRAME_LATE_S


def get_status_message(timestamp_s: float | None = None) -> bytes:
    """A GET_STATUS message: header version 1, empty device name, no body (CRC of nothing: 0).

    Version 1 so that PlusServer keeps the stream in the header version it has (it answers,
    and streams, in the highest version a client has sent)."""
    now = time.time() if timestamp_s is None else timestamp_s
    stamp = (int(now) << 32) | (int((now % 1.0) * 2**32) & 0xFFFFFFFF)
    return HEADER.pack(1, b"GET_STATUS", b"", stamp, 0, crc64(b""))


def oversized(header: bytes, url: str) -> str | None:
    """Why a message header announces a body too large to accept (one line), or None.

    Parameters
    ----------
    header : bytes
        The 58-byte header.
    url : str
        The sender, for the message.
    """
    _, kind, _, _, body_size, _ = HEADER.unpack(header)
    kind_text = kind.rstrip(b"\0 ").decode("ascii", "replace")
    limit = POSE_BODY_MAX_BYTES if kind_text in POSE_TYPES else MAX_BODY_BYTES
    if body_size <= limit:
        return None
    which = "a pose" if limit == POSE_BODY_MAX_BYTES else "any"
    return (
        # the type name is the sender's bytes: escaped, so it cannot break or colour the line
        f"{url} is not an OpenIGTLink stream: it announced a {body_size}-byte "
        f"{one_line_ascii(kind_text) or '?'} "
        f"message (at most {limit} bytes are accepted for {which} message)"
    )


def _crc64_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte << 56
        for _ in range(8):
            crc = ((crc << 1) ^ 0x42F0E1EBA9EA3693) if crc & (1 << 63) else crc << 1
        table.append(crc & 0xFFFFFFFFFFFFFFFF)
    return table


_CRC64 = _crc64_table()


def crc64(data: bytes) -> int:
    """OpenIGTLink's CRC-64 (ECMA-182 polynomial, MSB first, initial value 0, no final xor)."""
    crc = 0
    for byte in data:
        crc = _CRC64[((crc >> 56) ^ byte) & 0xFF] ^ ((crc << 8) & 0xFFFFFFFFFFFFFFFF)
    return crc


@dataclass
class Message:
    """One OpenIGTLink message: header fields, content (without extended header and
    metadata), metadata."""

    version: int
    kind: str
    device_name: str
    timestamp_s: float
    content: bytes
    metadata: dict = field(default_factory=dict)


def parse_message(header: bytes, body: bytes) -> Message:
    """A message from its 58-byte header and its body (CRC checked by the caller)."""
    version, kind, name, stamp, _, _ = HEADER.unpack(header)
    timestamp_s = (stamp >> 32) + (stamp & 0xFFFFFFFF) / 2**32
    content, metadata = body, {}
    if version >= 2 and len(body) >= EXTENDED_HEADER.size:
        extended_size, meta_header_size, meta_size, _ = EXTENDED_HEADER.unpack(body[: EXTENDED_HEADER.size])
        end = len(body) - meta_header_size - meta_size
        if extended_size < EXTENDED_HEADER.size or end < extended_size:
            raise ValueError("inconsistent extended header")
        content = body[extended_size:end]
        metadata = _parse_metadata(body[end:], meta_header_size)
    return Message(
        version,
        kind.rstrip(b"\0 ").decode("ascii", "replace"),
        name.rstrip(b"\0 ").decode("utf-8", "replace"),
        timestamp_s,
        content,
        metadata,
    )


def _parse_metadata(data: bytes, header_size: int) -> dict:
    if header_size < 2 or len(data) < header_size:
        return {}
    (count,) = struct.unpack(">H", data[:2])
    entries = [struct.unpack(">HHI", data[2 + 8 * k : 10 + 8 * k]) for k in range(count)]
    offset, metadata = header_size, {}
    for key_size, _, value_size in entries:
        key = data[offset : offset + key_size].decode("utf-8", "replace")
        offset += key_size
        metadata[key] = data[offset : offset + value_size].decode("utf-8", "replace")
        offset += value_size
    return metadata


def _matrix_from_transform(values) -> np.ndarray:
    matrix = np.eye(4)
    matrix[:3, :3] = np.array(values[:9], dtype=float).reshape(3, 3).T  # sent column by column
    matrix[:3, 3] = values[9:12]
    return matrix


def _matrix_from_position(position, quaternion_xyzw) -> np.ndarray:
    x, y, z, w = (float(v) for v in quaternion_xyzw)
    norm = float(np.sqrt(w * w + x * x + y * y + z * z))
    if not np.isfinite(norm) or norm < 0.5 or not np.all(np.isfinite(position)):
        return np.full((4, 4), np.nan)  # a placeholder, not a rotation
    return transform_from_position_quaternion(
        np.asarray(position, dtype=float), np.array([w, x, y, z]) / norm
    )


def tool_poses(message: Message) -> dict[str, np.ndarray]:
    """Every tool pose a message carries, by name (the device name for TRANSFORM/POSITION).

    Raises
    ------
    InvalidInputError
        A pose message in a form that cannot give a pose (wrong size, position only).
    """
    data, kind = message.content, message.kind
    if kind == "TRANSFORM":
        if len(data) < 48:
            raise InvalidInputError(
                f"{message.device_name}: TRANSFORM body of {len(data)} bytes, expected 48"
            )
        return {message.device_name: _matrix_from_transform(struct.unpack(">12f", data[:48]))}
    if kind == "POSITION":
        if len(data) == 28:
            values = struct.unpack(">7f", data)
            return {message.device_name: _matrix_from_position(values[:3], values[3:])}
        if len(data) == 24:
            x, y, z = struct.unpack(">6f", data)[3:]
            w = float(np.sqrt(max(1.0 - (x * x + y * y + z * z), 0.0)))
            return {message.device_name: _matrix_from_position(struct.unpack(">3f", data[:12]), (x, y, z, w))}
        raise InvalidInputError(
            f"{message.device_name}: POSITION of {len(data)} bytes has no orientation; "
            "a marker pose needs position and quaternion (28 or 24 bytes)"
        )
    if kind in ("TDATA", "QTDATA"):
        size = TDATA_ELEMENT if kind == "TDATA" else QTDATA_ELEMENT
        if len(data) % size:
            raise InvalidInputError(
                f"{message.device_name}: {kind} body of {len(data)} bytes is not n x {size}"
            )
        poses = {}
        for k in range(len(data) // size):
            element = data[k * size : (k + 1) * size]
            name = element[:20].rstrip(b"\0 ").decode("utf-8", "replace")
            values = struct.unpack(">12f" if kind == "TDATA" else ">7f", element[22:])
            poses[name] = (
                _matrix_from_transform(values)
                if kind == "TDATA"
                else _matrix_from_position(values[:3], values[3:])
            )
        return poses
    return {}


class _PeerGone(Exception):
    """The peer closed or reset the connection while GET_STATUS was being sent."""


def is_placeholder(matrix: np.ndarray) -> bool:
    """A matrix a sender puts where it has no pose: NaN, all zeros, exactly identity, or not a
    rigid transform. (A real marker is never exactly at the tracker's origin.)"""
    matrix = np.asarray(matrix, dtype=float)
    return (
        not np.all(np.isfinite(matrix))
        or not np.any(matrix[:3, :3])
        or bool(np.array_equal(matrix, np.eye(4)))
        or not is_rigid_transform(matrix, atol=1e-4)
    )


class IGTLTracker:
    """A tracker read from an OpenIGTLink stream (Tracker protocol).

    Parameters
    ----------
    host, port : str, int
    device_name : str
        The marker's name (PLUS naming), default ``MarkerToTracker``: a TRANSFORM or POSITION
        device name, or a tool name inside TDATA/QTDATA.
    connect_timeout_s : float
        How long to wait for the marker's first message before giving up.
    tools : mapping of str to str, optional
        Further tools to report in :attr:`TrackerFrame.tools`: the name each is reported by ->
        its device name in the stream (PLUS naming, ``PointerToTracker`` maps pointer
        coordinates into the tracker: ``tracker_from_pointer``), a TRANSFORM or POSITION
        device or a TDATA/QTDATA element. A tool comes in the marker's frame when its message
        carries the frame's timestamp; a frame that has the marker is handed on once every
        tool of it has come, or when the next frame starts (PLUS sends nothing for a tool not
        seen): one frame later then.
    """

    def __init__(
        self,
        host: str,
        port: int = IGTL_DEFAULT_PORT,
        device_name: str = "MarkerToTracker",
        connect_timeout_s: float = CONNECT_DEADLINE_S,
        tools: Mapping[str, str] | None = None,
    ):
        self.device_name = device_name
        #: The further tools: name -> device name.
        self.tools = dict(tools or {})
        for name, device in self.tools.items():
            if not str(name).strip() or not str(device).strip():
                raise InvalidInputError(
                    f"a tracked tool needs a name and a device name, got {name!r}: {device!r}"
                )
            if device == device_name:
                raise InvalidInputError(f"tool {name!r} is the marker's device {device!r}")
        if len(set(self.tools.values())) < len(self.tools):
            raise InvalidInputError("two tools are given the same OpenIGTLink device name")
        # the newest frame's tools that came (name -> (pose or None, status)), and its marker
        # frame while it waits for them
        self._group_tools: dict[str, tuple[np.ndarray | None, str]] = {}
        self._group_marker: TrackerFrame | None = None
        self.url = f"igtl://{host}:{port}"
        self._condition = threading.Condition()
        self._frames: collections.deque = collections.deque(maxlen=64)
        self._fatal: str | None = None
        self._closed = False
        #: When the last message of the stream (STATUS aside) came, monotonic s.
        self._last_message_at = time.monotonic()
        self._last_new_stamp_at = time.monotonic()
        self._group_stamp: float | None = None
        self._group_has_marker = False
        #: The newest frame's frame without the marker was handed on (a silence closed it).
        self._group_closed = False
        self._group_at = time.monotonic()  # when the newest frame's first message came
        # the silence since the last message: GET_STATUS asked, STATUS received, and the frame
        # periods in it handed on as frames without the marker
        self._last_probe_at = -np.inf
        self._last_status_at = -np.inf
        self._silence_probes = 0
        self._silence_statuses = 0
        self._silent_frames = 0
        self._outgoing = bytearray()  # the reader thread's alone: GET_STATUS not yet sent
        #: GET_STATUS asked and STATUS received over the connection.
        self.probes_sent = 0
        self.status_messages = 0
        self._last_returned_stamp = -np.inf
        self._frame_number = 0
        #: What the stream carried: message counts by (type, device name), header versions,
        #: senders' metadata keys, messages dropped for a bad CRC.
        self.seen: collections.Counter = collections.Counter()
        self.header_versions: set[int] = set()
        self.crc_errors = 0
        #: The marker's frames, and those whose pose was not one (NaN, 1e30 mm, scaled).
        self.marker_frames = 0
        self.refused_poses = 0
        self.stamps: collections.deque = collections.deque(maxlen=256)
        deadline = time.monotonic() + connect_timeout_s
        try:
            self._socket = socket.create_connection((host, port), timeout=connect_timeout_s)
        except OSError as exc:
            raise DeviceError(
                f"no {device_name} message from {self.url}: could not connect ({exc})"
            ) from None
        # short: the reader thread also asks GET_STATUS when the stream falls silent
        self._socket.settimeout(PROBE_INTERVAL_S / 2)
        self._thread = threading.Thread(target=self._read_loop, daemon=True)
        self._thread.start()
        with self._condition:
            while not self._frames and self._fatal is None and time.monotonic() < deadline:
                self._condition.wait(0.05)
            found = any(f.status != FRAME_MISSING for f in self._frames)
            while not found and self._fatal is None and time.monotonic() < deadline:
                self._condition.wait(0.05)
                found = any(f.status != FRAME_MISSING for f in self._frames)
        if not found:
            names = sorted({name for _, name in self.seen})
            self.close()
            if self._fatal is not None:
                raise DeviceError(self._fatal)
            raise DeviceError(
                f"no {device_name} message from {self.url} within {connect_timeout_s:.0f} s"
                + (
                    f" (it sends {', '.join(names)}; is the marker visible, and is that its name?)"
                    if names
                    else ""
                )
            )
        # A server may flush a backlog of old messages on connect: let it pass, keep the newest.
        time.sleep(BACKLOG_DRAIN_S)
        with self._condition:
            while len(self._frames) > 1:
                self._frames.popleft()

    # -- the reader thread -----------------------------------------------------------------
    def _read_loop(self) -> None:
        buffer = bytearray()
        skip = 0  # bytes still to read past of a large message that is not kept
        try:
            while not self._closed:
                self._probe_if_silent()
                try:
                    chunk = self._socket.recv(1 << 16)
                except TimeoutError:
                    continue
                if not chunk:
                    self._fail(f"{self.url} closed the connection")
                    return
                if skip:
                    passed = min(skip, len(chunk))
                    skip, chunk = skip - passed, chunk[passed:]
                buffer += chunk
                while len(buffer) >= HEADER.size:
                    header = bytes(buffer[: HEADER.size])
                    refusal = oversized(header, self.url)
                    if refusal is not None:
                        self._fail(refusal)
                        return
                    body_size = HEADER.unpack(header)[4]
                    if body_size > POSE_BODY_MAX_BYTES:  # an image or the like: read past it
                        self._read_past(header)
                        passed = min(len(buffer), HEADER.size + body_size)
                        skip = HEADER.size + body_size - passed
                        del buffer[:passed]
                        continue
                    if len(buffer) < HEADER.size + body_size:
                        break
                    header = bytes(buffer[: HEADER.size])
                    body = bytes(buffer[HEADER.size : HEADER.size + body_size])
                    del buffer[: HEADER.size + body_size]
                    self._receive(header, body)
        except _PeerGone as exc:
            if not self._closed:
                self._fail(f"{self.url} {exc}")
        except ConnectionResetError as exc:
            # a peer that closes with bytes unread (a GET_STATUS) resets the connection (RST)
            if not self._closed:
                self._fail(f"{self.url} reset the connection ({exc.strerror or exc})")
        except OSError as exc:
            if not self._closed:
                self._fail(f"{self.url} connection lost ({exc})")
        except InvalidInputError as exc:
            self._fail(str(exc))

    def _probe_if_silent(self) -> None:
        """Ask GET_STATUS when the stream has been silent for :data:`PROBE_AFTER_S`, then every
        :data:`PROBE_INTERVAL_S` while it stays silent (never more than one waiting to be sent).

        Raises
        ------
        _PeerGone
            Sending failed: the peer closed or reset the connection (ends the reader with one
            line).
        """
        now = time.monotonic()
        with self._condition:
            if (
                not self._outgoing
                and now - self._last_message_at >= PROBE_AFTER_S
                and now - self._last_probe_at >= PROBE_INTERVAL_S
            ):
                self._last_probe_at = now
                self._silence_probes += 1
                self.probes_sent += 1
                self._outgoing += get_status_message()
        while self._outgoing:
            try:
                sent = self._socket.send(self._outgoing)
            except TimeoutError:
                return  # the peer reads nothing: no answer will come, which the deadline tells
            except OSError as exc:
                raise _PeerGone(f"closed the connection (sending GET_STATUS: {exc.strerror or exc})") from exc
            del self._outgoing[:sent]

    def _read_past(self, header: bytes) -> None:
        """Count a large message that is not a pose (its body is not kept); it is a message of
        the stream, and its timestamp a tracker frame's."""
        version, kind, name, stamp, _, _ = HEADER.unpack(header)
        with self._condition:
            now = time.monotonic()
            self._last_message_at = now
            self.seen[
                (
                    kind.rstrip(b"\0 ").decode("ascii", "replace"),
                    name.rstrip(b"\0 ").decode("utf-8", "replace"),
                )
            ] += 1
            self.header_versions.add(version)
            self._frame_stamp((stamp >> 32) + (stamp & 0xFFFFFFFF) / 2**32, now)
            self._condition.notify_all()

    def _fail(self, reason: str) -> None:
        with self._condition:
            self._fatal = reason
            self._condition.notify_all()

    def _receive(self, header: bytes, body: bytes) -> None:
        now = time.monotonic()
        if HEADER.unpack(header)[5] != crc64(body):
            self.crc_errors += 1
            return
        try:
            message = parse_message(header, body)
        except (ValueError, struct.error):
            self.crc_errors += 1
            return
        try:
            poses = tool_poses(message) if message.kind in POSE_TYPES else {}
        except InvalidInputError:
            if message.device_name == self.device_name:
                raise  # the marker in a form that gives no pose: one clear line ends the run
            poses = {}  # another device's odd message is none of our business
        with self._condition:
            if message.kind in LINK_TYPES:
                # an answer to GET_STATUS, or a keep-alive: the server is there, but this is
                # no tracker frame (PLUS leaves its timestamp unset)
                self._last_status_at = now
                self._silence_statuses += 1
                self.status_messages += 1
                self._condition.notify_all()
                return
            self._last_message_at = now
            self.seen[(message.kind, message.device_name)] += 1
            for name in poses:
                if message.kind in ("TDATA", "QTDATA"):
                    self.seen[(message.kind + " tool", name)] += 1
            self.header_versions.add(message.version)
            stamp = message.timestamp_s
            self._frame_stamp(stamp, now)
            if stamp == self._group_stamp and not self._group_closed:
                for name, device in self.tools.items():
                    if device in poses:
                        self._group_tools[name] = self._tool_pose(poses[device], message.metadata)
            if self.device_name in poses and stamp == self._group_stamp:
                self._group_has_marker = True
                frame = self._marker_frame(stamp, poses[self.device_name], message.metadata)
                self.marker_frames += 1
                self.refused_poses += frame.refused_pose
                if self.tools:
                    self._group_marker = frame  # handed on with its tools
                else:
                    self._push(frame)
            if self._group_marker is not None and len(self._group_tools) == len(self.tools):
                self._close_group()
            self._condition.notify_all()

    def _tool_pose(self, matrix: np.ndarray, metadata: dict) -> tuple[np.ndarray | None, str]:
        """A further tool's (pose or None, status) by the marker's rules (placeholders are none)."""
        frame = self._marker_frame(0.0, matrix, metadata)
        return frame.tracker_from_marker, frame.status

    def _with_tools(
        self, frame: TrackerFrame, tools: dict[str, tuple[np.ndarray | None, str]]
    ) -> TrackerFrame:
        """``frame`` carrying every configured tool (those that did not come: missing)."""
        if not self.tools:
            return frame
        came = {name: tools.get(name, (None, FRAME_MISSING)) for name in self.tools}
        return TrackerFrame(
            frame.time_s,
            frame.frame_number,
            frame.status,
            frame.tracker_from_marker,
            frame.rms_mm,
            tools={name: pose for name, (pose, _) in came.items()},
            tool_statuses={name: status for name, (_, status) in came.items()},
        )

    def _close_group(self) -> None:
        """Hand on the newest frame (the lock held), once: its marker frame, or a frame without
        the marker, with the tools that came in it."""
        if self._group_closed:
            return
        frame = self._group_marker
        if frame is None and not self._group_has_marker:
            frame = TrackerFrame(self._group_stamp or 0.0, 0, FRAME_MISSING, None)
        if frame is not None:
            self._push(self._with_tools(frame, self._group_tools))
        self._group_closed = True
        self._group_marker = None

    def _frame_stamp(self, stamp: float, now: float) -> None:
        """A message of the tracker frame stamped ``stamp`` came at ``now`` (the lock held): a
        newer stamp starts a frame and closes the last, which, if it never carried the marker,
        did not see it (PLUS sends nothing for an invalid tool). Any message ends a silence."""
        self._silence_probes = self._silence_statuses = 0
        if stamp == self._group_stamp:
            return
        if self._group_stamp is not None and stamp > self._group_stamp:
            if (not self._group_has_marker or self._group_marker is not None) and not self._group_closed:
                self._close_group()
        if self._group_stamp is None or stamp > self._group_stamp:
            self._group_stamp, self._group_has_marker, self._group_closed = stamp, False, False
            self._group_tools, self._group_marker = {}, None
            self._group_at = now
            self._silent_frames = 0
            self._last_new_stamp_at = now
            self.stamps.append((now, stamp))

    def _frame_period_s(self) -> float | None:
        """The sender's frame period, s: the median step between its recent frame timestamps
        (a silence in them is one large step, which the median passes over); None before two."""
        stamps = [stamp for _, stamp in list(self.stamps)[-65:]]
        steps = np.diff(stamps)
        steps = steps[steps > 0]
        return float(np.median(steps)) if len(steps) else None

    def _keep_alives_only(self) -> bool:
        """More STATUS messages in this silence than GET_STATUS asked: the sender's keep-alive,
        which PlusServer sends only while its tracker delivers no frames."""
        return self._silence_statuses - self._silence_probes >= KEEP_ALIVES_WITHOUT_FRAMES

    def _frames_of_silence(self) -> bool:
        """Hand on, as frames without the marker, the frame periods of the present silence that
        passed before the sender's last answer to GET_STATUS (the lock held); True if any.

        The answer came after every frame the sender had sent before it: a frame due
        :func:`frame_late_s` before the answer and not come was not sent. The frames are
        stamped on the sender's clock, one frame period apart from the last frame that came.
        """
        answered_at = self._last_status_at
        if self._group_stamp is None or answered_at <= self._last_message_at or self._keep_alives_only():
            return False
        period = self._frame_period_s()
        if period is None:
            return False
        pushed = False
        if (not self._group_has_marker or self._group_marker is not None) and not self._group_closed:
            self._close_group()
            pushed = True
        late = frame_late_s(period)
        while self._group_at + (self._silent_frames + 1) * period + late <= answered_at:
            self._silent_frames += 1
            stamp = self._group_stamp + self._silent_frames * period
            self._push(self._with_tools(TrackerFrame(stamp, 0, FRAME_MISSING, None), {}))
            pushed = True
        return pushed

    def _marker_frame(self, stamp: float, matrix: np.ndarray, metadata: dict) -> TrackerFrame:
        if is_placeholder(matrix):
            return TrackerFrame(stamp, 0, FRAME_MISSING, None)
        status = str(metadata.get("TransformStatus", "OK")).strip().upper()
        return TrackerFrame(stamp, 0, FRAME_OK if status == "OK" else FRAME_INVALID, matrix)

    def _push(self, frame: TrackerFrame) -> None:
        self._frames.append(frame)

    # -- the Tracker protocol ---------------------------------------------------------------
    def next_frame(self, timeout_s: float) -> TrackerFrame:
        """The next frame (the marker's pose, or a frame without it) newer than the last one.

        Through a silence the sender answers GET_STATUS in, its frame periods come as frames
        without the marker (see the module's notes).

        Raises
        ------
        DeviceError
            The connection closed; for ``timeout_s``: no message and no answer to GET_STATUS,
            keep-alives only (a server without tracker frames), or timestamps that stopped
            advancing; or the marker came in a form that gives no pose.
        """
        deadline = time.monotonic() + timeout_s
        with self._condition:
            while True:
                # frames in order (a frame without the marker is known one frame late, when
                # the next frame starts), skipping any that lag the newest by more than MAX_LAG_S
                while self._frames and (
                    self._frames[0].time_s <= self._last_returned_stamp
                    or self._frames[0].time_s < self._frames[-1].time_s - MAX_LAG_S
                ):
                    self._frames.popleft()
                if self._frames:
                    frame = self._frames.popleft()
                    break
                if self._fatal is not None:
                    raise DeviceError(self._fatal)
                if self._frames_of_silence():
                    continue
                now = time.monotonic()
                if now > deadline or self._gone_for(now, timeout_s):
                    raise DeviceError(self._why_no_frame(now, timeout_s))
                self._condition.wait(min(0.05, max(deadline - now, 0.001)))
        self._last_returned_stamp = frame.time_s
        self._frame_number += 1
        return TrackerFrame(
            frame.time_s,
            self._frame_number,
            frame.status,
            frame.tracker_from_marker,
            frame.rms_mm,
            tools=frame.tools,
            tool_statuses=frame.tool_statuses,
            refused_tools=frame.refused_tools,
        )

    def _gone_for(self, now: float, timeout_s: float) -> bool:
        """Whether the silence has lasted ``timeout_s`` without a sign of a tracker (the lock
        held): no answer either, or keep-alives only. Counted from the last sign, not from
        the call, so that frames handed on in between do not lengthen it."""
        silent_s = now - self._last_message_at
        if silent_s < timeout_s:
            return False
        return self._keep_alives_only() or now - self._last_status_at >= timeout_s

    def _why_no_frame(self, now: float, timeout_s: float) -> str:
        """Why no frame came for ``timeout_s`` (one line; the lock held)."""
        silent_s = now - self._last_message_at
        if silent_s < timeout_s:
            return f"{self.url}: timestamps stopped advancing for {timeout_s:.1f} s: stale stream"
        if self._keep_alives_only():
            return (
                f"{self.url} sends keep-alive STATUS only, no tracker frames for {silent_s:.1f} s: "
                "its tracker stalled or was unplugged at the server"
            )
        if now - self._last_status_at >= timeout_s:
            return (
                f"no OpenIGTLink message for {timeout_s:.1f} s and no answer to GET_STATUS: "
                "stream stalled or lost"
            )
        return f"{self.url} answers GET_STATUS but sent no tracker frame for {silent_s:.1f} s: stream stalled"

    def preflight(self, duration_s: float = 1.0) -> list[DeviceFinding]:
        """Read-only checks: what the sender sends (types, device names, header versions), its
        frame rate over ``duration_s``, and whether the marker's name is among them."""
        time.sleep(duration_s)
        with self._condition:
            seen = dict(self.seen)
            versions = sorted(self.header_versions)
            stamps = list(self.stamps)
            fatal = self._fatal
            refused = refused_poses_finding(self.refused_poses, self.marker_frames)
        findings = []
        if fatal is not None:
            findings.append(DeviceFinding(FINDING_PROBLEM, "connection", fatal))
        kinds = sorted({kind for kind, _ in seen if not kind.endswith(" tool")})
        names = sorted({name for kind, name in seen})
        findings.append(
            DeviceFinding(
                FINDING_OK,
                "sender",
                f"{self.url}: {', '.join(kinds) or 'no messages'} from {', '.join(names) or 'nobody'}; "
                f"header version(s) {', '.join(map(str, versions)) or '-'}",
            )
        )
        recent = [(at, stamp) for at, stamp in stamps if at >= stamps[-1][0] - duration_s] if stamps else []
        if len(recent) >= 2 and recent[-1][0] > recent[0][0]:
            rate = (len(recent) - 1) / (recent[-1][0] - recent[0][0])
            findings.append(
                DeviceFinding(FINDING_OK, "frame rate", f"{rate:.1f} Hz (distinct sender timestamps)")
            )
        else:
            findings.append(
                DeviceFinding(FINDING_PROBLEM, "frame rate", "the stream's timestamps do not advance")
            )
        if self.device_name in names:
            findings.append(DeviceFinding(FINDING_OK, "marker", f"{self.device_name} is in the stream"))
        else:
            findings.append(
                DeviceFinding(
                    FINDING_WARNING,
                    "marker",
                    f"no {self.device_name} now (PLUS sends nothing while a tool is not seen): "
                    "make the marker visible, or check its name",
                )
            )
        if refused is not None:
            findings.append(refused)
        if self.crc_errors:
            findings.append(
                DeviceFinding(FINDING_WARNING, "transport", f"{self.crc_errors} message(s) with a bad CRC")
            )
        return findings

    def close(self) -> None:
        self._closed = True
        try:
            self._socket.close()
        except OSError:
            pass


def publish_transform(host: str, port: int, name: str, a_from_b, timestamp: float | None = None) -> None:
    """Send one TRANSFORM (e.g. the calibration as ``BaseToTracker``) to an OpenIGTLink server.

    Connecting and sending take at most :data:`PUBLISH_DEADLINE_S`; the connection then stays
    open :data:`PUBLISH_LINGER_S` while what the server sends is read past (headers only).

    Parameters
    ----------
    name : str
        PLUS-style ``<From>To<To>`` name; ``BaseToTracker`` carries ``tracker_from_base``.
    a_from_b : array_like, shape (4, 4), mm

    Raises
    ------
    DeviceError
        No connection or no send within the deadline, or a server that is not an OpenIGTLink
        server: a message announced larger than the bounds (:func:`oversized`), or the
        connection closed in the middle of one of its messages.
    """
    pyigtl = require("pyigtl", "igtl")
    matrix = np.asarray(a_from_b, dtype=float)
    if matrix.shape != (4, 4) or not is_rigid_transform(matrix):
        raise InvalidInputError(f"{name}: not a 4x4 rigid transform")
    message = pyigtl.TransformMessage(
        matrix, timestamp=time.time() if timestamp is None else timestamp, device_name=name
    ).pack()
    url = f"igtl://{host}:{port}"
    deadline = time.monotonic() + PUBLISH_DEADLINE_S
    try:
        connection = socket.create_connection((host, port), timeout=PUBLISH_DEADLINE_S)
    except TimeoutError:
        raise DeviceError(f"could not connect to {url} within {PUBLISH_DEADLINE_S:g} s") from None
    except OSError as exc:
        raise DeviceError(f"could not connect to {url} ({exc.strerror or exc})") from None
    with connection:
        try:
            connection.settimeout(max(deadline - time.monotonic(), 0.001))
            connection.sendall(message)
        except TimeoutError:
            raise DeviceError(f"could not send {name} to {url} within {PUBLISH_DEADLINE_S:g} s") from None
        except OSError as exc:
            raise DeviceError(f"could not send {name} to {url} ({exc.strerror or exc})") from None
        # Servers stream to every client: closing at once, with their messages unread, resets the
        # connection and can drop ours before the server has read it.
        _read_past_until(connection, url, name, time.monotonic() + PUBLISH_LINGER_S)


def _read_past_until(connection: socket.socket, url: str, name: str, until: float) -> None:
    """Read what the server sends until ``until`` (monotonic s), keeping nothing but the header
    in hand; a closed connection at a message boundary ends it early."""
    header = bytearray()
    skip = 0  # body bytes of the current message still to read past
    while (remaining := until - time.monotonic()) > 0:
        connection.settimeout(remaining)
        try:
            chunk = connection.recv(1 << 16)
        except TimeoutError:
            return
        except OSError as exc:
            raise DeviceError(
                f"{url} reset the connection ({exc.strerror or exc}): {name} may not have arrived"
            ) from None
        if not chunk:
            if skip or header:
                raise DeviceError(
                    f"{url} closed the connection in the middle of a message: {name} may not have arrived"
                )
            return
        while chunk:
            if skip:
                passed = min(skip, len(chunk))
                skip, chunk = skip - passed, chunk[passed:]
                continue
            taken = min(HEADER.size - len(header), len(chunk))
            header += chunk[:taken]
            chunk = chunk[taken:]
            if len(header) == HEADER.size:
                refusal = oversized(bytes(header), url)
                if refusal is not None:
                    raise DeviceError(f"{refusal}; {name} may not have arrived")
                skip = HEADER.unpack(bytes(header))[4]
                header.clear()


def open_device(address: DeviceAddress, options: DeviceOptions) -> IGTLTracker:
    """The ``igtl://`` row of the URL table (:data:`spacecal.adapters.DEVICE_SCHEMES`);
    ``options.tools`` are (name, device name) pairs."""
    return IGTLTracker(address.host, address.port or IGTL_DEFAULT_PORT, tools=dict(options.tools))
