"""A fake OptiTrack Motive NatNet server (UDP, unicast and multicast), written from NaturalPoint's
published NatNet packet format, independently of the adapter's reader.

Sources: the NatNet SDK's ``NatNetTypes.h`` (message ids, ``sServerDescription``,
``sRigidBodyData``, ``sFrameOfMocapData``), ``PacketClient.cpp`` and the SDK's Python sample
``NatNetClient.py`` (``__unpack_server_info``, ``__unpack_data_descriptions``,
``__unpack_rigid_body_description``, ``__unpack_mocap_data`` and the section unpackers, as
NaturalPoint ships it with SDK 4.1 and as copied in e.g. lunarring/optitrack_python
``natnetpacket/NatNetClient.py``). Everything is little-endian.

* A packet: u16 message id, u16 payload size, payload.
* NAT_CONNECT (0) to the command port (SDK 4.1: a 270-byte payload, ``Ping`` first, the
  NatNet version the client asks for at bytes 265-268, then a NUL; older clients send
  ``Ping`` alone; the fake streams its own version whatever is asked) -> NAT_SERVERINFO (1):
  ``sSender_Server`` (``NatNetTypes.h``, packed, 279 bytes): char[256] application name,
  u8[4] application version, u8[4] NatNet version, u64 high-resolution clock frequency, u16
  data port, u8 multicast, u8[4] multicast group.
* NAT_REQUEST_MODELDEF (4) -> NAT_MODELDEF (5): i32 description count; per description i32
  type, from 4.1 on an i32 byte count of what follows, then: marker set (0): name, i32 count,
  marker names; rigid body (1): name, i32 id, i32 parent id (-1: none), 3 float32 offset,
  (4.2 on) 4 float32 orientation offset qx qy qz qw (where the PyPI ``natnet`` package reads
  it; the SDK 4.1 sample predates it), i32 marker count, count x 3 float32 marker offsets,
  count x i32 active labels, (4.0 on) count marker names.
* NAT_KEEPALIVE (10) keeps a unicast client; NAT_DISCONNECT (9) ends it; any other request is
  answered NAT_UNRECOGNIZED_REQUEST (100).
* NAT_FRAMEOFDATA (7), to each unicast client's address (where its NAT_CONNECT came from), or
  to the multicast group on the data port: i32 frame number; marker sets (i32 count, [4.1: i32
  bytes], per set name, i32 count, positions); other markers (count, [bytes], positions); rigid
  bodies (count, [bytes], per body i32 id, 3 float32 position m, 4 float32 qx qy qz qw, float32
  mean marker error m, i16 params, bit 0 tracking valid); skeletons (count, [bytes]); assets
  (4.1 on: count, bytes); labeled markers (count, [bytes], per marker i32 id, 3 float32, float32
  size, i16 params, float32 residual); force plates and devices (count, [bytes], per item i32
  id, i32 channels, per channel i32 frames, frames x float32); then u32 timecode, u32
  sub-timecode, float64 timestamp (s), three u64 high-resolution stamps, (4.0 on) u32 + u32
  precision timestamp, i16 params, i32 end-of-data tag 0.

Poses come from a function of time (``poses(t_s) -> {name: tracker_from_body (4, 4) mm or
None}``): the fake converts them to what Motive streams (m; quaternion by scipy, scalar last).

Bad frames the real server can send, as switches (:meth:`FakeMotive.set`): ``untracked``
(names whose tracking-valid flag is off, the last pose still sent), ``absent`` (names left out
of the frame), ``zeros`` (names sent as all zeros with the flag on), ``mute`` (no frames; the
command port still answers), ``malformed`` (``truncated``: each frame cut short under a correct
header; ``absurd``: a rigid-body count of 2**30; ``short_header``: the payload size field
larger than the datagram), ``not_natnet`` (the command port answers with text, as another
service would).
"""

from __future__ import annotations

import socket
import struct
import threading
import time
from collections.abc import Callable, Mapping

import numpy as np
from scipy.spatial.transform import Rotation

CONNECT, SERVERINFO, REQUEST_MODELDEF, MODELDEF, FRAMEOFDATA = 0, 1, 4, 5, 7
DISCONNECT, KEEPALIVE, UNRECOGNIZED = 9, 10, 100

PoseFunction = Callable[[float], Mapping[str, "np.ndarray | None"]]


def natnet_packet(message: int, payload: bytes) -> bytes:
    return struct.pack("<HH", message, len(payload)) + payload


def _name(text: str) -> bytes:
    return text.encode("utf-8") + b"\0"


def _section(version: tuple[int, ...], count: int, items: bytes) -> bytes:
    """A frame section: i32 count, from 4.1 on i32 byte count, the items."""
    sized = version >= (4, 1)
    return struct.pack("<i", count) + (struct.pack("<i", len(items)) if sized else b"") + items


class FakeMotive:
    """Motive streaming rigid bodies over NatNet.

    Parameters
    ----------
    poses : callable
        ``poses(t_s)``: {rigid body name: tracker_from_body (4, 4) in mm, or None (not seen)}, at
        the frame's timestamp ``t_s`` (``clock()``).
    bodies : sequence of str
        The rigid bodies Motive has (their streaming ids 1, 2, ...), in that order.
    version : (int, int)
        The NatNet version streamed: (3, 0), (3, 1), (4, 0), (4, 1), ...
    rate_hz : float
    clock : callable, optional
        Motive's timestamp now, s (default: s since the fake started).
    host : str
        The address of both ports.
    multicast : str or None
        Stream to this group on ``data_port`` instead of to the clients.
    """

    def __init__(
        self,
        poses: PoseFunction,
        bodies=("Marker",),
        version: tuple[int, int] = (4, 1),
        rate_hz: float = 100.0,
        host: str = "127.0.0.1",
        multicast: str | None = None,
        data_port: int = 0,
        application: str = "Motive",
        application_version: tuple[int, int, int, int] = (3, 1, 0, 0),
        clock: Callable[[], float] | None = None,
    ):
        self.poses, self.bodies, self.version, self.rate_hz = poses, list(bodies), tuple(version), rate_hz
        self.application, self.application_version = application, application_version
        self.multicast = multicast
        self.command = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.command.bind((host, 0))
        self.command.settimeout(0.05)
        self.data = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.data.bind((host, 0))
        if multicast is not None:
            self.data.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
            self.data.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(host))
        self.port = self.command.getsockname()[1]
        self.data_port = data_port
        self.clients: set[tuple[str, int]] = set()
        self.requests: list[int] = []
        self.untracked: set[str] = set()
        self.absent: set[str] = set()
        self.zeros: set[str] = set()
        self.mute = False
        self.malformed: str | None = None
        self.not_natnet = False
        self.sent_frames = 0
        self._last: dict[str, np.ndarray] = {}
        started = time.monotonic()
        #: Motive's timestamp: s since it started (here: since the fake did, unless given).
        self.clock = clock or (lambda: time.monotonic() - started)
        self.connect_payloads: list[bytes] = []
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._threads = [
            threading.Thread(target=self._serve_commands, daemon=True),
            threading.Thread(target=self._stream, daemon=True),
        ]
        for thread in self._threads:
            thread.start()

    def set(self, **switches) -> None:
        """Change switches (``untracked``, ``absent``, ``zeros``, ``mute``, ``malformed``,
        ``not_natnet``) between frames."""
        with self._lock:
            for key, value in switches.items():
                if not hasattr(self, key):
                    raise AttributeError(key)
                setattr(self, key, set(value) if isinstance(value, (list, tuple, set)) else value)

    # -- the command port ----------------------------------------------------------------
    def server_info(self) -> bytes:
        payload = self.application.encode("utf-8")[:255].ljust(256, b"\0")
        payload += bytes(self.application_version) + bytes((*self.version, 0, 0))
        group = socket.inet_aton(self.multicast or "0.0.0.0")
        payload += struct.pack("<QHB4s", 10_000_000, self.data_port, self.multicast is not None, group)
        assert len(payload) == 279
        return natnet_packet(SERVERINFO, payload)

    def model_definitions(self) -> bytes:
        names = b"".join(map(_name, self.bodies))
        descriptions = [(0, _name("all") + struct.pack("<i", len(self.bodies)) + names)]
        for number, name in enumerate(self.bodies, start=1):
            markers = np.array([[0.0, 0.0, 0.0], [0.05, 0.0, 0.0], [0.0, 0.07, 0.01]])
            body = _name(name) + struct.pack("<ii3f", number, -1, 0.0, 0.0, 0.0)
            if self.version >= (4, 2):
                body += struct.pack("<4f", 0.0, 0.0, 0.0, 1.0)  # the orientation offset
            body += struct.pack("<i", len(markers)) + markers.astype("<f4").tobytes()
            body += struct.pack(f"<{len(markers)}i", *range(len(markers)))
            if self.version >= (4, 0):
                body += b"".join(_name(f"{name}_{k + 1}") for k in range(len(markers)))
            descriptions.append((1, body))
        payload = struct.pack("<i", len(descriptions))
        for kind, content in descriptions:
            payload += struct.pack("<i", kind)
            if self.version >= (4, 1):
                payload += struct.pack("<i", len(content))
            payload += content
        return natnet_packet(MODELDEF, payload)

    def _serve_commands(self) -> None:
        while not self._stop.is_set():
            try:
                data, client = self.command.recvfrom(65536)
            except (TimeoutError, OSError):
                continue
            if len(data) < 4:
                continue
            (message,) = struct.unpack_from("<H", data)
            with self._lock:
                self.requests.append(message)
                if self.not_natnet:
                    reply = b"HTTP/1.1 400 Bad Request\r\n\r\n"
                elif message == CONNECT:
                    self.connect_payloads.append(data[4:])
                    self.clients.add(client)
                    reply = self.server_info()
                elif message == REQUEST_MODELDEF:
                    reply = self.model_definitions()
                elif message == KEEPALIVE:
                    reply = b""
                elif message == DISCONNECT:
                    self.clients.discard(client)
                    reply = b""
                else:
                    reply = natnet_packet(UNRECOGNIZED, b"")
            if reply:
                try:
                    self.command.sendto(reply, client)
                except OSError:
                    pass

    # -- the data stream -------------------------------------------------------------------
    def _body(self, number: int, name: str, pose) -> bytes:
        """One rigid body of a frame, as Motive sends it (m, scalar-last quaternion)."""
        valid = name not in self.untracked
        if name in self.zeros:
            return struct.pack("<i3f4ffh", number, 0, 0, 0, 0, 0, 0, 0, 0.0, 1)
        if pose is None:
            pose = self._last.get(name)
            valid = False
        if pose is None:
            return struct.pack("<i3f4ffh", number, 0, 0, 0, 0, 0, 0, 0, 0.0, 0)
        self._last[name] = pose
        x, y, z = np.asarray(pose)[:3, 3] / 1000.0
        qx, qy, qz, qw = Rotation.from_matrix(np.asarray(pose)[:3, :3]).as_quat()
        return struct.pack("<i3f4ffh", number, x, y, z, qx, qy, qz, qw, 0.0002, int(valid))

    def frame(self, frame_number: int, t_s: float) -> bytes:
        """A NAT_FRAMEOFDATA packet at ``t_s`` (s since the fake started)."""
        version = self.version
        poses = dict(self.poses(t_s))
        numbered = [(k, name) for k, name in enumerate(self.bodies, start=1) if name not in self.absent]
        bodies = [self._body(k, name, poses.get(name)) for k, name in numbered]
        positions = [
            np.asarray(poses.get(name))[:3, 3] / 1000 if poses.get(name) is not None else np.zeros(3)
            for _, name in numbered
        ]
        marker_set = _name("all") + struct.pack("<i", len(positions)) + np.asarray(positions, "<f4").tobytes()
        payload = struct.pack("<i", frame_number)
        payload += _section(version, 1, marker_set)
        payload += _section(version, 0, b"")  # other (unlabeled legacy) markers
        count = 2**30 if self.malformed == "absurd" else len(bodies)
        payload += _section(version, count, b"".join(bodies))
        payload += _section(version, 0, b"")  # skeletons
        if version >= (4, 1):
            payload += _section(version, 0, b"")  # assets
        labeled = b"".join(
            struct.pack("<i3ffhf", (k << 16) | 1, *p, 0.014, 0, 0.0001)
            for (k, _), p in zip(numbered, positions, strict=True)
        )
        payload += _section(version, len(numbered), labeled)
        payload += _section(version, 0, b"")  # force plates
        device = struct.pack("<iii2f", 1, 1, 2, 0.5, 0.25)  # one device, one channel, two frames
        payload += _section(version, 1, device)
        payload += struct.pack("<II", 0, 0) + struct.pack("<d", t_s)
        payload += struct.pack("<QQQ", 0, 0, 0)
        if version >= (4, 0):
            payload += struct.pack("<II", int(t_s), 0)
        payload += struct.pack("<hi", 0, 0)
        packet = natnet_packet(FRAMEOFDATA, payload)
        if self.malformed == "truncated":
            cut = len(packet) // 2
            return packet[:2] + struct.pack("<H", cut - 4) + packet[4:cut]
        if self.malformed == "short_header":
            return packet[:-10]
        return packet

    def _stream(self) -> None:
        number = 1000
        period = 1.0 / self.rate_hz
        next_at = time.monotonic()
        while not self._stop.is_set():
            next_at += period
            if self._stop.wait(max(0.0, next_at - time.monotonic())):
                return
            with self._lock:
                targets = [(self.multicast, self.data_port)] if self.multicast else list(self.clients)
                # no frame is made for nobody: the world's noise streams, which the other fakes
                # draw from too, are drawn only while a client reads
                if self.mute or not targets:
                    continue
                number += 1
                packet = self.frame(number, self.clock())
                self.sent_frames += 1
            for target in targets:
                try:
                    self.data.sendto(packet, target)
                except OSError:
                    pass

    def close(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=2)
        self.command.close()
        self.data.close()
