"""The NDI adapter with the real ndicapy against the Combined API fake (TCP and pty)."""

import numpy as np
import pytest

pytest.importorskip("ndicapy")

from spacecal.adapters.ndi import NDITracker
from spacecal.core.errors import DeviceError, InvalidInputError
from spacecal.core.ports import FRAME_MISSING, FRAME_OK
from spacecal.testing.fakes.ndi import crc16

#: Real client libraries against the protocol fakes, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime


def test_crc_check_values():
    assert [crc16(t) for t in (b"OKAY", b"RESET", b"INIT:")] == [0xA896, 0xBE6F, 0xE3A5]


def connect(world, transport, roms, **options):
    if transport == "tcp":
        return NDITracker(world.info["host"], world.info["ndi_port"], roms, **options)
    return NDITracker(world.info["ndi_pty"], None, roms, **options)


def marker_position_truth(world):
    truth = world.truth()
    from spacecal.models.kinematics import forward_kinematics
    from spacecal.sim.scenario import scenario_from_dict
    from spacecal.sim.world import build_world

    sim = build_world(scenario_from_dict(truth["scenario"]))
    return (
        truth["tracker_from_base"]
        @ forward_kinematics(sim.true_model, truth["home_joints_rad"])
        @ truth["tcp_from_marker"]
    )[:3, 3]


@pytest.mark.parametrize("transport", ["tcp", "pty"])
@pytest.mark.parametrize("reply", ["bx", "tx"])
def test_frames_stream_with_the_true_pose(world, rom_file, transport, reply):
    tracker = connect(world, transport, [rom_file], reply=reply)
    frames = [tracker.next_frame(1.0) for _ in range(5)]
    tracker.close()
    numbers = [f.frame_number for f in frames]
    assert numbers == sorted(set(numbers)) and all(f.status == FRAME_OK for f in frames)
    positions = np.array([f.tracker_from_marker[:3, 3] for f in frames])
    # the fake's noise is 0.25 mm RMS per sphere (paper-white); TX rounds to 0.01 mm
    assert np.all(np.linalg.norm(positions - marker_position_truth(world), axis=1) < 1.5)
    assert frames[1].time_s - frames[0].time_s == pytest.approx(0.05, abs=0.051)


def test_three_tools_trigger_ndicapi_46_and_are_still_read(world, rom_file):
    tracker = connect(world, "tcp", [rom_file] * 3)
    frame = tracker.next_frame(1.0)
    assert tracker.decode_faults_handled >= 1 and tracker.reply == "bx"
    assert (
        frame.status == FRAME_OK
        and np.linalg.norm(frame.tracker_from_marker[:3, 3] - marker_position_truth(world)) < 1.5
    )
    tracker.close()


def test_occluded_marker_is_missing(world, rom_file):
    tracker = connect(world, "tcp", [rom_file])
    world.control("occlude on")
    frames = [tracker.next_frame(1.0) for _ in range(3)]
    assert frames[-1].status == FRAME_MISSING and frames[-1].tracker_from_marker is None
    tracker.close()


@pytest.mark.parametrize("transport", ["tcp", "pty"])
def test_unplugged_tracker_is_a_device_error(world, rom_file, transport):
    tracker = connect(world, transport, [rom_file])
    tracker.next_frame(1.0)
    world.control("unplug")
    with pytest.raises(DeviceError):
        for _ in range(40):
            tracker.next_frame(0.5)


def test_missing_rom_is_a_clear_error(world, tmp_path):
    with pytest.raises(InvalidInputError, match="ROM file"):
        connect(world, "tcp", [tmp_path / "nope.rom"])
