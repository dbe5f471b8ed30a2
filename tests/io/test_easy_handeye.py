"""easy_handeye / easy_handeye2 files: results in both directions, samples re-solved by spacecal."""

import sys

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from spacecal.core.errors import InvalidInputError, MissingExtraError
from spacecal.estimators import calibrate
from spacecal.geometry.transforms import invert_transform, make_transform
from spacecal.io.easy_handeye import (
    easy_handeye2_samples_text,
    read_easy_handeye_calibration,
    read_easy_handeye_samples,
    write_easy_handeye2_calibration,
)
from spacecal.io.ros_common import transform_to_ros

TRACKER_FROM_BASE = make_transform(
    Rotation.from_rotvec([0.2, -1.1, 0.4]).as_matrix(), [-150.0, 320.0, -1450.0]
)
TCP_FROM_MARKER = make_transform(Rotation.from_rotvec([0.3, 0.1, -0.2]).as_matrix(), [20.0, -35.0, 90.0])
FRAMES = {
    "robot_base_frame": "base",
    "robot_effector_frame": "tool0_controller",
    "tracking_base_frame": "polaris",
    "tracking_marker_frame": "marker",
}


def _message(matrix):
    """A geometry_msgs/Transform as rosidl's message_to_ordereddict gives it (metres, x y z w)."""
    xyz, q = transform_to_ros(matrix)
    return {
        "translation": {"x": float(xyz[0]), "y": float(xyz[1]), "z": float(xyz[2])},
        "rotation": {"x": float(q[0]), "y": float(q[1]), "z": float(q[2]), "w": float(q[3])},
    }


def _parameters(kind="eye_on_base"):
    # field order of easy_handeye2_msgs/HandeyeCalibrationParameters
    return {
        "name": "spacecal_test",
        "calibration_type": kind,
        **FRAMES,
        "freehand_robot_movement": True,
        "move_group_namespace": "/",
        "move_group": "manipulator",
    }


def _as_easy_handeye2_writes(data) -> str:
    # rosidl_runtime_py.message_to_yaml: yaml.dump of the ordered fields, block style, no line wrapping
    return yaml.dump(data, width=sys.maxsize, sort_keys=False, default_flow_style=False)


def test_calib_round_trip_states_the_direction(tmp_path):
    path = write_easy_handeye2_calibration(tmp_path / "spacecal_test.calib", TRACKER_FROM_BASE, **FRAMES)
    text = path.read_text()
    assert "pose of polaris in base" in text and "base_from_tracker" in text
    back = read_easy_handeye_calibration(path)
    assert back.source == "easy_handeye2" and back.name == "spacecal_test"
    assert (back.calibration_type, back.parent_frame, back.child_frame) == ("eye_on_base", "base", "polaris")
    assert np.max(np.abs(back.parent_from_child - invert_transform(TRACKER_FROM_BASE))) < 1e-9
    assert np.max(np.abs(back.tracker_from_base - TRACKER_FROM_BASE)) < 1e-9


def test_our_calib_equals_one_written_the_easy_handeye2_way(tmp_path):
    # easy_handeye2 stores, for eye_on_base, robot_base_frame -> tracking_base_frame: base_from_tracker
    theirs = {"parameters": _parameters(), "transform": _message(invert_transform(TRACKER_FROM_BASE))}
    (tmp_path / "theirs.calib").write_text(_as_easy_handeye2_writes(theirs))
    ours = write_easy_handeye2_calibration(tmp_path / "spacecal_test.calib", TRACKER_FROM_BASE, **FRAMES)
    assert yaml.safe_load(ours.read_text()) == yaml.safe_load((tmp_path / "theirs.calib").read_text())
    a, b = read_easy_handeye_calibration(ours), read_easy_handeye_calibration(tmp_path / "theirs.calib")
    assert np.max(np.abs(a.tracker_from_base - b.tracker_from_base)) < 1e-12


def test_ros1_easy_handeye_results_both_layouts(tmp_path):
    xyz, q = transform_to_ros(invert_transform(TRACKER_FROM_BASE))
    transformation = dict(zip(["x", "y", "z", "qx", "qy", "qz", "qw"], [float(v) for v in [*xyz, *q]]))
    nested = {
        "parameters": {
            "namespace": "/my_eob_calib/",
            "eye_on_hand": False,
            "move_group": "manipulator",
            **FRAMES,
        },
        "transformation": transformation,
    }
    flat = {
        "eye_on_hand": False,
        "robot_base_frame": "/base",
        "tracking_base_frame": "/polaris",
        "transformation": transformation,
    }
    for name, data in (("nested", nested), ("flat", flat)):
        (tmp_path / f"{name}.yaml").write_text(yaml.dump(data, default_flow_style=False))
        result = read_easy_handeye_calibration(tmp_path / f"{name}.yaml")
        assert result.source == "easy_handeye" and result.parent_frame == "base"
        assert np.max(np.abs(result.tracker_from_base - TRACKER_FROM_BASE)) < 1e-9
    assert read_easy_handeye_calibration(tmp_path / "nested.yaml").name == "my_eob_calib"


def _samples(count=40, noise_mm=0.0):
    rng = np.random.default_rng(3)
    rotations = Rotation.from_rotvec(rng.normal(0.0, 0.5, (count, 3))) * Rotation.from_rotvec([np.pi, 0, 0])
    base_from_tcp = make_transform(rotations.as_matrix(), rng.normal([500.0, 0.0, 400.0], 120.0, (count, 3)))
    tracker_from_marker = TRACKER_FROM_BASE @ base_from_tcp @ TCP_FROM_MARKER
    tracker_from_marker[:, :3, 3] += rng.normal(0.0, noise_mm, (count, 3))
    return base_from_tcp, tracker_from_marker


def test_easy_handeye2_samples_are_re_solved_by_spacecal(tmp_path):
    base_from_tcp, tracker_from_marker = _samples()
    theirs = {
        "parameters": _parameters(),
        # the sampler's eye_on_base lookup_transform(effector, base) = effector_from_base
        "samples": [
            {"robot": _message(invert_transform(a)), "tracking": _message(b)}
            for a, b in zip(base_from_tcp, tracker_from_marker)
        ],
    }
    (tmp_path / "theirs.samples").write_text(_as_easy_handeye2_writes(theirs))
    recording = read_easy_handeye_samples(tmp_path / "theirs.samples")
    assert len(recording) == 40 and recording.metadata["frames"]["tracker"] == "polaris"
    assert np.max(np.abs(recording.base_from_tcp_stack - base_from_tcp)) < 1e-9
    assert np.max(np.abs(recording.tracker_from_marker_stack - tracker_from_marker)) < 1e-9
    result = calibrate(recording, "ml")
    assert np.max(np.abs(result.tracker_from_base - TRACKER_FROM_BASE)) < 1e-6
    assert np.max(np.abs(result.tcp_from_marker - TCP_FROM_MARKER)) < 1e-6

    ours = tmp_path / "ours.samples"
    ours.write_text(
        easy_handeye2_samples_text(base_from_tcp, tracker_from_marker, name="spacecal_test", **FRAMES)
    )
    assert yaml.safe_load(ours.read_text()) == yaml.safe_load((tmp_path / "theirs.samples").read_text())


def test_easy_handeye_ros1_sample_lists_are_re_solved(tmp_path):
    # what `rosservice call .../get_sample_list` prints: a SampleList under "samples"
    base_from_tcp, tracker_from_marker = _samples()
    sample_list = {
        "samples": {
            "hand_world_samples": [_message(invert_transform(a)) for a in base_from_tcp],
            "camera_marker_samples": [_message(b) for b in tracker_from_marker],
        }
    }
    (tmp_path / "ros1.yaml").write_text(yaml.safe_dump(sample_list))
    recording = read_easy_handeye_samples(tmp_path / "ros1.yaml")
    assert recording.metadata["source"] == "easy_handeye samples (ROS 1)"
    assert np.max(np.abs(recording.base_from_tcp_stack - base_from_tcp)) < 1e-9
    result = calibrate(recording, "ml")
    assert np.max(np.abs(result.tracker_from_base - TRACKER_FROM_BASE)) < 1e-6
    # the visp TransformArray form, without the "samples" wrapper
    visp = {key: {"transforms": value} for key, value in sample_list["samples"].items()}
    (tmp_path / "visp.yaml").write_text(yaml.safe_dump(visp))
    assert len(read_easy_handeye_samples(tmp_path / "visp.yaml")) == len(base_from_tcp)


def test_bad_easy_handeye_files_are_one_clear_line(tmp_path):
    eye_in_hand = {"parameters": _parameters("eye_in_hand"), "samples": []}
    (tmp_path / "eih.samples").write_text(_as_easy_handeye2_writes(eye_in_hand))
    with pytest.raises(InvalidInputError, match="eye_on_base"):
        read_easy_handeye_samples(tmp_path / "eih.samples")
    broken = {"parameters": _parameters(), "transform": {"translation": {"x": 0, "y": 0}, "rotation": {}}}
    (tmp_path / "broken.calib").write_text(_as_easy_handeye2_writes(broken))
    with pytest.raises(InvalidInputError, match=r"transform.translation: missing field 'z'"):
        read_easy_handeye_calibration(tmp_path / "broken.calib")
    (tmp_path / "other.yaml").write_text("a: 1\n")
    with pytest.raises(InvalidInputError, match="neither an easy_handeye2"):
        read_easy_handeye_calibration(tmp_path / "other.yaml")
    eih = {"parameters": _parameters("eye_in_hand"), "transform": _message(np.eye(4))}
    (tmp_path / "eih.calib").write_text(_as_easy_handeye2_writes(eih))
    result = read_easy_handeye_calibration(tmp_path / "eih.calib")
    assert result.parent_frame == "tool0_controller"
    with pytest.raises(InvalidInputError, match="no tracker_from_base"):
        _ = result.tracker_from_base


def test_reading_without_pyyaml_names_the_extra(monkeypatch, tmp_path):
    (tmp_path / "x.calib").write_text("a: 1\n")
    monkeypatch.setitem(sys.modules, "yaml", None)
    with pytest.raises(MissingExtraError, match=r"spacecal\[ros\]"):
        read_easy_handeye_calibration(tmp_path / "x.calib")
