"""The station in headless Chromium on the UR and NDI protocol fakes (``spacecal.testing.fakes``,
a world in a process of its own, spoken to by the real client libraries ur_rtde and ndicapi):
from a new robot and tracker to an exported calibration, and a STOP mid-acquisition that
stills the fake controller's arm within the command line's stop times.

Each motion runs in a process of its own (:mod:`spacecal.station.motion_process`), as the
command line runs it, so the station's web server, Chromium drawing the live view and the
robot's loop do not share one interpreter. Like the adapter tests, each takes one of the
hardware lanes and their raised priority: its fake world keeps real-time deadlines too.
"""

from __future__ import annotations

import os
import re
import signal
import time

import pytest

from tests.adapters.conftest import ahead_of_other_tests, hardware_lane, rom_file, watchdog  # noqa: F401
from tests.adapters.ur_runs import ROBOT_MODEL, assert_everything_closed, tracker_url, ur_world
from tests.station.conftest import wait_js
from tests.station.test_browser import (
    ENDED_WITHIN_S,
    JOIN_WITHIN_S,
    STILL_WITHIN_S,
    STOP_AFTER_SAMPLES,
    Steps,
    confirm_and_finish,
    report_and_export,
    shot,
)

#: Real client libraries against the protocol fakes, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime

pytest.importorskip("rtde_control")
pytest.importorskip("ndicapy")

ROBOT = "UR10 (fake controller)"


def new_robot_and_tracker_on_the_fakes(page, url: str, world, rom) -> None:
    page.goto(url + "/")
    page.fill("#add-robot input[name=name]", ROBOT)
    page.fill("#add-robot input[name=url]", f"ur://{world.info['host']}")
    page.fill("#add-robot input[name=model]", ROBOT_MODEL["cb3"])
    page.click("#add-robot button")
    page.fill("#add-tracker input[name=name]", "Polaris (fake)")
    page.fill("#add-tracker input[name=url]", tracker_url(world))
    page.click("#add-tracker button")
    page.fill("#start input[name=rom]", str(rom))
    page.click("#start button")
    findings = page.inner_text("#findings")
    assert "robot" in findings and "tracker" in findings
    assert "must be fixed" not in findings, findings


def start_acquisition_on_the_fakes(page, served, world, rom):
    """A new robot and tracker, the dry run passed, the acquisition confirmed and moving: its run,
    once it has recorded ``STOP_AFTER_SAMPLES`` samples."""
    new_robot_and_tracker_on_the_fakes(page, served.url, world, rom)
    page.click("#dry-run")
    dry_run = page.inner_text("#dry-run-result")
    assert "motion gate: passed" in dry_run, dry_run
    page.click("#acquire")
    assert ROBOT in page.inner_text("#confirm-text")
    page.click("#confirm")
    page.wait_for_url(re.compile(r"/runs/\d+$"))
    wait_js(page, f"Number(document.getElementById('samples').textContent) >= {STOP_AFTER_SAMPLES}")
    run = served.station.runs.get(1)
    assert run.active, run.message
    return run


def wait_stopped(page, run) -> None:
    """Wait for the page to show the run stopped; if it does not, fail saying where the run and
    its motion process stood (the process prints every thread's stack on SIGUSR1)."""
    from playwright.sync_api import TimeoutError as PageTimeout

    def where() -> str:
        return (
            f"the page shows {page.inner_text('#run-state')!r} ({page.inner_text('#message')!r}); the "
            f"station's run: {run.state!r} ({run.message!r}), STOP at {run.stop_requested_at}, ended at "
            f"{run.ended_at}"
        )

    try:
        # any end first: a run that ended otherwise (failed, finished) says so at once
        wait_js(page, "!['starting', 'running'].includes(document.getElementById('run-state').textContent)")
    except PageTimeout:
        process = run._process
        alive = process is not None and process.poll() is None
        if alive:
            os.kill(process.pid, signal.SIGUSR1)
            time.sleep(2.0)
        raise AssertionError(
            f"{where()}, its process {'still running (its stacks on stderr)' if alive else 'ended'}"
        ) from None
    assert page.inner_text("#run-state") == "stopped", where()


def plan_and_acquire(page) -> None:
    """From the workspace to the acquisition's confirmation: plan, dry run, acquire."""
    page.click("#plan")
    assert "planned from where the robot stands" in page.inner_text("#plan-summary")
    page.click("#dry-run")
    dry_run = page.inner_text("#dry-run-result")
    assert "motion gate: passed" in dry_run, dry_run
    page.click("#acquire")
    page.wait_for_url(re.compile(r"/confirm/acquire\??$"))  # a form without fields ends in "?"


def test_from_a_new_robot_to_an_exported_calibration_on_the_protocol_fakes(served, page, rom_file, disk):  # noqa: F811
    steps = Steps()
    world = ur_world("cb3")
    try:
        new_robot_and_tracker_on_the_fakes(page, served.url, world, rom_file)
        steps.done("new robot and tracker, their findings")
        plan_and_acquire(page)
        steps.done("plan and dry run")

        message = confirm_and_finish(page, served, disk, ROBOT, lambda: plan_and_acquire(page))
        assert re.search(r"(\d+)/\1 moves", message), message
        # the live view drew the sweeps where the TCP was, the marker seen
        # the view redraws at most every five times its last draw took (a busy machine: seconds)
        wait_js(
            page,
            "(document.getElementById('view').data || [])"
            ".some(t => t.name.startsWith('TCP, marker seen') && t.x.length > 10)",
        )
        shot(page, "8-fakes-acquired")
        steps.done("acquire")

        page.click("#back")
        page.select_option("#method", "ml")
        page.click("#calibrate")
        verdict = page.inner_text("#verdict")
        assert verdict.split(":")[0] in ("Good", "Acceptable"), verdict
        steps.done("calibrate")

        page.click("#check")
        checked = confirm_and_finish(page, served, disk, ROBOT, lambda: page.click("#check"))
        assert checked.startswith("PASS"), checked
        page.click("#back")
        assert page.inner_text("#checks").startswith("PASS")
        steps.done("check")

        report_and_export(page, served.url, steps, "9-fakes-calibrated")
        [calibration] = served.station.ledger.calibrations()
        [check] = served.station.ledger.checks(calibration.id)
        assert check.source == "station" and check.passed
        assert_everything_closed(world)
        steps.print("browser workflow on the protocol fakes")
    finally:
        world.stop()


def test_stop_on_the_protocol_fakes_stills_the_arm(served, page, rom_file, disk):  # noqa: F811
    world = ur_world("cb3")
    try:
        run = start_acquisition_on_the_fakes(page, served, world, rom_file)
        shot(page, "7-fakes-acquiring")
        world.control("ur mark")
        marked_at = time.monotonic()
        page.click("#stop")
        wait_stopped(page, run)
        assert "interrupted by the user (STOP pressed at the station)" in page.inner_text("#message")
        after = assert_everything_closed(world)
        run.thread.join(timeout=JOIN_WITHIN_S)
        # the fake controller times the arm from the mark; the station's stop path starts when
        # the STOP reaches the station (the browser's click and request come before it)
        assert after["fault_to_still_s"] is not None and run.stop_requested_at is not None
        click_s = run.stop_requested_at - marked_at
        still_after_stop_s = after["fault_to_still_s"] - click_s
        ended_after = run.ended_at - run.stop_requested_at
        stalled = disk.stalled_s(run.stop_requested_at, run.ended_at)
        print(
            f"\nprotocol fakes: the STOP reached the station {click_s:.2f} s after the click; the arm "
            f"stood still {still_after_stop_s:.3f} s and the run ended {ended_after:.2f} s after that "
            f"(the disk stalled {stalled:.2f} s of it)",
            flush=True,
        )
        assert still_after_stop_s < STILL_WITHIN_S
        assert ended_after - stalled < ENDED_WITHIN_S
        assert not after["program_running"]  # nothing can resume a move
    finally:
        world.stop()


def test_a_refused_dry_run_offers_no_motion(served, page, rom_file):  # noqa: F811
    world = ur_world("cb3")
    try:
        new_robot_and_tracker_on_the_fakes(page, served.url, world, rom_file)
        world.control("protective_stop")  # the arm is stopped on its pendant
        page.click("#dry-run")
        said = page.inner_text("body")
        assert "protective" in said.lower(), said
        assert "motion gate: passed" not in said
        assert page.locator("#acquire").count() == 0  # nothing to confirm
        shot(page, "10-dry-run-refused")
        # nor can a confirmation be asked for directly
        page.goto(f"{served.url}/workspaces/1/confirm/acquire")
        assert "run the dry run first" in page.inner_text("body")
        assert served.station.runs.get(1) is None  # no motion was started
    finally:
        world.stop()


def test_closing_the_tab_mid_acquisition_stills_the_arm_on_the_protocol_fakes(served, page, rom_file, disk):  # noqa: F811
    world = ur_world("cb3")
    try:
        run = start_acquisition_on_the_fakes(page, served, world, rom_file)
        world.control("ur mark")
        marked_at = time.monotonic()
        page.close()
        run.thread.join(timeout=JOIN_WITHIN_S)
        assert run.state == "stopped", run.message
        assert "interrupted by the user (the station's page was closed or lost its connection)" in run.message
        after = assert_everything_closed(world)
        assert after["fault_to_still_s"] is not None and run.stop_requested_at is not None
        seen_s = run.stop_requested_at - marked_at
        still_after_stop_s = after["fault_to_still_s"] - seen_s
        print(
            f"\nprotocol fakes, tab closed: the station saw it {seen_s:.2f} s after; "
            f"the arm stood still {still_after_stop_s:.3f} s after that",
            flush=True,
        )
        assert still_after_stop_s < STILL_WITHIN_S
        stalled = disk.stalled_s(run.stop_requested_at, run.ended_at)
        assert run.ended_at - run.stop_requested_at - stalled < ENDED_WITHIN_S
        assert not after["program_running"]
    finally:
        world.stop()
