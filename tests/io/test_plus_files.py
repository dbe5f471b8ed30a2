import numpy as np
import pytest

from spacecal.core.errors import InvalidInputError
from spacecal.io.plus_config import (
    read_plus_landmarks,
    read_plus_transform,
    write_plus_coordinate_definitions,
)
from spacecal.io.plus_sequence import read_plus_sequence


def test_sequence_reader_parses_transforms_and_status(tmp_path):
    path = tmp_path / "s.igs.mha"
    path.write_text(
        "ObjectType = Image\nNDims = 3\nDimSize = 0 0 2\n"
        "Seq_Frame0000_MarkerToTrackerTransform = 1 0 0 10 0 1 0 20 0 0 1 30 0 0 0 1\n"
        "Seq_Frame0000_MarkerToTrackerTransformStatus = OK\nSeq_Frame0000_Timestamp = 1.5\n"
        "Seq_Frame0001_MarkerToTrackerTransform = 1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n"
        "Seq_Frame0001_MarkerToTrackerTransformStatus = INVALID\nSeq_Frame0001_Timestamp = 1.6\n"
        "ElementDataFile = LOCAL\n"
    )
    sequence = read_plus_sequence(path)
    stack = sequence.transform("MarkerToTracker")
    assert np.allclose(stack[0, :3, 3], [10, 20, 30]) and np.all(np.isnan(stack[1]))
    assert np.allclose(sequence.timestamps_s, [1.5, 1.6])
    with pytest.raises(InvalidInputError, match="has no StylusToTracker"):
        sequence.transform("StylusToTracker")


def test_bad_sequence_files(tmp_path):
    path = tmp_path / "x.mha"
    path.write_text("ObjectType = Image\n")
    with pytest.raises(InvalidInputError, match="not a PLUS sequence"):
        read_plus_sequence(path)
    with pytest.raises(InvalidInputError, match="no such"):
        read_plus_sequence(tmp_path / "none.mha")


def test_coordinate_definitions_round_trip(tmp_path):
    matrix = np.eye(4)
    matrix[:3, 3] = [1.5, -2.25, 1000.0]
    path = write_plus_coordinate_definitions(tmp_path / "c.xml", [(matrix, "Base", "Tracker", 0.25)])
    assert np.allclose(read_plus_transform(path, "Base", "Tracker"), matrix)
    text = path.read_text()
    assert 'Error="0.25"' in text and 'Date="' in text
    with pytest.raises(InvalidInputError, match="no TrackerToBase"):
        read_plus_transform(path, "Tracker", "Base")
    with pytest.raises(InvalidInputError, match="no <Landmark>"):
        read_plus_landmarks(path)
