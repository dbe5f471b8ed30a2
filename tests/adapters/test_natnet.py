"""The NatNet tracker against the Motive fake on loopback, on real time: poses equal to the
fake's truth (m to mm, a rotation that tells the quaternion's order), visibility from the
tracking-valid flag, a body missing from frames, zeros, the server's identity, every NatNet
version read, and bad servers ending by their deadlines with one line.

The bounds are the deadlines plus a margin for a loaded 2-core machine, never tight times."""

import time

import numpy as np
import pytest

from spacecal.adapters import natnet
from spacecal.adapters.natnet import NAT_DISCONNECT, NAT_KEEPALIVE, NatNetTracker
from spacecal.app.devices import device_identity, open_tracker, tracker_findings
from spacecal.core.errors import DeviceError, InvalidInputError
from spacecal.core.ports import FINDING_OK, FINDING_WARNING, FRAME_MISSING, FRAME_OK, DeviceIdentity
from spacecal.geometry.transforms import axis_angle_transform
from spacecal.testing.fakes.natnet import FakeMotive

#: Real client code against the protocol fake, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime

#: Time on top of a deadline for a loaded machine, s.
MARGIN_S = 3.0
#: Float32 metres at 2 m hold 1.2e-7 m (1.2e-4 mm); float32 quaternion components 6e-8.
POSITION_TOL_MM, ROTATION_TOL = 1e-3, 1e-6


def marker_truth(t_s: float) -> np.ndarray:
    """The marker moving and turning: 130 deg about a skew axis plus a slow turn, 1.2-1.4 m out
    (a rotation whose quaternion read in the wrong order is another rotation)."""
    return axis_angle_transform(
        [0.3, -0.5, 0.81], np.radians(130.0) + 0.2 * t_s, [150.0 + 20.0 * t_s, -80.0, 1300.0]
    )


def pointer_truth(t_s: float) -> np.ndarray:
    return axis_angle_transform([0.0, 1.0, 0.0], np.radians(-40.0), [-60.0, 30.0, 1100.0 + t_s])


def truth(t_s: float) -> dict:
    return {"Marker": marker_truth(t_s), "Pointer": pointer_truth(t_s)}


@pytest.fixture
def motive(request):
    version = getattr(request, "param", (4, 1))
    fake = FakeMotive(truth, bodies=("Reference", "Marker", "Pointer"), version=version, rate_hz=100.0)
    yield fake
    fake.close()


def tracker(fake, **kwargs) -> NatNetTracker:
    tools = {"pointer": "Pointer"}
    return NatNetTracker("127.0.0.1", fake.port, "Marker", tools, connect_timeout_s=2.0, **kwargs)


@pytest.mark.parametrize("motive", [(3, 0), (3, 1), (4, 0), (4, 1), (4, 2)], indirect=True)
def test_poses_read_equal_the_fakes_truth_in_mm(motive):
    reader = tracker(motive)
    try:
        frames = [reader.next_frame(1.0) for _ in range(20)]
    finally:
        reader.close()
    times = [frame.time_s for frame in frames]
    assert all(b > a for a, b in zip(times, times[1:], strict=False))
    numbers = [frame.frame_number for frame in frames]
    assert all(b > a for a, b in zip(numbers, numbers[1:], strict=False))
    for frame in frames:
        assert frame.status == FRAME_OK
        expected = marker_truth(frame.time_s)
        np.testing.assert_allclose(frame.tracker_from_marker[:3, 3], expected[:3, 3], atol=POSITION_TOL_MM)
        np.testing.assert_allclose(frame.tracker_from_marker[:3, :3], expected[:3, :3], atol=ROTATION_TOL)
        np.testing.assert_allclose(frame.tool("pointer"), pointer_truth(frame.time_s), atol=POSITION_TOL_MM)
        assert frame.rms_mm == pytest.approx(0.2, abs=1e-4)  # the fake's 0.0002 m mean marker error


def test_frames_come_in_order_and_a_reader_that_fell_behind_catches_up(motive):
    reader = tracker(motive)
    try:
        numbers = [reader.next_frame(1.0).frame_number for _ in range(30)]
        # a reader that keeps up gets every frame (loopback UDP loses none at 100 Hz)
        assert np.all(np.diff(numbers) == 1), numbers
        time.sleep(0.6)  # 60 frames wait
        frame = reader.next_frame(1.0)
        # passed over down to MAX_LAG_S behind the newest; the fake's clock is Motive's
        assert motive.clock() - frame.time_s < natnet.MAX_LAG_S + 0.1
        assert frame.frame_number > numbers[-1] + 30
    finally:
        reader.close()


def test_the_tracking_valid_flag_a_missing_body_and_zeros_are_frames_without_the_marker(motive):
    reader = tracker(motive)
    try:
        assert reader.next_frame(1.0).status == FRAME_OK
        for switch in ("untracked", "absent", "zeros"):
            motive.set(**{switch: {"Marker"}})
            reader.next_frame(1.0)  # a frame packed before the switch may still be on its way
            frames = [reader.next_frame(1.0) for _ in range(3)]
            assert all(f.status == FRAME_MISSING and f.tracker_from_marker is None for f in frames), switch
            assert all(f.tool_statuses["pointer"] == FRAME_OK for f in frames), switch
            motive.set(**{switch: set()})
            reader.next_frame(1.0)
            assert reader.next_frame(1.0).status == FRAME_OK
        motive.set(untracked={"Pointer"})
        reader.next_frame(1.0)
        frame = reader.next_frame(1.0)
        assert frame.status == FRAME_OK and frame.tools["pointer"] is None
        assert frame.tool_statuses["pointer"] == FRAME_MISSING
    finally:
        reader.close()


def test_the_server_says_what_it_is(motive):
    reader = tracker(motive)
    # the SDK 4.1 connect: 270 bytes, "Ping", the version asked for at bytes 265-268, a NUL
    payload = motive.connect_payloads[0]
    assert len(payload) == 271 and payload[:4] == b"Ping" and tuple(payload[265:269]) == (4, 1, 0, 0)
    try:
        assert reader.identity() == DeviceIdentity("Motive", None, "3.1.0.0 (NatNet 4.1.0.0)")
        assert device_identity(reader) == {"model": "Motive", "firmware": "3.1.0.0 (NatNet 4.1.0.0)"}
    finally:
        reader.close()


def test_opened_from_its_url_with_keep_alives_and_a_goodbye(motive):
    reader = open_tracker(f"natnet://127.0.0.1:{motive.port}?body=Marker&tools=Pointer", [], 100.0)
    try:
        assert reader.next_frame(1.0).tool("Pointer") is not None
        until = time.monotonic() + 1.5
        while time.monotonic() < until:
            reader.next_frame(1.0)
        assert NAT_KEEPALIVE in motive.requests
        assert motive.clients
    finally:
        reader.close()
    deadline = time.monotonic() + MARGIN_S
    while motive.clients and time.monotonic() < deadline:
        time.sleep(0.01)
    assert NAT_DISCONNECT in motive.requests and not motive.clients


def test_doctors_findings_name_the_server_version_bodies_and_rate(motive):
    reader = tracker(motive)
    try:
        findings = {f.subject: f for f in tracker_findings(reader)}
    finally:
        reader.close()
    assert findings["server"].level == FINDING_OK
    assert "Motive 3.1.0.0, NatNet 4.1.0.0" in findings["server"].text
    described = "'Marker' (the marker) is described, and 'Pointer'; 3 rigid bodies"
    assert described in findings["rigid bodies"].text
    rate = float(findings["frame rate"].text.split(" Hz")[0])
    assert rate == pytest.approx(100.0, rel=0.05)  # the fake's 100 Hz on its own timestamps
    assert findings["marker"].level == FINDING_OK


def test_doctor_warns_when_the_marker_is_not_tracked(motive):
    motive.set(untracked={"Marker"})
    reader = tracker(motive)
    try:
        findings = {f.subject: f for f in tracker_findings(reader)}
    finally:
        reader.close()
    assert findings["marker"].level == FINDING_WARNING and "'Marker' not tracked" in findings["marker"].text


def test_a_stream_without_the_named_rigid_body_is_one_line_naming_the_ones_there(motive):
    with pytest.raises(InvalidInputError) as caught:
        NatNetTracker("127.0.0.1", motive.port, "Needle", connect_timeout_s=2.0)
    text = str(caught.value)
    assert "no rigid body named 'Needle'" in text and "'Marker', 'Pointer', 'Reference'" in text
    assert "\n" not in text


def test_a_server_that_stops_sending_ends_the_wait_by_its_deadline(motive):
    reader = tracker(motive)
    try:
        reader.next_frame(1.0)
        motive.set(mute=True)
        started = time.monotonic()
        silence = "no NatNet frame from natnet://127.0.0.1:.* for 0.5 s"
        with pytest.raises(DeviceError, match=silence) as caught:
            while True:  # frames packed before the switch may still come
                reader.next_frame(0.5)
        assert time.monotonic() - started < 2 * 0.5 + MARGIN_S
        assert "\n" not in str(caught.value)
    finally:
        reader.close()


def test_timestamps_that_stop_advancing_end_the_wait_by_its_deadline():
    fake = FakeMotive(truth, ("Marker", "Pointer"), clock=lambda: 5.0)  # Motive paused on one frame
    try:
        reader = tracker(fake)
        try:
            assert reader.next_frame(1.0).time_s == 5.0
            started = time.monotonic()
            with pytest.raises(
                DeviceError, match="frames came for 0.5 s but their timestamps did not advance"
            ):
                reader.next_frame(0.5)
            assert time.monotonic() - started < 0.5 + MARGIN_S
        finally:
            reader.close()
    finally:
        fake.close()


def test_a_flood_of_datagrams_does_not_hold_a_call_past_its_deadline(motive):
    import socket
    import threading

    reader = tracker(motive)
    stop = threading.Event()
    # the flood comes from the server's address, in the frames' place: not one is a frame
    flood = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    flood.bind(("127.0.0.1", 0))
    target = reader._command.getsockname()

    def send() -> None:
        while not stop.is_set():
            flood.sendto(b"\x07\x00\xff\xff", ("127.0.0.1", target[1]))

    motive.set(mute=True)
    sender = threading.Thread(target=send, daemon=True)
    sender.start()
    try:
        started = time.monotonic()
        with pytest.raises(DeviceError, match="malformed NAT_FRAMEOFDATA"):
            while True:  # frames packed before the switch may still come
                reader.next_frame(0.5)
        assert time.monotonic() - started < 2 * 0.5 + MARGIN_S
    finally:
        stop.set()
        sender.join(timeout=2)
        flood.close()
        reader.close()


def test_a_closed_tracker_is_one_line_not_a_hang(motive):
    reader = tracker(motive)
    reader.close()
    with pytest.raises(DeviceError, match="was closed: no more frames"):
        reader.next_frame(0.5)


def test_doctor_on_the_command_line_checks_a_natnet_tracker(motive, capsys):
    from spacecal.cli import main

    code = main(["doctor", "--tracker", f"natnet://127.0.0.1:{motive.port}?body=Marker&tools=Pointer"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "tracker: server: ok: natnet://127.0.0.1:" in out and "NatNet 4.1.0.0" in out
    assert "every check passed" in out
    code = main(["doctor", "--tracker", f"natnet://127.0.0.1:{motive.port}?body=Needle"])
    out = capsys.readouterr().out
    assert code == 1 and "no rigid body named 'Needle'" in out


def test_nothing_listening_ends_connecting_by_its_deadline():
    fake = FakeMotive(truth)
    port = fake.port
    fake.close()  # the port is free again: nothing answers there
    started = time.monotonic()
    with pytest.raises(DeviceError, match="no NAT_SERVERINFO from natnet://127.0.0.1:.* within 1 s"):
        NatNetTracker("127.0.0.1", port, "Marker", connect_timeout_s=1.0)
    assert time.monotonic() - started < 1.0 + MARGIN_S


def test_a_server_that_is_not_natnet_is_one_line(motive):
    motive.set(not_natnet=True)
    started = time.monotonic()
    with pytest.raises(DeviceError, match="not a NatNet server") as caught:
        NatNetTracker("127.0.0.1", motive.port, "Marker", connect_timeout_s=1.0)
    assert time.monotonic() - started < 1.0 + MARGIN_S
    assert "\n" not in str(caught.value)


@pytest.mark.parametrize("motive", [(2, 10)], indirect=True)
def test_natnet_2_is_refused_with_its_version(motive):
    with pytest.raises(DeviceError, match="streams NatNet 2.10.0.0: spacecal reads NatNet 3.0 to 4.x"):
        tracker(motive)


@pytest.mark.parametrize(
    "fault,message",
    [
        ("truncated", "NAT_FRAMEOFDATA ends"),
        ("absurd", "1073741824 rigid bodies cannot fit"),
        ("short_header", r"announces \d+ payload bytes, \d+ came \(truncated\)"),
    ],
)
def test_malformed_frames_are_dropped_and_named_never_a_traceback(motive, fault, message):
    reader = tracker(motive)
    try:
        reader.next_frame(1.0)
        motive.set(malformed=fault)
        time.sleep(0.05)
        with pytest.raises(DeviceError, match=f"malformed NAT_FRAMEOFDATA packet.*{message}") as caught:
            for _ in range(20):
                reader.next_frame(0.5)
        assert "\n" not in str(caught.value)
        motive.set(malformed=None)
        assert reader.next_frame(1.0).status == FRAME_OK  # the stream goes on once it is whole
        assert reader.malformed > 0
    finally:
        reader.close()


def test_a_hostile_rigid_body_name_is_escaped_in_the_line():
    fake = FakeMotive(truth, bodies=("Marker\n\x1b[2J", "Pointer"))
    try:
        with pytest.raises(InvalidInputError) as caught:
            NatNetTracker("127.0.0.1", fake.port, "Marker", connect_timeout_s=2.0)
    finally:
        fake.close()
    text = str(caught.value)
    assert "\n" not in text and "\x1b" not in text and "'Marker\\n\\x1b[2J'" in text


def test_a_multicast_stream_is_read_from_the_group():
    try:
        fake = FakeMotive(truth, ("Marker", "Pointer"), multicast="239.255.42.99", data_port=21511)
    except OSError as exc:  # no multicast route on this machine
        pytest.skip(f"no multicast here ({exc})")
    try:
        try:
            reader = tracker(fake, multicast="239.255.42.99", data_port=21511)
        except DeviceError as exc:
            if "multicast" in str(exc):
                pytest.skip(f"no multicast here ({exc})")
            raise
        try:
            frame = reader.next_frame(1.0)
            expected = marker_truth(frame.time_s)
            np.testing.assert_allclose(frame.tracker_from_marker, expected, atol=POSITION_TOL_MM)
            assert NAT_KEEPALIVE not in fake.requests
        finally:
            reader.close()
    finally:
        fake.close()
