"""Every way a UR controller stops ends ``spacecal acquire`` cleanly and fast: one line naming
the cause, the robot still (measured by the fake controller: joint angles no longer change),
the program ended so that releasing the stop moves nothing, every device closed, the
recording intact and ``--resume`` completing it. Real ur_rtde against the fake controller;
half the cases on a CB3 (125 Hz), half on an e-Series (500 Hz)."""

import json
import signal
import subprocess
import time

import numpy as np
import pytest

pytest.importorskip("rtde_control")
pytest.importorskip("ndicapy")

from spacecal.io.acquisition_progress import progress_path
from spacecal.io.csv_core import metadata_path
from spacecal.io.raw_streams import read_raw_recording, stream_paths

from .ur_runs import (
    WhenRecorded,
    acquire_argv,
    assert_every_pairable_frame_kept,
    assert_everything_closed,
    dropped_by_the_pairing_rule,
    last_line,
    pairable_rows,
    paired_times,
    recorded_rows,
    run,
    stats,
    ur_world,
    wait_for_rows,
)

#: Real client libraries against the protocol fakes, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime

#: From the fault to the robot standing still (the fake's joint angles stop changing), s.
STILL_WITHIN_S = 1.0
#: From the fault to the end of the command, s: stopping, then closing the devices (ur_rtde's
#: disconnect sleeps 0.5 s per interface): typically 2 s, up to 6 s measured on a loaded
#: 2-core machine; the robot itself is still long before (STILL_WITHIN_S). Not counted: the
#: time the disk stalled meanwhile (:class:`~spacecal.testing.disk_probe.DiskProbe`), which the
#: command's last syncs of its recordings wait through (10.7 and 11.4 s ends were measured
#: beside 15-24 s stalls).
ENDED_WITHIN_S = 8.0
#: The same for a controller that vanished (the disk's stalls left out too): the state must
#: first be seen stale (0.5 s), the controller silent (0.3 s) and its dashboard silent (its 1 s
#: timeout) before the devices are closed; 5.5 s measured on a quiet machine.
VANISHED_ENDED_WITHIN_S = 12.0

#: Tracker rows recorded before the stop (the plan is short: 80 rows may be the whole run).
STOP_AFTER_ROWS = 40
#: Of them, frames inside the robot stream so far (``ur_runs.pairable_rows``): on a busy
#: machine the poller of a 500 Hz stream misses stretches, and 40 rows once held 5 such frames.
PAIRABLE_BEFORE_STOP = 10


#: name -> (generation, fault command, the line's cause, the operator's release command)
STOPS = {
    "safeguard stop": ("eseries", "safeguard_stop", "robot safeguard stop", "safeguard_reset"),
    "safety fault": ("cb3", "fault", "robot safety system fault", "clear"),
    "safety violation": ("eseries", "violation", "robot safety violation", "clear"),
    "program stopped on the pendant": (
        "cb3",
        "program_stop",
        "robot program stopped on the teach pendant",
        None,
    ),
    "program paused on the pendant": (
        "eseries",
        "program_pause",
        "robot program paused on the teach pendant",
        "program_play",
    ),
    "arm powered off": ("cb3", "power_off", "robot powered off", "mode RUNNING"),
    "robot mode not running": ("eseries", "mode IDLE", "robot not running (mode IDLE)", "mode RUNNING"),
    "RTDE connection dropped": ("cb3", "drop_rtde", "lost the RTDE connection", None),
}


def check_stopped_run(world, run_result, fault_at, recording, cause, disk, count_slack=0, label=None):
    ended_after = time.monotonic() - fault_at
    stalled = disk.stalled_s(fault_at, fault_at + ended_after)
    assert run_result.returncode == 1, run_result.stderr
    line = last_line(run_result.stderr)
    assert line.startswith("spacecal: error: acquisition stopped: "), run_result.stderr
    assert cause in line and "resume with --resume" in line
    assert "Traceback" not in run_result.stderr
    kept = paired_times(recording)
    written = recorded_rows(recording) - 1  # every frame in the raw tracker stream (one header row)
    # the paired recording holds the frames captured while the robot's stream was kept
    assert len(kept) <= written
    assert_every_pairable_frame_kept(recording, kept)
    assert any(f"{written - slack} samples kept" in line for slack in range(count_slack + 1)), line
    after = assert_everything_closed(world)
    print(
        f"{label or cause}: still {after['fault_to_still_s']:.3f} s after the fault; "
        f"command ended after {ended_after:.2f} s (the disk stalled {stalled:.2f} s of it)"
    )
    assert after["fault_to_still_s"] is not None and after["fault_to_still_s"] < STILL_WITHIN_S
    assert ended_after - stalled < ENDED_WITHIN_S
    assert not after["program_running"]  # ended: nothing can resume a move
    return kept, after


def resume_and_check(world, generation, recording, rom, kept):
    tracker_stream = recording.with_name(recording.stem + ".tracker.csv")
    before = tracker_stream.read_bytes()
    resumed = run(acquire_argv(world, generation, recording, rom, "--resume"))
    assert resumed.returncode == 0, resumed.stderr
    # nothing recorded is lost: the raw tracker stream only grows
    assert tracker_stream.read_bytes().startswith(before)
    again = paired_times(recording)  # without the reader's floor: see paired_times
    # the paired recording is derived again from the whole run: every kept frame is in it, but
    # for those the pairing rule drops at the whole run's offset
    lost = kept[~np.isin(kept, again)]
    robot_stream, tracker_stream_path, _ = stream_paths(recording.with_suffix(""))
    raw = read_raw_recording(robot_stream, tracker_stream_path)
    offset_s = json.loads(metadata_path(recording).read_text())["pairing"]["offset_s"]
    assert len(again) > len(kept)
    assert_every_pairable_frame_kept(recording, again)
    assert np.all(dropped_by_the_pairing_rule(raw, offset_s, lost)), lost
    assert recorded_rows(recording) - 1 >= len(again)
    assert "18/18 moves" in resumed.stdout


#: Stops after which the run is resumed to the end here (resuming is the same after every stop;
#: these three cover a paused program, an ended one and a new connection; it costs CI time).
RESUMED = {"safeguard stop", "program stopped on the pendant", "RTDE connection dropped"}


@pytest.mark.parametrize("stop", sorted(STOPS))
def test_each_stop_ends_the_run_and_nothing_moves_after_it(rom_file, tmp_path, stop, disk):
    generation, command, cause, release = STOPS[stop]
    world = ur_world(generation)
    try:
        recording = tmp_path / f"rec-{command.replace(' ', '-')}.csv"
        fault = WhenRecorded(
            world, f"ur {command}", recording, rows=STOP_AFTER_ROWS, pairable=PAIRABLE_BEFORE_STOP
        )
        result = run(acquire_argv(world, generation, recording, rom_file))
        fault.join(5)
        assert fault.reply == "OK" and fault.sent_at is not None, (
            f"the fault was not sent: {recorded_rows(recording)} frames, "
            f"{pairable_rows(recording)} pairable; "
            f"the run ended with {result.returncode}: {result.stderr.strip()[-800:]}"
        )
        kept, _ = check_stopped_run(world, result, fault.sent_at, recording, cause, disk)
        if release is not None:
            # the operator clears the stop on the pendant: a real controller would resume a
            # paused program's move here, so spacecal must have ended the program
            world.control(f"ur {release}")
            time.sleep(2.0)
            after = stats(world)
            assert after["still_for_s"] > 1.9 and not after["moving"], after
        if stop in RESUMED:
            resume_and_check(world, generation, recording, rom_file, kept)
    finally:
        world.stop()


@pytest.mark.parametrize("signal_name", ["SIGINT", "SIGTERM", "SIGHUP"])
def test_signals_stop_the_robot_at_once_and_keep_the_recording_resumable(
    rom_file, tmp_path, signal_name, disk
):
    generation = "eseries" if signal_name == "SIGTERM" else "cb3"
    world = ur_world(generation)
    try:
        recording = tmp_path / f"rec-{signal_name}.csv"
        process = subprocess.Popen(
            acquire_argv(world, generation, recording, rom_file),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        wait_for_rows(recording, STOP_AFTER_ROWS, process, pairable=PAIRABLE_BEFORE_STOP, world=world)
        world.control("ur mark")
        sent_at = time.monotonic()
        process.send_signal(getattr(signal, signal_name))
        time.sleep(0.2)
        process.send_signal(getattr(signal, signal_name))  # a second one must not abort the stop
        _, stderr = process.communicate(timeout=60)
        result = subprocess.CompletedProcess(process.args, process.returncode, "", stderr)
        what = "Ctrl-C" if signal_name == "SIGINT" else signal_name
        # a signal landing between a row's write and its count makes the line say one sample
        # fewer than the file holds (workflows.acquisition.run_plan); every row is intact
        kept, _ = check_stopped_run(
            world,
            result,
            sent_at,
            recording,
            "interrupted ",
            disk,
            count_slack=1,
            label=f"interrupted ({what})",
        )
        assert what in last_line(stderr)
        progress = json.loads(progress_path(recording).read_text())
        assert progress["moves_completed"] < progress["moves_total"] and progress["stopped_because"]
        if signal_name == "SIGTERM":  # (the resume itself is the same for every way of stopping)
            resume_and_check(world, generation, recording, rom_file, kept)
    finally:
        world.stop()


def test_the_fake_controller_resumes_a_paused_move_when_the_safeguard_is_reset():
    """The control for the tests above: a program left running after a safeguard stop moves
    the robot again when the safeguard is reset (as on a real controller), so "still after the
    reset" there shows spacecal ended its program, not a fake that never resumes."""
    from spacecal.adapters.ur import URRobot
    from spacecal.geometry.transforms import make_transform

    world = ur_world("cb3")
    robot = URRobot(world.info["host"], robot_model="UR10")
    try:
        start = robot.state().base_from_tcp
        robot.move_linear(start @ make_transform(np.eye(3), [0.0, 0.0, 80.0]), 50.0, 200.0, asynchronous=True)
        time.sleep(0.4)
        assert world.control("ur safeguard_stop") == "OK"
        time.sleep(0.5)
        assert stats(world)["still_for_s"] > 0.3
        assert world.control("ur safeguard_reset") == "OK"
        time.sleep(0.3)
        assert stats(world)["still_for_s"] < 0.1  # moving again: the paused move resumed
    finally:
        robot.stop()
        robot.close()
        world.stop()


def test_a_late_state_stream_is_not_taken_for_a_stopped_program():
    """ur_rtde starts the control program and returns once its own RTDE connection shows it
    running; spacecal reads the robot on a second connection, whose packets may arrive later
    (a busy thread, a congested link). The first state after the start must not read as "program
    stopped on the teach pendant" (which ended a pre-operative check on a loaded machine)."""
    from spacecal.adapters.ur import URRobot
    from spacecal.core.ports import SAFETY_NORMAL

    world = ur_world("cb3")
    assert world.control("ur lag_read_only 0.3") == "OK"
    robot = URRobot(world.info["host"], robot_model="UR10")
    try:
        assert robot.state().safety == SAFETY_NORMAL
    finally:
        robot.stop()
        robot.close()
        world.stop()


def test_a_controller_that_vanishes_mid_run_ends_the_run(rom_file, tmp_path, disk):
    """The controller is switched off or its cable pulled: every connection falls silent, and
    ur_rtde's isConnected() stays true while its thread tries to reconnect. Nothing can stop
    the arm from here any more, but the command must not wait for an answer that never comes
    (stopL waited for ever, and a SIGTERM could not end it): it ends with one line, the
    samples kept, the tracker closed."""
    world = ur_world("cb3")
    try:
        recording = tmp_path / "rec.csv"
        fault = WhenRecorded(world, "ur vanish", recording, pairable=PAIRABLE_BEFORE_STOP)
        result = run(acquire_argv(world, "cb3", recording, rom_file), timeout_s=60)
        ended_after = time.monotonic() - fault.sent_at
        assert result.returncode == 1, result.stderr
        line = last_line(result.stderr)
        # the adapter's own check (its timestamp stood still 0.5 s), the acquisition loop's (no
        # new state over several tracker frames) or, when it vanished just before a move was
        # sent, the move's (its state stood still while the command waited), whichever sees it
        # first: each says why
        assert line.startswith(
            (
                "spacecal: error: acquisition stopped: UR state is stale",
                "spacecal: error: acquisition stopped: robot data stale",
                f"spacecal: error: acquisition stopped: the UR controller on {world.info['host']} "
                "did not answer moveL",
            )
        ), result.stderr
        assert "samples kept" in line and "Traceback" not in result.stderr
        assert_every_pairable_frame_kept(recording, paired_times(recording))
        assert not stats(world)["tracker_tracking"]
        stalled = disk.stalled_s(fault.sent_at, fault.sent_at + ended_after)
        print(
            f"controller vanished: command ended after {ended_after:.2f} s "
            f"(the disk stalled {stalled:.2f} s of it)"
        )
        assert ended_after - stalled < VANISHED_ENDED_WITHIN_S
    finally:
        world.stop()
