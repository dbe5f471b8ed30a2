"""The verification on the robot (paper §5.2) in a real browser on the simulated devices: its dry
run, its own confirmation, the run's page, and the per-pose errors beside the paper's with the
files they came from; and STOP mid-verification stopping the robot for good.

The calibration's recording is acquired as fast as the simulated devices compute (the
acquisition's own browser tests cover it); the verification itself runs in real time, on
three needle poses to keep the test short.
"""

from __future__ import annotations

import json
import re
import time
from urllib.parse import urljoin

from spacecal import app as spacecal_app
from tests.station.conftest import wait_js
from tests.station.test_browser import (
    ENDED_WITHIN_S,
    JOIN_WITHIN_S,
    RUN_ENDED_JS,
    confirm_and_finish,
    new_robot_and_tracker,
    shot,
    wait_for_run_end,
)

#: Needle poses of the browser's verification (about 7 s of motion in real time).
POSES = 3


def calibrated_page(page, served, robot: str):
    """A new calibration of ``robot`` on the simulated devices, its recording acquired at once
    and calibrated from the page; the workspace."""
    new_robot_and_tracker(page, served.url, robot)
    work = served.station.workspace(1)
    spacecal_app.acquire(
        spacecal_app.AcquireSettings(
            str(work.recording_path), devices=work.devices, confirm_robot_motion=True, plan=None
        )
    )
    page.reload()
    page.click("#calibrate")
    assert page.inner_text("#verdict").startswith("Good:")
    return work


def dry_run_the_verification(page, work) -> None:
    page.fill("#verify-poses", str(POSES))
    page.click("#verify-dry-run")
    shown = page.inner_text("#verify-dry-run-result")
    assert "motion gate: passed" in shown and f"{POSES} needle poses planned" in shown, shown
    assert "nothing moved" in shown
    # a pose measured before STOP is kept in its file, marked interrupted, and not shown as done
    kept = list(work.folder.glob("verification-*.json"))
    assert all(json.loads(path.read_text(encoding="utf-8"))["interrupted"] for path in kept), kept


def test_verify_on_the_robot_from_the_page(served, page, disk):
    work = calibrated_page(page, served, "UR10 <bay 6>")
    sha = work.verification.calibration_sha256()
    assert sha[:12] in page.inner_text("#verify-calibration")
    dry_run_the_verification(page, work)
    page.click("#verify")
    assert sha[:12] in page.inner_text("#confirm-text")
    message = confirm_and_finish(page, served, disk, "UR10 <bay 6>", lambda: page.click("#verify"))
    assert message.startswith(f"verified at {POSES} needle poses"), message
    page.click("#back")
    shown = page.inner_text("#verification")
    shot(page, "12-verified")
    # what the page shows is the file it names, of the calibration it names
    assert page.inner_text("#verified-calibration") == "calibration.json"
    assert page.get_attribute("#verified-sha256", "title") == sha
    json_link = page.get_attribute("#verification-json", "href")
    assert sha[:12] in json_link
    served_json = page.request.get(urljoin(served.url + "/", json_link))
    assert served_json.ok
    data = json.loads(served_json.body())
    written = json.loads((work.folder / f"verification-{sha[:12]}.json").read_text())
    assert data == written
    position = [point["position_error_mm"] for point in data["points"]]
    assert len(position) == POSES
    rows = page.inner_text("#verification-poses").splitlines()[1:]
    assert [float(r.split()[1]) for r in rows] == [round(p, 3) for p in position]
    stats = page.inner_text("#verification-stats")
    assert f"{min(position):.3f}" in stats and f"{max(position):.3f}" in stats
    assert f"{data['statistics']['position_mm']['mean']:.3f}" in stats
    assert "min 0.87, mean < 1.05" in stats and "min 0.83, mean about 1.1" in stats
    assert data["measured_by"] in page.inner_text("#measured-by") and "calibrated marker" in shown
    figure = page.request.get(urljoin(served.url + "/", page.get_attribute("#verification-figure", "href")))
    assert figure.ok and figure.body()[:8] == b"\x89PNG\r\n\x1a\n"
    # the simulated devices reach the poses to well under the paper's millimetre
    assert max(position) < 1.05


def test_stop_mid_verification_stops_the_robot_for_good(served, page, disk):
    work = calibrated_page(page, served, "UR10 bay 7")
    dry_run_the_verification(page, work)
    page.click("#verify")
    page.click("#confirm")
    page.wait_for_url(re.compile(r"/runs/\d+$"))
    wait_js(page, "document.getElementById('run-state').textContent === 'running'")
    run = served.station.runs.get(1)
    deadline = time.monotonic() + 60
    while run.samples == 0 and run.active and time.monotonic() < deadline:
        time.sleep(0.02)
    assert run.samples > 0 and run.active, run.message  # held at the first pose, still moving
    page.click("#stop")
    wait_for_run_end(page, disk, RUN_ENDED_JS)
    assert page.inner_text("#run-state") == "stopped"
    message = page.inner_text("#message")
    # the verification's own interruption line: what it kept, and that the robot was stopped
    assert "verification interrupted after" in message and "STOP pressed at the station" in message, message
    assert "the robot was stopped" in message, message
    run.thread.join(timeout=JOIN_WITHIN_S)
    stalled = disk.stalled_s(run.stop_requested_at, run.ended_at)
    assert run.ended_at - run.stop_requested_at - stalled < ENDED_WITHIN_S
    samples = run.samples
    time.sleep(1.0)
    # nothing moves again by itself: no new run, no new sample, no verification kept
    assert served.station.runs.active() is None and served.station.runs.get(2) is None
    assert run.samples == samples and not run.active
    shot(page, "13-verify-stopped")
    page.click("#back")
    assert page.query_selector("#verification") is None
    # a pose measured before STOP is kept in its file, marked interrupted, and not shown as done
    kept = list(work.folder.glob("verification-*.json"))
    assert all(json.loads(path.read_text(encoding="utf-8"))["interrupted"] for path in kept), kept
