"""What ``calibrate`` prints is read from the calibration's typed fields: the robust method's
flagged frames are its sample counts' ``rejected_outlier``, the same frames its file lists."""

from __future__ import annotations

from spacecal import app
from spacecal.io.recordings import write_recording
from spacecal.io.results_json import read_calibration


def test_the_robust_method_s_flagged_frames_are_printed_as_its_file_lists_them(tmp_path, outlier_simulation):
    recording = write_recording(outlier_simulation.recording, tmp_path / "rec.csv")
    out = app.calibrate(app.CalibrateSettings(str(recording), str(tmp_path / "cal.json"), "robust"))
    listed = read_calibration(tmp_path / "cal.json").diagnostics["outliers"]
    assert len(listed) > 0  # the preset injects outliers
    assert f"outliers: {len(listed)} frames flagged (listed in the result file)" in out.lines


def test_a_method_that_flags_nothing_prints_no_outlier_line(tmp_path, white_simulation):
    recording = write_recording(white_simulation.recording, tmp_path / "rec.csv")
    out = app.calibrate(app.CalibrateSettings(str(recording), str(tmp_path / "cal.json"), "ml"))
    assert not any(line.startswith("outliers:") for line in out.lines)
