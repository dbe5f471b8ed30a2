"""A recording is the file its calibration was made from: ``report``, ``verify``, ``check
--recording`` and ``bound`` refuse the calibration's own recording in one line once it changed
(an edit, or an acquisition written over it), unless ``--accept-edited``."""

from __future__ import annotations

import pytest

from spacecal import app
from spacecal.cli.main import main


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    folder = tmp_path_factory.mktemp("identity")
    recording, calibration = folder / "recording.csv", folder / "cal.json"
    app.simulate(app.SimulateSettings(output=str(recording), force=True))
    app.calibrate(app.CalibrateSettings(str(recording), str(calibration), "ml", force=True))
    return folder, recording, calibration


def commands(folder, calibration):
    return {
        "report": ["report", str(calibration), "-o", str(folder / "report.html"), "--force"],
        "check": ["check", str(calibration), "--recording", str(folder / "recording.csv")],
        "bound": ["bound", str(folder / "recording.csv"), "--calibration", str(calibration)],
        "verify": ["verify", str(calibration), "--points", "3"],
    }


def test_an_edited_recording_is_refused_in_one_line(calibrated, capsys):
    folder, recording, calibration = calibrated
    original = recording.read_bytes()
    for name, argv in commands(folder, calibration).items():
        assert main(argv) == 0, (name, capsys.readouterr().err)
    capsys.readouterr()
    lines = original.decode().split("\n")
    header = lines[0].split(",")
    column = header.index("marker_x_mm")
    cells = lines[5].split(",")
    cells[column] = repr(float(cells[column]) + 0.01)  # one sample's marker 0.01 mm aside
    lines[5] = ",".join(cells)
    recording.write_text("\n".join(lines))
    try:
        for name, argv in commands(folder, calibration).items():
            assert main(argv) == 1, name
            err = capsys.readouterr().err
            assert err.count("\n") == 1 and "changed since the calibration was made from it" in err, (
                name,
                err,
            )
            assert "--accept-edited" in err
        # said so, it is used anyway (each takes --accept-edited for its recording)
        for name in ("report", "check", "bound", "verify"):
            assert main([*commands(folder, calibration)[name], "--accept-edited"]) == 0, (
                name,
                capsys.readouterr().err,
            )
    finally:
        recording.write_bytes(original)
    assert main(commands(folder, calibration)["report"]) == 0
