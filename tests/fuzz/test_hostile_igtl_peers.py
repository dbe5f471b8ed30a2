"""Seeded hostile OpenIGTLink senders: a stream that starts well, then sends mutated messages
(flipped bytes, lying body sizes, cut-off messages, hostile poses, names and timestamps, other
header versions) between good ones, then hangs up.

Whatever comes, the reader hands out only frames it can stand behind (a status it knows; a pose
that is a rigid transform within a tracker's reach, or none), or ends with one ``DeviceError``
line; never another exception, never a wait past its timeouts.
"""

import random
import struct
import time

import numpy as np
import pytest

from spacecal.adapters import igtl
from spacecal.adapters.igtl import IGTLTracker
from spacecal.core.errors import DeviceError
from spacecal.core.ports import FRAME_STATUSES, plausible_tracked_pose
from spacecal.testing.fakes.igtl import (
    HEADER,
    pack_message,
    position_content,
    qtdata_content,
    tdata_content,
    transform_content,
)
from spacecal.testing.fakes.peers import Peer

#: Seeded cases; each is a few hundred ms (the reader's backlog drain, then the stream).
CASES = 150
#: Time on top of the reader's own timeouts for a loaded machine, s.
MARGIN_S = 5.0
FRAME_TIMEOUT_S = 1.0
MARKER = "MarkerToTracker"


def pose(rng: random.Random) -> np.ndarray:
    angle = rng.uniform(-np.pi, np.pi)
    matrix = np.eye(4)
    matrix[:2, :2] = [[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]]
    matrix[:3, 3] = [rng.uniform(-300, 300), rng.uniform(-300, 300), rng.uniform(-2400, -900)]
    return matrix


def hostile_pose(rng: random.Random) -> np.ndarray:
    matrix = pose(rng)
    kind = rng.choice(["nan", "inf", "far", "scaled", "zero", "sheared", "huge"])
    if kind == "nan":
        matrix[rng.randrange(3), rng.randrange(4)] = np.nan
    elif kind == "inf":
        matrix[rng.randrange(3), 3] = np.inf
    elif kind == "far":
        matrix[:3, 3] = [1e30, 0.0, 0.0]
    elif kind == "scaled":
        matrix[:3, :3] *= 1000.0
    elif kind == "zero":
        matrix[:] = 0.0
    elif kind == "sheared":
        matrix[0, 1] += 0.5
    else:
        matrix[:3, :3] = 3e38
    return matrix


def message(rng: random.Random, matrix: np.ndarray, timestamp_s: float, name: str = MARKER) -> bytes:
    """One message carrying ``matrix`` for ``name`` in one of the forms senders use."""
    form = rng.choice(["TRANSFORM", "POSITION", "TDATA", "QTDATA"])
    with np.errstate(all="ignore"):
        rotation = matrix[:3, :3]
        finite = bool(np.all(np.isfinite(matrix)))
        if (finite or form == "QTDATA") and not (finite and abs(np.linalg.det(rotation) - 1) < 1e-3):
            # a quaternion form cannot carry a finite matrix that is no rotation (POSITION's
            # packer writes NaN for a non-finite one)
            form = "TRANSFORM" if form != "POSITION" or finite else form
        if form == "TRANSFORM":
            return pack_message("TRANSFORM", name, transform_content(matrix), timestamp_s)
        if form == "POSITION":
            return pack_message("POSITION", name, position_content(matrix), timestamp_s)
        if form == "TDATA":
            return pack_message("TDATA", "Tracker", tdata_content([(name, matrix)]), timestamp_s)
        return pack_message("QTDATA", "Tracker", qtdata_content([(name, matrix)]), timestamp_s)


def mutated(rng: random.Random, timestamp_s: float) -> bytes:
    """One hostile message (or a fragment of one)."""
    good = message(rng, pose(rng), timestamp_s)
    kind = rng.choice(
        ["flip", "body size", "cut", "pose", "name", "type", "version", "timestamp", "garbage", "empty"]
    )
    if kind == "flip":
        data = bytearray(good)
        for _ in range(rng.randint(1, 6)):
            data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
        return bytes(data)
    if kind == "body size":
        data = bytearray(good)
        size = rng.choice([0, 1, 47, 48, 49, 2**16 + 1, 2**31, 2**63 - 1, 2**64 - 1])
        data[42:50] = size.to_bytes(8, "big")
        return bytes(data)
    if kind == "cut":
        return good[: rng.randrange(1, len(good))]
    if kind == "pose":
        return message(rng, hostile_pose(rng), timestamp_s)
    if kind == "name":
        name = rng.choice(["\x1b[2J\x1b[31mMarker", "Marker\nToTracker", "é" * 10, "", "M" * 40])
        return message(rng, pose(rng), timestamp_s, name=name[:20])
    if kind == "type":
        version, _, device, stamp, size, crc = HEADER.unpack(good[: HEADER.size])
        kind_bytes = bytes(rng.randrange(256) for _ in range(12))
        return HEADER.pack(version, kind_bytes, device, stamp, size, crc) + good[HEADER.size :]
    if kind == "version":
        return struct.pack(">H", rng.choice([0, 3, 4, 255, 65535])) + good[2:]
    if kind == "timestamp":
        stamp = rng.choice([0.0, -1.0, 2.0**31, timestamp_s - 100.0, 4e9])
        return message(rng, pose(rng), max(stamp, 0.0))
    if kind == "garbage":
        return bytes(rng.randrange(256) for _ in range(rng.randint(1, 200)))
    return b""


def hostile_sender(seed: int):
    rng = random.Random(seed)

    def serve(connection, peer):
        stamp = 1000.0
        for _ in range(3):  # a good start: the reader connects and drains its backlog
            connection.sendall(message(rng, pose(rng), stamp))
            stamp += 0.05
            time.sleep(0.02)
        time.sleep(igtl.BACKLOG_DRAIN_S + 0.15)
        for _ in range(rng.randint(3, 12)):
            stamp += 0.05
            if rng.random() < 0.5:
                connection.sendall(mutated(rng, stamp))
            else:
                connection.sendall(message(rng, pose(rng), stamp))
            time.sleep(rng.choice([0.0, 0.005, 0.02]))
        connection.close()

    return serve


@pytest.mark.parametrize("seed", range(CASES))
def test_a_hostile_sender_gets_frames_the_reader_stands_behind_or_one_line(seed):
    with Peer(hostile_sender(seed)) as peer:
        started = time.monotonic()
        frames = []
        try:
            tracker = IGTLTracker(peer.host, peer.port, connect_timeout_s=2.0)
        except DeviceError as exc:
            error = exc
        else:
            try:
                error = None
                for _ in range(60):
                    frames.append(tracker.next_frame(FRAME_TIMEOUT_S))
            except DeviceError as exc:
                error = exc
            finally:
                tracker.close()
    elapsed = time.monotonic() - started
    for frame in frames:
        assert frame.status in FRAME_STATUSES
        assert np.isfinite(frame.time_s)
        assert frame.tracker_from_marker is None or plausible_tracked_pose(frame.tracker_from_marker)
    # the sender hangs up after at most 12 messages: the reader says so, one line
    assert error is not None, f"{len(frames)} frames and no end"
    text = str(error)
    assert text and "\n" not in text and "\x1b" not in text, text
    assert elapsed < 2.0 + igtl.BACKLOG_DRAIN_S + 2 * FRAME_TIMEOUT_S + MARGIN_S, elapsed
