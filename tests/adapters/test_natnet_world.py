"""Motive's NatNet stream from the fake world, the truth behind every fake tracker: the marker
and the reference on the TCP as rigid bodies, occluded and unplugged by the world's switches.

A world without tracker noise (white and volumetric noise, dropouts and robot repeatability
zero), so that what NatNet carries is the truth to float32: the reference's pose relative to the
marker's, ``inv(tracker_from_reference) @ tracker_from_marker``, is the truth's
``inv(tcp_from_reference) @ tcp_from_marker`` wherever the arm stands."""

import json
import time

import numpy as np
import pytest

from spacecal.adapters.natnet import NatNetTracker
from spacecal.core.errors import DeviceError
from spacecal.core.ports import FRAME_MISSING, FRAME_OK
from spacecal.sim.scenario import PRESETS
from spacecal.testing.fakes.client import WorldProcess

from .conftest import _addresses
from .loopback import NETWORK
from .ur_runs import HARDWARE_TEST_NICENESS

#: Real client code against the protocol fakes, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime

#: Float32 metres at 2 m hold 1.2e-7 m; the relative pose composes two, with a 0.3 m lever.
POSITION_TOL_MM, ROTATION_TOL = 2e-3, 1e-5


@pytest.fixture
def noiseless_world(tmp_path):
    scenario = PRESETS["paper-white"].to_dict() | {
        "name": "natnet-noiseless",
        "white_noise_rms_mm": 0.0,
        "volumetric_error_rms_mm": 0.0,
        "dropout_probability": 0.0,
    }
    path = tmp_path / "noiseless.json"
    path.write_text(json.dumps(scenario))
    host = f"127.{NETWORK}.0.{next(_addresses)}"
    process = WorldProcess("--host", host, "--scenario", str(path), niceness=HARDWARE_TEST_NICENESS)
    yield process
    process.stop()


def test_the_world_streams_its_truth_over_natnet(noiseless_world):
    world = noiseless_world
    truth = world.truth()
    expected = np.linalg.inv(truth["tcp_from_reference"]) @ truth["tcp_from_marker"]
    tools = {"reference": "Reference"}
    reader = NatNetTracker(world.info["host"], world.info["natnet_port"], "Marker", tools)
    try:
        frames = [reader.next_frame(1.0) for _ in range(10)]
        assert all(f.status == FRAME_OK for f in frames)
        for frame in frames:
            relative = np.linalg.inv(frame.tool("reference")) @ frame.tracker_from_marker
            np.testing.assert_allclose(relative[:3, 3], expected[:3, 3], atol=POSITION_TOL_MM)
            np.testing.assert_allclose(relative[:3, :3], expected[:3, :3], atol=ROTATION_TOL)
        # Motive's clock: half an hour ahead of the controller's, as the truth says
        assert truth["natnet_clock_minus_robot_clock_s"] == 1800.0
        assert frames[0].time_s > 1800.0
        world.control("occlude on")
        time.sleep(0.1)
        frame = reader.next_frame(1.0)
        assert frame.status == FRAME_MISSING and frame.tool_statuses["reference"] == FRAME_OK
        world.control("unplug")
        with pytest.raises(DeviceError, match="no NatNet frame from"):
            for _ in range(50):
                reader.next_frame(0.5)
    finally:
        reader.close()
