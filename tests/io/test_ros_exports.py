"""ROS 2 static transform exports (command line, launch file, URDF joint) read back to the same 4x4."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from spacecal.core.errors import InvalidInputError
from spacecal.geometry.transforms import invert_transform, make_transform
from spacecal.io.ros_exports import (
    StaticTransform,
    calibration_static_transform,
    parse_static_transform_publisher,
    parse_urdf_joint,
    read_ros2_launch,
    read_urdf_joint,
    static_transform_publisher_command,
    write_ros2_launch,
    write_urdf_joint,
)

TRACKER_FROM_BASE = make_transform(
    Rotation.from_rotvec([0.2, -1.1, 0.4]).as_matrix(), [-150.0, 320.0, -1450.0]
)


def _random_transforms(count=20):
    rng = np.random.default_rng(7)
    rotations = Rotation.random(count, random_state=8).as_matrix()
    return [make_transform(r, rng.normal(0.0, 1000.0, 3)) for r in rotations]


def test_calibration_edge_is_base_to_tracker_carrying_base_from_tracker():
    edge = calibration_static_transform(TRACKER_FROM_BASE, base_frame="base", tracker_frame="polaris")
    assert (edge.parent_frame, edge.child_frame) == ("base", "polaris")
    assert np.allclose(edge.parent_from_child, invert_transform(TRACKER_FROM_BASE), atol=1e-12)
    # a point given in the tracker frame lands where the calibration says it is in base
    point_in_base = np.array([10.0, -20.0, 30.0, 1.0])
    assert np.allclose(edge.parent_from_child @ (TRACKER_FROM_BASE @ point_in_base), point_in_base)
    flipped = calibration_static_transform(TRACKER_FROM_BASE, parent="tracker")
    assert flipped.parent_frame == "tracker" and np.allclose(flipped.parent_from_child, TRACKER_FROM_BASE)
    with pytest.raises(InvalidInputError, match="expected 'base' or 'tracker'"):
        calibration_static_transform(TRACKER_FROM_BASE, parent="world")


def test_command_line_reads_back_and_uses_the_humble_flags():
    for matrix in _random_transforms():
        edge = StaticTransform("base", "tracker", matrix)
        text = static_transform_publisher_command(edge)
        assert text.startswith("# parent frame 'base', child frame 'tracker': the pose of tracker in base")
        command = text.splitlines()[1]
        assert command.startswith("ros2 run tf2_ros static_transform_publisher --x ")
        assert command.endswith("--frame-id base --child-frame-id tracker")
        back = parse_static_transform_publisher(text)
        assert (back.parent_frame, back.child_frame) == ("base", "tracker")
        assert np.max(np.abs(back.parent_from_child - matrix)) < 1e-9


def test_command_line_reader_takes_the_older_forms():
    # translation 1 m along x, yaw 90 deg: the old positional "x y z yaw pitch roll parent child"
    yaw = parse_static_transform_publisher("1 0 0 1.5707963267948966 0 0 a b")
    assert np.allclose(yaw.parent_from_child[:3, :3] @ [1, 0, 0], [0, 1, 0])
    assert np.allclose(yaw.parent_from_child[:3, 3], [1000.0, 0, 0])
    quaternion = parse_static_transform_publisher("0 0 0.5 0 0 0.7071067811865476 0.7071067811865476 a b")
    assert np.allclose(quaternion.parent_from_child[:3, 3], [0, 0, 500.0])
    assert np.allclose(quaternion.parent_from_child[:3, :3], yaw.parent_from_child[:3, :3])
    flags = parse_static_transform_publisher("--x 1 --yaw 1.5707963267948966 --frame-id a --child-frame-id b")
    assert np.allclose(flags.parent_from_child, yaw.parent_from_child)
    with pytest.raises(InvalidInputError, match="missing --child-frame-id"):
        parse_static_transform_publisher("--x 1 --frame-id a")
    with pytest.raises(InvalidInputError, match="quaternion norm"):
        parse_static_transform_publisher("--qx 1 --qw 1 --frame-id a --child-frame-id b")


def test_launch_file_reads_back_without_running_it(tmp_path):
    for k, matrix in enumerate(_random_transforms()):
        edge = calibration_static_transform(matrix, base_frame="base", tracker_frame="tracker")
        path = write_ros2_launch(tmp_path / f"calibration_{k}.launch.py", edge)
        text = path.read_text()
        assert (
            "parent frame 'base', child frame 'tracker'" in text and '"--child-frame-id", "tracker"' in text
        )
        compile(text, str(path), "exec")  # valid Python
        back = read_ros2_launch(path)
        assert (back.parent_frame, back.child_frame) == ("base", "tracker")
        assert np.max(np.abs(back.parent_from_child - edge.parent_from_child)) < 1e-9


def test_urdf_joint_reads_back_and_uses_urdf_rpy(tmp_path):
    for k, matrix in enumerate(_random_transforms()):
        edge = StaticTransform("base", "tracker", matrix)
        path = write_urdf_joint(tmp_path / f"j{k}.urdf.xacro", edge)
        back = read_urdf_joint(path)
        assert (back.parent_frame, back.child_frame) == ("base", "tracker")
        assert np.max(np.abs(back.parent_from_child - matrix)) < 1e-9
    # URDF rpy is fixed-axis roll (x), pitch (y), yaw (z): R = Rz(yaw) Ry(pitch) Rx(roll)
    snippet = (
        '<joint name="j" type="fixed"><parent link="p"/><child link="c"/>'
        '<origin xyz="0.001 0 0" rpy="1.5707963267948966 0 1.5707963267948966"/></joint>'
    )
    rotation = parse_urdf_joint(snippet).parent_from_child[:3, :3]
    rz = Rotation.from_rotvec([0, 0, np.pi / 2]).as_matrix()
    rx = Rotation.from_rotvec([np.pi / 2, 0, 0]).as_matrix()
    assert np.allclose(rotation, rz @ rx) and not np.allclose(rotation, rx @ rz)
    assert np.allclose(parse_urdf_joint(snippet).parent_from_child[:3, 3], [1.0, 0, 0])


def test_urdf_reader_picks_the_joint_and_says_which_exist():
    two = (
        '<joint name="a" type="fixed"><parent link="base"/><child link="tracker"/></joint>'
        '<joint name="b" type="fixed"><parent link="base"/><child link="camera"/></joint>'
    )
    with pytest.raises(InvalidInputError, match="found 2 .*children: tracker, camera"):
        parse_urdf_joint(two)
    assert parse_urdf_joint(two, child_frame="camera").child_frame == "camera"
    assert np.allclose(parse_urdf_joint(two, child_frame="tracker").parent_from_child, np.eye(4))
    with pytest.raises(InvalidInputError, match="not valid XML"):
        parse_urdf_joint("<joint")
