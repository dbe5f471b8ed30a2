"""The station in a real browser (headless Chromium from Debian's package, driven by
Playwright) on the simulated devices: from a new robot to an exported calibration, and STOP
or a closed tab mid-acquisition stopping the robot within the command line's stop times.

Each step's time is printed (``pytest -s``); with ``SPACECAL_STATION_SHOTS=DIR`` the pages
are saved there as PNG screenshots.
"""

from __future__ import annotations

import os
import re
import time
from pathlib import Path
from urllib.parse import urljoin

from spacecal import app as spacecal_app
from spacecal.io.check_history import history_path
from spacecal.io.recording_csv import read_recording
from tests.station.conftest import wait_js

#: The command line's stop times (tests/adapters/test_ur_stops.py): from the stop to the robot
#: standing still, and to the end of the command, s. As there, the end bound leaves out the time
#: the disk stalled meanwhile (:class:`~spacecal.testing.disk_probe.DiskProbe`).
STILL_WITHIN_S = 1.0
ENDED_WITHIN_S = 8.0
#: How long to wait for a stopped run's thread: the run's end may wait through disk stalls.
JOIN_WITHIN_S = ENDED_WITHIN_S + 60
#: An acquisition on the simulated devices ends within this (the station runs them in real time:
#: ~60 s of motion, and more on 2 busy cores), ms, not counting the time the disk stalled
#: meanwhile (:func:`wait_for_run_end`; a 66-s stall was measured beside a loaded run).
ACQUISITION_WITHIN_MS = 240_000
#: Samples recorded before the STOP.
STOP_AFTER_SAMPLES = 40
#: A check's STOP comes this long after the robot's first check sample (a check on the
#: simulated devices in real time takes several seconds), s.
CHECK_STOP_AFTER_S = 0.2
#: The robot's first check sample comes within this long of the run's start (the calibration's
#: misfit field and the plan's gate come first; on a busy machine they take seconds), s.
CHECK_MOVING_WITHIN_S = 60.0


def shot(page, name: str) -> None:
    folder = os.environ.get("SPACECAL_STATION_SHOTS")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(Path(folder) / f"{name}.png"), full_page=True)


def shown_text(page, element: str) -> str:
    """The text of the page's ``#element``, or the error reading it (for a failure's message:
    the page itself may be what hangs)."""
    try:
        return page.inner_text(f"#{element}", timeout=5_000)
    except Exception as exc:
        return f"<{type(exc).__name__}>"


def run_page_state(page) -> str:
    """What a run's page shows of its progress, for a failure's message: whether the run was
    stuck (the same move and samples for minutes) or only slow."""
    elements = ("run-state", "move", "moves", "samples", "visible", "status", "message")
    return ", ".join(f"{e}={' '.join(shown_text(page, e).split())[:200]!r}" for e in elements)


def wait_for_run_end(page, disk, expression: str, within_ms: float = ACQUISITION_WITHIN_MS) -> None:
    """Wait until the page's ``expression`` holds, for ``within_ms`` of time in which the disk
    did not stall (:class:`~spacecal.testing.disk_probe.DiskProbe`): a motion's run writes and
    syncs its recording, and its page and browser wait with it."""
    from playwright.sync_api import TimeoutError as PageTimeout

    started = time.monotonic()
    progress = []  # (s since the wait began, samples shown): stuck or only slow
    while True:
        left_s = started + within_ms / 1000.0 + disk.stalled_s(started, time.monotonic()) - time.monotonic()
        if left_s <= 0:
            stalled = disk.stalled_s(started, time.monotonic())
            raise AssertionError(
                f"{expression} did not hold within {within_ms / 1000.0:.0f} s "
                f"(and {stalled:.1f} s of disk stalls); samples shown over the wait: {progress}; "
                f"the page then showed: {run_page_state(page)}"
            )
        try:
            wait_js(page, expression, timeout=min(left_s, 30.0) * 1000.0)
            return
        except PageTimeout:
            progress.append((round(time.monotonic() - started), shown_text(page, "samples")))


#: The run's page shows that it ended (however it ended).
RUN_ENDED_JS = "!['starting', 'running'].includes(document.getElementById('run-state').textContent)"


def shown_run(page, served):
    """The run whose page ``page`` shows (``/runs/N``)."""
    return served.station.runs.get(int(page.url.rsplit("/", 1)[1]))


def acquisition_confirmed(page, served):
    """From the calibration's page: the dry run (it must pass), the acquisition confirmed; the
    run, its page shown."""
    page.click("#dry-run")
    assert "motion gate: passed" in page.inner_text("#dry-run-result")
    page.click("#acquire")
    page.click("#confirm")
    page.wait_for_url(re.compile(r"/runs/\d+$"))
    return shown_run(page, served)


def calibrated_from_a_simulation(page, served, robot: str):
    """A new calibration of ``robot`` whose recording is simulated as an acquisition records
    it, calibrated from its page; its workspace."""
    from spacecal import app as spacecal_app

    new_robot_and_tracker(page, served.url, robot)
    work = served.station.workspace(1)
    spacecal_app.simulate(spacecal_app.SimulateSettings(output=str(work.recording_path)))
    page.reload()
    page.click("#calibrate")
    return work


def stopped_for_a_stalled_page(run, disk) -> bool:
    """Whether the station stopped ``run`` because its page went silent, with a single disk
    stall at least the page's ping timeout long beside it (see :func:`confirm_and_finish`)."""
    from spacecal.station.motions import PAGE_LOST
    from spacecal.station.server import PAGE_PING_TIMEOUT_S

    if PAGE_LOST not in run.stop_reason:
        return False
    stall = disk.longest_stall_s(run.started_at, run.ended_at or time.monotonic())
    return stall >= PAGE_PING_TIMEOUT_S


def confirm_and_finish(page, served, disk, robot: str, again, while_running=None) -> str:
    """Confirm the motion the page names for ``robot``, follow its run to the end (calling
    ``while_running`` for what the page must show meanwhile); the run's last message, once it
    finished.

    The station stops a run whose page stopped answering its pings for
    :data:`~spacecal.station.server.PAGE_PING_TIMEOUT_S` (nobody could press STOP). Beside loaded
    runs on a shared virtual disk this machine's disk stalled 21 to 66 s at a time, and a page's
    pings went unanswered through a 43-s stall. A run stopped so must have a single stall at
    least that long beside it, and its page must show the stop once the station answers again;
    the motion is then confirmed once more (``again`` leads from the workspace to its
    confirmation). A run stopped for anything else fails the test, as does a second stop."""
    for attempt in (1, 2):
        assert robot in page.inner_text("#confirm-text")
        page.click("#confirm")
        page.wait_for_url(re.compile(r"/runs/\d+$"))
        run = shown_run(page, served)
        try:
            if while_running is not None:
                while_running()
        except Exception:  # a page's wait timed out, or what it showed was wrong
            if not stopped_for_a_stalled_page(run, disk):
                raise
        wait_for_run_end(page, disk, RUN_ENDED_JS)
        state, message = page.inner_text("#run-state"), page.inner_text("#message")
        if attempt == 1 and state == "stopped" and stopped_for_a_stalled_page(run, disk):
            assert run.stop_reason in message and not run.active, message
            print(f"\nstopped, its page silent through a disk stall ({message}): again", flush=True)
            page.click("#back")
            again()
            continue
        assert state == "finished", f"{state}: {message}"
        return message
    raise AssertionError("unreachable")


class Steps:
    """Times each step of a browser test."""

    def __init__(self) -> None:
        self.started = self.last = time.monotonic()
        self.times: list[tuple[str, float]] = []

    def done(self, name: str) -> None:
        now = time.monotonic()
        self.times.append((name, now - self.last))
        self.last = now

    def print(self, title: str) -> None:
        print(
            f"\n{title}: " + ", ".join(f"{name} {seconds:.1f} s" for name, seconds in self.times), flush=True
        )
        print(f"{title}: total {time.monotonic() - self.started:.1f} s", flush=True)


def new_robot_and_tracker(page, url: str, robot: str) -> None:
    page.goto(url + "/")
    page.fill("#add-robot input[name=name]", robot)
    page.click("#add-robot button")
    page.fill("#add-tracker input[name=name]", "Vicra (simulated)")
    page.click("#add-tracker button")
    page.click("#start button")
    page.wait_for_selector("#robot-name")


def report_and_export(page, url: str, steps: Steps, shot_name: str) -> None:
    """The report (served, an HTML page) and the exports to Slicer, PLUS and ROS 2."""
    page.click("#report")
    report = page.get_attribute("#report-link", "href")
    response = page.request.get(urljoin(url + "/", report))
    assert response.ok and b"<html" in response.body()[:500].lower()
    steps.done("report")
    for box in ("slicer", "plus", "ros2_launch"):
        page.check(f"#export-form input[name={box}]")
    page.click("#export")
    exported = page.inner_text("#exported")
    for name in ("tracker_from_base.tfm", "plus_config.xml", "tracker.launch.py"):
        assert name in exported
    shot(page, shot_name)
    steps.done("export")


def test_from_a_new_robot_to_an_exported_calibration(served, page, disk):
    steps = Steps()
    robot = "UR10 <bay 1>"
    new_robot_and_tracker(page, served.url, robot)
    assert page.inner_text("#robot-name") == robot  # shown as text, not markup
    assert "simulated devices" in page.inner_text("#findings")
    shot(page, "1-calibration")
    steps.done("new robot and tracker")

    page.click("#plan")
    assert "19 moves" in page.inner_text("#plan-summary")
    steps.done("plan")
    page.click("#dry-run")
    assert "motion gate: passed" in page.inner_text("#dry-run-result")
    steps.done("dry run")

    page.click("#acquire")
    confirmation = page.inner_text("#confirm-text")
    assert robot in confirmation and "calibration motion: 19 moves" in confirmation
    shot(page, "2-confirm")

    def acquiring() -> None:
        wait_js(page, f"Number(document.getElementById('samples').textContent) >= 100 || {RUN_ENDED_JS}")
        # the live view draws the sweeps where the TCP was, in the plan's set-up
        # the view redraws at most every five times its last draw took (a busy machine: seconds)
        wait_js(
            page,
            "(document.getElementById('view').data || [])"
            ".some(t => t.name.startsWith('TCP, marker seen') && t.x.length > 10)",
        )
        shot(page, "3-acquiring")

    def acquire_again() -> None:
        page.click("#dry-run")
        page.click("#acquire")

    message = confirm_and_finish(page, served, disk, robot, acquire_again, acquiring)
    assert "19/19 moves" in message
    # the simulated robot took as long as the real one would: at least its simulated time
    run = shown_run(page, served)
    times = read_recording(run.output.record.result.recording_path).time_s
    assert run.ended_at - run.first_frame_at >= 0.95 * (times[-1] - times[0]) > 20.0
    steps.done("acquire")

    page.click("#back")
    page.select_option("#method", "ml")
    page.click("#calibrate")
    verdict = page.inner_text("#verdict")
    assert verdict.startswith("Good:") and "expected error" in verdict
    steps.done("calibrate")

    page.click("#check")
    checked = confirm_and_finish(page, served, disk, robot, lambda: page.click("#check"))
    assert checked.startswith("PASS"), checked
    page.click("#back")
    assert page.inner_text("#checks").startswith("PASS")
    steps.done("check")

    report_and_export(page, served.url, steps, "4-calibrated")

    page.goto(served.url + "/trends")
    assert "station" in page.inner_text("#calibrations") and "PASS" in page.inner_text("#checks")
    assert page.evaluate("document.getElementById('trend').data.length") == 2  # checks, expected error
    shot(page, "5-trends")
    steps.done("trends")
    [calibration] = served.station.ledger.calibrations()
    assert calibration.source == "station" and calibration.robot == robot
    [check] = served.station.ledger.checks(calibration.id)
    assert check.source == "station" and check.passed
    steps.print("browser workflow")


def start_acquisition(page, url: str, robot: str):
    new_robot_and_tracker(page, url, robot)
    page.click("#dry-run")
    page.click("#acquire")
    page.click("#confirm")
    page.wait_for_url(re.compile(r"/runs/\d+$"))
    wait_js(page, f"Number(document.getElementById('samples').textContent) >= {STOP_AFTER_SAMPLES}")


def assert_stilled(run, reason: str, disk) -> None:
    """The run stopped on the Ctrl-C path: ended within the CLI's stop time (the disk's stalls
    left out), no frame after ``STILL_WITHIN_S``, and it never starts again."""
    assert run.thread is not None
    run.thread.join(timeout=JOIN_WITHIN_S)
    assert run.state == "stopped", run.message
    assert f"acquisition stopped: interrupted by the user ({reason})" in run.message
    assert "samples kept in" in run.message
    assert run.stop_requested_at is not None and run.ended_at is not None
    stalled = disk.stalled_s(run.stop_requested_at, run.ended_at)
    assert run.ended_at - run.stop_requested_at - stalled < ENDED_WITHIN_S
    assert run.last_frame_at is not None and run.last_frame_at - run.stop_requested_at < STILL_WITHIN_S
    frames = run.view.snapshot(0)["latest_sequence"]
    time.sleep(1.0)
    assert run.view.snapshot(0)["latest_sequence"] == frames and not run.active
    print(
        f"\nstopped ({reason}): robot's last frame {run.last_frame_at - run.stop_requested_at:.2f} s and "
        f"run ended {run.ended_at - run.stop_requested_at:.2f} s after the stop "
        f"(the disk stalled {stalled:.2f} s of it)",
        flush=True,
    )


def test_stop_mid_acquisition_stills_the_robot(served, page, disk):
    start_acquisition(page, served.url, "UR10 bay 2")
    page.click("#stop")
    wait_js(page, "document.getElementById('run-state').textContent === 'stopped'")
    message = page.inner_text("#message")
    assert "acquisition stopped: interrupted by the user (STOP pressed at the station)" in message
    shot(page, "6-stopped")
    run = served.station.runs.get(1)
    assert_stilled(run, "STOP pressed at the station", disk)
    assert served.station.runs.active() is None


def test_closing_the_tab_mid_acquisition_stops_the_robot(served, page, disk):
    start_acquisition(page, served.url, "UR10 bay 3")
    page.close()
    run = served.station.runs.get(1)
    assert_stilled(run, "the station's page was closed or lost its connection", disk)


def test_leaving_mid_acquisition_asks_first_and_then_stops_the_robot(served, page, disk):
    """Reload, Back or closing the tab stops the robot (nobody could press STOP): while it moves
    the browser asks first. Staying keeps the run; leaving stops it as a closed tab does."""
    start_acquisition(page, served.url, "UR10 bay 6")
    page.mouse.click(5, 5)  # a person's click: browsers ask before leaving only after one
    asked = []

    def stay(dialog):
        asked.append(dialog.type)
        dialog.dismiss()

    page.once("dialog", stay)
    page.close(run_before_unload=True)
    wait_js(page, "true")  # the page is still open: the dialog was answered "stay"
    run = served.station.runs.get(1)
    assert asked == ["beforeunload"] and run.active and not page.is_closed()
    samples = run.samples
    time.sleep(1.0)
    assert run.samples > samples  # still acquiring

    page.close()  # leaving (the answer "leave" ends the page as a close does)
    assert_stilled(run, "the station's page was closed or lost its connection", disk)


def test_an_ended_run_says_so_in_its_heading_and_stop_is_not_live(served, page, disk):
    start_acquisition(page, served.url, "UR10 bay 7")
    page.click("#stop")
    wait_js(page, "document.getElementById('run-state').textContent === 'stopped'")
    assert page.inner_text("#run-title").endswith(": stopped")
    assert page.is_disabled("#stop") and "idle" in (page.get_attribute("#stop", "class") or "")
    grey = page.evaluate("getComputedStyle(document.getElementById('stop')).backgroundColor")
    red, green, blue = (int(v) for v in re.findall(r"\d+", grey)[:3])
    assert red == green == blue and red > 100, grey  # grey, no longer STOP's red
    # an ended run asks nothing on leaving: the page goes at once
    asked = []
    page.on("dialog", lambda dialog: (asked.append(dialog.type), dialog.dismiss()))
    page.mouse.click(5, 5)
    with page.expect_event("close", timeout=5000):
        page.close(run_before_unload=True)
    assert page.is_closed() and asked == []


#: Kept by the page before its own scripts run: every websocket it opens, so the test can drop one
#: as a lost network would (the page cannot tell the two apart).
RECORD_SOCKETS = """
window.openedSockets = [];
window.WebSocket = class extends window.WebSocket {
  constructor(...args) { super(...args); window.openedSockets.push(this); }
};
"""


def test_a_page_that_lost_its_connection_shows_how_the_run_ended(served, page, disk):
    """The run stops (nobody could press STOP), and the page, reconnecting, shows that it
    stopped and why, with the samples the run kept, rather than a run still running."""
    page.add_init_script(RECORD_SOCKETS)
    start_acquisition(page, served.url, "UR10 bay 5")
    page.evaluate("window.openedSockets[0].close()")
    run = served.station.runs.get(1)
    assert_stilled(run, "the station's page was closed or lost its connection", disk)
    wait_for_run_end(page, disk, "document.getElementById('run-state').textContent === 'stopped'")
    assert "the station's page was closed or lost its connection" in page.inner_text("#message")
    assert int(page.inner_text("#samples")) == run.samples
    assert page.evaluate("window.openedSockets.length") >= 2  # it reconnected
    assert page.is_disabled("#stop")
    shot(page, "6b-reconnected")


def test_stop_mid_check_stops_the_robot_and_logs_nothing(served, page, disk):
    new_robot_and_tracker(page, served.url, "UR10 bay 4")
    work = served.station.workspace(1)
    # the calibration's recording, acquired as fast as the simulated devices compute
    spacecal_app.acquire(
        spacecal_app.AcquireSettings(
            str(work.recording_path), devices=work.devices, confirm_robot_motion=True, plan=None
        )
    )
    page.reload()
    page.click("#calibrate")
    assert page.inner_text("#verdict").startswith("Good:")
    page.click("#check")
    page.click("#confirm")
    page.wait_for_url(re.compile(r"/runs/\d+$"))
    wait_js(page, "document.getElementById('run-state').textContent === 'running'")
    run = served.station.runs.get(1)
    # STOP while the robot moves: after the check's first sample, not while it still computes
    # its plan (pressed then, the run says "stopped", true but not what this test is about)
    deadline = time.monotonic() + CHECK_MOVING_WITHIN_S
    while run.samples == 0 and run.active and time.monotonic() < deadline:
        time.sleep(0.02)
    assert run.samples > 0 and run.moves_total > 0, run.message
    time.sleep(CHECK_STOP_AFTER_S)
    assert run.active, run.message  # the check is still moving when STOP is pressed
    page.click("#stop")
    wait_js(page, "document.getElementById('run-state').textContent === 'stopped'")
    message = page.inner_text("#message")
    assert "check stopped: interrupted by the user (STOP pressed at the station)" in message
    assert "the robot was stopped and nothing was logged" in message
    run.thread.join(timeout=JOIN_WITHIN_S)
    stalled = disk.stalled_s(run.stop_requested_at, run.ended_at)
    assert run.ended_at - run.stop_requested_at - stalled < ENDED_WITHIN_S
    shot(page, "11-check-stopped")
    page.click("#back")
    assert page.inner_text("#checks") == ""
    assert served.station.ledger.checks() == []
    assert not history_path(str(work.calibration_path)).exists()


def test_back_onto_a_used_confirmation_moves_nothing_and_says_so_in_the_stations_page(served, page, disk):
    """Back after STOP lands on the confirmation page the run started from; its "Yes" is spent,
    so the station answers with its own page (styled, with the way on), says the robot did not
    move, and starts nothing."""
    start_acquisition(page, served.url, "UR10 bay 8")
    page.click("#stop")
    run = served.station.runs.get(1)
    assert_stilled(run, "STOP pressed at the station", disk)
    page.go_back()  # the confirmation, as the browser kept it
    page.wait_for_selector("#confirm")
    page.click("#confirm")
    page.wait_for_selector("#robot-name")  # the calibration's page, not a bare refusal
    assert "the robot did not move" in page.inner_text("#error")  # the station's own page, its header
    assert page.locator("header a").count() == 2 and page.locator("h1").count() == 1
    assert served.station.runs.latest() is run and served.station.runs.next_id() == 2
    shot(page, "19-back-onto-a-used-confirmation")
