"""``spacecal acquire --resume`` after a stop in the middle of a move: the arm stands between
two poses of the plan, so the resumed run first takes it back to where the interrupted move
started, a move the motion gate checks like every other, the dry run shows and
``--confirm-robot-motion`` covers; a stop during that approach ends the run as any stop.
Real ur_rtde against the fake e-Series controller, the NDI fake as the tracker."""

import json
import threading
import time

import numpy as np
import pytest

pytest.importorskip("rtde_control")
pytest.importorskip("ndicapy")

from spacecal.io.acquisition_progress import progress_path
from spacecal.io.raw_streams import read_raw_recording, stream_paths
from spacecal.io.recording_csv import read_recording

from .ur_runs import (
    acquire_argv,
    assert_every_pairable_frame_kept,
    assert_everything_closed,
    last_line,
    paired_times,
    recorded_rows,
    run,
    stats,
    ur_world,
)

#: Real client libraries against the protocol fakes, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime

GENERATION = "eseries"
#: A slow rotation (10 deg/s), so that the first move (rot_x, 0 to +10 deg) lasts a second and a
#: stop after a few samples leaves the arm degrees from the move's start.
SLOW = ("--angular-speed-deg-s", "10")
#: Samples (one every 100 ms in a rotation) before the safeguard stop: well inside move 1.
STOP_AFTER_ROWS = 4
#: Or, on a machine so busy that the tracker is polled at a fraction of its rate, this long
#: into move 1 (s) with at least one sample: about halfway through its 10 degrees.
STOP_INTO_MOVE_S = 0.5
#: From the stop to the arm standing still (the fake's joint angles), s (as test_ur_stops).
STILL_WITHIN_S = 1.0


def argv(world, recording, rom, *extra):
    return acquire_argv(
        world, GENERATION, recording, rom, *SLOW, *extra, rotation_deg="10", translation_mm="100", brisk=False
    )


def progress(recording):
    return json.loads(progress_path(recording).read_text())


class StopInMoveOne(threading.Thread):
    """A safeguard stop in the middle of move 1: once it has recorded STOP_AFTER_ROWS samples,
    or is STOP_INTO_MOVE_S into the move with one (the fake controller's view of the move, not
    the recording's pace alone, says where the arm is)."""

    def __init__(self, world, recording):
        super().__init__(daemon=True)
        self.world, self.recording = world, recording
        self.start()

    def run(self):
        deadline = time.monotonic() + 90
        moving_since = None
        while time.monotonic() < deadline:
            rows = recorded_rows(self.recording) - 1  # less the header
            now = stats(self.world)
            if moving_since is None and now["moving"] and len(now["commands"]) >= 1:
                moving_since = time.monotonic()
            into = 0.0 if moving_since is None else time.monotonic() - moving_since
            far_enough = rows >= STOP_AFTER_ROWS or (rows >= 1 and into >= STOP_INTO_MOVE_S)
            if moving_since is not None and far_enough:
                break
            time.sleep(0.02)
        self.world.control("ur safeguard_stop")


def stopped_in_move_one(world, recording, rom):
    """A run stopped by a safeguard stop in the middle of its first move, the safeguard reset."""
    fault = StopInMoveOne(world, recording)
    result = run(argv(world, recording, rom))
    fault.join(5)
    assert result.returncode == 1 and "robot safeguard stop" in last_line(result.stderr), result.stderr
    done = progress(recording)
    assert done["moves_completed"] == 0 and done["stopped_because"], done
    world.control("ur safeguard_reset")  # the operator releases the stop: nothing moves
    time.sleep(0.5)
    assert not stats(world)["moving"]
    return result


def tracker_rows(recording):
    return recording.with_name(recording.stem + ".tracker.csv").read_bytes()


def raw_times(recording):
    """``time_s`` of every frame in the raw tracker stream (its first column), read as written:
    the stream's reader wants ten frames, and the stopped run has fewer."""
    lines = tracker_rows(recording).decode().splitlines()
    assert lines[0].startswith("time_s,")
    return np.array([float(line.split(",", 1)[0]) for line in lines[1:]])


def test_resume_after_a_safeguard_stop_mid_move_approaches_the_plan_and_completes(rom_file, tmp_path):
    world = ur_world(GENERATION)
    try:
        recording = tmp_path / "rec.csv"
        stopped_in_move_one(world, recording, rom_file)
        before = tracker_rows(recording)
        kept = raw_times(recording)
        assert len(kept) >= 1

        # the dry run shows the approach, checked by the gate, and moves nothing
        dry = run(argv(world, recording, rom_file, "--resume", "--dry-run"))
        assert dry.returncode == 0, dry.stderr
        approach = [line for line in dry.stdout.splitlines() if line.startswith("resume: ")]
        assert len(approach) == 1 and "to the start of move 1/18 (rot_x)" in approach[0], dry.stdout
        print(approach[0])
        degrees = float(approach[0].split(" mm and ")[1].split(" deg")[0])
        assert 1.0 < degrees < 10.0, approach  # part of the way through a 10 deg rotation
        assert "motion gate:" in dry.stdout and "refused" not in dry.stdout and "nothing moved" in dry.stdout
        assert not stats(world)["moving"] and stats(world)["still_for_s"] > 1.0
        assert tracker_rows(recording) == before

        # the approach is motion too: not without --confirm-robot-motion
        unconfirmed = [
            a for a in argv(world, recording, rom_file, "--resume") if a != "--confirm-robot-motion"
        ]
        refused = run(unconfirmed)
        assert refused.returncode == 1 and "--confirm-robot-motion" in last_line(refused.stderr)
        assert tracker_rows(recording) == before

        resumed = run(argv(world, recording, rom_file, "--resume"))
        assert resumed.returncode == 0, resumed.stderr
        assert "18/18 moves" in resumed.stdout
        assert any(line.startswith("resume: ") for line in resumed.stdout.splitlines()), resumed.stdout
        # the recording is whole: the earlier frames kept as they were, none twice, more after
        assert tracker_rows(recording).startswith(before)
        times = raw_times(recording)
        assert np.all(np.diff(times) > 0) and np.all(np.isin(kept, times)) and len(times) > len(kept) + 100
        data = read_recording(recording)
        assert np.all(np.diff(data.time_s) > 0)
        # every move of the plan streamed the robot's states under its segment, and every frame
        # the pairing rule admits is in the paired recording (how many that is depends on how
        # much of the 500 Hz stream a busy machine's poller kept, not on the resume)
        robot_stream, tracker_stream, _ = stream_paths(recording.with_suffix(""))
        raw = read_raw_recording(robot_stream, tracker_stream)
        assert set(raw.robot_segment) >= {"rot_x", "rot_y", "rot_z", "lin_x", "lin_y", "lin_z"}
        assert_every_pairable_frame_kept(recording, paired_times(recording))
        assert progress(recording)["moves_completed"] == 18
    finally:
        world.stop()


def test_a_stop_during_the_approach_stops_as_any_stop_and_a_resume_then_completes(rom_file, tmp_path, disk):
    world = ur_world(GENERATION)
    try:
        recording = tmp_path / "rec.csv"
        stopped_in_move_one(world, recording, rom_file)
        before = tracker_rows(recording)
        moves_before = len(stats(world)["commands"])
        sent_at: list[float] = []

        def stop_once_moving():
            # the approach is the resumed run's first motion
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:
                now = stats(world)
                if now["moving"] and len(now["commands"]) > moves_before:
                    world.control("ur safeguard_stop")
                    sent_at.append(time.monotonic())
                    return
                time.sleep(0.01)

        watcher = threading.Thread(target=stop_once_moving, daemon=True)
        watcher.start()
        result = run(argv(world, recording, rom_file, "--resume"))
        watcher.join(5)
        assert sent_at, "the approach never moved"
        assert result.returncode == 1
        line = last_line(result.stderr)
        assert line.startswith("spacecal: error: acquisition stopped: ") and "robot safeguard stop" in line
        assert "resume with --resume" in line and "Traceback" not in result.stderr
        after = assert_everything_closed(world)
        assert after["fault_to_still_s"] is not None and after["fault_to_still_s"] < STILL_WITHIN_S
        assert not after["program_running"]
        # nothing was recorded on the way back, nothing lost, the plan still at move 1
        assert tracker_rows(recording).startswith(before)
        assert progress(recording)["moves_completed"] == 0
        world.control("ur safeguard_reset")
        time.sleep(1.0)
        assert not stats(world)["moving"]  # the stopped approach does not go on by itself

        resumed = run(argv(world, recording, rom_file, "--resume"))
        assert resumed.returncode == 0, resumed.stderr
        assert "18/18 moves" in resumed.stdout
        assert tracker_rows(recording).startswith(before)
        assert np.all(np.diff(raw_times(recording)) > 0)
    finally:
        world.stop()
