"""A station restarted keeps its work: each workspace reopens under the id its links carry, from
the files on disk (the calibration read and its hash checked), on both records; ids are never
reused; a tab left open across the restart keeps working, and a confirmation issued before it
moves nothing."""

from __future__ import annotations

import re

from .conftest import need


def station_on(data, record):
    testclient = need("starlette.testclient")
    from spacecal.station.server import StationOptions, build

    station, application = build(StationOptions(data=str(data), record=record))
    return station, testclient.TestClient(application, base_url="http://127.0.0.1:8770")


def calibrated_workspace(station, web):
    """Workspace 1, calibrated from a simulated recording and reported: its verdict's headline."""
    from spacecal import app

    web.post("/devices", data={"kind": "robot", "name": "UR10 OR-2", "url": "sim"})
    web.post("/devices", data={"kind": "tracker", "name": "Vicra OR-2", "url": "sim"})
    made = web.post("/workspaces", data={"robot": "1", "tracker": "1"}, follow_redirects=False)
    assert made.status_code == 303
    work = station.workspaces[1]
    web.post("/workspaces/1/step/plan")
    app.simulate(app.SimulateSettings(output=str(work.recording_path)))
    web.post("/workspaces/1/step/calibrate", data={"method": "ml"})
    web.post("/workspaces/1/step/report")
    web.post("/workspaces/1/export", data={"slicer": "on"})
    assert work.calibration is not None and work.report is not None
    return work.calibration.record.verdict.headline


def test_a_restart_keeps_every_workspace_under_its_id(tmp_path, record_url):
    data = tmp_path / "station"
    station, web = station_on(data, record_url)
    try:
        headline = calibrated_workspace(station, web)
        web.post("/workspaces", data={"robot": "1", "tracker": "1"})
        before = web.get("/workspaces/1").text
        confirmation = web.get("/workspaces/1/confirm/check").text
        ticket = re.search(r'name="ticket" value="([^"]+)"', confirmation).group(1)
    finally:
        station.runs.stop_all("the test ended")
        station.ledger.close()

    station, web = station_on(data, record_url)
    try:
        assert sorted(station.workspaces) == [1, 2]
        page = web.get("/workspaces/1")
        assert page.status_code == 200
        text = page.text
        # what it shows comes from its files: the verdict, the calibration, the report, the export
        assert headline in text and 'id="verdict"' in text and 'id="calibrate-result"' in text
        assert "tracker_from_base.tfm" in text and 'id="report"' in text
        assert "UR10 OR-2" in text and "Vicra OR-2" in text
        # the record's calibration row is this file's: its check history is there
        work = station.workspaces[1]
        assert work.calibration_record_id is not None
        # a dry run is not carried over: the robot may stand elsewhere
        assert not work.dry_run_ok and 'id="acquire"' not in text
        assert 'id="plan-summary"' in text and 'id="plan-summary"' in before
        # a confirmation issued before the restart moves nothing
        started = web.post("/workspaces/1/motion/check", data={"ticket": ticket}, follow_redirects=False)
        assert station.runs.latest() is None
        shown = web.get(started.headers.get("location", "/workspaces/1")).text + started.text
        assert "the robot did not move" in shown
        # a tab left open: its buttons work (the calibrate step on the workspace's recording)
        again = web.post("/workspaces/1/step/calibrate", data={"method": "ml"})
        assert again.status_code == 200 and 'id="verdict"' in again.text
        # a new workspace never takes an old one's id
        web.post("/workspaces", data={"robot": "1", "tracker": "1"})
        assert sorted(station.workspaces) == [1, 2, 3]
        missing = web.get("/workspaces/99")
        assert missing.status_code == 404 and "Internal Server Error" not in missing.text
    finally:
        station.runs.stop_all("the test ended")
        station.ledger.close()


def test_an_edited_calibration_is_not_reopened_as_done(tmp_path):
    data = tmp_path / "station"
    record = f"sqlite:///{tmp_path / 'record.db'}"
    station, web = station_on(data, record)
    try:
        calibrated_workspace(station, web)
        path = station.workspaces[1].calibration_path
    finally:
        station.runs.stop_all("the test ended")
        station.ledger.close()
    path.write_text(path.read_text().replace('"method": "ml"', '"method": "paper"', 1))

    station, web = station_on(data, record)
    try:
        text = web.get("/workspaces/1").text
        assert 'id="verdict"' not in text and 'id="report"' not in text and 'id="check"' not in text
        assert "calibration.json is not shown" in text and "edited" in text
    finally:
        station.runs.stop_all("the test ended")
        station.ledger.close()


def test_run_ids_go_on_across_a_restart_and_an_old_run_address_says_what_it_was(tmp_path):
    """A run's address of yesterday never names today's run: ids continue from the last one
    started (kept in the station's folder before the run moves), and an address of a run before
    the restart is a 404 page that says where its files are."""
    import pytest

    from spacecal.core.errors import InvalidInputError
    from spacecal.station.server import RUN_COUNTER_NAME

    data = tmp_path / "station"
    station, web = station_on(data, None)
    try:
        assert station.runs.next_id() == 1
        calibrated_workspace(station, web)
        check = web.get("/workspaces/1/confirm/check").text
        ticket = re.search(r'name="ticket" value="([^"]+)"', check).group(1)
        started = web.post("/workspaces/1/motion/check", data={"ticket": ticket}, follow_redirects=False)
        assert started.status_code == 303 and started.headers["location"].endswith("/runs/1")
        assert (data / RUN_COUNTER_NAME).read_text().strip() == "1"
    finally:
        station.runs.stop_all("the test ended")
        station.ledger.close()

    station, web = station_on(data, None)
    try:
        assert station.runs.next_id() == 2
        old = web.get("/runs/1")
        assert old.status_code == 404 and "before the station last started" in old.text
        assert web.get("/runs/2").status_code == 404 and "no such run" in web.get("/runs/2").text
    finally:
        station.runs.stop_all("the test ended")
        station.ledger.close()

    (data / RUN_COUNTER_NAME).write_text("seven\n")
    with pytest.raises(InvalidInputError, match="not a run number"):
        station_on(data, None)
