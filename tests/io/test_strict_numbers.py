"""Numbers in files: the plain decimal forms only, in every reader (one parser for all).

Python's float() reads "1_000" as 1000.0 and "١٢" as 12.0, numpy reads both too; a data file
holding either is mistyped or mis-exported, and the readers say so in one line.
"""

import csv
import io
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from spacecal.core.errors import InvalidInputError
from spacecal.core.strict_numbers import parse_float, parse_floats, parse_int
from spacecal.geometry.transforms import make_transform
from spacecal.io.plus_config import read_plus_landmarks, read_plus_transform
from spacecal.io.plus_sequence import read_plus_sequence
from spacecal.io.pose_files import read_matrix_folder
from spacecal.io.raw_streams import read_raw_recording, write_raw_recording
from spacecal.io.recording_csv import last_time_s, read_recording, write_recording
from spacecal.io.results_json import read_json_object
from spacecal.io.slicer import read_slicer_transform, write_slicer_transform
from spacecal.records import RawRecording, Recording

#: Forms Python's float() (or numpy) accepts that a data file must not hold.
REFUSED = [
    "1_000",
    "1_0.5",
    "0x10",
    "0b11",
    "0o17",
    "\u0661\u0662",
    "\uff11",
    "1,5",
    "1.2.3",
    "",
    " ",
    ".",
    "e5",
    "1e",
    "--1",
    "+-1",
    "1e5_0",
    "\u00a01",
    "1\u2003",
    "inf_",
    "nann",
    "0x1p3",
    "1j",
    "1/2",
    "½",
    "²",
]
ACCEPTED = {
    "0": 0.0,
    "-12": -12.0,
    "+3": 3.0,
    "0.5": 0.5,
    ".5": 0.5,
    "5.": 5.0,
    "1e-05": 1e-05,
    "1.5E+3": 1500.0,
    " 2.5 ": 2.5,
    "\t7\t": 7.0,
    "007": 7.0,
    "-0.0": -0.0,
    "1.000000000000000000e+00": 1.0,
}


@pytest.mark.parametrize("text", REFUSED)
def test_refused_forms(text):
    with pytest.raises(ValueError):
        parse_float(text)
    with pytest.raises(ValueError):
        parse_floats(f"1 {text} 2" if text.strip() else "1 x")


@pytest.mark.parametrize("text,value", sorted(ACCEPTED.items()))
def test_accepted_forms(text, value):
    assert parse_float(text) == value


def test_non_finite_words_are_numbers_the_callers_refuse_by_name():
    assert np.isnan(parse_float("nan")) and parse_float("-Infinity") == -np.inf
    assert parse_int("42") == 42 and parse_int("-7") == -7
    for text in ("1_0", "4" * 5000, "0x1", "\u0661"):
        with pytest.raises(ValueError):
            parse_int(text)


def _poses(count, seed):
    rng = np.random.default_rng(seed)
    rotations = Rotation.random(count, random_state=seed).as_matrix()
    return np.array([make_transform(r, rng.uniform(-400, 400, 3)) for r in rotations])


def _recording(count=12):
    return Recording(
        time_s=np.arange(count) * 0.1,
        segment=np.array(["static"] * count),
        joints_rad=np.full((count, 6), np.nan),
        base_from_tcp_stack=_poses(count, 1),
        tracker_from_marker_stack=_poses(count, 2),
        marker_rms_mm=np.full(count, 0.1),
    )


def _replace_cell(path, line, column, value):
    rows = list(csv.reader(io.StringIO(path.read_text(), newline="")))
    rows[line - 1][rows[0].index(column)] = value
    out = io.StringIO()
    csv.writer(out).writerows(rows)
    path.write_text(out.getvalue())


def _one_line_refusal(call, *patterns):
    with pytest.raises(InvalidInputError) as caught:
        call()
    message = str(caught.value)
    assert "\n" not in message
    for pattern in patterns:
        assert pattern in message, message
    return message


@pytest.mark.parametrize("column", ["time_s", "tcp_x_mm", "marker_qw", "marker_rms_mm"])
def test_recording_csv_refuses_digit_groups(tmp_path, column):
    path = write_recording(_recording(), tmp_path / "rec.csv")
    assert len(read_recording(path)) == 12
    _replace_cell(path, 5, column, "1_000")
    _one_line_refusal(lambda: read_recording(path), "line 5", column, "'1_000'", "'_'")


def test_recording_resume_time_skips_a_grouped_number(tmp_path):
    path = write_recording(_recording(), tmp_path / "rec.csv")
    _replace_cell(path, 13, "time_s", "1_100")
    assert last_time_s(path) == pytest.approx(1.0)  # the row before: 1_100 is not a time


def _raw_recording() -> RawRecording:
    """The test recording as raw streams (the tracker on the robot's clock)."""
    return RawRecording.from_paired(_recording(), metadata={})


def test_raw_streams_refuse_digit_groups(tmp_path):
    raw = _raw_recording()
    robot, tracker = write_raw_recording(raw, tmp_path / "raw")
    read_raw_recording(robot, tracker)
    _replace_cell(tracker, 3, "marker_x_mm", "1_00.5")
    _one_line_refusal(lambda: read_raw_recording(robot, tracker), "marker_x_mm", "'1_00.5'")
    write_raw_recording(raw, tmp_path / "raw")
    _replace_cell(robot, 4, "tcp_qx", "\u0660.5")  # an Arabic-Indic zero
    _one_line_refusal(lambda: read_raw_recording(robot, tracker), "tcp_qx")


def test_raw_streams_refuse_a_value_beyond_the_last_column(tmp_path):
    raw = _raw_recording()
    robot, tracker = write_raw_recording(raw, tmp_path / "raw")
    lines = robot.read_text().splitlines()
    lines[3] += ",12345"
    robot.write_text("\n".join(lines) + "\n")
    _one_line_refusal(lambda: read_raw_recording(robot, tracker), "line 4 does not have the header's")


def test_pose_folder_refuses_digit_groups(tmp_path):
    folder = tmp_path / "poses"
    folder.mkdir()
    for k, pose in enumerate(_poses(3, 4)):
        np.savetxt(folder / f"p{k}.txt", pose)
    assert np.allclose(read_matrix_folder(folder), _poses(3, 4))
    (folder / "p1.txt").write_text("1 0 0 1_000\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    _one_line_refusal(lambda: read_matrix_folder(folder), "p1.txt", "line 1", "1_000")
    (folder / "p1.txt").write_text("# a comment\n1 0 0 10 # x\n0 1 0 0\n\n0 0 1 0\n0 0 0 1\n")
    assert read_matrix_folder(folder)[1][0, 3] == 10.0
    (folder / "p1.txt").write_text("1 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    _one_line_refusal(lambda: read_matrix_folder(folder), "rows of different lengths")


SEQUENCE = (
    "ObjectType = Image\nNDims = 3\nDimSize = 0 0 2\n"
    "Seq_Frame0000_MarkerToTrackerTransform = {matrix}\n"
    "Seq_Frame0000_Timestamp = {time}\n"
    "Seq_Frame0001_MarkerToTrackerTransform = 1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n"
    "Seq_Frame0001_Timestamp = 1.6\n"
)


@pytest.mark.parametrize(
    "matrix,time,pattern",
    [
        ("1 0 0 1_0 0 1 0 0 0 0 1 0 0 0 0 1", "1.5", "frame 0 MarkerToTrackerTransform"),
        ("1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1", "1_5", "timestamp is not a number"),
        ("1 0 0 0x1 0 1 0 0 0 0 1 0 0 0 0 1", "1.5", "not a number"),
    ],
)
def test_plus_sequence_refuses_digit_groups(tmp_path, matrix, time, pattern):
    path = tmp_path / "s.igs.mha"
    path.write_text(SEQUENCE.format(matrix="1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1", time="1.5"))
    assert read_plus_sequence(path).timestamps_s[0] == 1.5
    path.write_text(SEQUENCE.format(matrix=matrix, time=time))
    _one_line_refusal(lambda: read_plus_sequence(path), pattern)


def test_plus_sequence_frame_numbers_are_bounded(tmp_path):
    path = tmp_path / "s.igs.mha"
    path.write_text("Seq_Frame" + "9" * 5000 + "_Timestamp = 1\n")  # int() of it would raise
    _one_line_refusal(lambda: read_plus_sequence(path), "not a PLUS sequence")


def test_plus_configuration_refuses_digit_groups(tmp_path):
    path = tmp_path / "c.xml"
    path.write_text(
        '<PlusConfiguration><CoordinateDefinitions><Transform From="A" To="B" '
        'Matrix="1 0 0 1_0 0 1 0 0 0 0 1 0 0 0 0 1"/></CoordinateDefinitions>'
        '<Landmarks><Landmark Name="L1" Position="1_0 2 3"/></Landmarks></PlusConfiguration>'
    )
    _one_line_refusal(lambda: read_plus_transform(path, "A", "B"), "16 finite numbers")
    _one_line_refusal(lambda: read_plus_landmarks(path), "'L1'", "'1_0 2 3'")


def test_slicer_transform_refuses_digit_groups(tmp_path):
    path = write_slicer_transform(_poses(1, 5)[0], tmp_path / "t.tfm")
    assert np.allclose(read_slicer_transform(path), _poses(1, 5)[0])
    text = path.read_text().replace("Parameters: ", "Parameters: 1_0", 1)
    path.write_text(text)
    _one_line_refusal(lambda: read_slicer_transform(path), "plain decimal numbers")
    path.write_text(text.replace("1_0", "").replace("FixedParameters: 0 0 0", "FixedParameters: 0 nan 0"))
    _one_line_refusal(lambda: read_slicer_transform(path), "not finite")


def test_json_refuses_integers_int_cannot_read(tmp_path):
    path = tmp_path / "x.json"
    path.write_text(json.dumps({"a": 1}).replace("1", "1" * 5000))
    _one_line_refusal(lambda: read_json_object(path, "calibration"), "5000 digits")
