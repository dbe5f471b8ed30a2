"""The touched-points CSV: frame in the column names, labels unique, numbers strict."""

import numpy as np
import pytest

from spacecal.core.errors import InvalidInputError
from spacecal.io.touched_points import read_touched_points


def test_a_touched_points_file_reads(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text(
        "# touched with the stylus\nlabel,x_in_tracker_mm,y_in_tracker_mm,z_in_tracker_mm\n"
        "F-1,1,2,-1500\nF-2,3,4,-1490.5\n"
    )
    frame, points = read_touched_points(path)
    assert frame == "tracker" and list(points) == ["F-1", "F-2"]
    assert np.array_equal(points["F-2"], [3, 4, -1490.5])
    path.write_text("label,x_in_reference_mm,y_in_reference_mm,z_in_reference_mm\nF-1,1,2,3\n")
    assert read_touched_points(path)[0] == "reference"


@pytest.mark.parametrize(
    "text, match",
    [
        ("label,x,y,z\nF-1,1,2,3\n", "the header must be"),
        (
            "label,x_in_tracker_mm,y_in_tracker_mm,z_in_tracker_mm\nF-1,1,2,-1500\nF-1,1,2,-1500\n",
            "touched twice",
        ),
        ("label,x_in_tracker_mm,y_in_tracker_mm,z_in_tracker_mm\nF-1,1,nan,-1500\n", "not a finite number"),
        ("label,x_in_tracker_mm,y_in_tracker_mm,z_in_tracker_mm\nF-1,0.01,0.02,-1.5\n", "metres"),
        ("label,x_in_tracker_mm,y_in_tracker_mm,z_in_tracker_mm\n,1,2,-1500\n", "no label"),
    ],
)
def test_bad_touched_points_are_refused_in_one_line(tmp_path, text, match):
    path = tmp_path / "t.csv"
    path.write_text(text)
    with pytest.raises(InvalidInputError, match=match) as caught:
        read_touched_points(path)
    assert "\n" not in str(caught.value)
