"""The OpenIGTLink adapter with the real pyigtl against a PLUS-like server."""

import json
import time

import numpy as np
import pytest

pytest.importorskip("pyigtl")

from spacecal.adapters.igtl import IGTLTracker, publish_transform
from spacecal.core.errors import DeviceError
from spacecal.core.ports import FRAME_MISSING, FRAME_OK

#: Real client libraries against the protocol fakes, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime


def test_marker_to_tracker_stream_with_status(world):
    tracker = IGTLTracker("127.0.0.1", world.info["igtl_port"])
    frames = [tracker.next_frame(1.0) for _ in range(6)]
    assert all(f.status == FRAME_OK for f in frames)
    assert np.all(np.diff([f.time_s for f in frames]) > 0)  # by timestamp, never repeated
    world.control("occlude on")
    time.sleep(0.15)
    frames = [tracker.next_frame(1.0) for _ in range(3)]
    assert frames[-1].status == FRAME_MISSING  # TransformStatus INVALID in the metadata
    tracker.close()


def test_stale_and_lost_streams_are_device_errors(world):
    tracker = IGTLTracker("127.0.0.1", world.info["igtl_port"])
    tracker.next_frame(1.0)
    world.control("stale")
    with pytest.raises(DeviceError, match="stale|stalled"):
        for _ in range(40):
            tracker.next_frame(0.5)
    tracker.close()


def test_publish_calibration_as_base_to_tracker(world):
    calibration = np.eye(4)
    calibration[:3, 3] = [1.0, 2.0, 3.0]
    publish_transform("127.0.0.1", world.info["igtl_port"], "BaseToTracker", calibration)
    deadline = time.monotonic() + 5
    received = None
    while time.monotonic() < deadline and received is None:
        reply = world.control("received BaseToTracker")
        received = None if reply == "NONE" else np.array(json.loads(reply))
        time.sleep(0.1)
    assert received is not None and np.allclose(received, calibration)


def test_no_server_is_a_device_error():
    with pytest.raises(DeviceError, match="no MarkerToTracker message"):
        IGTLTracker("127.0.0.1", 9, connect_timeout_s=0.5)


def test_export_command_sends_the_calibration(world, tmp_path, white_simulation):
    from spacecal.cli import main
    from spacecal.estimators import calibrate
    from spacecal.io.results_json import write_calibration

    result = calibrate(white_simulation.recording, "paper", uncertainty=False)
    path = write_calibration(result, tmp_path / "cal.json")
    assert main(["export", str(path), "--igtl", f"127.0.0.1:{world.info['igtl_port']}"]) == 0
    deadline = time.monotonic() + 5
    received = "NONE"
    while time.monotonic() < deadline and received == "NONE":
        received = world.control("received BaseToTracker")
        time.sleep(0.1)
    assert np.allclose(np.array(json.loads(received)), result.tracker_from_base, atol=1e-3)
