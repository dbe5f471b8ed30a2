"""``spacecal acquire`` / ``calibrate`` as a user runs them, with tracker faults injected mid-run:
frame statuses recorded, doubtful frames left out of calibration, transport errors retried,
old firmware read, PLUS's silence for an unseen tool recorded as missing, a dead stream ends
the run."""

import subprocess
import threading
import time

import pytest

pytest.importorskip("rtde_control")
pytest.importorskip("ndicapy")

from spacecal.core.ports import FRAME_MISSING, FRAME_OK, FRAME_PARTIALLY_OUT_OF_VOLUME
from spacecal.io.recording_csv import read_recording

from .test_end_to_end import SPACECAL, acquire_command

#: Real client libraries against the protocol fakes, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime


def rows_written(recording):
    """Frames written so far: ``acquire`` writes the raw tracker stream frame by frame (the
    paired ``rec.csv`` is derived from the streams when the run ends)."""
    stream = recording.with_name(recording.stem + ".tracker.csv")
    return stream.read_bytes().count(b"\n") if stream.is_file() else 0


def faults_at_rows(world, recording, plan, timeout_s=120.0):
    """Send each ``(rows, command)`` of ``plan`` once the run has written that many rows."""

    def run():
        deadline = time.monotonic() + timeout_s
        for rows, command in plan:
            while rows_written(recording) <= rows and time.monotonic() < deadline:
                time.sleep(0.05)
            world.control(command)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def acquire(world, kind, recording, rom, timeout=150):
    return subprocess.run(
        acquire_command(world, kind, recording, rom, "15", "120"),
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_partially_out_of_volume_frames_are_recorded_and_left_out(world, rom_file, tmp_path):
    recording = tmp_path / "rec.csv"
    faults_at_rows(world, recording, [(22, "ndi partial_volume on"), (30, "ndi partial_volume off")])
    run = acquire(world, "ndi", recording, rom_file)
    assert run.returncode == 0, run.stderr
    data = read_recording(recording)
    doubtful = data.marker_status == FRAME_PARTIALLY_OUT_OF_VOLUME
    assert doubtful.sum() >= 3 and data.has_pose[doubtful].all()  # the pose is kept, flagged
    assert not data.visible[doubtful].any() and (data.marker_status == FRAME_OK).sum() > 30
    calibrations = {}
    for extra in ([], ["--include-doubtful-frames"]):
        out = tmp_path / f"cal{len(extra)}.json"
        run = subprocess.run(
            # a robot-world solver: no per-sweep sample counts, which a loaded machine thins out
            [*SPACECAL, "calibrate", str(recording), "--method", "shah", "-o", str(out)]
            + ["--thresholds-mm", "0.5,1,1000", *extra],  # about statuses, not accuracy
            capture_output=True,
            text=True,
            timeout=90,
        )
        assert run.returncode == 0, run.stderr
        calibrations[bool(extra)] = run.stdout
    assert f"{doubtful.sum()} doubtful frame(s) (partially_out_of_volume) left out" in calibrations[False]
    assert "used as asked" in calibrations[True]
    used = [int(text.split(" of ")[0].split("; ")[-1]) for text in (calibrations[False], calibrations[True])]
    assert used[1] > used[0]


def test_old_firmware_and_spoiled_replies_still_complete_the_run(make_world, rom_file, tmp_path):
    world = make_world("--ndi-generation", "polaris-old")  # no BX: read with TX
    recording = tmp_path / "rec.csv"
    faults_at_rows(world, recording, [(20, "ndi crc_error 2"), (40, "ndi short_reply 2")])
    run = acquire(world, "ndi-serial", recording, rom_file)
    assert run.returncode == 0, run.stderr
    assert world.control("ndi spoiled") == "4"
    assert (read_recording(recording).marker_status == FRAME_OK).sum() > 30


def test_a_tracker_that_keeps_spoiling_replies_ends_the_run(world, rom_file, tmp_path):
    recording = tmp_path / "rec.csv"
    faults_at_rows(world, recording, [(20, "ndi crc_error 1000")])
    run = acquire(world, "ndi", recording, rom_file)
    assert run.returncode == 1
    last = run.stderr.strip().splitlines()[-1]
    assert "tracker lost" in last and "3 replies in a row failed" in last and "Traceback" not in run.stderr
    assert len(read_recording(recording)) > 10


def test_plus_silence_of_the_marker_is_missing_and_a_silent_stream_ends_the_run(world, rom_file, tmp_path):
    recording = tmp_path / "rec.csv"
    faults_at_rows(world, recording, [(15, "occlude on"), (30, "occlude off"), (40, "igtl mute on")])
    run = acquire(world, "igtl", recording, rom_file)
    # the marker's silence while the reference kept coming was "not seen", not "tracker lost";
    # only the silence of the whole stream ended the run
    assert run.returncode == 1
    last = run.stderr.strip().splitlines()[-1]
    assert "tracker lost" in last and "stalled or lost" in last and "Traceback" not in run.stderr
    data = read_recording(recording)
    # the run went on through the marker's silence: it ended only after the whole stream fell silent
    assert rows_written(recording) - 1 >= 40 and (data.marker_status == FRAME_MISSING).sum() >= 8, last
    assert not data.has_pose[~data.visible].any()  # nothing but a plainly seen marker has a pose
