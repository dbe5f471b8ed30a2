"""``spacecal report`` through the app function and the command line: files in, a report
out, and a wrong file refused in one line."""

import json

import numpy as np
import pytest

from spacecal import app
from spacecal.cli.main import main
from spacecal.core.errors import InvalidInputError
from spacecal.records import PhantomResult


@pytest.fixture(scope="module")
def calibration_file(tmp_path_factory, recording_file):
    folder = tmp_path_factory.mktemp("app-report")
    out = app.calibrate(app.CalibrateSettings(str(recording_file), str(folder / "cal.json"), method="ml"))
    return out.files_written[0]


def phantom_file(folder):
    phantom = PhantomResult(
        np.array([0.4, 0.5]), np.array([0.6, 0.7]), np.array([0.2, 0.3]), [{}, {}], 0.2, "paper"
    )
    path = folder / "phantom.json"
    path.write_text(json.dumps(phantom.to_dict()))
    return path


def test_a_phantom_result_as_verification_is_one_clear_error(calibration_file, tmp_path, capsys):
    phantom = phantom_file(tmp_path)
    with pytest.raises(InvalidInputError, match="phantom experiment result"):
        app.report(
            app.ReportSettings(str(calibration_file), str(tmp_path / "r.html"), verification=str(phantom))
        )
    assert not (tmp_path / "r.html").exists()
    code = main(
        ["report", str(calibration_file), "--verification", str(phantom), "-o", str(tmp_path / "r.html")]
    )
    out, err = capsys.readouterr()
    assert code == 1 and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert "spacecal verify -o" in err


@pytest.mark.parametrize(
    "content, expected",
    [
        ({"schema": "spacecal.calibration", "schema_version": 2}, "a calibration"),
        ({"schema": "someone.else"}, "'someone.else'"),
        ({"hello": 1}, "not a spacecal result"),
    ],
)
def test_other_files_as_verification_are_named(calibration_file, tmp_path, content, expected):
    path = tmp_path / "other.json"
    path.write_text(json.dumps(content))
    with pytest.raises(InvalidInputError, match=expected):
        app.report(
            app.ReportSettings(str(calibration_file), str(tmp_path / "r.html"), verification=str(path))
        )


def test_png_dir_gets_every_figure(calibration_file, tmp_path):
    out = app.report(
        app.ReportSettings(str(calibration_file), str(tmp_path / "r.html"), png_dir=str(tmp_path / "png"))
    )
    html, *figures = out.files_written
    assert html == tmp_path / "r.html"
    assert [p.name for p in figures] == ["sweeps.png", "residuals.png", "uncertainty.png"]
    assert all(p.stat().st_size > 10_000 for p in figures)
