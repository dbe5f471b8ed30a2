import json

import numpy as np
import pytest

from spacecal.core.errors import InvalidInputError
from spacecal.estimators import calibrate
from spacecal.io.results_json import read_calibration, write_calibration


def test_calibration_round_trip(tmp_path, white_simulation):
    result = calibrate(white_simulation.recording)
    path = write_calibration(result, tmp_path / "cal.json")
    data = json.loads(path.read_text())
    assert {
        "tracker_from_base",
        "tcp_from_marker",
        "method",
        "sample_counts",
        "diagnostics",
        "schema_version",
    } <= set(data)
    again = read_calibration(path)
    assert np.array_equal(again.tracker_from_base, result.tracker_from_base)
    assert again.method == "paper" and again.sweep_fits.sphere.radius_mm > 0


@pytest.mark.parametrize(
    "edit,message",
    [
        (lambda d: d.pop("tracker_from_base"), "missing 'tracker_from_base'"),
        (lambda d: d.__setitem__("tcp_from_marker", [[1, 2], [3, 4]]), "not a 4x4 rigid"),
        (lambda d: d.__setitem__("schema_version", 99), "schema_version 99"),
    ],
)
def test_bad_calibration_files(tmp_path, white_simulation, edit, message):
    path = write_calibration(calibrate(white_simulation.recording), tmp_path / "cal.json")
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))
    with pytest.raises(InvalidInputError, match=message):
        read_calibration(path)
    path.write_text("{not json")
    with pytest.raises(InvalidInputError, match="not valid JSON"):
        read_calibration(path)
