"""The run page's live 3-D view, in a real browser (headless Chromium from Debian's package,
driven by Playwright) on the simulated devices. During an acquisition the plan's path is drawn
in the robot base frame (the station's plan is the paper's sweeps: it has no site), with each
sample where the TCP was, green where the marker was seen and red where it was not, and the
time left counting down. During a check the same page draws the set-up in the tracker frame
through the calibration, with the tracker's measurement volume; the
calibration's page says where the calibration put the robot (``tracker_from_base`` and the
distances from the tracker). With
``SPACECAL_STATION_SHOTS=DIR`` the pages are saved there (``27-acquiring-in-the-scene.png``,
``28-checking-in-the-tracker-frame.png``)."""

from __future__ import annotations

import json
import re

import numpy as np

from tests.station.conftest import wait_js
from tests.station.test_browser import (
    RUN_ENDED_JS,
    acquisition_confirmed,
    new_robot_and_tracker,
    shot,
    wait_for_run_end,
)

#: The sweeps at this many times real time: what is asserted is what the page draws, not the
#: pace (still seconds of motion, so the page is seen while the robot moves).
FAST = 4.0
#: A drawn TCP sample lies on the plan's path (its moves are straight lines between their end
#: poses, or turns about the TCP) within the simulated arm's own path error, mm.
ON_THE_PATH_MM = 1.0


def traces(page) -> dict[str, dict]:
    """The live view's plotly traces by name, with the name's ``(count)`` left off."""
    data = page.evaluate(
        "(document.getElementById('view').data || []).map(t => ({name: t.name, x: t.x, y: t.y, z: t.z}))"
    )
    return {re.sub(r" \(\d+\)$", "", t["name"]): t for t in data}


def distance_to_path(points: np.ndarray, path: np.ndarray) -> np.ndarray:
    """Each point's distance (mm) to the nearest segment of the polyline ``path`` (M, 3) taken
    as pairs (start, end) of each move."""
    starts, ends = path[0::2], path[1::2]
    best = np.full(len(points), np.inf)
    for a, b in zip(starts, ends, strict=True):
        ab = b - a
        t = np.clip(((points - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(points - (a + t[:, None] * ab), axis=1))
    return best


def xyz(trace: dict) -> np.ndarray:
    return np.array([trace["x"], trace["y"], trace["z"]], dtype=float).T


def test_the_live_view_draws_the_samples_into_the_set_up(served, page, disk, monkeypatch):
    monkeypatch.setattr("spacecal.station.workspace.SIMULATED_SPEED", FAST)
    new_robot_and_tracker(page, served.url, "UR10 bay 11")
    page.click("#plan")
    run = acquisition_confirmed(page, served)
    assert page.get_attribute("#view", "data-frame") == "robot base"

    # the robot moves: samples drawn where the TCP was, the time left counting down
    wait_js(page, f"Number(document.getElementById('samples').textContent) >= 60 || {RUN_ENDED_JS}")
    wait_js(
        page,
        "(document.getElementById('view').data || [])"
        ".some(t => t.name.startsWith('TCP, marker seen') && t.x.length > 20)",
    )
    first_left = page.inner_text("#time-left")
    assert run.active, run.message  # seen while the robot moves
    left = re.fullmatch(r"; about (\d+) s left", first_left)
    assert left is not None, first_left
    shown = traces(page)
    for name in (
        "robot base",
        "planned TCP path",
        "TCP, marker seen",
        "TCP, marker not seen",
        "TCP now",
    ):
        assert name in shown, sorted(shown)
    layout = page.evaluate("document.getElementById('view').layout.scene")
    assert [layout[f"{k}axis"]["title"]["text"] for k in "xyz"] == [f"robot base {k} (mm)" for k in "xyz"]
    shot(page, "27-acquiring-in-the-scene")

    # the drawn samples are the run's TCP positions on the plan's path, in the plan's frame
    plan = json.loads(served.station.workspace(1).plan_path.read_text())
    path = np.array(
        [
            np.asarray(move[key])[:3, 3]
            for move in plan["moves"]
            for key in ("start_base_from_tcp", "end_base_from_tcp")
        ]
    )
    assert np.allclose(xyz(shown["planned TCP path"]), path)
    drawn = xyz(shown["TCP, marker seen"])
    off = distance_to_path(drawn, path)
    print(f"\nlive samples drawn: {len(drawn)}, off the planned path at most {off.max():.3f} mm")
    assert off.max() < ON_THE_PATH_MM
    # the time left is the plan's, at the run's pace, and falls as the run goes on
    total = sum(move["duration_s"] for move in plan["moves"]) / FAST
    assert int(left.group(1)) <= total + 1
    wait_js(
        page,
        f"!document.getElementById('time-left').textContent.includes(' {left.group(1)} s') || {RUN_ENDED_JS}",
    )

    wait_for_run_end(page, disk, RUN_ENDED_JS)
    assert page.inner_text("#run-state") == "finished", page.inner_text("#message")
    assert page.inner_text("#time-left") == ""  # nothing left once it ended
    # every recorded sample drawn, each in its colour: the page's counts are the run's
    seen, unseen = (len(xyz(traces(page)[name])) for name in ("TCP, marker seen", "TCP, marker not seen"))
    counted = run.view.snapshot(0)
    assert seen + unseen == counted["samples"] and seen == counted["visible"] and seen > 100

    # a check: the same page in the tracker frame, through the calibration
    page.click("#back")
    page.select_option("#method", "ml")
    page.click("#calibrate")
    page.wait_for_selector("#tracker-from-base")
    # where the calibration puts the robot, on the calibration's page: not in the report alone
    calibration = served.station.workspace(1).calibration.record
    tracker_from_base = np.asarray(calibration.tracker_from_base)
    matrix = page.evaluate(
        "Array.from(document.querySelectorAll('#tracker-from-base tr'))"
        ".map(r => Array.from(r.cells).map(c => Number(c.textContent)))"
    )
    assert np.allclose(matrix, tracker_from_base, atol=5e-4)
    home = tracker_from_base @ np.asarray(plan["home_base_from_tcp"])
    distance = page.inner_text("#tracker-distance")
    assert f"{np.linalg.norm(tracker_from_base[:3, 3]):.0f} mm from the tracker" in distance, distance
    assert f"the TCP at home {np.linalg.norm(home[:3, 3]):.0f} mm" in distance, distance
    page.click("#check")
    page.click("#confirm")
    page.wait_for_url(re.compile(r"/runs/\d+$"))
    assert page.get_attribute("#view", "data-frame") == "tracker"
    wait_js(page, "(document.getElementById('view').data || []).some(t => t.name === 'measurement volume')")
    shown = traces(page)
    for name in ("robot base", "Vicra (simulated)", "measurement volume", "planned TCP path"):
        assert name in shown, sorted(shown)
    tracker_path = path @ tracker_from_base[:3, :3].T + tracker_from_base[:3, 3]
    assert np.allclose(xyz(shown["planned TCP path"]), tracker_path)
    layout = page.evaluate("document.getElementById('view').layout.scene")
    assert layout["xaxis"]["title"]["text"] == "tracker x (mm)"
    wait_for_run_end(page, disk, RUN_ENDED_JS)
    assert page.inner_text("#run-state") == "finished", page.inner_text("#message")
    # a check streams no samples to the page (drawing them would share the page's thread with
    # STOP): its view is the set-up it moves in, with nothing drawn as if sampled
    drawn = traces(page)
    assert len(xyz(drawn["TCP, marker seen"])) == 0 and len(xyz(drawn["TCP, marker not seen"])) == 0
    shot(page, "28-checking-in-the-tracker-frame")
