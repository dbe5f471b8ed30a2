"""One judgement of a calibration: for a calibration graded good, acceptable, poor and unusable
(one simulated recording, graded against four sets of ``--thresholds-mm``), the command line's
exit code and verdict line, the report's headline and colour, the station's page and the
record's grade all say the same."""

from __future__ import annotations

import html
import re
import shutil

import pytest

from spacecal import app
from spacecal.cli.main import main
from spacecal.io.results_json import read_calibration
from spacecal.ledger import Ledger

#: Multiples of the calibration's expected error e that make each grade's thresholds
#: (good, acceptable, poor limits), so the grade is known whatever e the simulation gives.
THRESHOLD_FACTORS = {
    "good": (2.0, 3.0, 4.0),
    "acceptable": (0.5, 2.0, 3.0),
    "poor": (1 / 3, 0.5, 2.0),
    "unusable": (0.25, 1 / 3, 0.5),
}


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    folder = tmp_path_factory.mktemp("judgement")
    path = folder / "recording.csv"
    app.simulate(app.SimulateSettings(output=str(path), force=True))
    first = app.calibrate(app.CalibrateSettings(str(path), str(folder / "first.json"), "ml", force=True))
    return path, first.record.verdict.expected_error_mm


@pytest.mark.parametrize("grade", THRESHOLD_FACTORS)
def test_the_cli_the_report_the_station_and_the_record_agree(grade, recording, tmp_path, capsys):
    path, expected_mm = recording
    thresholds = ",".join(f"{f * expected_mm:.6f}" for f in THRESHOLD_FACTORS[grade])
    calibration, record = tmp_path / "cal.json", tmp_path / "record.db"

    # the command line
    arguments = ["calibrate", str(path), "--method", "ml", "-o", str(calibration), "--force"]
    code = main([*arguments, "--thresholds-mm", thresholds, "--record", str(record)])
    out, err = capsys.readouterr()
    verdict = read_calibration(calibration).verdict
    assert verdict.grade == grade
    assert code == (1 if grade == "unusable" else 0), err
    assert f"verdict: {verdict.text}" in out
    if grade == "unusable":
        assert err.startswith("spacecal: error: calibration unusable") and err.count("\n") == 1

    # the report
    report = tmp_path / "report.html"
    assert main(["report", str(calibration), "--recording", str(path), "-o", str(report), "--force"]) == 0
    page = report.read_text()
    headline = re.search(r"<div class='headline'>(.*?)</div>", page).group(1)
    assert headline == verdict.headline
    assert f"class='verdict {verdict.level}'" in page

    # the record
    ledger = Ledger.open(str(record))
    try:
        [row] = ledger.calibrations()
        assert row.grade == grade
    finally:
        ledger.close()

    # the station, with the site's thresholds
    testclient = pytest.importorskip("starlette.testclient")
    from spacecal.station.server import StationOptions, build

    options = StationOptions(
        data=str(tmp_path / "station"), simulated=True, error_thresholds=app.ErrorThresholds.parse(thresholds)
    )
    station, application = build(options)
    try:
        web = testclient.TestClient(application, base_url="http://127.0.0.1:8770")
        web.post("/workspaces", data={"robot": "1", "tracker": "1"})
        work = station.workspaces[1]
        shutil.copy(path, work.recording_path)
        page = web.post("/workspaces/1/step/calibrate", data={"method": "ml"}).text
        shown = re.search(r'id="verdict" class="verdict grade-(\w+) level-(\w+)"', page)
        assert shown is not None and shown.groups() == (grade, verdict.level)
        assert re.search(r'id="verdict-headline">(.*?)</b>', page).group(1) == html.escape(verdict.headline)
        [row] = station.ledger.calibrations()
        assert row.grade == grade
    finally:
        station.ledger.close()
