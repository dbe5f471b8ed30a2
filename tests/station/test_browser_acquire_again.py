"""Acquiring again after a calibration, in a real browser (headless Chromium from Debian's
package, driven by Playwright) on the simulated devices: from the moment the new acquisition is
confirmed the page no longer shows the old verdict, check, report or exports as the workspace's,
the steps go back to the acquisition, and the report that can then be written is the new
recording's. And a recording changed on disk after its calibration: the page hides the result
and says why. With ``SPACECAL_STATION_SHOTS=DIR`` the pages are saved there
(``21-acquiring-again.png``, ``22-acquired-again.png``, ``23-recording-changed.png``)."""

from __future__ import annotations

import hashlib
from urllib.parse import urljoin

from tests.station.test_browser import (
    RUN_ENDED_JS,
    acquisition_confirmed,
    calibrated_from_a_simulation,
    shot,
    wait_for_run_end,
)

#: The new acquisition's sweeps at this many times real time (the station runs them in real
#: time, about a minute): what is asserted here is what the pages show around the acquisition,
#: not its timing. Still about 12 s of motion, so the second tab sees the run while it moves.
FAST = 5.0


def stepper(page) -> dict[str, str]:
    """Each step's state as the stepper shows it, ``next`` for the one marked next."""
    states = {}
    for item in page.locator("#stepper li").all():
        key = (item.get_attribute("id") or "").removeprefix("stepper-")
        marked_next = item.get_attribute("aria-current") == "step"
        states[key] = "next" if marked_next else item.get_attribute("data-state")
    return states


def sha12(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:12]


def test_acquiring_again_after_a_calibration_retires_it_on_the_page(
    served, page, disk, browser_context, monkeypatch
):
    monkeypatch.setattr("spacecal.station.workspace.SIMULATED_SPEED", FAST)
    # calibrated, reported and exported from a recording simulated as an acquisition records it
    work = calibrated_from_a_simulation(page, served, "UR10 bay 9")
    old_headline = page.inner_text("#verdict-headline")
    page.click("#report")
    page.check("#export-form input[name=slicer]")
    page.click("#export")
    assert "tracker_from_base.tfm" in page.inner_text("#exported")
    old_recording = sha12(work.recording_path)
    assert stepper(page)["report"] == "done" and stepper(page)["calibrate"] == "done"

    # a new acquisition, confirmed from the page; the workspace's page watched in a second tab
    run = acquisition_confirmed(page, served)
    other = browser_context.new_page()
    other.goto(f"{served.url}/workspaces/1")
    said = other.inner_text("#superseded")
    assert f"superseded by run {run.id}" in said and old_headline in said and "earlier-1/" in said
    # nothing of the old calibration is shown as the workspace's, and nothing offers it
    for gone in ("#verdict", "#calibrate-result", "#report", "#report-link", "#export-form", "#check"):
        assert other.locator(gone).count() == 0, gone
    assert other.inner_text("#exported") == "" and other.inner_text("#checks") == ""
    for locked in ("#calibrate-locked", "#report-locked", "#export-locked", "#check-locked"):
        assert other.is_disabled(locked), locked
    assert other.inner_text("#report-why").startswith("calibrate first")
    steps = stepper(other)
    assert steps["calibrate"] == steps["report"] == steps["export"] == "locked", steps
    assert other.get_attribute("#stepper-acquire a", "title") == "the robot is moving"
    shot(other, "21-acquiring-again")
    assert run.active  # all of it seen while the new acquisition was under way
    other.close()

    wait_for_run_end(page, disk, RUN_ENDED_JS)
    assert page.inner_text("#run-state") == "finished", page.inner_text("#message")
    page.click("#back")
    page.wait_for_selector("#robot-name")
    # the steps went back: recorded afresh, the calibration is next, the report still locked
    steps = stepper(page)
    assert steps["acquire"] == "done" and steps["calibrate"] == "next", steps
    assert steps["report"] == steps["export"] == steps["check"] == "locked", steps
    assert page.is_enabled("#calibrate") and page.is_disabled("#report-locked")
    assert f"superseded by run {run.id}" in page.inner_text("#superseded")
    new_recording = sha12(work.recording_path)
    assert new_recording != old_recording
    assert sha12(work.folder / "earlier-1" / "recording.csv") == old_recording  # kept whole
    shot(page, "22-acquired-again")

    # the one report that can be written now is the new recording's
    page.click("#calibrate")
    assert page.locator("#superseded").count() == 0 and page.locator("#verdict").count() == 1
    page.click("#report")
    report = page.request.get(urljoin(served.url + "/", page.get_attribute("#report-link", "href"))).text()
    assert f"sha256 {new_recording}" in report and old_recording not in report


def test_a_recording_changed_after_its_calibration_hides_the_result_and_says_why(served, page):
    work = calibrated_from_a_simulation(page, served, "UR10 bay 10")
    page.click("#report")
    assert page.locator("#verdict").count() == 1 and page.locator("#report-link").count() == 1
    # 39 samples fewer in the recording, after its calibration
    lines = work.recording_path.read_text().splitlines(keepends=True)
    header = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    work.recording_path.write_text("".join(lines[: header + 1] + lines[header + 40 :]))

    page.reload()
    said = page.inner_text("#superseded")
    assert said.startswith("recording.csv changed on disk after the calibration"), said
    assert "its verdict, check, report and exports are not shown" in said
    for gone in ("#verdict", "#calibrate-result", "#report", "#report-link", "#export-form", "#check"):
        assert page.locator(gone).count() == 0, gone
    assert page.is_disabled("#report-locked") and page.is_disabled("#export-locked")
    # the recording is still there: it can be calibrated again (this workspace has no plan of
    # its own, so the stepper's "next" stays on the plan)
    steps = stepper(page)
    assert steps["acquire"] == "done" and steps["calibrate"] in ("current", "next"), steps
    assert page.is_enabled("#calibrate") and page.locator("#calibrate-locked").count() == 0
    assert steps["report"] == steps["export"] == "locked", steps
    assert page.get_attribute("#superseded", "role") == "status"  # a screen reader says it
    shot(page, "23-recording-changed")
    assert work.calibration_path.is_file() and (work.folder / "report.html").is_file()  # left as they are
