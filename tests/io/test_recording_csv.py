import numpy as np
import pytest

from spacecal.core.errors import InvalidInputError
from spacecal.io.csv_core import metadata_path
from spacecal.io.recording_csv import COLUMNS, STATUS_COLUMN, RecordingWriter, read_recording, write_recording


def test_round_trip_is_exact(tmp_path, white_simulation):
    original = white_simulation.recording
    path = write_recording(original, tmp_path / "rec.csv")
    again = read_recording(path)
    assert np.array_equal(again.time_s, original.time_s)
    assert list(again.segment) == list(original.segment)
    assert np.allclose(again.base_from_tcp_stack, original.base_from_tcp_stack, atol=1e-12)
    seen = original.visible
    assert np.array_equal(again.visible, seen)
    assert np.allclose(
        again.tracker_from_marker_stack[seen], original.tracker_from_marker_stack[seen], atol=1e-12
    )
    assert again.metadata["robot"]["model"] == "UR10"
    assert metadata_path(path).name == "rec.meta.json"


def test_header_is_exactly_the_documented_columns(recording_file):
    header = recording_file.read_text().splitlines()[0].split(",")
    assert header == COLUMNS + [STATUS_COLUMN]


def test_extra_columns_are_ignored(tmp_path, recording_file):
    lines = recording_file.read_text().splitlines()
    lines = [lines[0] + ",operator_note"] + [line + ",hello" for line in lines[1:]]
    path = tmp_path / "extra.csv"
    path.write_text("\n".join(lines) + "\n")
    assert len(read_recording(path)) == len(lines) - 1


def test_each_row_reaches_disk_before_the_next(tmp_path, white_simulation):
    rec = white_simulation.recording
    path = tmp_path / "live.csv"
    writer = RecordingWriter(path)
    for k in range(12):
        writer.append(
            rec.time_s[k],
            rec.segment[k],
            rec.joints_rad[k],
            rec.base_from_tcp_stack[k],
            rec.tracker_from_marker_stack[k],
            rec.marker_rms_mm[k],
        )
        assert len(path.read_text().splitlines()) == k + 2  # readable while still open
    assert len(read_recording(path)) == 12  # a reader gets every row even without close()
    writer.close()


def mutate(recording_file, tmp_path, edit):
    lines = recording_file.read_text().splitlines()
    header, rows = lines[0].split(","), [line.split(",") for line in lines[1:]]
    header, rows = edit(header, rows)
    path = tmp_path / "bad.csv"
    path.write_text("\n".join([",".join(header)] + [",".join(r) for r in rows]) + "\n")
    return path


def col(header, name):
    return header.index(name)


def set_cell(name, value, row=5):
    def edit(header, rows):
        rows[row][col(header, name)] = value
        return header, rows

    return edit


def scale_columns(names, factor):
    def edit(header, rows):
        for r in rows:
            for name in names:
                if r[col(header, name)]:
                    r[col(header, name)] = repr(float(r[col(header, name)]) * factor)
        return header, rows

    return edit


def blank_marker(header, rows):
    for r in rows:
        for name in COLUMNS[-8:]:
            r[col(header, name)] = ""
    return header, rows


def swap_times(header, rows):
    i = col(header, "time_s")
    rows[7][i], rows[8][i] = rows[8][i], rows[7][i]
    return header, rows


BAD_INPUTS = {
    "missing column": (
        lambda h, r: ([c for c in h if c != "tcp_qz"], [row[:-9] + row[-8:] for row in r]),
        "missing column.*tcp_qz",
    ),
    "misspelt column": (
        lambda h, r: ([("q3_deg" if c == "q3_rad" else c) for c in h], r),
        "missing column.*q3_rad \\(found 'q3_deg'\\?\\)",
    ),
    "NaN cell": (set_cell("q3_rad", "nan"), "line 7, column q3_rad: 'nan' is not a finite number"),
    "text cell": (set_cell("tcp_y_mm", "abc"), "line 7, column tcp_y_mm: 'abc' is not a number"),
    "non-monotonic time": (swap_times, "time_s is not increasing at line 10"),
    "non-unit quaternion": (set_cell("marker_qw", "1.3"), "line 7: marker quaternion has norm"),
    "metres": (scale_columns(["tcp_x_mm", "tcp_y_mm", "tcp_z_mm"], 1e-3), "look like metres"),
    "too few samples": (lambda h, r: (h, r[:4]), "has 4 samples; at least 10"),
    "all invisible": (blank_marker, "marker was not visible in any"),
    "partly empty marker": (set_cell("marker_qx", ""), "marker cells are partly empty"),
    "a value beyond the last column": (
        lambda h, r: (h, [row + ["12345"] if k == 5 else row for k, row in enumerate(r)]),
        "line 7 has .* cells; the header has",
    ),
    "a cell short": (
        lambda h, r: (h, [row[:-1] if k == 5 else row for k, row in enumerate(r)]),
        "line 7 has .* cells; the header has",
    ),
}


def test_an_empty_cell_beyond_the_last_column_is_nothing(recording_file, tmp_path):
    """A spreadsheet's trailing comma adds an empty cell; it holds no value to misplace."""
    trailing = mutate(recording_file, tmp_path, lambda h, r: (h, [row + [""] for row in r]))
    assert len(read_recording(trailing)) == len(read_recording(recording_file))


@pytest.mark.parametrize("case", sorted(BAD_INPUTS))
def test_bad_input_names_the_problem(case, recording_file, tmp_path):
    edit, message = BAD_INPUTS[case]
    with pytest.raises(InvalidInputError, match=message):
        read_recording(mutate(recording_file, tmp_path, edit))


def test_empty_and_missing_files(tmp_path):
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    with pytest.raises(InvalidInputError, match="empty"):
        read_recording(empty)
    with pytest.raises(InvalidInputError, match="no such recording"):
        read_recording(tmp_path / "nope.csv")


def test_raw_sphere_columns_round_trip(tmp_path):
    import dataclasses

    from spacecal.experiments.simulation import simulate
    from spacecal.sim.scenario import PRESETS

    simulation = simulate(
        dataclasses.replace(
            PRESETS["paper-white"], record_spheres=True, rotation_deg=30.0, translation_mm=200.0
        )
    )
    path = write_recording(simulation.recording, tmp_path / "spheres.csv")
    assert "sphere4_z_mm" in path.read_text().splitlines()[0]
    again = read_recording(path)
    seen = simulation.recording.visible
    assert np.array_equal(again.spheres_in_tracker[seen], simulation.recording.spheres_in_tracker[seen])
    assert np.all(np.isnan(again.spheres_in_tracker[~seen]))


def _seven_joint_recording():
    """A recording of a seven-joint arm (a KUKA LBR iiwa): joints, TCP poses, marker poses."""
    from spacecal.geometry.transforms import axis_angle_transform
    from spacecal.models.kinematics import RobotModel, forward_kinematics
    from spacecal.records import Recording
    from spacecal.records.calibration import robot_model_to_dict

    model = RobotModel(
        name="iiwa7",
        a_mm=np.zeros(7),
        d_mm=np.array([340.0, 0.0, 400.0, 0.0, 400.0, 0.0, 126.0]),
        alpha_rad=np.radians([-90.0, 90.0, 90.0, -90.0, -90.0, 90.0, 0.0]),
    )
    rng = np.random.default_rng(5)
    joints = rng.uniform(-1.5, 1.5, (12, 7))
    tcp = forward_kinematics(model, joints)
    tracker_from_base = axis_angle_transform([0, 0, 1], 30.0, [100.0, -2000.0, 300.0])
    marker = tracker_from_base @ tcp
    return Recording(
        time_s=np.arange(12.0),
        segment=np.full(12, "poses"),
        joints_rad=joints,
        base_from_tcp_stack=tcp,
        tracker_from_marker_stack=marker,
        marker_rms_mm=np.full(12, 0.1),
        metadata={"robot": {"model": "iiwa7", "kinematic_model": robot_model_to_dict(model)}},
    )


def test_a_seven_joint_recording_round_trips(tmp_path):
    original = _seven_joint_recording()
    path = write_recording(original, tmp_path / "iiwa.csv")
    header = path.read_text().splitlines()[0].split(",")
    assert header[2:9] == [f"q{i}_rad" for i in range(1, 8)]
    again = read_recording(path)
    assert np.array_equal(again.joints_rad, original.joints_rad)
    assert np.allclose(again.base_from_tcp_stack, original.base_from_tcp_stack, atol=1e-12)
    from spacecal.estimators.methods.recorded_model import nominal_robot_model

    assert nominal_robot_model(again).n_joints == 7


def test_seven_joint_raw_streams_round_trip(tmp_path):
    from spacecal.io.raw_streams import read_raw_recording, write_raw_recording
    from spacecal.records import RawRecording

    paired = _seven_joint_recording()
    raw = RawRecording(
        robot_time_s=paired.time_s,
        robot_segment=paired.segment,
        joints_rad=paired.joints_rad,
        base_from_tcp_stack=paired.base_from_tcp_stack,
        tracker_time_s=paired.time_s + 0.01,
        tracker_from_marker_stack=paired.tracker_from_marker_stack,
        marker_rms_mm=paired.marker_rms_mm,
        metadata=paired.metadata,
    )
    robot, tracker = write_raw_recording(raw, tmp_path / "iiwa")
    again = read_raw_recording(robot, tracker)
    assert np.array_equal(again.joints_rad, raw.joints_rad)


def test_a_writer_refuses_joint_angles_of_another_arm(tmp_path):
    with RecordingWriter(tmp_path / "r.csv", None, 0) as writer:
        with pytest.raises(InvalidInputError, match="7 joint angles for a recording of 6 joints"):
            writer.append(0.0, "s", np.zeros(7), np.eye(4))


def test_joint_columns_that_do_not_match_the_named_ur_arm_are_refused(tmp_path):
    recording = _seven_joint_recording()
    recording.metadata = {"robot": {"model": "UR10"}}
    path = write_recording(recording, tmp_path / "wrong.csv")
    with pytest.raises(InvalidInputError, match="7 joint columns and its robot, a UR10, 6 joints"):
        read_recording(path)
