"""The set-up in 3-D: before a calibration the plan is drawn in the robot base frame, after it
everything is in the tracker's frame through tracker_from_base (the base's origin drawn where the
calibration puts it, the volume the tracker kind's), samples seen and unseen apart, and every
axis names its frame; an operator's name is text in the figure."""

import json

import numpy as np

from spacecal import app
from spacecal.io.recordings import open_path
from spacecal.models.tracker import PyramidVolume
from spacecal.station.scene import setup_scene, volume_edges


def trace(figure, name):
    return next(t for t in figure["data"] if t["name"].startswith(name))


def test_the_scene_is_in_the_base_frame_before_a_calibration_and_in_the_tracker_frame_after(tmp_path):
    plan_file, recording_file, calibration_file = (
        tmp_path / "plan.json",
        tmp_path / "rec.csv",
        tmp_path / "cal.json",
    )
    app.plan(app.PlanSettings(budget_s=15.0, output=str(plan_file)))
    plan = json.loads(plan_file.read_text())
    before = setup_scene(plan)
    assert before["frame"] == "robot base"
    assert before["layout"]["scene"]["xaxis"]["title"]["text"] == "robot base x (mm)"
    assert not any(t["name"].startswith("measurement volume") for t in before["data"])
    path = trace(before, "planned TCP path")
    first = np.array(plan["moves"][0]["start_base_from_tcp"])[:3, 3]
    np.testing.assert_allclose([path["x"][0], path["y"][0], path["z"][0]], first)

    app.simulate(app.SimulateSettings(output=str(recording_file)))
    calibration = app.calibrate(app.CalibrateSettings(str(recording_file), str(calibration_file))).record
    recording = open_path(recording_file).recording
    after = setup_scene(plan, calibration, recording, PyramidVolume(), "Vicra <b>OR-2</b>")
    assert after["frame"] == "tracker"
    assert after["layout"]["scene"]["zaxis"]["title"]["text"] == "tracker z (mm)"
    base = trace(after, "robot base")
    np.testing.assert_allclose(
        [base["x"][0], base["y"][0], base["z"][0]], calibration.tracker_from_base[:3, 3]
    )
    moved = trace(after, "planned TCP path")
    expected = calibration.tracker_from_base @ np.append(first, 1.0)
    np.testing.assert_allclose([moved["x"][0], moved["y"][0], moved["z"][0]], expected[:3])
    seen = trace(after, "samples seen")
    assert len(seen["x"]) == min(600, int(recording.visible.sum()))
    tracker = next(t for t in after["data"] if "OR-2" in t["name"] and t["mode"] == "markers")
    assert "<b>" not in tracker["name"] and "&lt;b&gt;" in tracker["name"]  # drawn as text
    assert "OR-2" in after["layout"]["title"]["text"] and "<b>" not in after["layout"]["title"]["text"]


def test_the_volume_is_drawn_as_its_twelve_edges_at_its_depths():
    volume = PyramidVolume()
    points = [p for p in volume_edges(volume) if p is not None]
    depths = sorted({round(-p[2], 6) for p in points})
    assert depths == [volume.near_mm, volume.far_mm]
    far = [p for p in points if np.isclose(-p[2], volume.far_mm)]
    assert np.isclose(max(p[0] for p in far) - min(p[0] for p in far), volume.far_width_mm)
    assert sum(p is None for p in volume_edges(volume)) == 6  # two rings and four side edges


def test_the_calibration_page_draws_the_set_up_and_moves_it_into_the_tracker_frame(served, page):
    """In Chromium: after planning the page draws the plan in the robot base frame; after the
    calibration the same view is in the tracker's frame with its measurement volume."""
    from tests.station.test_browser import new_robot_and_tracker, shot

    new_robot_and_tracker(page, served.url, "UR10 scene")
    page.click("#plan")
    page.wait_for_selector("#scene .legendtext", timeout=30_000)
    assert page.get_attribute("#scene", "data-frame") == "robot base"
    assert "planned TCP path" in page.inner_text("#scene")
    shot(page, "17-scene-planned")
    work = served.station.workspace(1)
    app.simulate(app.SimulateSettings(output=str(work.recording_path)))
    page.reload()
    page.click("#calibrate")
    page.wait_for_selector("#scene .legendtext", timeout=30_000)
    assert page.get_attribute("#scene", "data-frame") == "tracker"
    legend = page.inner_text("#scene")
    assert "measurement volume" in legend and "samples seen" in legend
    shot(page, "18-scene-calibrated")
