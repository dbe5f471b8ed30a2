"""The station's motions in processes of their own, without a browser: what each way out of
the child process shows on the run's page."""

from __future__ import annotations

import dataclasses
import signal
import time

import pytest

from spacecal import app
from spacecal.station import motions
from spacecal.station.motions import Runs

#: A child process imports spacecal and starts the simulated devices within this, s (2 busy cores).
STARTS_WITHIN_S = 120.0


def wait_until(condition, timeout_s: float = STARTS_WITHIN_S) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError("timed out")
        time.sleep(0.05)


def simulated_acquisition(tmp_path) -> app.AcquireSettings:
    return app.AcquireSettings(
        str(tmp_path / "rec.csv"),
        devices=app.DeviceSettings("sim", "sim"),
        confirm_robot_motion=True,
        simulated_speed=1.0,
    )


def watched(run):
    """The run with its page connected, as the station's live view connects it."""
    run.page_connected()
    return run


def test_an_error_in_the_child_is_the_command_lines_one_line(tmp_path):
    run = watched(Runs().start(1, "bay 1", app.CheckSettings(str(tmp_path / "none.json")), "check"))
    run.thread.join(timeout=STARTS_WITHIN_S)
    assert run.state == "failed"
    assert "none.json" in run.message and "\n" not in run.message
    assert run.exit_code == 0


def test_a_stop_before_the_process_starts_moves_nothing(tmp_path):
    runs = Runs()
    run = runs.start(1, "bay 1", simulated_acquisition(tmp_path))
    run.request_stop("STOP pressed at the station")
    run.thread.join(timeout=STARTS_WITHIN_S)
    assert run.state == "stopped"
    assert run.first_frame_at is None and run.samples == 0
    assert "STOP pressed at the station" in run.message


def test_a_stop_mid_acquisition_is_sigint_and_keeps_the_samples(tmp_path):
    runs = Runs()
    run = watched(runs.start(1, "bay 1", simulated_acquisition(tmp_path)))
    wait_until(lambda: run.samples >= 20)
    run.request_stop("STOP pressed at the station")
    run.thread.join(timeout=STARTS_WITHIN_S)
    assert run.state == "stopped"
    assert "acquisition stopped: interrupted by the user (STOP pressed at the station)" in run.message
    assert "samples kept in" in run.message
    assert run.ended_at - run.stop_requested_at < 8.0
    assert runs.active() is None


def test_a_child_that_dies_is_shown_as_such(tmp_path):
    run = watched(Runs().start(1, "bay 1", simulated_acquisition(tmp_path)))
    wait_until(lambda: run.samples >= 5)
    run._process.send_signal(signal.SIGKILL)
    run.thread.join(timeout=STARTS_WITHIN_S)
    assert run.state == "failed"
    assert f"ended without a word (exit code {-signal.SIGKILL})" in run.message


def test_a_motion_waits_for_its_page_and_never_starts_without_it(tmp_path, monkeypatch):
    monkeypatch.setattr(motions, "PAGE_CONNECT_WITHIN_S", 1.0)
    run = Runs().start(1, "bay 1", simulated_acquisition(tmp_path))
    time.sleep(0.5)
    assert run.state == "starting" and run._process is None  # waiting for its page
    run.thread.join(timeout=10)
    assert run.state == "stopped" and run._process is None
    assert run.message == "stopped before the robot moved: the station's page never connected"
    assert not (tmp_path / "rec.csv").exists()


def test_a_page_that_connects_late_starts_the_motion(tmp_path, monkeypatch):
    monkeypatch.setattr(motions, "PAGE_CONNECT_WITHIN_S", 30.0)
    run = Runs().start(1, "bay 1", simulated_acquisition(tmp_path))
    time.sleep(2.0)  # a browser slow to open the page
    assert run._process is None and run.message == "waiting for the run's page to connect"
    run.page_connected()
    try:
        wait_until(lambda: run.samples >= 5)
    finally:
        run.request_stop("the test ended")
        run.thread.join(timeout=STARTS_WITHIN_S)
    assert "the test ended" in run.message and run.samples >= 5


def test_closing_the_last_page_stops_the_run(tmp_path):
    run = watched(watched(Runs().start(1, "bay 1", simulated_acquisition(tmp_path))))
    wait_until(lambda: run.samples >= 5)
    run.page_disconnected()
    assert run.stop_requested_at is None  # another page still watches it
    run.page_disconnected()
    run.thread.join(timeout=STARTS_WITHIN_S)
    assert run.state == "stopped"
    assert "the station's page was closed or lost its connection" in run.message


def test_one_motion_at_a_time(tmp_path):
    runs = Runs()
    run = runs.start(1, "bay 1", simulated_acquisition(tmp_path))
    try:
        with pytest.raises(RuntimeError, match="another acquisition is running"):
            runs.start(1, "bay 1", app.CheckSettings(str(tmp_path / "cal.json")), "check")
    finally:
        runs.stop_all("the test ended")
    assert run.state == "stopped"


def test_a_record_that_fails_after_a_finished_motion_keeps_the_motions_result(tmp_path):
    settings = dataclasses.replace(simulated_acquisition(tmp_path), simulated_speed=None)

    def record_fails(run):
        raise OSError("disk full")

    run = watched(Runs().start(1, "bay 1", settings, on_done=record_fails))
    run.thread.join(timeout=STARTS_WITHIN_S)
    assert run.state == "finished"
    assert run.message.startswith("wrote rec.csv") and "samples" in run.message
    assert run.message.endswith("; it could not be recorded: disk full")
