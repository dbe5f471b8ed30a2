"""TUM trajectory files: exact round trips, the frames of an import, and one line for each bad file."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from spacecal.core.errors import InvalidInputError
from spacecal.geometry.transforms import make_transform
from spacecal.io import tum
from spacecal.io.tum import raw_recording_from_tum, read_tum, tum_text, write_tum

EPOCH_S = 1_700_000_000.0  # a Unix time, as SLAM tools and ROS stamp their poses


def poses(count, seed=0, reach_mm=800.0):
    rng = np.random.default_rng(seed)
    rotations = Rotation.random(count, random_state=rng).as_matrix()
    return make_transform(rotations, rng.uniform(-reach_mm, reach_mm, size=(count, 3)))


def times(count, seed=0):
    return EPOCH_S + np.cumsum(np.random.default_rng(seed).uniform(0.001, 0.05, size=count))


@pytest.mark.parametrize("units", ["m", "mm"])
def test_round_trip_is_exact(tmp_path, units):
    stack, time_s = poses(200), times(200)
    path = write_tum(tmp_path / "poses.tum", time_s, stack, units, comments=("robot base_from_tcp",))
    read = read_tum(path, units)
    assert np.array_equal(read.time_s, time_s)
    # the translation is scaled by 1000 and back: equal to the last bit or two
    assert np.max(np.abs(read.world_from_body_stack - stack)) < 1e-12 * 800
    assert read.normalised == 0 and read.units == units and read.path == path
    assert list(read.lines[:2]) == [3, 4]  # after the comment and the column line
    text = path.read_text().splitlines()
    assert text[0] == "# robot base_from_tcp" and text[1].startswith(tum.COLUMNS_LINE)


def test_what_tum_files_in_the_wild_hold(tmp_path):
    """evo and the TUM RGB-D ground truth: comments, four-decimal quaternions, tabs, CRLF,
    trailing comments, blank lines; the units and the quaternion order as the format says."""
    path = tmp_path / "groundtruth.txt"
    path.write_bytes(
        b"# ground truth trajectory\r\n# timestamp tx ty tz qx qy qz qw\r\n\r\n"
        b"1305031098.6659 1.3563\t0.6305 1.6380 0.6132 0.5962 -0.3311 -0.3986\r\n"
        b"1305031098.6758 1.3543 0.6306 1.6360 0.6129 0.5966 -0.3316 -0.3980  # a note\r\n"
    )
    read = read_tum(path)
    assert read.lines.tolist() == [4, 5] and read.normalised == 2
    assert read.time_s[0] == 1305031098.6659
    assert np.allclose(read.world_from_body_stack[0, :3, 3], [1356.3, 630.5, 1638.0])
    quaternion_xyzw = np.array([0.6132, 0.5962, -0.3311, -0.3986])
    expected = Rotation.from_quat(quaternion_xyzw / np.linalg.norm(quaternion_xyzw)).as_matrix()
    assert np.allclose(read.world_from_body_stack[0, :3, :3], expected, atol=1e-15)


def test_a_tum_file_states_its_frames_units_and_order():
    text = tum_text([0.5], make_transform(np.eye(3), [1000.0, -2.0, 3.5])[None])
    assert text.splitlines()[-1] == "0.5 1.0 -0.002 0.0035 0.0 0.0 0.0 1.0"
    assert "world_from_body" in text and "(s, m," in text
    with pytest.raises(InvalidInputError, match="strictly increasing"):
        tum_text([1.0, 1.0], poses(2))
    with pytest.raises(InvalidInputError, match="units must be one of m, mm"):
        tum_text([1.0], poses(1), units="cm")


GOOD = "1.0 0.1 0.2 0.3 0 0 0 1\n"
BAD_LINES = {
    "separator": ("2.0 1_000 0.2 0.3 0 0 0 1", "line 2: tx '1_000' is not a plain number"),
    "nan": ("2.0 0.1 nan 0.3 0 0 0 1", "line 2: ty 'nan' is not a finite number"),
    "inf": ("2.0 0.1 0.2 -inf 0 0 0 1", "line 2: tz '-inf' is not a finite number"),
    "overflow": ("2.0 0.1 0.2 1e999 0 0 0 1", "line 2: tz 1e999 overflows"),
    "hex": ("2.0 0x10 0.2 0.3 0 0 0 1", "line 2: tx '0x10' is not a plain number"),
    "absurd translation": ("2.0 0.1 2e6 0.3 0 0 0 1", r"line 2: translation 2e\+06 m is beyond \+-1e\+06 m"),
    "nanoseconds": ("1403636579758555392 0.1 0.2 0.3 0 0 0 1", "line 2: timestamp .* nanoseconds"),
    "non-unit quaternion": ("2.0 0.1 0.2 0.3 0 0 0 0.5", "line 2: quaternion qx qy qz qw has norm 0.5"),
    "zero quaternion": ("2.0 0.1 0.2 0.3 0 0 0 0", "line 2: quaternion qx qy qz qw has norm 0"),
    "duplicate time": (
        "1.0 0.1 0.2 0.3 0 0 0 1",
        r"line 2: timestamp 1.0 repeats the previous pose's \(1.0, line 1\)",
    ),
    "time going back": ("0.5 0.1 0.2 0.3 0 0 0 1", "line 2: timestamp 0.5 is before the previous"),
    "seven columns": ("2.0 0.1 0.2 0.3 0 0 1", "line 2: 7 columns; a TUM line has 8"),
    "nine columns": ("2.0 0.1 0.2 0.3 0 0 0 1 7", "line 2: 9 columns; a TUM line has 8"),
    "commas": ("2.0,0.1,0.2,0.3,0,0,0,1", "line 2: commas"),
    "header without #": (
        "timestamp tx ty tz qx qy qz qw",
        "line 2: timestamp 'timestamp' .* must start with #",
    ),
}


@pytest.mark.parametrize("name", list(BAD_LINES))
def test_each_malformed_line_is_one_line_naming_file_and_line(tmp_path, name):
    line, message = BAD_LINES[name]
    path = tmp_path / "bad.tum"
    path.write_text(GOOD + line + "\n" + "3.0 0.1 0.2 0.3 0 0 0 1\n")
    with pytest.raises(InvalidInputError, match=message) as info:
        read_tum(path)
    assert str(info.value).startswith(f"{path}: ") and "\n" not in str(info.value)


def test_files_that_are_not_trajectories(tmp_path, monkeypatch):
    empty = tmp_path / "empty.tum"
    empty.write_text("# nothing but a comment\n\n")
    with pytest.raises(InvalidInputError, match="no poses"):
        read_tum(empty)
    with pytest.raises(InvalidInputError, match="no such robot TUM trajectory file"):
        read_tum(tmp_path / "missing.tum", what="robot TUM trajectory")
    packed = tmp_path / "poses.tum.gz"
    packed.write_bytes(b"\x1f\x8b\x08\x00rest")
    with pytest.raises(InvalidInputError, match="gzip"):
        read_tum(packed)
    big = write_tum(tmp_path / "big.tum", np.arange(50.0), poses(50))
    monkeypatch.setattr(tum, "MAX_TUM_BYTES", 1000)
    with pytest.raises(InvalidInputError, match="too large for a TUM trajectory"):
        read_tum(big)
    monkeypatch.setattr(tum, "MAX_TUM_BYTES", 10**9)
    monkeypatch.setattr(tum, "MAX_POSES", 20)
    with pytest.raises(InvalidInputError, match="more than 20 poses"):
        read_tum(big)
    with pytest.raises(InvalidInputError, match="units must be one of m, mm, got 'inch'"):
        read_tum(big, units="inch")


def test_the_import_keeps_each_clock_and_the_frames(tmp_path):
    robot_path = write_tum(tmp_path / "robot.tum", times(30), poses(30, seed=1))
    tracker_path = write_tum(tmp_path / "tracker.tum", times(12, seed=2) - 300.0, poses(12, seed=2))
    robot, tracker = read_tum(robot_path), read_tum(tracker_path)
    raw = raw_recording_from_tum(robot, tracker)
    # both clocks counted from the earlier first stamp: the 300 s between them are kept
    origin = tracker.time_s[0]
    assert raw.metadata["tum"]["time_origin_s"] == origin
    assert np.array_equal(raw.robot_time_s, robot.time_s - origin)
    assert np.array_equal(raw.tracker_time_s, tracker.time_s - origin)
    assert np.array_equal(raw.base_from_tcp_stack, robot.world_from_body_stack)
    assert np.array_equal(raw.tracker_from_marker_stack, tracker.world_from_body_stack)
    assert np.all(np.isnan(raw.joints_rad)) and np.all(np.isnan(raw.marker_rms_mm))
    meta = raw.metadata
    assert meta["source"] == "TUM import" and meta["units"]["length"] == "mm"
    assert meta["tum"]["units"] == {"robot": "m", "tracker": "m"} and meta["tum"]["eye_in_hand"] is False
    assert meta["tum"]["robot_file"] == str(robot_path) and meta["tracker"]["pose_only"] is True
    assert "tracker_from_marker" in meta["tum"]["tracker_poses"] and "frames" not in meta
    # trajectories made in memory (no file) are named as such
    unnamed = raw_recording_from_tum(dataclasses.replace(robot, path=None), tracker).metadata
    assert unnamed["tum"]["robot_file"] is None and unnamed["robot"]["name"].startswith(
        "poses from a trajectory"
    )
    # eye-in-hand: the camera's trajectory in the target goes in as it is, the frames say so
    eye = raw_recording_from_tum(robot, tracker, eye_in_hand=True)
    assert np.array_equal(eye.tracker_from_marker_stack, tracker.world_from_body_stack)
    assert eye.metadata["tum"]["eye_in_hand"] is True
    assert eye.metadata["tum"]["tracker_poses"].startswith("target_from_camera")
    assert eye.metadata["frames"]["tracker"].startswith("target") and eye.metadata["frames"][
        "marker"
    ].startswith("camera")


def test_an_import_refuses_too_few_poses_and_the_wrong_units(tmp_path):
    robot = read_tum(write_tum(tmp_path / "robot.tum", times(30), poses(30)))
    few = read_tum(write_tum(tmp_path / "few.tum", times(9), poses(9)))
    with pytest.raises(InvalidInputError, match="few.tum: 9 poses; at least 10"):
        raw_recording_from_tum(robot, few)
    # a file in mm read as metres: 800 mm became 800 m
    as_metres = read_tum(write_tum(tmp_path / "mm.tum", times(30), poses(30), units="mm"))
    with pytest.raises(InvalidInputError, match=r"mm.tum: line 2: translation .* m is beyond .*--units mm"):
        raw_recording_from_tum(as_metres, robot)
    # a file in metres read as mm: a reach of 0.8 mm
    as_mm = read_tum(write_tum(tmp_path / "m.tum", times(30), poses(30)), units="mm")
    with pytest.raises(
        InvalidInputError, match="m.tum: every translation is below 5 mm.*leave out --units mm"
    ):
        raw_recording_from_tum(robot, as_mm)
