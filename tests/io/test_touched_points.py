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


def test_written_touches_read_back(tmp_path):
    from spacecal.io.touched_points import write_touched_points

    points = {"F-1": np.array([12.5, -40.25, -1510.0]), "F,2": np.array([1.0, 2.0, -1400.0])}
    path = write_touched_points(tmp_path / "t.csv", points, comments=["from a pointer\nsecond line"])
    frame, read = read_touched_points(path)
    assert frame == "tracker" and list(read) == list(points)
    assert all(np.allclose(read[k], points[k], atol=1e-4) for k in points)


@pytest.mark.parametrize(
    "points, match",
    [
        ({}, "no touched points"),
        ({"#F-1": [1.0, 2.0, -1000.0]}, "label"),
        ({"": [1.0, 2.0, -1000.0]}, "label"),
        ({"F-1": [1.0, float("nan"), -1000.0]}, "finite"),
        ({"F-1": [1.0, 2.0]}, "finite"),
        ({"F-1": [0.01, 0.02, -1.0]}, "metres"),
    ],
)
def test_bad_touches_are_not_written(tmp_path, points, match):
    from spacecal.io.touched_points import write_touched_points

    with pytest.raises(InvalidInputError, match=match):
        write_touched_points(tmp_path / "t.csv", points)
    assert not (tmp_path / "t.csv").exists()


def test_the_pointer_tip_accuracy_is_written_and_read_back(tmp_path):
    from spacecal.io.touched_points import read_touched_file, write_touched_points

    points = {"F-1": np.array([12.5, -40.25, -1510.0]), "F-2": np.array([1.0, 2.0, -1400.0])}
    path = write_touched_points(tmp_path / "t.csv", points, tip_accuracy_mm=0.35)
    assert path.read_text().splitlines()[0].endswith(",tip_accuracy_mm")
    touched = read_touched_file(path)
    assert touched.frame == "tracker" and list(touched.points) == list(points)
    assert touched.tip_accuracy_mm == pytest.approx(0.35)
    # without the column, no accuracy is stated
    assert read_touched_file(write_touched_points(tmp_path / "u.csv", points)).tip_accuracy_mm is None


@pytest.mark.parametrize(
    "cells, match",
    [("-0.1", "is not 0 to"), ("11", "is not 0 to"), ("nan", "not a finite number"), ("", "cells")],
)
def test_a_bad_tip_accuracy_is_refused_in_one_line(tmp_path, cells, match):
    from spacecal.io.touched_points import read_touched_file

    path = tmp_path / "t.csv"
    row = "F-1,1,2,-1500" + ("," + cells if cells else "")
    path.write_text(f"label,x_in_tracker_mm,y_in_tracker_mm,z_in_tracker_mm,tip_accuracy_mm\n{row}\n")
    with pytest.raises(InvalidInputError, match=match) as caught:
        read_touched_file(path)
    assert "\n" not in str(caught.value)


@pytest.mark.parametrize("accuracy", [-0.1, float("nan"), 10.5])
def test_a_bad_tip_accuracy_is_not_written(tmp_path, accuracy):
    from spacecal.io.touched_points import write_touched_points

    with pytest.raises(InvalidInputError, match="tip's accuracy"):
        write_touched_points(tmp_path / "t.csv", {"F-1": [1.0, 2.0, -1000.0]}, tip_accuracy_mm=accuracy)
    assert not (tmp_path / "t.csv").exists()
