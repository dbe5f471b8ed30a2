"""OptiTrack Motive over NatNet: its rigid bodies as the marker and further tools, read by a small
strict reader of the NatNet packet format of our own (standard library only).

Why our own reader, not the PyPI ``natnet`` package (0.3.0, MIT): that package unpacks with
native-order ``struct`` formats (``"H"``, ``"I"``, ``"L"``) instead of NatNet's little-endian
ones, bounds no count against the bytes that are there, raises inside its receiving threads on
a truncated packet or a name that is not UTF-8 (the thread dies, the stream just stops), and
prints its warnings to standard output. A reader whose every read is bounded by the packet, on
one socket read with the caller's deadline, is less code than wrapping it.

The format (NaturalPoint's NatNet SDK: ``NatNetTypes.h``, ``PacketClient.cpp`` and its Python
sample ``NatNetClient.py``, 4.1; all little-endian): a packet is u16 message id, u16 payload
size, payload. The client sends NAT_CONNECT (0) to Motive's command port (1510; the SDK's
payload: 270 bytes, ``Ping`` first, the NatNet version asked for at bytes 265-268); Motive answers
NAT_SERVERINFO (1): char[256] application name, u8[4] its version, u8[4] the NatNet version it
streams (then its clock frequency and connection details, not read). NAT_REQUEST_MODELDEF (4)
is answered by NAT_MODELDEF (5), the data descriptions: i32 count, then per description i32
type (1: rigid body), from NatNet 4.1 on an i32 byte count, and for a rigid body its name
(NUL-terminated), i32 id, i32 parent id, 3 float32 offset and (3.0 on) its markers. Frames are
NAT_FRAMEOFDATA (7): i32 frame number, then sections, each an i32 count (from 4.1 on followed
by an i32 byte count): marker sets, other markers, rigid bodies (i32 id,
3 float32 position in m, 4 float32 quaternion qx qy qz qw, float32 mean marker error in m, i16
parameters whose bit 0 is "tracking valid"), skeletons, assets (4.1 on), labeled markers, force
plates, devices, and a suffix: u32 timecode, u32 sub-timecode, float64 timestamp (s since Motive
started), then (3.0 on) three u64 high-resolution stamps. In unicast Motive sends the frames to
the address the client's NAT_CONNECT came from, and drops a client that stops sending
NAT_KEEPALIVE (10); in multicast to the group (239.255.42.99) on the data port (1511).

Versions read: NatNet 3.0 to 4.x (Motive 2.x and 3.x), in the version NAT_SERVERINFO names.
NatNet 2.x (marker positions inside each rigid body) is refused with one line. The sections
other than the rigid bodies are read past by their counts (before 4.1) or byte counts (4.1 on);
every count is bounded by the bytes left; only what the timestamp needs of the suffix is read.

Frames: in timestamp order, each newer than the last one returned; a reader that fell behind
skips to :data:`MAX_LAG_S` behind the newest frame that came. A malformed datagram is dropped
and counted; a frame timeout with malformed datagrams only is one line naming the first.

Poses: ``tracker_from_marker`` is the rigid body's pose in Motive's frame (its ground plane
calibration), position converted from m to mm, quaternion ``qx, qy, qz, qw`` (normalised). A body
whose tracking-valid flag is off, a body missing from a frame, and a pose that is a placeholder
(all zeros, or a zero quaternion) are frames without the marker (``missing``).
"""

from __future__ import annotations

import collections
import select
import socket
import struct
import time
from dataclasses import dataclass, field
from urllib.parse import parse_qs

import numpy as np

from spacecal.adapters import DeviceAddress, DeviceOptions
from spacecal.core.errors import DeviceError, InvalidInputError
from spacecal.core.ports import (
    FINDING_OK,
    FINDING_PROBLEM,
    FINDING_WARNING,
    FRAME_MISSING,
    FRAME_OK,
    DeviceFinding,
    DeviceIdentity,
    TrackerFrame,
    refused_poses_finding,
)
from spacecal.core.text import one_line_ascii
from spacecal.geometry.transforms import transform_from_position_quaternion

NAT_CONNECT, NAT_SERVERINFO, NAT_REQUEST, NAT_RESPONSE = 0, 1, 2, 3
NAT_REQUEST_MODELDEF, NAT_MODELDEF, NAT_REQUEST_FRAMEOFDATA, NAT_FRAMEOFDATA = 4, 5, 6, 7
NAT_MESSAGESTRING, NAT_DISCONNECT, NAT_KEEPALIVE, NAT_UNRECOGNIZED_REQUEST = 8, 9, 10, 100
#: Motive's default command and data ports and multicast group.
COMMAND_PORT, DATA_PORT, MULTICAST_GROUP = 1510, 1511, "239.255.42.99"
#: Data description types (``NatNetTypes.h``: ``Descriptor_MarkerSet`` ...).
DESCRIPTION_MARKER_SET, DESCRIPTION_RIGID_BODY, DESCRIPTION_SKELETON = 0, 1, 2
#: A rigid body in a frame from NatNet 3.0 on: i32 id, 3 + 4 float32, float32 error, i16 params.
RIGID_BODY = struct.Struct("<i3f4ffh")
#: The NatNet versions read (major, minor): from 3.0 up to, not including, 5.0.
OLDEST_VERSION, FIRST_UNKNOWN_VERSION = (3, 0), (5, 0)

#: How long connecting (NAT_SERVERINFO, then NAT_MODELDEF) may take, s: Motive answers on a
#: local network in milliseconds; the requests are sent again every :data:`RESEND_S` (UDP).
CONNECT_DEADLINE_S = 5.0
RESEND_S = 0.5
#: Unicast keep-alive interval, s (the SDK's client sends one with every command-socket wake-up,
#: Motive drops a unicast client after some seconds without).
KEEP_ALIVE_S = 1.0
#: Frames lagging the newest that came by more than this (Motive's timestamps, s) are passed
#: over, never returned (as for OpenIGTLink): a reader that fell behind catches up.
MAX_LAG_S = 0.25
#: Largest UDP datagram read.
RECEIVE_BYTES = 65536
#: Datagrams taken in one read of the socket: a second of Motive at 240 Hz, and then some.
MAX_DATAGRAMS_AT_ONCE = 512
#: Longest rigid-body name kept, characters (Motive limits names to 256 bytes).
MAX_NAME_BYTES = 256


class MalformedPacket(ValueError):
    """A NatNet packet that does not hold what its header and counts say (one line)."""


class _Reader:
    """Little-endian reads bounded by the bytes there; every overrun is a MalformedPacket."""

    def __init__(self, data: bytes | memoryview, what: str):
        self.data, self.offset, self.what = memoryview(data), 0, what

    @property
    def left(self) -> int:
        return len(self.data) - self.offset

    def take(self, size: int) -> memoryview:
        if size < 0 or size > self.left:
            raise MalformedPacket(f"{self.what} ends {size - self.left} byte(s) early at byte {self.offset}")
        chunk = self.data[self.offset : self.offset + size]
        self.offset += size
        return chunk

    def unpack(self, layout: struct.Struct) -> tuple:
        return layout.unpack(self.take(layout.size))

    def i32(self) -> int:
        return int(self.unpack(_I32)[0])

    def count(self, smallest_item: int, what: str) -> int:
        """A count of items of at least ``smallest_item`` bytes each: never more than fit."""
        value = self.i32()
        if value < 0 or value * smallest_item > self.left:
            raise MalformedPacket(f"{self.what}: {value} {what} cannot fit in the {self.left} bytes left")
        return value

    def string(self) -> str:
        end = bytes(self.data[self.offset : self.offset + MAX_NAME_BYTES + 1]).find(b"\0")
        if end < 0:
            raise MalformedPacket(f"{self.what}: a name without its end (NUL) within {MAX_NAME_BYTES} bytes")
        text = bytes(self.take(end + 1)[:end]).decode("utf-8", "replace")
        return text

    def sized(self, what: str) -> _Reader:
        """The block a NatNet 4.1 byte count announces, as its own reader."""
        size = self.i32()
        if size < 0 or size > self.left:
            raise MalformedPacket(f"{self.what}: {what} of {size} bytes, {self.left} left")
        return _Reader(self.take(size), f"{self.what} ({what})")


_I32 = struct.Struct("<i")
_HEADER = struct.Struct("<HH")
_VEC3 = 12


@dataclass(frozen=True)
class ServerInfo:
    """What NAT_SERVERINFO says: the application, its version and the NatNet version."""

    application: str
    application_version: tuple[int, int, int, int]
    natnet_version: tuple[int, int, int, int]

    @property
    def natnet_text(self) -> str:
        return ".".join(map(str, self.natnet_version))

    @property
    def application_text(self) -> str:
        return ".".join(map(str, self.application_version))


@dataclass(frozen=True)
class BodyPose:
    """One rigid body of a frame: position (m), quaternion (qx, qy, qz, qw), mean marker error
    (m), tracking valid."""

    position_m: tuple[float, float, float]
    quaternion_xyzw: tuple[float, float, float, float]
    error_m: float
    valid: bool


@dataclass(frozen=True)
class NatNetFrame:
    """One NAT_FRAMEOFDATA: frame number, timestamp (s, Motive's clock), rigid bodies by id."""

    frame_number: int
    timestamp_s: float
    bodies: dict[int, BodyPose] = field(default_factory=dict)


def split_packet(packet: bytes) -> tuple[int, memoryview]:
    """(message id, payload) of one datagram; the payload is what its size field says.

    Raises
    ------
    MalformedPacket
        Shorter than its header, or than the payload size it announces.
    """
    if len(packet) < _HEADER.size:
        raise MalformedPacket(f"a {len(packet)}-byte datagram is no NatNet packet")
    message, size = _HEADER.unpack_from(packet)
    if size > len(packet) - _HEADER.size:
        raise MalformedPacket(
            f"message {message} announces {size} payload bytes, {len(packet) - _HEADER.size} came (truncated)"
        )
    return message, memoryview(packet)[_HEADER.size : _HEADER.size + size]


def parse_server_info(payload: bytes | memoryview) -> ServerInfo:
    """NAT_SERVERINFO's payload: char[256] name, u8[4] application version, u8[4] NatNet version."""
    reader = _Reader(payload, "NAT_SERVERINFO")
    name = bytes(reader.take(256)).split(b"\0", 1)[0].decode("utf-8", "replace")
    application = struct.unpack("<4B", reader.take(4))
    natnet = struct.unpack("<4B", reader.take(4))
    return ServerInfo(name, application, natnet)


def _sized_from(version: tuple[int, ...]) -> bool:
    """NatNet 4.1 on: every frame section and data description carries its byte count."""
    return tuple(version[:2]) >= (4, 1)


def _skip_rigid_body_description(reader: _Reader, version: tuple[int, ...]) -> tuple[str, int]:
    name = reader.string()
    body_id = reader.i32()
    reader.take(4 + _VEC3)  # parent id, offset
    markers = reader.count(_VEC3 + 4, "rigid-body markers")
    reader.take(markers * (_VEC3 + 4))  # offsets, active labels
    if version[0] >= 4:
        for _ in range(markers):
            reader.string()
    return name, body_id


def parse_model_definitions(payload: bytes | memoryview, version: tuple[int, ...]) -> dict[str, int]:
    """The rigid bodies NAT_MODELDEF describes: {name: id}.

    From NatNet 4.1 on each description has its byte count: of a rigid body only its name and
    id are read. Before 4.1 a description has no byte count, so reading stops at the first type
    that is neither a marker set, a rigid body nor a skeleton (Motive sends those first).
    """
    reader = _Reader(payload, "NAT_MODELDEF")
    bodies: dict[str, int] = {}
    for _ in range(reader.count(4, "data descriptions")):
        kind = reader.i32()
        if _sized_from(version):
            block = reader.sized(f"description of type {kind}")
            if kind == DESCRIPTION_RIGID_BODY:
                # name and id only: what follows grew with the versions (4.2 put an orientation
                # offset before the markers), and the byte count says where it ends
                name = block.string()
                bodies[name] = block.i32()
            continue
        if kind == DESCRIPTION_MARKER_SET:
            reader.string()
            for _ in range(reader.count(1, "marker names")):
                reader.string()
        elif kind == DESCRIPTION_RIGID_BODY:
            name, body_id = _skip_rigid_body_description(reader, version)
            bodies[name] = body_id
        elif kind == DESCRIPTION_SKELETON:
            reader.string()
            reader.i32()
            for _ in range(reader.count(4, "skeleton bones")):
                _skip_rigid_body_description(reader, version)
        else:
            break
    return bodies


def _skip_section(reader: _Reader, version: tuple[int, ...], what: str, item: int) -> None:
    """A frame section of ``count`` fixed-size items (marker sets aside)."""
    count = reader.count(item, what)
    if _sized_from(version):
        reader.sized(what)
    else:
        reader.take(count * item)


def _skip_channels(reader: _Reader, what: str) -> None:
    """Force plates and devices before 4.1: per item id, channel count, per channel frames."""
    for _ in range(reader.count(8, what)):
        reader.i32()
        for _ in range(reader.count(4, f"{what} channels")):
            reader.take(4 * reader.count(4, f"{what} channel frames"))


def parse_frame(payload: bytes | memoryview, version: tuple[int, ...]) -> NatNetFrame:
    """A NAT_FRAMEOFDATA payload of NatNet ``version`` (3.0 to 4.x).

    Raises
    ------
    MalformedPacket
        The packet does not hold what its counts say (truncated, a count larger than the bytes
        left, a 4.1 byte count that does not match its rigid bodies).
    """
    reader = _Reader(payload, "NAT_FRAMEOFDATA")
    sized = _sized_from(version)
    frame_number = reader.i32()
    # marker sets: name, count, positions
    sets = reader.count(5, "marker sets")
    if sized:
        reader.sized("marker sets")
    else:
        for _ in range(sets):
            reader.string()
            reader.take(_VEC3 * reader.count(_VEC3, "markers of a marker set"))
    _skip_section(reader, version, "other markers", _VEC3)
    count = reader.count(RIGID_BODY.size, "rigid bodies")
    block = reader.sized("rigid bodies") if sized else reader
    bodies = {}
    for _ in range(count):
        body_id, x, y, z, qx, qy, qz, qw, error, params = block.unpack(RIGID_BODY)
        bodies[body_id] = BodyPose((x, y, z), (qx, qy, qz, qw), error, bool(params & 0x01))
    if sized and block.left:
        raise MalformedPacket(f"NAT_FRAMEOFDATA: {block.left} bytes after its {count} rigid bodies")
    if sized:
        for what in ("skeletons", "assets", "labeled markers", "force plates", "devices"):
            reader.count(0, what)
            reader.sized(what)
    else:
        for _ in range(reader.count(8, "skeletons")):
            reader.i32()
            reader.take(RIGID_BODY.size * reader.count(RIGID_BODY.size, "skeleton bones"))
        _skip_section(reader, version, "labeled markers", 26)  # id, position, size, params, residual
        _skip_channels(reader, "force plates")
        _skip_channels(reader, "devices")
    reader.take(8)  # timecode, sub-timecode
    (timestamp,) = struct.unpack("<d", reader.take(8))
    if not np.isfinite(timestamp):
        raise MalformedPacket(f"NAT_FRAMEOFDATA: timestamp {timestamp}")
    return NatNetFrame(frame_number, float(timestamp), bodies)


def packet(message: int, payload: bytes = b"") -> bytes:
    """A request to the server: u16 message id, u16 payload size, payload."""
    return _HEADER.pack(message, len(payload)) + payload


#: The NatNet version asked for on connecting (a server that streams an older one says so in
#: NAT_SERVERINFO, and frames are read in the version it says).
REQUESTED_VERSION = (4, 1, 0, 0)


def connect_payload() -> bytes:
    """NAT_CONNECT's payload as the SDK's ``NatNetClient.py`` (4.1) sends it: 270 bytes,
    ``Ping`` first, the requested NatNet version at bytes 265-268, then a NUL."""
    payload = bytearray(270)
    payload[:4] = b"Ping"
    payload[265:269] = bytes(REQUESTED_VERSION)
    return bytes(payload) + b"\0"


def pose_of(body: BodyPose) -> np.ndarray | None:
    """``tracker_from_body`` (4, 4), mm, or None for a placeholder (zero quaternion, all zeros,
    not finite)."""
    position = np.asarray(body.position_m, dtype=float)
    x, y, z, w = (float(v) for v in body.quaternion_xyzw)
    norm = float(np.sqrt(x * x + y * y + z * z + w * w))
    if not (np.isfinite(norm) and np.all(np.isfinite(position))) or norm < 0.5:
        return None
    if not np.any(position) and (x, y, z) == (0.0, 0.0, 0.0):
        return None  # zeros where Motive has no pose: a marker is never exactly at the origin
    return transform_from_position_quaternion(position * 1000.0, np.array([w, x, y, z]) / norm)


@dataclass(frozen=True)
class NatNetOptions:
    """What a ``natnet://`` URL's query asks for.

    Attributes
    ----------
    body : str
        The calibrated marker's rigid-body name in Motive (``body=``).
    tools : tuple of (str, str)
        Further tools: (the name they are reported by, the rigid body's name) (``tools=A,B``).
    multicast : str or None
        The multicast group to read frames from (``multicast=239.255.42.99``); None: unicast.
    data_port : int
        Motive's data port (``data_port=``), for multicast.
    """

    body: str
    tools: tuple[tuple[str, str], ...] = ()
    multicast: str | None = None
    data_port: int = DATA_PORT


def natnet_options(query: str, options: DeviceOptions) -> NatNetOptions:
    """The URL query (``body=Marker&tools=Pointer,Reference&multicast=GROUP&data_port=P``) with
    ``options.tools`` (name, rigid body) added. ``--rom`` is not a rigid body's name: it names
    NDI tool definition files, which the recording reads as the marker's geometry.

    Raises
    ------
    InvalidInputError
        No marker body named, an unknown key, a bad port, a tool named twice.
    """
    try:
        fields = parse_qs(query, keep_blank_values=True, strict_parsing=bool(query))
    except ValueError:
        raise InvalidInputError(f"natnet:// query {one_line_ascii(query)!r} is not key=value&...") from None
    unknown = sorted(set(fields) - {"body", "tools", "multicast", "data_port"})
    if unknown:
        raise InvalidInputError(
            f"natnet:// takes body=, tools=, multicast=, data_port=; not {one_line_ascii(unknown[0])}="
        )
    body = (fields.get("body") or [""])[-1].strip()
    if not body:
        raise InvalidInputError(
            "a NatNet tracker needs the marker's rigid-body name: natnet://HOST?body=NAME"
        )
    names = [name.strip() for text in fields.get("tools", []) for name in text.split(",") if name.strip()]
    tools = tuple((name, name) for name in names) + tuple(options.tools)
    reported = [name for name, _ in tools]
    if len(set(reported)) != len(reported) or body in {rigid for _, rigid in tools}:
        raise InvalidInputError("natnet://: a rigid body is named twice (the marker and the tools)")
    multicast = (fields.get("multicast") or [""])[-1].strip()
    port_text = (fields.get("data_port") or [str(DATA_PORT)])[-1]
    if not port_text.isdigit() or not 0 < int(port_text) < 65536:
        raise InvalidInputError(
            f"natnet:// data_port must be a port number, got {one_line_ascii(port_text)!r}"
        )
    return NatNetOptions(body, tools, multicast or None, int(port_text))


class NatNetTracker:
    """Motive's NatNet stream as a tracker (Tracker, Preflight, Identified protocols).

    Parameters
    ----------
    host, port : str, int
        Motive's address and command port (1510).
    body : str
        The calibrated marker's rigid-body name.
    tools : mapping of str to str, optional
        Further tools: the name each is reported by -> its rigid-body name.
    multicast : str or None
        Read frames from this multicast group on ``data_port`` (None: unicast).
    connect_timeout_s : float
        Deadline of connecting: NAT_SERVERINFO and NAT_MODELDEF.

    Raises
    ------
    DeviceError
        No NatNet server answered within the deadline, one that is not NatNet answered, or its
        NatNet version is not read.
    InvalidInputError
        A rigid body named is not in Motive's data descriptions.
    """

    def __init__(
        self,
        host: str,
        port: int = COMMAND_PORT,
        body: str = "Marker",
        tools: dict[str, str] | None = None,
        multicast: str | None = None,
        data_port: int = DATA_PORT,
        connect_timeout_s: float = CONNECT_DEADLINE_S,
    ):
        self.url = f"natnet://{host}:{port}"
        try:
            self.server = (socket.gethostbyname(host), port)
        except OSError as exc:
            raise DeviceError(f"{self.url}: cannot resolve {host} ({exc.strerror or exc})") from None
        self.body = body
        self.tools = dict(tools or {})
        self.multicast = multicast
        self.malformed = 0
        self.first_malformed: str | None = None
        self.refused_poses = 0
        self.marker_frames = 0
        self.frames_seen = 0
        #: Timestamps of every frame parsed (returned or passed over for a newer one), s.
        self.stamps: collections.deque[float] = collections.deque(maxlen=4096)
        self._last_stamp = -np.inf
        self._pending: list[NatNetFrame] = []
        self._last_keep_alive = 0.0
        self._command = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._data: socket.socket | None = None
        try:
            self._command.bind(("", 0))
            self._command.setblocking(False)
            if multicast is not None:
                self._data = self._join(multicast, data_port)
            deadline = time.monotonic() + connect_timeout_s
            self.info = self._server_info(deadline, connect_timeout_s)
            self.version = self.info.natnet_version
            if not OLDEST_VERSION <= tuple(self.version[:2]) < FIRST_UNKNOWN_VERSION:
                raise DeviceError(
                    f"{self.url} streams NatNet {self.info.natnet_text}: spacecal reads NatNet 3.0 to 4.x "
                    "(Motive 2 and 3)"
                )
            self.bodies = self._model_definitions(deadline, connect_timeout_s)
            wanted = {self.body: self.body, **self.tools}
            self.ids = {name: self._body_id(rigid) for name, rigid in wanted.items()}
        except BaseException:
            self.close()
            raise

    # -- connecting -------------------------------------------------------------------------
    def _join(self, group: str, port: int) -> socket.socket:
        data = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            data.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            data.bind(("", port))
            # joined on the interface that faces the server (the default one may not)
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
                probe.connect(self.server)
                interface = probe.getsockname()[0]
            membership = socket.inet_aton(group) + socket.inet_aton(interface)
            data.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, membership)
            data.setblocking(False)
        except OSError as exc:
            data.close()
            raise DeviceError(
                f"cannot join the NatNet multicast group {one_line_ascii(group)} on port {port} "
                f"({exc.strerror or exc})"
            ) from None
        return data

    def _send(self, message: int, payload: bytes = b"") -> None:
        try:
            self._command.sendto(packet(message, payload), self.server)
        except OSError as exc:
            raise DeviceError(f"cannot send to {self.url} ({exc.strerror or exc})") from None

    def _answer(self, request: int, payload: bytes, wanted: int, deadline: float, timeout_s: float):
        """The payload of the first ``wanted`` packet from the server, the request sent again
        every :data:`RESEND_S`, by ``deadline``; counts what else came."""
        others, sent_at = 0, -np.inf
        while True:
            now = time.monotonic()
            if now >= deadline:
                what = {NAT_SERVERINFO: "NAT_SERVERINFO", NAT_MODELDEF: "NAT_MODELDEF"}[wanted]
                if others:
                    raise DeviceError(
                        f"{self.url} answered with {others} packet(s) that are not NatNet's {what}: "
                        "not a NatNet server (is this Motive's command port?)"
                    )
                raise DeviceError(
                    f"no {what} from {self.url} within {timeout_s:g} s: is Motive running with "
                    "streaming on (Edit > Settings > Streaming), on this address?"
                )
            if now - sent_at >= RESEND_S:
                self._send(request, payload)
                sent_at = now
            for data in self._receive(self._command, min(deadline, sent_at + RESEND_S)):
                try:
                    message, content = split_packet(data)
                except MalformedPacket:
                    others += 1
                    continue
                if message == wanted:
                    return content
                if message not in (NAT_FRAMEOFDATA, NAT_MESSAGESTRING, NAT_RESPONSE, NAT_SERVERINFO):
                    others += 1

    def _receive(self, sock: socket.socket, until: float) -> list[bytes]:
        """Datagrams from the server on ``sock``, waiting until ``until`` (monotonic) for the
        first; others waiting are taken too, at most :data:`MAX_DATAGRAMS_AT_ONCE` (a flood
        cannot hold a call past its deadline)."""
        datagrams: list[bytes] = []
        while len(datagrams) < MAX_DATAGRAMS_AT_ONCE:
            try:
                data, sender = sock.recvfrom(RECEIVE_BYTES)
            except BlockingIOError:
                remaining = until - time.monotonic()
                if datagrams or remaining <= 0:
                    return datagrams
                select.select([sock], [], [], remaining)
                continue
            except ConnectionRefusedError:  # an ICMP answer to an earlier send: nothing listens
                if time.monotonic() >= until:
                    return datagrams
                continue
            except OSError as exc:
                raise DeviceError(f"{self.url}: the socket failed ({exc.strerror or exc})") from None
            if self.multicast is not None or sender[0] == self.server[0]:
                datagrams.append(data)
        return datagrams

    def _server_info(self, deadline: float, timeout_s: float) -> ServerInfo:
        content = self._answer(NAT_CONNECT, connect_payload(), NAT_SERVERINFO, deadline, timeout_s)
        try:
            return parse_server_info(content)
        except MalformedPacket as exc:
            raise DeviceError(f"{self.url}: {exc}: not a NatNet server") from None

    def _model_definitions(self, deadline: float, timeout_s: float) -> dict[str, int]:
        content = self._answer(NAT_REQUEST_MODELDEF, b"", NAT_MODELDEF, deadline, timeout_s)
        try:
            return parse_model_definitions(content, self.version)
        except MalformedPacket as exc:
            raise DeviceError(f"{self.url}: its data descriptions are malformed: {exc}") from None

    def _body_id(self, name: str) -> int:
        if name not in self.bodies:
            # the names are Motive's (untrusted) and the user's: escaped, one line
            known = ", ".join(f"'{one_line_ascii(n)}'" for n in sorted(self.bodies)) or "none"
            raise InvalidInputError(
                f"{self.url}: no rigid body named '{one_line_ascii(name)}' in Motive's data "
                f"descriptions (its rigid bodies: {known}): check the name, and that the rigid body "
                "is streamed"
            )
        return self.bodies[name]

    # -- frames ------------------------------------------------------------------------------
    def _keep_alive(self, now: float) -> None:
        if self.multicast is None and now - self._last_keep_alive >= KEEP_ALIVE_S:
            self._send(NAT_KEEPALIVE)
            self._last_keep_alive = now

    def _frames(self, until: float) -> list[NatNetFrame]:
        frames = []
        for data in self._receive(self._data or self._command, until):
            try:
                message, content = split_packet(data)
                if message == NAT_FRAMEOFDATA:
                    frames.append(parse_frame(content, self.version))
            except MalformedPacket as exc:
                self.malformed += 1
                self.first_malformed = self.first_malformed or str(exc)
        return frames

    def next_frame(self, timeout_s: float) -> TrackerFrame:
        """The next frame newer than the last one returned, in timestamp order; frames lagging
        the newest that came by more than :data:`MAX_LAG_S` are passed over.

        Raises
        ------
        DeviceError
            No such frame within ``timeout_s`` (Motive stopped streaming, timestamps that do not
            advance, or only malformed packets), or the socket failed (closed).
        """
        if self._command.fileno() < 0:
            raise DeviceError(f"{self.url} was closed: no more frames")
        deadline = time.monotonic() + timeout_s
        malformed_before, seen_before = self.malformed, self.frames_seen
        self._take(self._frames(time.monotonic()))  # what is waiting, so that lag is known
        while True:
            pending = sorted(
                (f for f in self._pending if f.timestamp_s > self._last_stamp), key=lambda f: f.timestamp_s
            )
            if pending:
                newest = pending[-1].timestamp_s
                pending = [f for f in pending if f.timestamp_s >= newest - MAX_LAG_S]
                frame, self._pending = pending[0], pending[1:]
                break
            self._pending = []
            now = time.monotonic()
            self._keep_alive(now)
            if now >= deadline:
                bad = self.malformed - malformed_before
                if bad:
                    raise DeviceError(
                        f"{self.url}: {bad} malformed NAT_FRAMEOFDATA packet(s) and no frame for "
                        f"{timeout_s:.1f} s (first: {self.first_malformed})"
                    )
                if self.frames_seen > seen_before:
                    raise DeviceError(
                        f"{self.url}: frames came for {timeout_s:.1f} s but their timestamps did not "
                        "advance: Motive is paused, or was restarted (connect again)"
                    )
                raise DeviceError(
                    f"no NatNet frame from {self.url} for {timeout_s:.1f} s: Motive stopped streaming "
                    "or the network dropped"
                )
            self._take(self._frames(min(deadline, now + KEEP_ALIVE_S)))
        self._last_stamp = frame.timestamp_s
        return self._tracker_frame(frame)

    def _take(self, frames: list[NatNetFrame]) -> None:
        self.frames_seen += len(frames)
        self.stamps.extend(frame.timestamp_s for frame in frames)
        self._pending.extend(frames)

    def _pose(self, frame: NatNetFrame, name: str) -> tuple[np.ndarray | None, str, float]:
        body = frame.bodies.get(self.ids[name])
        if body is None or not body.valid:
            return None, FRAME_MISSING, float("nan")
        pose = pose_of(body)
        if pose is None:
            return None, FRAME_MISSING, float("nan")
        return pose, FRAME_OK, float(body.error_m) * 1000.0

    def _tracker_frame(self, frame: NatNetFrame) -> TrackerFrame:
        pose, status, rms_mm = self._pose(frame, self.body)
        tools = {name: self._pose(frame, name) for name in self.tools}
        result = TrackerFrame(
            frame.timestamp_s,
            frame.frame_number,
            status,
            pose,
            rms_mm,
            tools={name: found[0] for name, found in tools.items()},
            tool_statuses={name: found[1] for name, found in tools.items()},
        )
        if pose is not None:
            self.marker_frames += 1
            self.refused_poses += int(result.refused_pose)
        return result

    # -- what it is, and preflight ------------------------------------------------------------
    def identity(self) -> DeviceIdentity:
        """The server application (``Motive``) as the model; its version and the NatNet version
        as the firmware; Motive sends no serial number."""
        return DeviceIdentity(
            model=self.info.application,
            firmware=f"{self.info.application_text} (NatNet {self.info.natnet_text})",
        )

    def preflight(self, duration_s: float = 1.0) -> list[DeviceFinding]:
        """Read-only checks: the server and its NatNet version, the rigid bodies described,
        the frame rate over ``duration_s`` and whether the marker is tracked now."""
        findings = [
            DeviceFinding(
                FINDING_OK,
                "server",
                f"{self.url}: {self.info.application or 'unnamed'} {self.info.application_text}, "
                f"NatNet {self.info.natnet_text}",
            ),
            DeviceFinding(
                FINDING_OK,
                "rigid bodies",
                f"{self.body!r} (the marker) is described"
                + (f", and {', '.join(map(repr, self.tools.values()))}" if self.tools else "")
                + f"; {len(self.bodies)} rigid bod{'y' if len(self.bodies) == 1 else 'ies'} in all",
            ),
        ]
        end = time.monotonic() + duration_s
        self.stamps.clear()
        frames, seen = [], 0
        while (remaining := end - time.monotonic()) > 0:
            try:
                frame = self.next_frame(remaining)
            except DeviceError:
                break
            frames.append(frame.time_s)
            seen += frame.status == FRAME_OK
        stamps = sorted(set(self.stamps))
        if len(stamps) >= 2:
            # every frame that came, also those passed over for a newer one
            rate = (len(stamps) - 1) / (stamps[-1] - stamps[0])
            findings.append(DeviceFinding(FINDING_OK, "frame rate", f"{rate:.1f} Hz (Motive's timestamps)"))
        else:
            findings.append(
                DeviceFinding(
                    FINDING_PROBLEM,
                    "frame rate",
                    f"fewer than two frames in {duration_s:g} s: is Motive live?",
                )
            )
        if frames and seen:
            findings.append(DeviceFinding(FINDING_OK, "marker", f"tracked in {seen} of {len(frames)} frames"))
        elif frames:
            findings.append(
                DeviceFinding(
                    FINDING_WARNING,
                    "marker",
                    f"{self.body!r} not tracked in {len(frames)} frames: make it visible to the cameras",
                )
            )
        if self.malformed:
            findings.append(
                DeviceFinding(
                    FINDING_WARNING,
                    "transport",
                    f"{self.malformed} malformed packet(s) dropped (first: {self.first_malformed})",
                )
            )
        refused = refused_poses_finding(self.refused_poses, self.marker_frames)
        if refused is not None:
            findings.append(refused)
        return findings

    def close(self) -> None:
        """Tell Motive this client is gone (unicast), and close the sockets."""
        for sock in (self._command, self._data):
            if sock is None or sock.fileno() < 0:
                continue
            if sock is self._command and self.multicast is None:
                try:
                    sock.sendto(packet(NAT_DISCONNECT), self.server)
                except OSError:
                    pass
            try:
                sock.close()
            except OSError:
                pass


def open_device(address: DeviceAddress, options: DeviceOptions) -> NatNetTracker:
    """The ``natnet://`` row of the URL table (:data:`spacecal.adapters.DEVICE_SCHEMES`):
    ``natnet://HOST[:COMMAND_PORT]?body=NAME[&tools=A,B][&multicast=GROUP][&data_port=P]``;
    ``options.tools`` are (name, rigid-body name) pairs."""
    chosen = natnet_options(address.query, options)
    return NatNetTracker(
        address.host,
        address.port or COMMAND_PORT,
        chosen.body,
        dict(chosen.tools),
        chosen.multicast,
        chosen.data_port,
    )
