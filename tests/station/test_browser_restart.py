"""A station restarted with its tabs open, in a real browser (headless Chromium from Debian's
package, driven by Playwright), on SQLite and on PostgreSQL: the server stopped and a new one
started on the same port, data folder and record. The calibration's tab, reloaded, shows the
same calibration under the same id with its verdict; a confirmation page loaded before the
restart and answered after it moves nothing and says so; an old run's address says what it
was. With ``SPACECAL_STATION_SHOTS=DIR`` the pages are saved there (``24-restarted.png``,
``25-confirmed-after-a-restart.png``, ``26-a-run-before-the-restart.png``)."""

from __future__ import annotations

import re

from tests.station.test_browser import RUN_ENDED_JS, calibrated_from_a_simulation, shot, wait_for_run_end

#: The check's moves at this many times real time (a check takes about 8 s in real time): the
#: run only has to have been made before the restart.
FAST = 5.0


def test_a_tab_open_across_a_restart_shows_the_same_calibration(
    station_server, browser_context, disk, monkeypatch
):
    monkeypatch.setattr("spacecal.station.workspace.SIMULATED_SPEED", FAST)
    served = station_server.start()
    page = browser_context.new_page()
    calibrated_from_a_simulation(page, served, "UR10 OR-3")
    headline = page.inner_text("#verdict-headline")
    page.click("#report")
    # a check, so that the station has a run before the restart
    page.click("#check")
    page.click("#confirm")
    page.wait_for_url(re.compile(r"/runs/\d+$"))
    run_address = page.url
    wait_for_run_end(page, disk, RUN_ENDED_JS)
    assert page.inner_text("#run-state") == "finished", page.inner_text("#message")
    page.click("#back")
    page.wait_for_selector("#robot-name")
    workspace_address = page.url
    checks = page.inner_text("#checks")
    assert checks.startswith("PASS"), checks
    # another tab: the check's confirmation, loaded and not yet answered
    confirmation = browser_context.new_page()
    confirmation.goto(workspace_address)
    confirmation.click("#check")
    assert "UR10 OR-3" in confirmation.inner_text("#confirm-text")

    station_server.stop()
    restarted = station_server.start()
    assert restarted.station is not served.station and restarted.url == served.url

    # the calibration's tab, reloaded: the same calibration, under the same id, with its verdict
    page.reload()
    assert page.url == workspace_address == f"{served.url}/workspaces/1"
    assert page.inner_text("#robot-name") == "UR10 OR-3"
    assert page.inner_text("#verdict-headline") == headline
    assert page.locator("#report-link").count() == 1 and page.inner_text("#checks") == checks
    assert page.get_attribute("#stepper-calibrate", "data-state") == "done"
    assert page.get_attribute("#stepper-check", "data-state") == "done"  # its check, from its history
    # a dry run is not carried over (the robot may stand elsewhere): acquiring is locked
    assert page.is_disabled("#acquire-locked")
    shot(page, "24-restarted")

    # the confirmation loaded before the restart, answered after it: nothing moves, and it says so
    confirmation.click("#confirm")
    confirmation.wait_for_selector("#robot-name")
    assert "the robot did not move" in confirmation.inner_text("#error")
    assert restarted.station.runs.latest() is None and restarted.station.runs.next_id() == 2
    shot(confirmation, "25-confirmed-after-a-restart")

    # the run's address from before the restart: a page that says what it was
    answered = page.goto(run_address)
    assert answered is not None and answered.status == 404
    said = page.inner_text("#error")
    assert said.startswith("run 1 was before the station last started") and "its calibration's folder" in said
    assert page.locator("#home").count() == 1  # and the way back
    shot(page, "26-a-run-before-the-restart")
