"""Atomic writes keep the permissions a plain open() gives: 0o666 less the umask for a new file,
the old bits for a replaced one (tempfile.mkstemp's 0o600 kept Slicer, PLUS and ROS nodes running
as another user from reading the exports)."""

import contextlib
import os
import stat

import numpy as np
import pytest

from spacecal.core.errors import InvalidInputError
from spacecal.io.atomic import atomic_path, write_text_atomic
from spacecal.io.easy_handeye import write_easy_handeye2_calibration
from spacecal.io.plus_config import write_plus_coordinate_definitions
from spacecal.io.results_json import write_json
from spacecal.io.ros_exports import calibration_static_transform, write_ros2_launch, write_urdf_joint
from spacecal.io.slicer import write_slicer_transform
from spacecal.io.ur_driver_calibration import write_ur_calibration
from spacecal.models.robot_kinds import robot_kind

FRAMES = {
    "robot_base_frame": "base",
    "robot_effector_frame": "tool0",
    "tracking_base_frame": "tracker",
    "tracking_marker_frame": "marker",
}
EDGE = calibration_static_transform(np.eye(4))
WRITERS = {
    "slicer": lambda p: write_slicer_transform(np.eye(4), p / "t.tfm"),
    "plus": lambda p: write_plus_coordinate_definitions(p / "c.xml", [(np.eye(4), "Base", "Tracker", None)]),
    "launch": lambda p: write_ros2_launch(p / "c.launch.py", EDGE),
    "urdf": lambda p: write_urdf_joint(p / "c.urdf", EDGE),
    "easy_handeye2": lambda p: write_easy_handeye2_calibration(p / "c.calib", np.eye(4), **FRAMES),
    "ur_calibration": lambda p: write_ur_calibration(p / "k.yaml", robot_kind("UR10").model()),
    "json": lambda p: write_json({"a": 1}, p / "r.json"),
}


@contextlib.contextmanager
def umask(value):
    previous = os.umask(value)
    try:
        yield
    finally:
        os.umask(previous)


def _mode(path):
    return stat.S_IMODE(os.stat(path).st_mode)


@pytest.mark.parametrize("mask", [0o022, 0o077, 0o002, 0o000])
@pytest.mark.parametrize("writer", sorted(WRITERS))
def test_new_files_get_the_mode_open_would_give(tmp_path, writer, mask):
    with umask(mask):
        path = WRITERS[writer](tmp_path)
        with open(tmp_path / "plain.txt", "w") as handle:
            handle.write("x")
    assert _mode(path) == 0o666 & ~mask == _mode(tmp_path / "plain.txt")
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []  # no temporary left


def test_a_replaced_file_keeps_its_permission_bits(tmp_path):
    path = tmp_path / "out.txt"
    path.write_text("old")
    os.chmod(path, 0o640)
    with umask(0o077):
        write_text_atomic("new", path)
    assert path.read_text() == "new" and _mode(path) == 0o640


def test_an_interrupted_write_leaves_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "out.txt"
    path.write_text("old")
    with pytest.raises(RuntimeError), atomic_path(path) as temporary:
        temporary.write_text("half")
        raise RuntimeError("interrupted")
    assert path.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def test_a_nul_in_a_file_name_is_one_line(tmp_path):
    with pytest.raises(InvalidInputError, match="NUL"):
        write_text_atomic("x", str(tmp_path / "a\x00b.txt"))


def test_a_long_name_still_gets_a_temporary_beside_it(tmp_path):
    path = tmp_path / ("n" * 240 + ".tfm")
    write_slicer_transform(np.eye(4), path)
    assert path.is_file()
