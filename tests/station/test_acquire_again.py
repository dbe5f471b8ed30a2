"""An acquisition confirmed again after a stopped one starts over on fresh files, and the
stopped one's files are kept whole beside them (``earlier-N/``): nothing recorded is lost, and
the new run is not refused for a recording that exists."""

from __future__ import annotations

import re
import time

#: A child process imports spacecal and starts the simulated devices within this, s (2 busy cores).
STARTS_WITHIN_S = 120.0


def confirm_and_start(web, station):
    """Confirm the acquisition of workspace 1 and start it, with a page watching: its run."""
    page = web.get("/workspaces/1/confirm/acquire").text
    ticket = re.search(r'name="ticket" value="([^"]+)"', page).group(1)
    started = web.post("/workspaces/1/motion/acquire", data={"ticket": ticket}, follow_redirects=False)
    assert started.status_code == 303, started.text
    run = station.runs.get(int(started.headers["location"].rsplit("/", 1)[1]))
    run.page_connected()  # the run's page, connected
    return run


def calibrated_at_the_station(station, web):
    """Workspace 1 planned, a finished recording in its folder (simulated as acquisition would
    record it), and calibrated by the station's own step: the workspace."""
    from spacecal import app

    work = station.workspaces[1]
    web.post("/workspaces/1/step/plan")
    app.simulate(app.SimulateSettings(output=str(work.recording_path)))
    assert web.post("/workspaces/1/step/calibrate", data={"method": "ml"}).status_code == 200
    assert work.calibration is not None
    return work


def wait_for_samples(run) -> None:
    deadline = time.monotonic() + STARTS_WITHIN_S
    while run.samples < 5 and run.active:
        assert time.monotonic() < deadline, run.message
        time.sleep(0.05)
    assert run.active, run.message


def test_an_acquisition_after_a_stopped_one_starts_over_and_keeps_the_stopped_files(simulated_workspace):
    station, web = simulated_workspace
    work = station.workspaces[1]
    web.post("/workspaces/1/step/plan")
    web.post("/workspaces/1/step/dry-run")
    assert work.dry_run_ok

    first = confirm_and_start(web, station)
    wait_for_samples(first)
    first.request_stop("STOP pressed at the station")
    first.thread.join(timeout=STARTS_WITHIN_S)
    assert first.state == "stopped" and "samples kept in" in first.message, first.message
    assert "acquiring again starts over" in first.message and "--resume" not in first.message
    stopped_files = {p.name: p.read_bytes() for p in work.folder.glob("recording.*")}
    assert {"recording.robot.csv", "recording.tracker.csv"} <= set(stopped_files), sorted(stopped_files)

    second = confirm_and_start(web, station)
    wait_for_samples(second)  # not refused: "recording.csv exists"
    second.request_stop("the test ended")
    second.thread.join(timeout=STARTS_WITHIN_S)
    kept = work.folder / "earlier-1"
    assert {p.name: p.read_bytes() for p in kept.iterdir()} == stopped_files
    assert second.state == "stopped" and "samples kept in" in second.message, second.message
    robot_stream = work.folder / "recording.robot.csv"
    assert robot_stream.read_bytes() != stopped_files["recording.robot.csv"]  # its own samples


def test_an_acquisition_after_a_calibration_retires_it_and_everything_that_followed(simulated_workspace):
    """A calibrated, reported and exported workspace acquired again: the page stops showing the
    old verdict, check, report and exports at once (they no longer belong to the files on disk),
    says what was superseded, and keeps every retired file whole in ``earlier-N/``; no report can
    pair the old calibration with the new recording."""

    station, web = simulated_workspace
    # a finished recording in the workspace, then the station's own steps: calibrate, report, export
    work = calibrated_at_the_station(station, web)
    headline = work.calibration.record.verdict.headline
    web.post("/workspaces/1/step/report")
    web.post("/workspaces/1/export", data={"slicer": "on"})
    page = web.get("/workspaces/1").text
    assert 'id="verdict"' in page and 'id="report"' in page and 'id="check"' in page
    retired = {p.name: p.read_bytes() for p in work.folder.iterdir() if p.is_file() and p.name != "plan.json"}
    assert {"recording.csv", "calibration.json", "report.html", "tracker_from_base.tfm"} <= set(retired)

    web.post("/workspaces/1/step/dry-run")
    assert work.dry_run_ok
    run = confirm_and_start(web, station)
    wait_for_samples(run)
    page = web.get("/workspaces/1").text
    # while the new recording is made, nothing of the old one is shown as this workspace's
    assert 'id="verdict"' not in page and 'id="calibrate-result"' not in page
    assert 'id="report"' not in page and 'id="check"' not in page and 'id="export-form"' not in page
    assert f"superseded by run {run.id}" in page and headline in page and "earlier-1/" in page
    run.request_stop("the test ended")
    run.thread.join(timeout=STARTS_WITHIN_S)
    kept = work.folder / "earlier-1"
    assert {p.name: p.read_bytes() for p in kept.iterdir()} == retired  # kept whole
    assert not work.calibration_path.exists() and not (work.folder / "report.html").exists()
    # the report step has no calibration to pair with the new recording: one line, nothing written
    refused = web.post("/workspaces/1/step/report")
    assert "calibration.json" in refused.text and not (work.folder / "report.html").exists()


def test_a_report_is_refused_when_the_recording_changed_after_its_calibration(simulated_workspace):
    """The recording edited on disk after the station calibrated it: the page stops showing the
    calibration's verdict as the workspace's, and "Write the report" writes nothing and says
    which file changed, so no report pairs a calibration with samples it was not made from."""

    station, web = simulated_workspace
    work = calibrated_at_the_station(station, web)
    lines = work.recording_path.read_text().splitlines(keepends=True)
    header = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    work.recording_path.write_text("".join(lines[: header + 1] + lines[header + 40 :]))  # 39 samples fewer

    refused = web.post("/workspaces/1/step/report")
    assert not (work.folder / "report.html").exists()
    assert "recording.csv changed on disk" in refused.text, refused.text[-2000:]
    page = web.get("/workspaces/1").text
    # the calibration no longer describes the file: its verdict is not shown, the step says why
    assert 'id="verdict"' not in page and 'id="report-link"' not in page and 'id="export-form"' not in page
    assert "recording.csv changed on disk after the calibration" in page
    assert work.calibration_path.is_file()  # the files are left as they are
