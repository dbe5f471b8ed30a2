"""A PLUS Server occlusion is a gap of frames without the marker, not a lost tracker.

PlusServer sends only valid transforms (``SendValidTransformsOnly``, its default): with the
marker the only transform it is configured to send (``igtl reference off``), an occlusion is
silence. It answers GET_STATUS with STATUS while it runs, and sends its keep-alive STATUS only
when its tracker delivers no frames at all (PlusLib ``vtkPlusOpenIGTLinkServer``). spacecal asks
GET_STATUS when the stream falls silent: answered, the gap is frames without the marker; a
server that closes the connection, stops answering or has no tracker frames ends the run.
"""

import subprocess
import threading
import time

import numpy as np
import pytest

pytest.importorskip("rtde_control")

from spacecal.adapters.igtl import IGTLTracker
from spacecal.core.errors import DeviceError
from spacecal.core.ports import FRAME_MISSING, FRAME_OK
from spacecal.io.raw_streams import read_raw_recording
from spacecal.io.recording_csv import read_recording

from .test_end_to_end import acquire_command
from .test_end_to_end_status import rows_written

#: Real client libraries against the protocol fakes, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime

#: The occlusion, s.
OCCLUSION_S = 2.0
#: The run's longest wait for a tracker frame (``AcquisitionSettings.frame_timeout_s``), s.
FRAME_TIMEOUT_S = 1.0


def longest_missing_run(times, statuses):
    """(first, last) time of the longest run of consecutive missing frames."""
    best, start = (0.0, 0.0), None
    for k, status in enumerate(statuses):
        if status == FRAME_MISSING:
            start = k if start is None else start
            if times[k] - times[start] >= best[1] - best[0]:
                best = (times[start], times[k])
        else:
            start = None
    return best


def test_the_reader_records_a_silent_occlusion_as_missing_frames(make_world):
    world = make_world("--igtl-sender", "plus")
    world.control("igtl reference off")  # PLUS configured with the marker's transform only
    tracker = IGTLTracker("127.0.0.1", world.info["igtl_port"])
    try:
        frames = [tracker.next_frame(FRAME_TIMEOUT_S) for _ in range(5)]
        assert all(f.status == FRAME_OK for f in frames)
        world.control("occlude on")
        hidden_at = time.monotonic()
        while time.monotonic() - hidden_at < OCCLUSION_S:
            frames.append(tracker.next_frame(FRAME_TIMEOUT_S))
        world.control("occlude off")
        while frames[-1].status != FRAME_OK:
            frames.append(tracker.next_frame(FRAME_TIMEOUT_S))
    finally:
        tracker.close()
    times = np.array([f.time_s for f in frames])
    statuses = [f.status for f in frames]
    assert np.all(np.diff(times) > 0)  # in order, never repeated
    first, last = longest_missing_run(times, statuses)
    # one frame per tracker period through the gap (the fake streams at 20 Hz), none with a pose
    missing = [f for f in frames if f.status == FRAME_MISSING]
    assert all(f.tracker_from_marker is None for f in missing)
    assert OCCLUSION_S - 0.3 < last - first < OCCLUSION_S + 0.3, (first, last)
    period = float(np.median(np.diff(times[:5])))
    assert len(missing) >= 0.8 * (last - first) / period


@pytest.mark.parametrize(
    ("fault", "message"),
    [
        ("igtl hang_up", "closed the connection"),  # the server went away: a FIN
        ("igtl mute on", "no answer to GET_STATUS"),  # hung: the connection open, nothing answered
        ("unplug", "no tracker frames"),  # PLUS runs, its tracker is gone: keep-alives only
    ],
)
def test_a_server_that_is_gone_ends_the_reader_within_the_deadline(make_world, fault, message):
    world = make_world("--igtl-sender", "plus")
    world.control("igtl reference off")
    tracker = IGTLTracker("127.0.0.1", world.info["igtl_port"])
    try:
        tracker.next_frame(FRAME_TIMEOUT_S)
        world.control(fault)
        sent_at = time.monotonic()
        with pytest.raises(DeviceError, match=message):
            for _ in range(200):
                tracker.next_frame(FRAME_TIMEOUT_S)
        ended_after = time.monotonic() - sent_at
    finally:
        tracker.close()
    print(f"{fault}: the reader ended {ended_after:.2f} s after it")
    assert ended_after < FRAME_TIMEOUT_S + 0.5


def occlude_for(world, recording, rows, seconds):
    """Hide the marker for ``seconds`` once the run has written ``rows`` frames."""

    def run():
        deadline = time.monotonic() + 120
        while rows_written(recording) <= rows and time.monotonic() < deadline:
            time.sleep(0.02)
        world.control("occlude on")
        time.sleep(seconds)
        world.control("occlude off")

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def test_an_acquisition_through_a_plus_occlusion_completes_with_the_gap_not_seen(world, rom_file, tmp_path):
    world.control("igtl reference off")
    recording = tmp_path / "rec.csv"
    occlusion = occlude_for(world, recording, 30, OCCLUSION_S)
    run = subprocess.run(
        acquire_command(world, "igtl", recording, rom_file, "15", "120"),
        capture_output=True,
        text=True,
        timeout=150,
    )
    occlusion.join(5)
    assert run.returncode == 0, run.stderr
    assert "18/18 moves" in run.stdout
    raw = read_raw_recording(recording.with_name("rec.robot.csv"), recording.with_name("rec.tracker.csv"))
    assert raw.marker_status is not None
    assert np.all(np.diff(raw.tracker_time_s) > 0)  # no frame twice
    first, last = longest_missing_run(raw.tracker_time_s, raw.marker_status)
    # the samples of the gap (one per sample period, 50-100 ms) span the occlusion
    assert OCCLUSION_S - 0.35 < last - first < OCCLUSION_S + 0.35, (first, last)
    gap = (raw.tracker_time_s >= first) & (raw.tracker_time_s <= last)
    assert np.all(raw.marker_status[gap] == FRAME_MISSING)
    assert np.all(np.isnan(raw.tracker_from_marker_stack[gap]))
    data = read_recording(recording)
    assert (data.marker_status == FRAME_MISSING).sum() >= 15 and not data.has_pose[~data.visible].any()
    assert (data.marker_status == FRAME_OK).sum() > 100  # seen again after the gap


def test_an_acquisition_stops_within_the_deadline_when_the_plus_server_hangs(world, rom_file, tmp_path):
    world.control("igtl reference off")
    recording = tmp_path / "rec.csv"
    sent_at: list[float] = []

    def hang():
        while rows_written(recording) <= 30:
            time.sleep(0.02)
        world.control("occlude on")  # an occlusion first: answered, so not lost
        time.sleep(1.5)
        world.control("igtl mute on")  # then the server hangs: nothing sent, nothing answered
        sent_at.append(time.monotonic())

    threading.Thread(target=hang, daemon=True).start()
    run = subprocess.run(
        acquire_command(world, "igtl", recording, rom_file, "15", "120"),
        capture_output=True,
        text=True,
        timeout=150,
    )
    ended_after = time.monotonic() - sent_at[0]
    assert run.returncode == 1
    last = run.stderr.strip().splitlines()[-1]
    assert "tracker lost" in last and "no answer to GET_STATUS" in last and "Traceback" not in run.stderr
    # the robot stopped and the devices closed (ur_rtde's disconnect sleeps 0.5 s per interface)
    print(f"the run ended {ended_after:.2f} s after the server hung")
    assert ended_after < FRAME_TIMEOUT_S + 4.0
    data = read_recording(recording)
    assert (data.marker_status == FRAME_MISSING).sum() >= 8  # the occlusion before it, not seen
