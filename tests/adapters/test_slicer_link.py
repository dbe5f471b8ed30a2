"""The Slicer link on real connections: the OpenIGTLink C++ library (a Slicer stand-in,
``tests/igtl_reference/slicer_standin.cxx``) and pyigtl as independent peers, and peers that
send what no Slicer should (raw bytes laid out from the protocol document).

The expected plan points are the sent RAS numbers with x and y negated by hand (LPS =
diag(-1, -1, 1) RAS); the expected NeedleToRAS is diag(-1, -1, 1, 1) @ inv(tracker_from_image_lps)
@ tracker_from_needle. The peers hold float32: 1e-3 mm is 8 float32 steps at 1500 mm.
"""

import signal
import socket
import struct
import subprocess
import threading
import time

import numpy as np
import pytest

pyigtl = pytest.importorskip("pyigtl")

from spacecal.adapters.slicer_link import (  # noqa: E402
    NEEDLE_TO_RAS,
    NEEDLE_TO_TRACKER,
    STALL_TIMEOUT_S,
    SlicerLink,
)
from spacecal.core.errors import DeviceError, InvalidInputError  # noqa: E402
from spacecal.records.needle_plan import ImageRegistration  # noqa: E402

from .igtl_reference_programs import build_reference_programs, free_port  # noqa: E402

#: Real client libraries on real time, with wall-clock rates: run apart (-m realtime).
pytestmark = pytest.mark.realtime

FLOAT32_MM = 1e-3
RAS_FROM_LPS = np.diag([-1.0, -1.0, 1.0, 1.0])


def rotation(axis, angle):
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def transform(axis, angle, translation):
    matrix = np.eye(4)
    matrix[:3, :3] = rotation(axis, angle)
    matrix[:3, 3] = translation
    return matrix


#: The needle in the tracker, and the image (LPS) in the tracker: nothing symmetric.
NEEDLE = transform([0.3, -0.5, 0.8], 0.7, [101.5, -37.25, -1412.0])
TRACKER_FROM_IMAGE_LPS = transform([-0.2, 0.9, 0.1], 2.1, [-250.0, 80.5, -1300.25])
EXPECTED_NEEDLE_TO_RAS = RAS_FROM_LPS @ np.linalg.inv(TRACKER_FROM_IMAGE_LPS) @ NEEDLE


@pytest.fixture(scope="module")
def standin(tmp_path_factory):
    return build_reference_programs(tmp_path_factory.mktemp("igtl_slicer"), ("slicer_standin",))[
        "slicer_standin"
    ]


class Feeder:
    """Gives the link the needle's pose at 50 Hz from another thread, as a tracker loop would,
    and keeps how long each call took (the caller must never wait on the network)."""

    def __init__(self, link, pose=NEEDLE, **extra):
        self.link, self.pose, self.extra = link, pose, extra
        self.durations = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        while not self._stop.is_set():
            started = time.perf_counter()
            self.link.update_needle(self.pose, **self.extra)
            self.durations.append(time.perf_counter() - started)
            time.sleep(0.02)

    def stop(self):
        self._stop.set()
        self._thread.join(2)


def standin_report(output: str):
    counts, matrices = {}, {}
    for line in output.splitlines():
        words = line.split()
        if words and words[0] == "COUNT":
            counts[words[1]] = (int(words[2]), float(words[3]))
        elif words and words[0] == "MATRIX":
            matrices[words[1]] = np.vstack([np.array(words[2:], dtype=float).reshape(3, 4), [0, 0, 0, 1]])
        elif words and words[0] == "CRCFAIL":
            counts["CRCFAIL"] = int(words[1])
    return counts, matrices


def rate_hz(count_and_span):
    count, span = count_and_span
    return (count - 1) / span


def test_the_reference_library_as_slicer(standin):
    """The C++ library sends the plan as Slicer does and receives the needle at the set rate."""
    with SlicerLink.serve(port=0, rate_hz=20) as link:
        link.set_registration(ImageRegistration(TRACKER_FROM_IMAGE_LPS, image_frame="image_lps"))
        program = subprocess.Popen([str(standin), str(link.port), "2.0"], stdout=subprocess.PIPE, text=True)
        try:
            first = link.wait_for_plan(5.0)
            # POINT "Plan": "entry" (12.5, -40.25, 7) and "Target" (-31.75, 18.5, -102) in RAS
            assert np.array_equal(first.plan.entry_in_image, [-12.5, 40.25, 7.0])
            assert np.array_equal(first.plan.target_in_image, [31.75, -18.5, -102.0])
            assert first.plan.image_frame == "image_lps" and first.devices == ("Plan", "Plan")
            assert (first.plan.entry_label, first.plan.target_label) == ("entry", "Target")
            # then TRANSFORM "TargetToRAS", translation (-30.5, 22.25, -98): the target moves
            second = link.wait_for_plan(5.0, after_revision=first.revision)
            assert np.array_equal(second.plan.target_in_image, [30.5, -22.25, -98.0])
            assert np.array_equal(second.plan.entry_in_image, first.plan.entry_in_image)
            assert second.devices == ("Plan", "TargetToRAS")
            assert program.stdout.readline().strip() == "SENT"
            feeder = Feeder(link)
            output, _ = program.communicate(timeout=20)
            feeder.stop()
        finally:
            program.kill()
            program.wait(10)
        status = link.status()
    counts, matrices = standin_report(output)
    assert program.returncode == 0, output
    assert counts["CRCFAIL"] == 0  # the library's CRC check passed on every message
    for name in (NEEDLE_TO_TRACKER, NEEDLE_TO_RAS):
        assert counts[name][1] > 1.5, output  # received over most of the 2 s
        assert 10.0 <= rate_hz(counts[name]) <= 22.0, output  # 20 Hz set: >= 10 Hz wanted
    assert np.allclose(matrices[NEEDLE_TO_TRACKER], NEEDLE, atol=FLOAT32_MM)
    assert np.allclose(matrices[NEEDLE_TO_RAS], EXPECTED_NEEDLE_TO_RAS, atol=FLOAT32_MM)
    assert status.crc_errors == 0 and status.refused == 0 and status.messages_received == 2
    assert max(feeder.durations) < 0.05


def test_a_nan_point_from_the_reference_library_withholds_the_plan(standin):
    with SlicerLink.serve(port=0) as link:
        program = subprocess.Popen(
            [str(standin), str(link.port), "0.2", "bad"], stdout=subprocess.PIPE, text=True
        )
        try:
            with pytest.raises(InvalidInputError, match="POINT Plan, point 3 .*non-finite"):
                link.wait_for_plan(5.0)
            assert program.stdout.readline().strip() == "SENT"
            # TargetToRAS is fine, but the plan on Slicer's screen holds a NaN: still withheld
            with pytest.raises(InvalidInputError, match="until Plan is sent again"):
                link.latest_plan()
            program.communicate(timeout=20)
        finally:
            program.kill()
            program.wait(10)
        assert link.status().refused == 1


def pyigtl_plan(entry_ras, target_ras, header_version=2):
    message = pyigtl.PointMessage(
        positions=[entry_ras, [0.0, 0.0, 0.0], target_ras],
        names=["entry", "F-2", "target"],
        groups="Selected",
        device_name="Plan",
    )
    message.header_version = header_version
    message.metadata = {"Source": "pyigtl"} if header_version > 1 else {}
    return message


def count_needle_messages(peer, seconds):
    """Needle messages received by a pyigtl peer over ``seconds`` (pyigtl keeps the newest
    message per device: polled every 5 ms, each is counted once by its timestamp)."""
    stamps = {NEEDLE_TO_TRACKER: set(), NEEDLE_TO_RAS: set()}
    last = {}
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        for message in peer.get_latest_messages():
            if message.device_name in stamps:
                stamps[message.device_name].add(message.timestamp)
                last[message.device_name] = np.asarray(message.matrix)
        time.sleep(0.005)
    return {name: len(values) for name, values in stamps.items()}, last


class MovingFeeder(Feeder):
    """A needle whose poses carry new timestamps (pyigtl counts messages by timestamp)."""

    def _run(self):
        while not self._stop.is_set():
            started = time.perf_counter()
            self.link.update_needle(self.pose, timestamp_s=time.time(), **self.extra)
            self.durations.append(time.perf_counter() - started)
            time.sleep(0.005)


def test_pyigtl_as_slicer_client():
    """pyigtl connects as Slicer's client connector would, with header version 2 and metadata."""
    with SlicerLink.serve(port=0, rate_hz=25) as link:
        link.set_registration(ImageRegistration(TRACKER_FROM_IMAGE_LPS, image_frame="image_lps"))
        peer = pyigtl.OpenIGTLinkClient("127.0.0.1", link.port)
        try:
            link.wait_for_peer(5.0)
            peer.send_message(pyigtl_plan([3.5, -8.25, 41.0], [-20.75, 60.5, -5.0]), wait=True)
            plan = link.wait_for_plan(5.0)
            assert np.array_equal(plan.plan.entry_in_image, [-3.5, 8.25, 41.0])
            assert np.array_equal(plan.plan.target_in_image, [20.75, -60.5, -5.0])
            entry = pyigtl.TransformMessage(
                transform([0, 0, 1], 0.5, [7.0, -9.5, 44.25]), device_name="EntryToRAS"
            )
            peer.send_message(entry, wait=True)
            moved = link.wait_for_plan(5.0, after_revision=plan.revision)
            assert np.array_equal(moved.plan.entry_in_image, [-7.0, 9.5, 44.25])
            assert moved.devices == ("EntryToRAS", "Plan")
            feeder = MovingFeeder(link)
            counts, last = count_needle_messages(peer, 2.0)
            feeder.stop()
        finally:
            peer.stop()
    for name in (NEEDLE_TO_TRACKER, NEEDLE_TO_RAS):
        assert 10 * 2.0 <= counts[name] <= 26 * 2.0, counts  # 25 Hz set
    assert np.allclose(last[NEEDLE_TO_TRACKER], NEEDLE, atol=FLOAT32_MM)
    assert np.allclose(last[NEEDLE_TO_RAS], EXPECTED_NEEDLE_TO_RAS, atol=FLOAT32_MM)


def test_spacecal_as_client_of_a_slicer_server_with_a_reference_registration():
    """Slicer's connector as server (pyigtl's server here); the registration is to a patient
    marker, so NeedleToRAS needs the marker's pose with each needle pose."""
    port = free_port()
    server = pyigtl.OpenIGTLinkServer(port=port, local_server=True)
    tracker_from_reference = transform([1, 1, 0], -0.4, [40.0, 12.5, -1350.0])
    reference_from_image_lps = transform([0, 1, 1], 1.2, [-10.0, 5.5, 30.0])
    try:
        with SlicerLink.connect("127.0.0.1", port, rate_hz=20) as link:
            link.wait_for_peer(5.0)
            link.set_registration(
                ImageRegistration(
                    reference_from_image_lps, image_frame="image_lps", tracker_frame="reference"
                )
            )
            server.send_message(pyigtl_plan([1.0, 2.0, 3.0], [4.0, -5.0, 60.0], header_version=1), wait=True)
            plan = link.wait_for_plan(5.0).plan
            assert np.array_equal(plan.target_in_image, [-4.0, 5.0, 60.0])
            feeder = MovingFeeder(link, tracker_from_reference=tracker_from_reference)
            counts, last = count_needle_messages(server, 1.0)
            feeder.stop()
            without = MovingFeeder(link)  # the marker not seen: NeedleToTracker only
            time.sleep(0.5)
            without.stop()
            status = link.status()
    finally:
        server.stop()
    expected = (
        RAS_FROM_LPS
        @ np.linalg.inv(reference_from_image_lps)
        @ np.linalg.inv(tracker_from_reference)
        @ NEEDLE
    )
    assert counts[NEEDLE_TO_RAS] >= 10, counts
    assert np.allclose(last[NEEDLE_TO_RAS], expected, atol=FLOAT32_MM)
    assert status.frames_without_ras >= 5


def raw_message(kind: bytes, name: bytes, body: bytes, body_size=None, crc=0) -> bytes:
    """A header version 1 message laid out by hand (the header's CRC is not checked for the
    messages it is used for: they are refused or ignored before)."""
    size = len(body) if body_size is None else body_size
    return struct.pack(">H12s20sQQQ", 1, kind, name, 0, size, crc) + body


def wait_until(condition, timeout_s=5.0):
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "condition not met in time"
        time.sleep(0.02)


def test_oversized_bodies_close_the_connection_and_the_next_peer_is_served():
    with SlicerLink.serve(port=0) as link:
        for kind, size, bound in (
            (b"TRANSFORM", 1 << 20, 65536),
            (b"POINT", 70_000, 65536),
            (b"IMAGE", 1 << 30, 67108864),
        ):
            with socket.create_connection(("127.0.0.1", link.port), timeout=5) as peer:
                peer.sendall(raw_message(kind, b"Plan", b"", body_size=size))
                wait_until(
                    lambda bound=bound: any(
                        f"above the {bound}-byte bound" in p for p in link.status().problems
                    )
                )
                peer.settimeout(5)
                assert peer.recv(1) == b""  # closed by the link
        # a large image under the bound is read past, and the stream stays in step after it
        with socket.create_connection(("127.0.0.1", link.port), timeout=5) as peer:
            peer.sendall(
                raw_message(b"IMAGE", b"CT", bytes(300_000)) + pyigtl_plan([1, 2, 3], [5, 6, 7]).pack()
            )
            plan = link.wait_for_plan(5.0)
        status = link.status()
    assert np.array_equal(plan.plan.entry_in_image, [-1, -2, 3])
    assert status.ignored == {("IMAGE", "CT"): 1} and status.disconnections >= 3


def test_a_bad_crc_withholds_the_plan_until_a_good_message():
    good = pyigtl_plan([10.0, 20.0, 30.0], [-10.0, -20.0, 35.0], header_version=1).pack()
    damaged = bytearray(good)
    damaged[50] ^= 0x01  # one bit of the CRC field
    with (
        SlicerLink.serve(port=0) as link,
        socket.create_connection(("127.0.0.1", link.port), timeout=5) as peer,
    ):
        peer.sendall(bytes(damaged))
        wait_until(lambda: link.status().crc_errors == 1)
        with pytest.raises(InvalidInputError, match="POINT Plan: bad CRC"):
            link.latest_plan()
        with pytest.raises(InvalidInputError, match="bad CRC"):
            link.wait_for_plan(1.0)
        peer.sendall(good)
        # a refusal is raised at once by wait_for_plan: wait for the good message to arrive
        wait_until(lambda: link.status().messages_received == 2)
        plan = link.wait_for_plan(5.0)
    assert np.array_equal(plan.plan.target_in_image, [10.0, 20.0, 35.0]) and plan.revision == 1


def test_unknown_devices_are_counted_and_ignored():
    with (
        SlicerLink.serve(port=0) as link,
        socket.create_connection(("127.0.0.1", link.port), timeout=5) as peer,
    ):
        unknown = [
            pyigtl.PointMessage(positions=[[1, 2, 3], [4, 5, 6]], names=["entry", "target"], device_name="F"),
            pyigtl.TransformMessage(np.eye(4), device_name="StylusToTracker"),
            pyigtl.StringMessage("hello", device_name="CMD"),
            pyigtl.TransformMessage(np.eye(4), device_name="Plan"),  # the plan's name, the wrong type
        ]
        peer.sendall(b"".join(message.pack() for message in unknown))
        wait_until(lambda: link.status().messages_received == 4)
        with pytest.raises(
            DeviceError, match="no entry and target plan point within 0.3 s .*Slicer sent POINT F"
        ):
            link.wait_for_plan(0.3)
        status = link.status()
    assert status.ignored == {
        ("POINT", "F"): 1,
        ("TRANSFORM", "StylusToTracker"): 1,
        ("STRING", "CMD"): 1,
        ("TRANSFORM", "Plan"): 1,
    }
    assert status.refused == 0 and status.crc_errors == 0


def test_a_peer_vanishing_mid_stream_never_blocks_the_caller(standin):
    with SlicerLink.serve(port=0, rate_hz=20) as link:
        feeder = Feeder(link)
        program = subprocess.Popen([str(standin), str(link.port), "30"], stdout=subprocess.PIPE, text=True)
        try:
            assert program.stdout.readline().strip() == "SENT"
            wait_until(lambda: link.status().frames_sent >= 10)
            program.send_signal(signal.SIGKILL)
            program.wait(10)
            wait_until(lambda: link.status().disconnections == 1)
            dropped_then = link.status().frames_dropped
            time.sleep(0.5)  # nobody connected: frames due are dropped and counted
            status = link.status()
            assert status.frames_dropped >= dropped_then + 5 and not status.connected
            assert any("closed the connection" in p or "connection lost" in p for p in status.problems)
            # Slicer reconnects: served again
            peer = pyigtl.OpenIGTLinkClient("127.0.0.1", link.port)
            try:
                assert peer.wait_for_message(NEEDLE_TO_TRACKER, timeout=5) is not None
            finally:
                peer.stop()
        finally:
            program.kill()
            feeder.stop()
    assert max(feeder.durations) < 0.05  # update_needle never waited on the network


def test_a_peer_that_stops_reading_is_disconnected_and_frames_are_dropped():
    with SlicerLink.serve(port=0, rate_hz=100) as link:
        link.set_registration(ImageRegistration(TRACKER_FROM_IMAGE_LPS, image_frame="image_lps"))
        peer = socket.socket()
        peer.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # it fills in seconds
        peer.connect(("127.0.0.1", link.port))
        feeder = Feeder(link)
        try:
            wait_until(lambda: link.status().frames_dropped > 0, timeout_s=30)
            started = time.monotonic()
            wait_until(lambda: link.status().disconnections == 1, timeout_s=STALL_TIMEOUT_S + 5)
            assert time.monotonic() - started <= STALL_TIMEOUT_S + 1.0
        finally:
            feeder.stop()
            peer.close()
        status = link.status()
    assert any(f"read nothing for {STALL_TIMEOUT_S:g} s" in p for p in status.problems)
    assert max(feeder.durations) < 0.05


def test_a_missing_slicer_server_is_one_line_and_close_is_prompt():
    link = SlicerLink.connect("127.0.0.1", free_port())
    with pytest.raises(DeviceError, match="did not connect within 0.5 s .*could not connect"):
        link.wait_for_peer(0.5)
    started = time.monotonic()
    link.close()
    assert time.monotonic() - started < 2.0
    assert not any(t.name == "spacecal-slicer-link" and t.is_alive() for t in threading.enumerate())
