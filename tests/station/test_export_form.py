"""The export form through the app's test client: one target that fails leaves the others
written and listed, its reason beside it in an operator's words, the ticks kept; the UR
driver's calibration is offered only for a calibration that can fill it."""

from __future__ import annotations

import html
import re
import time

import pytest

from .conftest import need


@pytest.fixture
def calibrated(tmp_path):
    """A station with workspace 1 on the simulated devices, its recording simulated:
    ``(station, client, work)``; calibrate it with the method a test needs."""
    testclient = need("starlette.testclient")
    from spacecal import app
    from spacecal.station.server import StationOptions, build

    station, application = build(StationOptions(data=str(tmp_path / "station")))
    web = testclient.TestClient(application, base_url="http://127.0.0.1:8770")
    try:
        web.post("/devices", data={"kind": "robot", "name": "UR10 bay 1", "url": "sim"})
        web.post("/devices", data={"kind": "tracker", "name": "Vicra", "url": "sim"})
        web.post("/workspaces", data={"robot": "1", "tracker": "1"})
        work = station.workspaces[1]
        app.simulate(app.SimulateSettings(output=str(work.recording_path)))
        yield station, web, work
    finally:
        station.runs.stop_all("the test ended")
        station.ledger.close()


def shown(page: str, element: str) -> str | None:
    found = re.search(rf'id="{element}"[^>]*>(.*?)</(?:p|span)>', page, re.S)
    return None if found is None else html.unescape(found.group(1))


def ticked(page: str) -> set[str]:
    return set(re.findall(r'<input type="checkbox" name="(\w+)" value="1" checked>', page))


def test_one_export_that_fails_leaves_the_others_written_and_says_why_beside_it(calibrated):
    station, web, work = calibrated
    web.post("/workspaces/1/step/calibrate", data={"method": "ml"})
    (work.folder / "plus_config.xml").mkdir()  # where the PLUS file goes: it cannot be written
    page = web.post("/workspaces/1/export", data={"slicer": "1", "plus": "1", "ros2_launch": "1"})
    assert page.url.fragment == "export-form"
    text = page.text
    assert shown(text, "export-written") == "wrote tracker_from_base.tfm, tracker.launch.py"
    assert (work.folder / "tracker_from_base.tfm").is_file() and (work.folder / "tracker.launch.py").is_file()
    why = shown(text, "export-plus-error")
    assert why is not None and why.startswith("PLUS configuration (plus_config.xml) was not written: ")
    assert "Errno" not in why and "--" not in why and str(work.folder) not in why, why
    assert shown(text, "export-failed") == "1 of 3 not written: see beside it"
    assert ticked(text) == {"slicer", "plus", "ros2_launch"}  # as the operator left them
    listed = re.search(r'<ul id="exported">(.*?)</ul>', text, re.S).group(1)
    assert "tracker_from_base.tfm" in listed and "tracker.launch.py" in listed and "plus_config" not in listed
    # nothing ticked: said beside the form
    assert shown(web.post("/workspaces/1/export", data={}).text, "export-error") == "tick where to export"


def test_the_ur_driver_file_is_offered_only_for_a_calibration_that_can_fill_it(calibrated):
    station, web, work = calibrated
    web.post("/workspaces/1/step/calibrate", data={"method": "ml"})
    page = web.get("/workspaces/1").text
    assert 'name="ur_calibration"' not in page
    reason = shown(page, "export-ur_calibration-unavailable")
    assert reason is not None and "calibrate with the method kinematic" in reason and "--" not in reason
    # asked for anyway: refused in the same words, nothing written, the rest written
    page = web.post("/workspaces/1/export", data={"slicer": "1", "ur_calibration": "1"}).text
    assert "calibrate with the method kinematic" in shown(page, "export-ur_calibration-error")
    assert not (work.folder / "ur_calibration.yaml").exists()
    assert shown(page, "export-written") == "wrote tracker_from_base.tfm"
    # a kinematic calibration holds the robot's joints: offered, and written
    started = time.monotonic()
    web.post("/workspaces/1/step/calibrate", data={"method": "kinematic"})
    print(f"\nkinematic calibration at the station: {time.monotonic() - started:.1f} s")
    assert work.calibration.record.robot_model is not None
    page = web.get("/workspaces/1").text
    assert 'name="ur_calibration"' in page and shown(page, "export-ur_calibration-unavailable") is None
    page = web.post("/workspaces/1/export", data={"ur_calibration": "1"}).text
    assert shown(page, "export-written") == "wrote ur_calibration.yaml"
    assert (work.folder / "ur_calibration.yaml").is_file() and shown(page, "export-failed") is None
