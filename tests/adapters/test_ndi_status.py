"""NDI frame status, tracker generations and transport faults, with the real ndicapy against
the Combined API fake (faults injected through the world's control port)."""

import numpy as np
import pytest

pytest.importorskip("ndicapy")

from spacecal.adapters.ndi import (
    PORT_OUT_OF_VOLUME,
    PORT_PARTIALLY_OUT_OF_VOLUME,
    PORT_PROCESSING_EXCEPTION,
    SYSTEM_TOO_MUCH_INFRARED,
    NDITracker,
    frame_status,
)
from spacecal.core.errors import DeviceError
from spacecal.core.ports import (
    FINDING_OK,
    FINDING_WARNING,
    FRAME_DISABLED,
    FRAME_INTERFERENCE,
    FRAME_MISSING,
    FRAME_OK,
    FRAME_OUT_OF_VOLUME,
    FRAME_PARTIALLY_OUT_OF_VOLUME,
    FRAME_PROCESSING_EXCEPTION,
)

from .test_ndi import connect, marker_position_truth

VALID = (1.0, 0.0, 0.0, 0.0, 1.0, 2.0, -1500.0, 0.1)
OK_PORT = 0x31


@pytest.mark.parametrize(
    ("handle", "port", "system", "expected"),
    [
        (VALID, OK_PORT, 0, FRAME_OK),
        ("MISSING", OK_PORT, 0, FRAME_MISSING),
        ("DISABLED", 0x01, 0, FRAME_DISABLED),
        (VALID, OK_PORT | PORT_OUT_OF_VOLUME, 0, FRAME_OUT_OF_VOLUME),
        (VALID, OK_PORT | PORT_PARTIALLY_OUT_OF_VOLUME, 0, FRAME_PARTIALLY_OUT_OF_VOLUME),
        (VALID, OK_PORT | PORT_PROCESSING_EXCEPTION, 0, FRAME_PROCESSING_EXCEPTION),
        (VALID, OK_PORT, SYSTEM_TOO_MUCH_INFRARED, FRAME_INTERFERENCE),
        (VALID, OK_PORT, 0x0010, FRAME_PROCESSING_EXCEPTION),  # hardware failure
    ],
)
def test_frame_status_from_every_status_field(handle, port, system, expected):
    assert frame_status(handle, port, system) == expected


def settle(tracker, status, tries=20):
    """Frames until one has ``status`` (a switch reaches the next camera frame)."""
    for _ in range(tries):
        frame = tracker.next_frame(2.0)
        if frame.status == status:
            return frame
    raise AssertionError(f"no {status} frame; last {frame.status}")


@pytest.mark.parametrize("reply", ["bx", "tx"])
@pytest.mark.realtime
def test_volume_and_status_bits_become_frame_statuses(world, rom_file, reply):
    tracker = connect(world, "tcp", [rom_file], reply=reply)
    truth = marker_position_truth(world)
    world.control("ndi partial_volume on")
    frame = settle(tracker, FRAME_PARTIALLY_OUT_OF_VOLUME)
    # the reported pose is kept with its status
    assert np.linalg.norm(frame.tracker_from_marker[:3, 3] - truth) < 1.5
    world.control("ndi out_of_volume on")  # 0x0800 in the reply option: reported with the pose
    frame = settle(tracker, FRAME_OUT_OF_VOLUME)
    assert frame.tracker_from_marker is not None
    world.control("ndi out_of_volume off")
    world.control("ndi partial_volume off")
    world.control("ndi processing_exception on")
    settle(tracker, FRAME_PROCESSING_EXCEPTION)
    world.control("ndi processing_exception off")
    world.control("ndi interference on")
    settle(tracker, FRAME_INTERFERENCE)
    world.control("ndi interference off")
    world.control("ndi disabled on")
    frame = settle(tracker, FRAME_DISABLED)
    assert frame.tracker_from_marker is None
    world.control("ndi disabled off")
    settle(tracker, FRAME_OK)
    tracker.close()


@pytest.mark.parametrize(
    ("generation", "transport", "reply"),
    [("polaris-old", "pty", "tx"), ("vicra", "pty", "bx"), ("spectra", "pty", "bx"), ("vega", "tcp", "bx")],
)
@pytest.mark.realtime
def test_every_generation_tracks_and_reports_itself(make_world, rom_file, generation, transport, reply):
    world = make_world("--ndi-generation", generation)
    tracker = connect(world, transport, [rom_file])
    frame = settle(tracker, FRAME_OK)  # (the scenario drops a frame now and then)
    assert tracker.reply == reply  # firmware without BX answers ERROR01 and is read with TX
    assert np.linalg.norm(frame.tracker_from_marker[:3, 3] - marker_position_truth(world)) < 1.5
    findings = {f.subject: f for f in tracker.preflight(duration_s=1.0)}
    tracker.close()
    assert findings["tracker"].level == FINDING_OK and "G.00" in findings["tracker"].text
    assert findings["reply form"].level == (FINDING_OK if reply == "bx" else FINDING_WARNING)
    assert "Hz measured" in findings["frame rate"].text  # its level depends on the host's load
    assert "enabled" in findings["tools"].text and findings["marker status"].level == FINDING_OK


@pytest.mark.parametrize(("transport", "fault"), [("tcp", "crc_error"), ("pty", "short_reply")])
@pytest.mark.parametrize("reply", ["bx", "tx"])
@pytest.mark.realtime
def test_a_spoiled_reply_is_retried(world, rom_file, transport, fault, reply):
    if fault == "short_reply" and reply == "bx":
        pytest.skip("a short binary reply is a reply timeout: covered by the drop test")
    tracker = connect(world, transport, [rom_file], reply=reply)
    tracker.next_frame(2.0)
    world.control(f"ndi {fault} 2")
    frames = [tracker.next_frame(2.0) for _ in range(4)]
    assert world.control("ndi spoiled") == "2"
    # the scenario drops a frame now and then: missing is fine, nothing else is
    assert tracker.transport_errors_retried == 2 and {f.status for f in frames} <= {FRAME_OK, FRAME_MISSING}
    assert tracker.reply == reply  # a transport error is no reason to change the reply form
    world.control(f"ndi {fault} 3")  # three in a row: the tracker is lost
    with pytest.raises(DeviceError, match="3 replies in a row failed"):
        tracker.next_frame(2.0)
    tracker.close()


@pytest.mark.realtime
def test_a_reply_that_never_comes_is_retried_after_the_serial_timeout(world, rom_file):
    tracker = connect(world, "pty", [rom_file])
    tracker.next_frame(2.0)
    world.control("ndi drop 1")  # ndicapi waits 5 s for a serial reply
    frame = tracker.next_frame(2.0)
    # the retry delivers a frame; the scenario itself drops a marker now and then, so the
    # frame after the lost reply may be missing, and a seen one must follow
    assert tracker.transport_errors_retried == 1 and frame.status in {FRAME_OK, FRAME_MISSING}
    later = [tracker.next_frame(2.0).status for _ in range(5)]
    assert FRAME_OK in later and tracker.transport_errors_retried == 1
    tracker.close()


@pytest.mark.realtime
def test_preflight_reports_a_doubtful_marker(world, rom_file):
    tracker = connect(world, "tcp", [rom_file])
    world.control("ndi partial_volume on")
    findings = {f.subject: f for f in tracker.preflight(duration_s=1.0)}
    tracker.close()
    assert findings["marker status"].level == FINDING_WARNING
    assert FRAME_PARTIALLY_OUT_OF_VOLUME in findings["marker status"].text
    assert isinstance(NDITracker.preflight, object)
