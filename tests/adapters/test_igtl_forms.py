"""Every message form an OpenIGTLink sender may use for a tool pose, and PLUS's silence for a
tool it does not see, with the adapter's reader against the PLUS / Slicer / old-sender fake."""

import time

import numpy as np
import pytest

from spacecal.adapters.igtl import IGTLTracker, crc64, is_placeholder
from spacecal.core.errors import DeviceError
from spacecal.core.ports import FINDING_OK, FINDING_WARNING, FRAME_INVALID, FRAME_MISSING, FRAME_OK

from .test_ndi import marker_position_truth


def test_crc64_matches_the_reference_implementation():
    crcmod = pytest.importorskip("crcmod")
    reference = crcmod.mkCrcFun(0x142F0E1EBA9EA3693, rev=False, initCrc=0, xorOut=0)
    for data in (b"", b"OpenIGTLink", bytes(range(256)) * 3):
        assert crc64(data) == reference(data)


def test_placeholders_are_never_poses():
    pose = np.eye(4)
    pose[:3, 3] = [10.0, 20.0, -1500.0]
    assert not is_placeholder(pose)
    for placeholder in (np.eye(4), np.zeros((4, 4)), np.full((4, 4), np.nan), 2 * pose):
        assert is_placeholder(placeholder)


def frames_until(tracker, status, tries=40):
    for _ in range(tries):
        frame = tracker.next_frame(2.0)
        if frame.status == status:
            return frame
    raise AssertionError(f"no {status} frame")


FORMS = [
    ("plus", "transform", "2"),
    ("plus", "transform", "3"),
    ("slicer", "transform", "2"),
    ("old", "transform", "1"),
    ("plus", "position", "2"),
    ("old", "position24", "1"),
    ("plus", "tdata", "2"),
    ("old", "qtdata", "1"),
]


@pytest.mark.parametrize(("sender", "form", "header"), FORMS)
@pytest.mark.realtime
def test_every_form_gives_the_pose_and_a_missing_marker(make_world, sender, form, header):
    world = make_world("--igtl-sender", sender, "--igtl-marker-name", "StylusToTracker")
    world.control(f"igtl form {form}")
    world.control(f"igtl header {header}")
    time.sleep(0.1)
    tracker = IGTLTracker("127.0.0.1", world.info["igtl_port"], device_name="StylusToTracker")
    frame = frames_until(tracker, FRAME_OK)
    assert np.linalg.norm(frame.tracker_from_marker[:3, 3] - marker_position_truth(world)) < 1.5
    world.control("occlude on")  # PLUS/Slicer: nothing sent for it; old: a placeholder
    frame = frames_until(tracker, FRAME_MISSING)
    assert frame.tracker_from_marker is None
    world.control("occlude off")
    frames_until(tracker, FRAME_OK)
    findings = {f.subject: f for f in tracker.preflight(duration_s=0.5)}
    tracker.close()
    assert "StylusToTracker" in findings["sender"].text and "ReferenceToTracker" in findings["sender"].text
    assert findings["frame rate"].level == FINDING_OK and findings["marker"].level == FINDING_OK


@pytest.mark.parametrize("placeholder", ["identity", "zero", "nan"])
@pytest.mark.realtime
def test_an_old_senders_placeholder_is_missing(make_world, placeholder):
    world = make_world("--igtl-sender", "old")
    world.control(f"igtl placeholder {placeholder}")
    tracker = IGTLTracker("127.0.0.1", world.info["igtl_port"])
    world.control("occlude on")
    frames_until(tracker, FRAME_MISSING)
    frames = [tracker.next_frame(2.0) for _ in range(4)]
    tracker.close()
    assert all(f.status == FRAME_MISSING and f.tracker_from_marker is None for f in frames)


@pytest.mark.realtime
def test_plus_silence_of_one_tool_is_not_seen_not_lost(make_world):
    world = make_world("--igtl-sender", "plus")
    tracker = IGTLTracker("127.0.0.1", world.info["igtl_port"])
    frames_until(tracker, FRAME_OK)
    world.control("occlude on")  # SendValidTransformsOnly: the marker's messages stop
    frames_until(tracker, FRAME_MISSING)
    frames = [tracker.next_frame(2.0) for _ in range(5)]
    assert all(f.status == FRAME_MISSING for f in frames)
    assert np.all(np.diff([f.time_s for f in frames]) > 0)  # one per tracker frame, the stream's rate
    findings = {f.subject: f for f in tracker.preflight(duration_s=0.3)}
    assert findings["marker"].level == FINDING_OK  # seen before; the name is right
    world.control("igtl send_invalid on")  # SendValidTransformsOnly="FALSE": INVALID + identity
    frames = [tracker.next_frame(2.0) for _ in range(4)]
    assert frames[-1].status == FRAME_MISSING and frames[-1].tracker_from_marker is None
    world.control("igtl reference off")
    world.control("igtl mute on")  # the whole stream silent, the connection alive: lost
    with pytest.raises(DeviceError, match="stalled or lost"):
        for _ in range(20):
            tracker.next_frame(0.5)
    tracker.close()


@pytest.mark.realtime
def test_a_closed_connection_ends_the_run(make_world):
    world = make_world()
    tracker = IGTLTracker("127.0.0.1", world.info["igtl_port"])
    tracker.next_frame(2.0)
    world.control("igtl hang_up")
    with pytest.raises(DeviceError, match="closed the connection"):
        for _ in range(20):
            tracker.next_frame(0.5)
    tracker.close()


@pytest.mark.realtime
def test_position_without_orientation_is_refused_in_one_line(make_world):
    world = make_world("--igtl-sender", "plus")
    world.control("igtl form position12")
    with pytest.raises(DeviceError, match="has no orientation"):
        tracker = IGTLTracker("127.0.0.1", world.info["igtl_port"], connect_timeout_s=2.0)
        tracker.next_frame(2.0)


@pytest.mark.realtime
def test_a_wrong_marker_name_lists_what_the_sender_sends(make_world):
    world = make_world("--igtl-sender", "plus")
    with pytest.raises(DeviceError, match="it sends .*MarkerToTracker.*ReferenceToTracker"):
        IGTLTracker(
            "127.0.0.1", world.info["igtl_port"], device_name="StylusToTracker", connect_timeout_s=1.0
        )


def test_invalid_status_with_a_real_pose_is_kept_as_invalid():
    from spacecal.adapters.igtl import IGTLTracker as Tracker

    pose = np.eye(4)
    pose[:3, 3] = [1.0, 2.0, -1000.0]
    frame = Tracker._marker_frame(None, 3.0, pose, {"TransformStatus": "INVALID"})
    assert frame.status == FRAME_INVALID and frame.tracker_from_marker is not None
    assert Tracker._marker_frame(None, 3.0, np.eye(4), {}).status == FRAME_MISSING
    assert FINDING_WARNING != FINDING_OK
