"""Names written into other tools' files: checked against each tool's rule before anything is
written, and written through escaping writers (ElementTree for XML, literals for Python)."""

import ast
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from spacecal.app.ros import RosExportSettings, export_ros
from spacecal.core.errors import InvalidInputError
from spacecal.io.names import (
    check_calibration_name,
    check_plus_frame_names,
    check_ros_frame_name,
    check_ros_node_name,
    plus_to_count,
)
from spacecal.io.plus_config import plus_coordinate_definition, read_plus_transform
from spacecal.io.ros_exports import (
    StaticTransform,
    calibration_static_transform,
    parse_static_transform_publisher,
    parse_urdf_joint,
    read_ros2_launch,
    ros2_launch_text,
    static_transform_publisher_command,
    urdf_joint_text,
    write_ros2_launch,
)

GOOD_FRAMES = ["base", "base_link", "tool0", "ur/base", "_private", "a/b/c", "A1_b2", "x" * 100]
BAD_FRAMES = {
    "": "empty",
    "/base": "cannot start with '/'",
    "base/": "'/' must separate",
    "a//b": "'/' must separate",
    "0base": "must not start with a digit",
    "ur/0base": "must not start with a digit",
    "base link": "' ' is not allowed",
    "base-link": "'-' is not allowed",
    "caf\u00e9": "is not allowed",
    "x" * 101: "longer than 100",
    'x"""+__import__("os").system("id")+"""': "is not allowed",
    "a\nb": "is not allowed",
    "a<b": "is not allowed",
    "a&b": "is not allowed",
    "~/private": "is not allowed",
    "{sub}": "is not allowed",
}


@pytest.mark.parametrize("name", GOOD_FRAMES)
def test_ros_frame_names_accepted(name):
    assert check_ros_frame_name(name, "--tracker-frame") == name


@pytest.mark.parametrize("name,why", sorted(BAD_FRAMES.items()))
def test_ros_frame_names_refused_naming_the_option(name, why):
    with pytest.raises(InvalidInputError) as caught:
        check_ros_frame_name(name, "--tracker-frame")
    message = str(caught.value)
    assert message.startswith("--tracker-frame ") and why in message and "\n" not in message
    assert len(message) < 400


def test_node_and_calibration_names():
    assert check_ros_node_name("base_to_tracker_calibration")
    for bad in ("a/b", "1a", "", "a-b", "a b"):
        with pytest.raises(InvalidInputError):
            check_ros_node_name(bad)
    for good in ("calibration", "my-cal.v2", "2024_run", "A"):
        assert check_calibration_name(good) == good
    for bad in ("", ".hidden", "-opt", "a/b", "a b", "a\nb", "caf\u00e9", "x" * 101, "a\x00"):
        with pytest.raises(InvalidInputError):
            check_calibration_name(bad)


@pytest.mark.parametrize(
    "from_frame,to_frame",
    [("Base", "Tracker"), ("Marker", "TCP"), ("StylusTip", "Stylus"), ("Tool", "Tracker"), ("A", "B2")],
)
def test_plus_frame_names_accepted(from_frame, to_frame):
    assert check_plus_frame_names(from_frame, to_frame) == (from_frame, to_frame)
    assert plus_to_count(f"{from_frame}To{to_frame}") == 1


@pytest.mark.parametrize(
    "from_frame,to_frame",
    [
        ("base", "Tracker"),  # PLUS capitalises; a lower-case name would not be found again
        ("BaseTo", "Tracker"),  # BaseToToTracker: two 'To'
        ("Base", "ToTracker"),
        ("Base", "To1"),
        ("Base", "Tra cker"),
        ("Base", 'T"/><x'),
        ("Base", "Tracker\n"),
        ("Base", ""),
        ("Base", "T\u00e9"),
    ],
)
def test_plus_frame_names_refused(from_frame, to_frame):
    with pytest.raises(InvalidInputError):
        check_plus_frame_names(from_frame, to_frame)
    with pytest.raises(InvalidInputError):
        plus_coordinate_definition(np.eye(4), from_frame, to_frame)


def test_plus_elements_are_built_with_an_xml_library(tmp_path):
    element = ET.fromstring(plus_coordinate_definition(np.eye(4), "Base", "Tracker", 0.25))
    assert element.get("From") == "Base" and element.get("To") == "Tracker"
    assert np.array_equal(np.array(element.get("Matrix").split(), float).reshape(4, 4), np.eye(4))
    with pytest.raises(InvalidInputError, match="finite"):
        plus_coordinate_definition(np.full((4, 4), np.nan), "Base", "Tracker")


def test_the_app_refuses_a_bad_frame_before_reading_or_writing(tmp_path):
    hostile = 'x"""+__import__("os").system("touch owned")+"""'
    for flag, field in (("--tracker-frame", "tracker_frame"), ("--base-frame", "base_frame")):
        settings = RosExportSettings(
            str(tmp_path / "missing-calibration.json"),
            ros2_launch=str(tmp_path / "cal.launch.py"),
            urdf=str(tmp_path / "cal.urdf"),
            **{field: hostile},
        )
        with pytest.raises(InvalidInputError, match=f"^{flag} "):
            export_ros(settings)
    with pytest.raises(InvalidInputError, match="^--tool-frame "):
        export_ros(
            RosExportSettings(
                str(tmp_path / "c.json"), easy_handeye2=str(tmp_path / "a.calib"), tool_frame="a b"
            )
        )
    with pytest.raises(InvalidInputError, match="^--easy-handeye2: the calibration name"):
        export_ros(RosExportSettings(str(tmp_path / "c.json"), easy_handeye2=str(tmp_path / "my cal.calib")))
    assert sorted(p.name for p in tmp_path.iterdir()) == []


EDGE = calibration_static_transform(np.eye(4), base_frame="ur/base", tracker_frame="polaris")


def test_writers_refuse_bad_frames_themselves():
    for parent, child in (("/base", "tracker"), ("base", "a<b"), ('x"""', "tracker"), ("base", "0t")):
        edge = StaticTransform(parent, child, np.eye(4))  # readers keep what a file says
        for writer in (ros2_launch_text, urdf_joint_text, static_transform_publisher_command):
            with pytest.raises(InvalidInputError, match="not a ROS frame name"):
                writer(edge)


def test_launch_file_holds_only_literals(tmp_path):
    text = ros2_launch_text(EDGE)
    tree = ast.parse(text)
    strings = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)}
    calls = {n.func.id for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)}
    assert calls == {"LaunchDescription", "Node"}
    assert {"ur/base", "polaris", "ur_base_to_polaris_calibration"} <= strings
    path = write_ros2_launch(tmp_path / "c.launch.py", EDGE)
    assert read_ros2_launch(path).child_frame == "polaris"
    with pytest.raises(InvalidInputError, match="launch node name"):
        ros2_launch_text(EDGE, node_name="a/b")


def test_urdf_is_built_with_an_xml_library():
    text = urdf_joint_text(EDGE)
    root = ET.fromstring(f"<r>{text}</r>")
    assert [e.tag for e in root] == ["link", "joint"]
    assert root.find("joint/parent").get("link") == "ur/base"
    assert parse_urdf_joint(text).parent_frame == "ur/base"
    with pytest.raises(InvalidInputError, match="URDF joint name"):
        urdf_joint_text(EDGE, joint_name="a b")


def test_urdf_and_plus_readers_refuse_a_dtd(tmp_path):
    bomb = '<!DOCTYPE r [<!ENTITY a "aaaaaaaaaa">]><joint name="&a;" type="fixed"/>'
    with pytest.raises(InvalidInputError, match="document type"):
        parse_urdf_joint(bomb)
    path = tmp_path / "c.xml"
    path.write_text('<?xml version="1.0"?>\n<!doctype PlusConfiguration>\n<PlusConfiguration/>')
    with pytest.raises(InvalidInputError, match="document type"):
        read_plus_transform(path, "A", "B")


@pytest.mark.parametrize(
    "text",
    [
        "--x 1_000 --frame-id a --child-frame-id b",
        "--qx 0x0 --qw 1 --frame-id a --child-frame-id b",
        "1_0 0 0 0 0 0 1 a b",
        "\u0661 0 0 0 0 0 a b",
    ],
)
def test_command_line_reader_refuses_digit_groups(text):
    with pytest.raises(InvalidInputError, match="number"):
        parse_static_transform_publisher(text)


def test_urdf_reader_refuses_digit_groups():
    snippet = (
        '<joint name="j" type="fixed"><parent link="p"/><child link="c"/><origin xyz="1_0 0 0"/></joint>'
    )
    with pytest.raises(InvalidInputError, match="plain decimal"):
        parse_urdf_joint(snippet)
