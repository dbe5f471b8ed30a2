"""3D Slicer live over OpenIGTLink: the needle plan from Slicer, the needle's pose back to it.

3D Slicer's OpenIGTLinkIF module (SlicerOpenIGTLink extension) connects to spacecal, or
spacecal to it, on one TCP connection; docs/slicer_live.md says how to set Slicer up.

From Slicer (what OpenIGTLinkIF sends for an outgoing node, ``vtkMRMLIGTLConnectorNode``):

* POINT ``Plan`` (:data:`PLAN_DEVICE`): a markups point list named ``Plan``, one element per
  control point (OpenIGTLink POINT body, ``igtl_point.h``: 136 bytes per element, name
  char[64], group char[32], RGBA u8[4], XYZ float32[3], radius float32, owner char[20]; the
  spec calls the radius field "diameter"). The entry and the target are the points labelled as
  in a markups file (:data:`~spacecal.io.slicer_markups.ENTRY_LABELS`, ``TARGET_LABELS``:
  ``entry`` / ``target``, also ``start`` / ``end``, case-insensitive). Slicer sends a point
  list only (a Line markup is not sent as POINT), in the node's own coordinates, RAS.
* TRANSFORM ``EntryToRAS`` and ``TargetToRAS`` (:data:`ENTRY_DEVICE`, :data:`TARGET_DEVICE`):
  linear transform nodes whose translation is the point; a TRANSFORM carries the node's
  to-parent matrix (12 float32: the rotation column by column, then the translation), and the
  parent is Slicer's world, RAS. The rotation is not used.

Each accepted message replaces the points it carries (the newest value of each point wins,
whichever message carried it) and advances the plan's revision. The plan is returned in
``image_lps`` (``LPS = diag(-1, -1, 1) RAS``), as :func:`spacecal.io.slicer_markups.plan_from_markups`
returns a plan read from a file, so the rest of spacecal cannot tell the two apart.

A refused plan message (a bad CRC, a non-finite or absurd coordinate, a missing, repeated or
unprintable label, entry and target closer than 1 mm) withholds the plan: until the same device
sends a good message, :meth:`SlicerLink.latest_plan` and :meth:`SlicerLink.wait_for_plan` raise
the refusal, because the plan on Slicer's screen is then not the plan spacecal holds. Messages
of other types or other device names are counted and otherwise ignored.

To Slicer, at :data:`DEFAULT_RATE_HZ` from a background thread:

* TRANSFORM ``NeedleToTracker`` (:data:`NEEDLE_TO_TRACKER`): ``tracker_from_needle``, mm;
* TRANSFORM ``NeedleToRAS`` (:data:`NEEDLE_TO_RAS`): ``image_ras_from_needle``, once a
  registration is set (:meth:`SlicerLink.set_registration`), so a needle model under it in
  Slicer moves over the CT.

Header version 1 (every OpenIGTLink receiver reads it), CRC-64 of the body. The newest pose
given to :meth:`SlicerLink.update_needle` is sent each period while it is fresher than
:data:`POSE_MAX_AGE_S`; after that nothing is sent (Slicer keeps showing the last pose). A
period whose pose cannot be sent (no peer, or the last frame's bytes still unsent because the
peer reads slowly) is a dropped frame, counted; a peer that takes no byte for
:data:`STALL_TIMEOUT_S` is disconnected. The caller never waits on the network:
:meth:`~SlicerLink.update_needle` only stores the pose.

Bounds on what the peer sends: a header version other than 1 or 2, a type name that is not
printable ASCII, a TRANSFORM or POINT body above :data:`PLAN_BODY_MAX_BYTES`, or any body above
:data:`~spacecal.adapters.igtl.MAX_BODY_BYTES` closes the connection with one line (in
:meth:`SlicerLink.status`); other large messages (images) are read past, never kept.
"""

from __future__ import annotations

import collections
import math
import select
import socket
import struct
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from spacecal.adapters.igtl import (
    HEADER,
    MAX_BODY_BYTES,
    POSE_BODY_MAX_BYTES,
    crc64,
    parse_message,
)
from spacecal.core.errors import DeviceError, InvalidInputError
from spacecal.core.text import check_name, exception_line, quoted, sanitize_for_terminal
from spacecal.geometry.anatomical import RAS_FROM_LPS, flip_lps_ras
from spacecal.geometry.transforms import NEARLY_RIGID_TOLERANCE, check_transform, invert_transform
from spacecal.io.slicer_markups import ENTRY_LABELS, TARGET_LABELS
from spacecal.records.needle_plan import ImageRegistration, NeedlePlan

#: spacecal's port as the OpenIGTLink server for Slicer: 18944, OpenIGTLink's usual port, is
#: PlusServer's (the tracker spacecal may read at the same time), so the next one.
SLICER_LINK_DEFAULT_PORT = 18945
#: The port of a Slicer connector in server mode (OpenIGTLinkIF's default).
SLICER_SERVER_DEFAULT_PORT = 18944

#: Device names (PLUS/SlicerIGT ``FromToTo`` naming for transforms).
PLAN_DEVICE = "Plan"
ENTRY_DEVICE = "EntryToRAS"
TARGET_DEVICE = "TargetToRAS"
NEEDLE_TO_TRACKER = "NeedleToTracker"
NEEDLE_TO_RAS = "NeedleToRAS"
PLAN_DEVICES = {PLAN_DEVICE: "POINT", ENTRY_DEVICE: "TRANSFORM", TARGET_DEVICE: "TRANSFORM"}

#: The needle's sending rate, Hz, and the rates accepted (Slicer redraws at up to 60 Hz).
DEFAULT_RATE_HZ = 20.0
MIN_RATE_HZ, MAX_RATE_HZ = 1.0, 100.0
#: A pose older than this (s since :meth:`SlicerLink.update_needle`) is no longer sent: the
#: needle is not being seen, and repeating its last pose would show it as live.
POSE_MAX_AGE_S = 0.5
#: A peer that takes none of our bytes for this long while some wait is disconnected, s.
STALL_TIMEOUT_S = 2.0
#: Our socket's send buffer, bytes: small, so a peer that stops reading is noticed (and frames
#: dropped) after seconds, not after megabytes of stale poses are queued for it.
SEND_BUFFER_BYTES = 16 * 1024
#: Client mode: one connection attempt's deadline, and the pause between attempts, s.
CONNECT_TIMEOUT_S = 0.5
RECONNECT_INTERVAL_S = 1.0
#: How long the background thread may take to stop on :meth:`SlicerLink.close`, s (it waits at
#: most :data:`LOOP_WAIT_S` at a time, or one connection attempt).
CLOSE_DEADLINE_S = 2.0
LOOP_WAIT_S = 0.02

#: One POINT element (igtl_point.h ``igtl_point_element``), big-endian.
POINT_ELEMENT = struct.Struct(">64s32s4B3ff20s")
#: Largest TRANSFORM or POINT body accepted, bytes: a TRANSFORM is 48, a POINT 136 per point
#: (480 points), header v2 metadata a few hundred more.
PLAN_BODY_MAX_BYTES = POSE_BODY_MAX_BYTES
#: Farthest a plan point may be from the image origin, mm: a CT is under a metre across, and a
#: float32 of 1e30 is finite but no position.
MAX_COORDINATE_MM = 1.0e4
#: Longest control point label (the POINT name field, char[64]).
MAX_LABEL_CHARS = 64
#: Distinct ignored (type, device) pairs counted by name; the rest are counted together.
MAX_IGNORED_KEYS = 32
#: Problems kept for :meth:`SlicerLink.status` (the newest).
MAX_PROBLEMS = 8

_TRANSFORM_BODY = struct.Struct(">12f")


@dataclass(frozen=True)
class SlicerPlan:
    """A needle plan received from Slicer.

    Attributes
    ----------
    plan : spacecal.records.needle_plan.NeedlePlan
        Entry and target in ``image_lps``, mm.
    revision : int
        Advances with every accepted plan message (1 for the first complete plan).
    devices : tuple of str
        The devices that gave the entry and the target, e.g. ``("Plan", "TargetToRAS")``.
    """

    plan: NeedlePlan
    revision: int
    devices: tuple[str, str]


@dataclass(frozen=True)
class LinkStatus:
    """What the link has done, for a report (a snapshot).

    Attributes
    ----------
    url : str
        Where spacecal listens (``igtl-server://HOST:PORT``) or connects (``igtl://HOST:PORT``).
    connected : bool
        A peer is connected now.
    peer : str or None
        The peer's address.
    connections, disconnections : int
        Peers connected, and connections lost or closed by spacecal.
    frames_sent : int
        Needle frames handed whole to the network.
    frames_dropped : int
        Periods with a fresh pose that could not be sent (no peer, or the peer reading slowly).
    frames_without_ras : int
        Frames sent without ``NeedleToRAS``: a registration into ``reference`` and no pose of
        the reference marker given with the needle's.
    messages_received, crc_errors, refused : int
        Messages from the peer; those with a bad CRC; plan messages refused.
    ignored : dict
        ``(type, device name) -> count`` of messages that are not part of the plan.
    problems : tuple of str
        The newest problems, one line each.
    """

    url: str
    connected: bool
    peer: str | None
    connections: int
    disconnections: int
    frames_sent: int
    frames_dropped: int
    frames_without_ras: int
    messages_received: int
    crc_errors: int
    refused: int
    ignored: dict[tuple[str, str], int] = field(default_factory=dict)
    problems: tuple[str, ...] = ()

    def lines(self) -> list[str]:
        """The status for a person, one fact a line."""
        lines = [
            f"{self.url}: " + (f"connected to {self.peer}" if self.connected else "no peer connected"),
            f"needle frames sent {self.frames_sent}, dropped {self.frames_dropped}, "
            f"without NeedleToRAS {self.frames_without_ras}; "
            f"connections {self.connections}, lost {self.disconnections}",
            f"messages received {self.messages_received}, bad CRC {self.crc_errors}, "
            f"plan refused {self.refused}",
        ]
        if self.ignored:
            lines.append(
                "ignored: "
                + ", ".join(f"{kind} {name} x{count}" for (kind, name), count in self.ignored.items())
            )
        lines += [f"problem: {problem}" for problem in self.problems]
        return lines


class _StreamError(Exception):
    """The peer's bytes are not an OpenIGTLink stream we accept: the connection is closed."""


def _stamp(timestamp_s: float) -> int:
    """OpenIGTLink's 64-bit timestamp: seconds << 32 | fraction * 2**32."""
    seconds = int(timestamp_s)
    return (seconds << 32) | (int((timestamp_s - seconds) * 2**32) & 0xFFFFFFFF)


def transform_message(device_name: str, a_from_b: np.ndarray, timestamp_s: float) -> bytes:
    """One TRANSFORM message, header version 1: ``a_from_b`` (4, 4) mm as the 12 float32 the
    protocol sends (the rotation column by column, then the translation), CRC-64 of the body."""
    body = _TRANSFORM_BODY.pack(*a_from_b[:3, :3].T.reshape(-1), *a_from_b[:3, 3])
    header = HEADER.pack(
        1, b"TRANSFORM", device_name.encode("ascii"), _stamp(timestamp_s), len(body), crc64(body)
    )
    return header + body


def _field_text(raw: bytes, what: str) -> str:
    """A NUL-padded char[] field as text (UTF-8), refused when it is not printable."""
    value = raw.split(b"\0", 1)[0]
    try:
        text = value.decode("utf-8").strip(" ")
    except UnicodeDecodeError:
        raise InvalidInputError(f"{what} {quoted(value)} is not UTF-8 text") from None
    return check_name(text, what, MAX_LABEL_CHARS) if text else text


def _point_in_lps(values: tuple[float, ...], what: str) -> np.ndarray:
    """A point sent in RAS (3 float32) as ``image_lps``, refused when not a position."""
    point = np.array(values, dtype=float)
    if not np.all(np.isfinite(point)):
        raise InvalidInputError(f"{what} has a non-finite coordinate ({', '.join(f'{v:g}' for v in point)})")
    if float(np.max(np.abs(point))) > MAX_COORDINATE_MM:
        raise InvalidInputError(
            f"{what} is {float(np.max(np.abs(point))):.3g} mm from the origin "
            f"(at most {MAX_COORDINATE_MM:g} mm)"
        )
    return flip_lps_ras(point)


def plan_points_from_point_message(
    content: bytes, device: str = PLAN_DEVICE
) -> tuple[np.ndarray, np.ndarray, tuple[str, str]]:
    """The entry and target of a POINT message body (header v2 extension removed).

    Parameters
    ----------
    content : bytes
        n x 136-byte elements (``igtl_point_element``).
    device : str
        The device name, for messages.

    Returns
    -------
    entry_in_image_lps, target_in_image_lps : numpy.ndarray, shape (3,)
        The two points, sent in RAS, in ``image_lps``, mm.
    labels : tuple of str
        The entry's and the target's labels.

    Raises
    ------
    InvalidInputError
        A body that is not whole elements, more than the bound of points, a label that is not
        printable, a non-finite or absurd coordinate, the entry or target missing or repeated.
    """
    size = POINT_ELEMENT.size
    if not content or len(content) % size:
        raise InvalidInputError(f"POINT {device}: body of {len(content)} bytes is not n x {size}")
    labels, points = [], []
    for index in range(len(content) // size):
        name, _group, _r, _g, _b, _a, x, y, z, _radius, _owner = POINT_ELEMENT.unpack_from(
            content, index * size
        )
        where = f"POINT {device}, point {index + 1}"
        label = _field_text(name, f"{where} name")
        labels.append(label)
        points.append(_point_in_lps((x, y, z), f"{where} ({quoted(label)})"))
    chosen = {}
    for role, candidates in (("entry", ENTRY_LABELS), ("target", TARGET_LABELS)):
        for candidate in candidates:
            hits = [i for i, label in enumerate(labels) if label.lower() == candidate]
            if len(hits) > 1:
                raise InvalidInputError(
                    f"POINT {device}: {len(hits)} points are labelled {quoted(candidate)}"
                )
            if hits:
                chosen[role] = hits[0]
                break
        else:
            raise InvalidInputError(
                f"POINT {device}: no point labelled {' or '.join(quoted(c) for c in candidates)} "
                f"for the {role} (labels: {', '.join(quoted(label) for label in labels[:8])}"
                f"{', ...' if len(labels) > 8 else ''})"
            )
    entry, target = chosen["entry"], chosen["target"]
    return points[entry], points[target], (labels[entry], labels[target])


def point_from_transform_message(content: bytes, device: str) -> np.ndarray:
    """The translation of a TRANSFORM body (a to-parent matrix in RAS) as ``image_lps``, mm.

    Raises
    ------
    InvalidInputError
        Not 48 bytes, a non-finite number anywhere in the matrix, or an absurd translation.
    """
    if len(content) != _TRANSFORM_BODY.size:
        raise InvalidInputError(f"TRANSFORM {device}: body of {len(content)} bytes, expected 48")
    values = _TRANSFORM_BODY.unpack(content)
    if not all(math.isfinite(v) for v in values):
        raise InvalidInputError(f"TRANSFORM {device}: the matrix has a non-finite number")
    return _point_in_lps(values[9:], f"TRANSFORM {device} translation")


class _Framer:
    """Cuts the peer's bytes into messages, within the bounds; large other messages are read
    past with their header only."""

    def __init__(self) -> None:
        self._buffer = bytearray()
        self._skip = 0

    def feed(self, chunk: bytes) -> list[tuple[bytes, bytes | None]]:
        """Messages completed by ``chunk``: (header, body), body None for one read past.

        Raises
        ------
        _StreamError
            A header no OpenIGTLink sender writes, or a body above the bounds.
        """
        if self._skip:
            passed = min(self._skip, len(chunk))
            self._skip -= passed
            chunk = chunk[passed:]
        self._buffer += chunk
        messages: list[tuple[bytes, bytes | None]] = []
        while len(self._buffer) >= HEADER.size:
            header = bytes(self._buffer[: HEADER.size])
            version, kind, _, _, body_size, _ = HEADER.unpack(header)
            kind_text = kind.rstrip(b"\0").decode("ascii", "replace")
            if version not in (1, 2) or not kind_text or not all(" " < c <= "~" for c in kind_text):
                raise _StreamError(
                    f"not an OpenIGTLink stream (header version {version}, type {quoted(kind_text)})"
                )
            limit = PLAN_BODY_MAX_BYTES if kind_text in ("TRANSFORM", "POINT") else MAX_BODY_BYTES
            if body_size > limit:
                raise _StreamError(
                    f"a {body_size}-byte {kind_text} message is above the {limit}-byte bound: not accepted"
                )
            if body_size > PLAN_BODY_MAX_BYTES:  # an image or the like: never kept
                messages.append((header, None))
                passed = min(len(self._buffer), HEADER.size + body_size)
                self._skip = HEADER.size + body_size - passed
                del self._buffer[:passed]
                continue
            if len(self._buffer) < HEADER.size + body_size:
                break
            body = bytes(self._buffer[HEADER.size : HEADER.size + body_size])
            del self._buffer[: HEADER.size + body_size]
            messages.append((header, body))
        return messages


class SlicerLink:
    """The OpenIGTLink link with 3D Slicer during needle guidance (one peer at a time).

    Make one with :meth:`serve` (spacecal listens; Slicer's connector is a client) or
    :meth:`connect` (Slicer's connector is a server). One background thread owns the socket:
    it accepts or connects (again after a loss), reads the plan, and sends the needle at
    ``rate_hz``. Every public method returns at once, except the two waits, which have a
    deadline, and :meth:`close`, which takes at most :data:`CLOSE_DEADLINE_S`. Use it as a
    context manager, or call :meth:`close`.

    Raises
    ------
    DeviceError
        :meth:`serve` could not listen on the port.
    InvalidInputError
        A rate outside :data:`MIN_RATE_HZ` to :data:`MAX_RATE_HZ`.
    """

    def __init__(self, role: str, host: str, port: int, rate_hz: float = DEFAULT_RATE_HZ):
        if role not in ("server", "client"):
            raise InvalidInputError(f"role {quoted(role)} is not server or client")
        if not (MIN_RATE_HZ <= float(rate_hz) <= MAX_RATE_HZ):
            raise InvalidInputError(
                f"rate {rate_hz:g} Hz is not within {MIN_RATE_HZ:g} to {MAX_RATE_HZ:g} Hz"
            )
        self._role, self._host, self._port = role, host, int(port)
        self.url = f"igtl-server://{host}:{port}" if role == "server" else f"igtl://{host}:{port}"
        self.period_s = 1.0 / float(rate_hz)
        self._condition = threading.Condition()
        self._stop = threading.Event()
        # the background thread's alone
        self._peer: socket.socket | None = None
        self._peer_name: str | None = None
        self._framer = _Framer()
        self._outgoing = bytearray()
        self._progress_at = 0.0
        self._next_connect_at = 0.0
        self._next_tick_at = time.monotonic()
        # shared, under the condition's lock
        self._pose: tuple[np.ndarray, np.ndarray | None, float, float] | None = None
        self._image_ras_from: tuple[str, np.ndarray] | None = None
        self._points: dict[str, tuple[np.ndarray, str, str]] = {}  # role -> (point, label, device)
        self._revision = 0
        self._refusals: dict[str, str] = {}
        self._counts: collections.Counter = collections.Counter()
        self._ignored: collections.Counter = collections.Counter()
        self._problems: collections.deque = collections.deque(maxlen=MAX_PROBLEMS)
        self._listener: socket.socket | None = None
        if role == "server":
            try:
                self._listener = socket.create_server((host, self._port), backlog=1)
            except OSError as exc:
                raise DeviceError(
                    f"cannot listen for Slicer on {host}:{port} ({exc.strerror or exc})"
                ) from None
            self._listener.setblocking(False)
            self._port = self._listener.getsockname()[1]
            self.url = f"igtl-server://{host}:{self._port}"
        self._thread = threading.Thread(target=self._run, name="spacecal-slicer-link", daemon=True)
        self._thread.start()

    @classmethod
    def serve(
        cls, port: int = SLICER_LINK_DEFAULT_PORT, host: str = "127.0.0.1", rate_hz: float = DEFAULT_RATE_HZ
    ) -> SlicerLink:
        """Listen for Slicer's OpenIGTLinkIF connector (client mode) on ``host:port``.

        ``host`` ``127.0.0.1`` takes Slicer on this computer only; ``0.0.0.0`` any computer of
        the network. Port 0 picks a free port (read :attr:`port`). A second connection
        replaces the first (Slicer reconnecting after a loss)."""
        return cls("server", host, port, rate_hz)

    @classmethod
    def connect(
        cls, host: str, port: int = SLICER_SERVER_DEFAULT_PORT, rate_hz: float = DEFAULT_RATE_HZ
    ) -> SlicerLink:
        """Connect to Slicer's OpenIGTLinkIF connector in server mode at ``host:port``; retried
        every :data:`RECONNECT_INTERVAL_S` until it answers, and again after a loss."""
        return cls("client", host, port, rate_hz)

    @property
    def port(self) -> int:
        """The port listened on, or connected to."""
        return self._port

    # -- the caller's side -------------------------------------------------------------------
    def set_registration(self, registration: ImageRegistration | None) -> None:
        """Send ``NeedleToRAS`` from now on, with this ``tracker_from_image`` (or stop: None).

        A registration into ``reference`` (a marker on the patient) needs that marker's pose
        with every needle pose (:meth:`update_needle`'s ``tracker_from_reference``).

        Raises
        ------
        InvalidInputError
            The registration's image frame is ``image`` (LPS or RAS not stated).
        """
        if registration is None:
            chosen = None
        else:
            if registration.image_frame not in ("image_lps", "image_ras"):
                raise InvalidInputError(
                    f"registration {registration.name}: its image frame does not say LPS or RAS, "
                    "so the needle cannot be placed in Slicer's RAS"
                )
            image_from_registered = invert_transform(registration.tracker_from_image)
            if registration.image_frame == "image_lps":
                image_from_registered = RAS_FROM_LPS @ image_from_registered
            chosen = (registration.tracker_frame, image_from_registered)
        with self._condition:
            self._image_ras_from = chosen

    def update_needle(
        self,
        tracker_from_needle: np.ndarray,
        *,
        tracker_from_reference: np.ndarray | None = None,
        timestamp_s: float | None = None,
    ) -> None:
        """Give the needle's newest pose; it is sent from the background thread (never waits).

        Parameters
        ----------
        tracker_from_needle : array_like, shape (4, 4)
            The needle (tip frame) in the tracker, mm.
        tracker_from_reference : array_like, shape (4, 4), optional
            The patient reference marker's pose at the same time, mm, for a registration into
            ``reference``.
        timestamp_s : float, optional
            When the pose was measured, Unix time, s (the messages' timestamp); default now.

        Raises
        ------
        InvalidInputError
            A pose that is not a finite rigid transform (a placeholder of a tracker that did
            not see the needle is not a pose: do not give one).
        """
        needle = check_transform(tracker_from_needle, "tracker_from_needle", atol=NEARLY_RIGID_TOLERANCE)
        reference = (
            None
            if tracker_from_reference is None
            else check_transform(
                tracker_from_reference, "tracker_from_reference", atol=NEARLY_RIGID_TOLERANCE
            )
        )
        stamp = time.time() if timestamp_s is None else float(timestamp_s)
        if not math.isfinite(stamp) or stamp < 0:
            raise InvalidInputError(f"timestamp {stamp!r} s is not a time")
        with self._condition:
            self._pose = (needle, reference, stamp, time.monotonic())

    def latest_plan(self) -> SlicerPlan | None:
        """The plan as now received (None while the entry or the target has not come).

        Raises
        ------
        InvalidInputError
            The newest message of a plan device was refused (the line says why).
        """
        with self._condition:
            return self._plan()

    def wait_for_plan(self, timeout_s: float, after_revision: int = 0) -> SlicerPlan:
        """Wait, at most ``timeout_s``, for a plan newer than ``after_revision``.

        Raises
        ------
        InvalidInputError
            A plan message was refused (at once, not at the deadline).
        DeviceError
            No such plan within ``timeout_s`` (the line says what did come).
        """
        deadline = time.monotonic() + float(timeout_s)
        with self._condition:
            while True:
                plan = self._plan()
                if plan is not None and plan.revision > after_revision:
                    return plan
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise DeviceError(self._why_no_plan(timeout_s))
                self._condition.wait(min(remaining, 0.1))

    def wait_for_peer(self, timeout_s: float) -> str:
        """Wait, at most ``timeout_s``, for a peer; its address.

        Raises
        ------
        DeviceError
            No peer within ``timeout_s``.
        """
        deadline = time.monotonic() + float(timeout_s)
        with self._condition:
            while self._counts["connected"] == 0:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    problem = f" ({self._problems[-1]})" if self._problems else ""
                    raise DeviceError(f"{self.url}: Slicer did not connect within {timeout_s:g} s{problem}")
                self._condition.wait(min(remaining, 0.1))
            return str(self._peer_name)

    def status(self) -> LinkStatus:
        """A snapshot of the link's counts and newest problems."""
        with self._condition:
            counts = self._counts
            return LinkStatus(
                url=self.url,
                connected=bool(counts["connected"]),
                peer=self._peer_name if counts["connected"] else None,
                connections=counts["connections"],
                disconnections=counts["disconnections"],
                frames_sent=counts["sent"],
                frames_dropped=counts["dropped"],
                frames_without_ras=counts["without_ras"],
                messages_received=counts["received"],
                crc_errors=counts["crc"],
                refused=counts["refused"],
                ignored=dict(self._ignored),
                problems=tuple(self._problems),
            )

    def close(self) -> None:
        """Stop the thread (at most :data:`CLOSE_DEADLINE_S`) and close every socket."""
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join(CLOSE_DEADLINE_S)
        if self._thread.is_alive():  # stuck in a system call: the sockets' close ends it
            self._close_sockets()

    def __enter__(self) -> SlicerLink:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    # -- plan state (the lock held) ----------------------------------------------------------
    def _plan(self) -> SlicerPlan | None:
        if self._refusals:
            device, reason = next(iter(self._refusals.items()))
            raise InvalidInputError(f"plan from Slicer withheld: {reason} (until {device} is sent again)")
        if "entry" not in self._points or "target" not in self._points:
            return None
        plan = self._needle_plan(self._points)
        return SlicerPlan(plan, self._revision, (self._points["entry"][2], self._points["target"][2]))

    @staticmethod
    def _needle_plan(points: dict[str, tuple[np.ndarray, str, str]]) -> NeedlePlan:
        entry, entry_label, entry_device = points["entry"]
        target, target_label, target_device = points["target"]
        try:
            return NeedlePlan(
                entry_in_image=entry,
                target_in_image=target,
                image_frame="image_lps",
                name=PLAN_DEVICE,
                entry_label=entry_label,
                target_label=target_label,
            )
        except InvalidInputError as exc:
            raise InvalidInputError(f"plan from Slicer ({entry_device}, {target_device}): {exc}") from None

    def _why_no_plan(self, timeout_s: float) -> str:
        if not self._counts["connections"]:
            return f"{self.url}: no plan within {timeout_s:g} s: Slicer never connected"
        have = sorted(self._points)
        missing = [role for role in ("entry", "target") if role not in have]
        seen = ", ".join(f"{kind} {name}" for kind, name in list(self._ignored)[:6])
        return (
            f"{self.url}: no {' and '.join(missing) or 'new'} plan point within {timeout_s:g} s "
            f"(send POINT {PLAN_DEVICE}, or TRANSFORM {ENTRY_DEVICE} and {TARGET_DEVICE})"
            + (f"; Slicer sent {seen}" if seen else "")
        )

    def _problem(self, line: str) -> None:
        self._problems.append(line)
        self._condition.notify_all()

    # -- the background thread ---------------------------------------------------------------
    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                if self._peer is None:
                    self._find_peer()
                self._serve_peer()
                now = time.monotonic()
                if now >= self._next_tick_at:
                    self._tick(now)
        finally:
            self._close_sockets()

    def _find_peer(self) -> None:
        """Accept a connection, or make one (every :data:`RECONNECT_INTERVAL_S`)."""
        wait = max(min(self._next_tick_at - time.monotonic(), LOOP_WAIT_S), 0.0)
        if self._listener is not None:
            readable, _, _ = select.select([self._listener], [], [], wait)
            if readable:
                self._accept()
            return
        now = time.monotonic()
        if now < self._next_connect_at:
            self._stop.wait(wait)
            return
        self._next_connect_at = now + RECONNECT_INTERVAL_S
        try:
            connection = socket.create_connection((self._host, self._port), timeout=CONNECT_TIMEOUT_S)
        except OSError as exc:
            with self._condition:
                line = f"{self.url}: could not connect ({exc.strerror or exc}); retrying"
                if not self._problems or self._problems[-1] != line:
                    self._problem(line)
            return
        self._adopt(connection, f"{self._host}:{self._port}")

    def _accept(self) -> None:
        assert self._listener is not None
        try:
            connection, address = self._listener.accept()
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            with self._condition:
                self._problem(f"{self.url}: accepting a connection failed ({exc.strerror or exc})")
            return
        self._adopt(connection, f"{address[0]}:{address[1]}")

    def _adopt(self, connection: socket.socket, name: str) -> None:
        connection.setblocking(False)
        connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        connection.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER_BYTES)
        self._peer, self._framer, self._outgoing = connection, _Framer(), bytearray()
        with self._condition:
            self._peer_name = name
            self._counts["connected"] = 1
            self._counts["connections"] += 1
            self._condition.notify_all()

    def _drop_peer(self, reason: str) -> None:
        if self._peer is None:
            return
        try:
            self._peer.close()
        except OSError:
            pass
        self._peer, self._outgoing = None, bytearray()
        with self._condition:
            self._counts["connected"] = 0
            self._counts["disconnections"] += 1
            self._problem(f"{self.url}: {self._peer_name}: {reason}")
        # a client tries again after the interval; a server accepts the next connection
        self._next_connect_at = time.monotonic() + RECONNECT_INTERVAL_S

    def _serve_peer(self) -> None:
        """Read what the peer sent and write what waits, for at most until the next tick."""
        peer = self._peer
        if peer is None:
            return
        wait = max(min(self._next_tick_at - time.monotonic(), LOOP_WAIT_S), 0.0)
        watched = [peer] if self._listener is None else [peer, self._listener]
        try:
            readable, writable, _ = select.select(watched, [peer] if self._outgoing else [], [], wait)
        except (OSError, ValueError) as exc:
            self._drop_peer(f"connection lost ({exc})")
            return
        if self._listener is not None and self._listener in readable:
            self._accept_replacing()
            return
        if peer in readable and not self._receive(peer):
            return
        if self._outgoing and peer in writable:
            self._flush(peer)
        if self._outgoing and time.monotonic() - self._progress_at > STALL_TIMEOUT_S:
            self._drop_peer(f"read nothing for {STALL_TIMEOUT_S:g} s: connection closed")

    def _accept_replacing(self) -> None:
        """A new connection while one is open: Slicer reconnecting, the old one half dead."""
        old = self._peer
        self._peer = None
        self._accept()
        if self._peer is None:
            self._peer = old
            return
        if old is not None:
            try:
                old.close()
            except OSError:
                pass
            with self._condition:
                self._counts["disconnections"] += 1
                self._problem(f"{self.url}: a new connection replaced the previous one")

    def _receive(self, peer: socket.socket) -> bool:
        """Read and handle the peer's messages; False when the connection was closed."""
        try:
            chunk = peer.recv(1 << 16)
        except (BlockingIOError, InterruptedError):
            return True
        except OSError as exc:
            self._drop_peer(f"connection lost ({exc.strerror or exc})")
            return False
        if not chunk:
            self._drop_peer("closed the connection")
            return False
        try:
            messages = self._framer.feed(chunk)
        except _StreamError as exc:
            self._drop_peer(f"{exc}; connection closed")
            return False
        for header, body in messages:
            self._handle(header, body)
        return True

    def _handle(self, header: bytes, body: bytes | None) -> None:
        """One message of the peer: a plan update, a refusal, or something counted and ignored."""
        _, kind_raw, name_raw, _, _, crc = HEADER.unpack(header)
        kind = kind_raw.rstrip(b"\0").decode("ascii")
        try:
            device = name_raw.split(b"\0", 1)[0].decode("utf-8")
        except UnicodeDecodeError:
            device = name_raw.split(b"\0", 1)[0].decode("utf-8", "replace")
        with self._condition:
            self._counts["received"] += 1
            if PLAN_DEVICES.get(device) != kind or body is None:
                key = (kind, sanitize_for_terminal(device, 40))
                if key not in self._ignored and len(self._ignored) >= MAX_IGNORED_KEYS:
                    key = ("other", "devices")
                self._ignored[key] += 1
                return
            if crc64(body) != crc:
                self._counts["crc"] += 1
                self._refuse(
                    device, f"{kind} {device}: bad CRC (the message was damaged or is not OpenIGTLink)"
                )
                return
            try:
                content = parse_message(header, body).content
                if kind == "POINT":
                    entry, target, (entry_label, target_label) = plan_points_from_point_message(
                        content, device
                    )
                    updates = {
                        "entry": (entry, entry_label, device),
                        "target": (target, target_label, device),
                    }
                else:
                    role = "entry" if device == ENTRY_DEVICE else "target"
                    updates = {role: (point_from_transform_message(content, device), role, device)}
                merged = {**self._points, **updates}
                if "entry" in merged and "target" in merged:
                    self._needle_plan(merged)  # entry and target 1 mm apart at least
            except (ValueError, struct.error) as exc:  # InvalidInputError is a ValueError
                self._refuse(device, exception_line(exc))
                return
            self._refusals.pop(device, None)
            self._points.update(updates)
            self._revision += 1
            self._condition.notify_all()

    def _refuse(self, device: str, reason: str) -> None:
        self._counts["refused"] += 1
        self._refusals[device] = reason
        self._problem(reason)

    def _flush(self, peer: socket.socket) -> None:
        try:
            sent = peer.send(self._outgoing)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            self._drop_peer(f"connection lost while sending ({exc.strerror or exc})")
            return
        if sent:
            del self._outgoing[:sent]
            self._progress_at = time.monotonic()
            if not self._outgoing:
                with self._condition:
                    self._counts["sent"] += 1

    def _tick(self, now: float) -> None:
        """One period: queue the newest fresh pose, or count the frame as dropped."""
        self._next_tick_at += self.period_s
        if self._next_tick_at < now:  # fell behind (a busy machine): no burst of late frames
            self._next_tick_at = now + self.period_s
        with self._condition:
            pose, image_ras_from = self._pose, self._image_ras_from
            if pose is None or now - pose[3] > POSE_MAX_AGE_S:
                return
            peer = self._peer
            if peer is None or self._outgoing:
                self._counts["dropped"] += 1
                return
        tracker_from_needle, tracker_from_reference, stamp, _ = pose
        frame = transform_message(NEEDLE_TO_TRACKER, tracker_from_needle, stamp)
        if image_ras_from is not None:
            registered, image_ras_from_registered = image_ras_from
            if registered == "tracker":
                frame += transform_message(
                    NEEDLE_TO_RAS, image_ras_from_registered @ tracker_from_needle, stamp
                )
            elif tracker_from_reference is not None:
                reference_from_needle = invert_transform(tracker_from_reference) @ tracker_from_needle
                frame += transform_message(
                    NEEDLE_TO_RAS, image_ras_from_registered @ reference_from_needle, stamp
                )
            else:  # a registration to the patient's marker, and no pose of that marker now
                with self._condition:
                    self._counts["without_ras"] += 1
        self._outgoing += frame
        self._progress_at = time.monotonic()
        self._flush(peer)

    def _close_sockets(self) -> None:
        for sock in (self._peer, self._listener):
            if sock is not None:
                try:
                    sock.close()
                except OSError:
                    pass
        self._peer = None
        with self._condition:
            self._counts["connected"] = 0
            self._condition.notify_all()
