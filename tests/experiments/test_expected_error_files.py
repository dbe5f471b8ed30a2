"""The expected error travels into the calibration file, the CLI's output and PLUS's Error."""

import json
import re

from spacecal.cli.main import main


def test_calibrate_prints_and_export_writes_the_expected_error(recording_file, tmp_path, capsys):
    calibration = tmp_path / "cal.json"
    assert main(["calibrate", str(recording_file), "--method", "ml", "-o", str(calibration)]) == 0
    out, _ = capsys.readouterr()
    expected = json.loads(calibration.read_text())["diagnostics"]["expected_error"]
    assert f"expected error at a target near the site: {expected['position_mm']:.2f} mm" in out
    plus = tmp_path / "plus.xml"
    assert main(["export", str(calibration), "--plus", str(plus)]) == 0
    errors = re.findall(r'From="Base"[^>]*Error="([^"]+)"|Error="([^"]+)"[^>]*From="Base"', plus.read_text())
    value = next(float(a or b) for a, b in errors)
    assert abs(value - expected["position_mm"]) < 1e-3


def test_thresholds_flag_regrades_and_unusable_exits_1(recording_file, tmp_path, capsys):
    calibration = tmp_path / "cal.json"
    code = main(
        [
            "calibrate",
            str(recording_file),
            "--method",
            "shah",
            "-o",
            str(calibration),
            "--thresholds-mm",
            "1e-4,2e-4,3e-4",
        ]
    )
    _, err = capsys.readouterr()
    assert code == 1 and err.strip().startswith("spacecal: error: calibration unusable")
    assert json.loads(calibration.read_text())["diagnostics"]["verdict"]["grade"] == "unusable"
    assert main(["calibrate", str(recording_file), "-o", str(calibration), "--thresholds-mm", "2,1,3"]) == 1
