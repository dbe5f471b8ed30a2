"""The operator's names of the devices (a station's "UR10 OR-2") go with the recording into the
calibration's provenance and its report, so a filed report names the one robot and tracker of
that room, not only their model."""

import pytest

from spacecal import app
from spacecal.core.errors import InvalidInputError


def test_the_names_of_the_devices_reach_the_calibration_and_its_report(tmp_path):
    recording, calibration, report = tmp_path / "rec.csv", tmp_path / "cal.json", tmp_path / "report.html"
    devices = app.DeviceSettings(robot_name="UR10 OR-2", tracker_name="Vicra OR-2 <left>")
    app.acquire(
        app.AcquireSettings(
            str(recording), devices=devices, scenario="paper-white", confirm_robot_motion=True
        )
    )
    made = app.calibrate(app.CalibrateSettings(str(recording), str(calibration), method="ml")).record
    assert made.provenance.devices["robot"]["station_name"] == "UR10 OR-2"
    assert made.provenance.devices["tracker"]["station_name"] == "Vicra OR-2 <left>"
    app.report(app.ReportSettings(str(calibration), str(report)))
    html = report.read_text()
    assert "UR10 OR-2, UR10" in html and "Vicra OR-2 &lt;left&gt;" in html  # named, and escaped


@pytest.mark.parametrize("name", ["", "   ", "x" * 101, "UR10\nOR-2", "UR10\x00"])
def test_a_device_name_that_is_not_one_line_of_text_is_refused(name):
    with pytest.raises(InvalidInputError, match="name must be 1 to 100 printable characters"):
        app.DeviceSettings(robot_name=name)
