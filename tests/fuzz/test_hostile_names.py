"""Hostile names through every generated format: each is refused with one inert line, or written so
that reading the file back gives exactly the name.

Formats: the ROS 2 launch file, the URDF joint, the static_transform_publisher command, the
easy_handeye2 .calib and .samples files, the UR driver calibration YAML, the PLUS configuration
and the Slicer transform (whose only text is its file name, which Slicer shows as the node name).
The launch file is also rendered from unchecked names and executed with stand-in launch modules:
whatever the name, it holds only the expected string literals and runs no code of the name's.
"""

from __future__ import annotations

import ast
import dataclasses
import sys
import types
import xml.etree.ElementTree as ET
from functools import partial

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from spacecal.core.errors import InvalidInputError
from spacecal.core.text import sanitize_for_terminal
from spacecal.geometry.transforms import make_transform
from spacecal.io.easy_handeye import (
    easy_handeye2_samples_text,
    read_easy_handeye_calibration,
    read_easy_handeye_samples,
    write_easy_handeye2_calibration,
)
from spacecal.io.names import MAX_ROS_NAME_CHARS, check_ros_frame_name
from spacecal.io.plus_config import read_plus_transform, write_plus_coordinate_definitions
from spacecal.io.ros_exports import (
    StaticTransform,
    parse_static_transform_publisher,
    read_ros2_launch,
    read_urdf_joint,
    render_launch_text,
    render_urdf_joint,
    static_transform_publisher_command,
    write_ros2_launch,
    write_urdf_joint,
)
from spacecal.io.slicer import read_slicer_transform, write_slicer_transform
from spacecal.io.ur_driver_calibration import read_ur_calibration, write_ur_calibration
from spacecal.io.yaml_text import parse_yaml, yaml_string
from spacecal.models.robot_kinds import robot_kind

PAYLOAD = '"""+__import__("pathlib").Path("OWNED").write_text("x")+"""'
SPECIALS = [
    '"', "'", '"""', "'''", "\\", '\\"', "\n", "\r\n", "\r", "\x85", "\u2028", "\u2029", "<", ">", "&", "]]>",
    "<!--", "-->", "--", "&amp;", "&#0;", '"/><x a="', "\x00", "\x01", "\x07", "\x1b[2J", "\x1b]0;t\x07",
    "\x7f", "\x9b", "\u202e", "\u200b", "\ufeff", "\ud800", "\udfff", "\uffff", "\U0010ffff", "\u00a0",
    "\t", " ", "#", "{", "}", "{0}", "%s", "$(id)", "`id`", ";", "|", "*", "&a", "!!python/object", ":",
    ": ", "- ", "? ", "/", "//", ".", "-", "~", "@", "\u00e9", "\u4e2d", "\U0001f600",
]  # fmt: skip
WHOLE = [
    "", " ", "yes", "No", "null", "~", "true", "1_000", "0x10", "1:30", "2001-12-14", ".inf", "1e5", "-",
    "---", "...", "%YAML 1.2", "|", ">", "[a]", "{a: 1}", "a: b", "#c", "/base", "base/", "a//b", "0base",
    "ur/0", "a-b", "a b", "a.b", "~/x", "{sub}", "__import__", "\\N{BULLET}", "\\x00", "\\u0000", "\\\n",
    PAYLOAD, "x" + PAYLOAD, "x'''+__import__('os').system('id')+'''", "x\n#", "x\nhash: calib_0\nevil: 1",
    '"/><joint name="evil', "x]]><evil/>", "x" * 10_000, "a" * (MAX_ROS_NAME_CHARS + 1), "\u00e9" * 5000,
    "\x1b" * 1000, "x\x00" * 100,
    # valid names of each tool, which must be written and read back exactly
    "base", "tracker", "ur/base_link", "_private", "tool0", "A1_b2", "a" * MAX_ROS_NAME_CHARS, "Base",
    "Tracker", "MarkerA", "Probe2",
]  # fmt: skip
NAMES = list(dict.fromkeys(WHOLE + [f"base{s}" for s in SPECIALS] + [f"{s}tracker" for s in SPECIALS]))
assert len(NAMES) >= 100

TRACKER_FROM_BASE = make_transform(Rotation.from_rotvec([0.2, -1.1, 0.4]).as_matrix(), [-150.0, 320.0, -1450])
FRAMES = {
    "robot_base_frame": "base",
    "robot_effector_frame": "tool0",
    "tracking_base_frame": "tracker",
    "tracking_marker_frame": "marker",
}


def _ids(name: str) -> str:
    return sanitize_for_terminal(name, 40)


def _refused_in_one_line(error: BaseException) -> None:
    message = str(error)
    assert message and "\n" not in message and len(message) < 1000, message[:300]
    assert message == sanitize_for_terminal(message, 10**6), message[:300]  # nothing a terminal acts on


def _outcome(write, read_back, name):
    """Run ``write``; a refusal must be one inert line, a file must read back exactly ``name``."""
    try:
        written = write()
    except InvalidInputError as error:
        _refused_in_one_line(error)
        return "refused"
    assert read_back(written) == name
    return "written"


def _is_ros_name(name: str) -> bool:
    try:
        check_ros_frame_name(name)
    except InvalidInputError:
        return False
    return True


@pytest.fixture
def folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a payload that ran would leave OWNED here
    yield tmp_path
    assert not (tmp_path / "OWNED").exists()


def _frame_of(reader, role, written):
    edge = reader(written)
    return edge.parent_frame if role == "parent" else edge.child_frame


@pytest.mark.parametrize("name", NAMES, ids=_ids)
def test_ros_exports(folder, name):
    valid = _is_ros_name(name)
    for role in ("parent", "child"):
        parent, child = (name, "tracker") if role == "parent" else ("base", name)
        if parent == child:
            continue
        try:
            edge = StaticTransform(parent, child, np.linalg.inv(TRACKER_FROM_BASE))
        except InvalidInputError as error:  # whitespace: refused when the edge is made
            _refused_in_one_line(error)
            assert not valid
            continue
        outcomes = {
            _outcome(
                partial(write_ros2_launch, folder / "c.launch.py", edge),
                partial(_frame_of, read_ros2_launch, role),
                name,
            ),
            _outcome(
                partial(write_urdf_joint, folder / "c.urdf", edge),
                partial(_frame_of, read_urdf_joint, role),
                name,
            ),
            _outcome(
                partial(static_transform_publisher_command, edge),
                partial(_frame_of, parse_static_transform_publisher, role),
                name,
            ),
        }
        assert outcomes == {"written" if valid else "refused"}


def _write_calib(path, frames):
    return write_easy_handeye2_calibration(path, TRACKER_FROM_BASE, **frames)


def _write_samples(path, frames):
    stack = np.broadcast_to(TRACKER_FROM_BASE, (3, 4, 4))
    path.write_text(easy_handeye2_samples_text(stack, stack, name="c", **frames))
    return path


#: easy_handeye2 frame parameter -> spacecal's frame in the metadata of the samples read back.
SAMPLE_FRAMES = {
    "robot_base_frame": "base",
    "robot_effector_frame": "tcp",
    "tracking_base_frame": "tracker",
    "tracking_marker_frame": "marker",
}


@pytest.mark.parametrize("name", NAMES, ids=_ids)
def test_easy_handeye2_files(folder, name):
    expected = "written" if _is_ros_name(name) else "refused"
    for key, ours in SAMPLE_FRAMES.items():
        frames = {**FRAMES, key: name}
        calib = _outcome(
            partial(_write_calib, folder / "c.calib", frames),
            lambda p, key=key: getattr(read_easy_handeye_calibration(p), key),
            name,
        )
        samples = _outcome(
            partial(_write_samples, folder / "c.samples", frames),
            lambda p, ours=ours: read_easy_handeye_samples(p).metadata["frames"][ours],
            name,
        )
        assert calib == samples == expected
    _outcome(
        partial(_write_calib, folder / "n.calib", {**FRAMES, "name": name}),
        lambda p: read_easy_handeye_calibration(p).name,
        name,
    )


@pytest.mark.parametrize("name", NAMES, ids=_ids)
def test_yaml_scalars_and_the_ur_calibration(folder, name):
    # the emitter alone: every string, checked or not, reads back exactly (PyYAML and the strict reader)
    assert yaml.safe_load(f"k: {yaml_string(name)}\n") == {"k": name}
    assert parse_yaml(f"k: {yaml_string(name)}\n", "f", "t") == {"k": name}
    model = dataclasses.replace(robot_kind("UR10").model(), name=name)
    hash_text = name or "calib_0"
    path = write_ur_calibration(folder / "k.yaml", model, kinematics_hash=hash_text)
    text = path.read_text()
    # the file's own two keys only: the description and the tool offset the last link folds into
    assert text.isascii() and sorted(yaml.safe_load(text)) == ["kinematics", "tool_offset"]
    assert read_ur_calibration(path).kinematics_hash == hash_text


def _plus_name_read_back(from_frame, to_frame, name, path):
    return (
        name if np.array_equal(read_plus_transform(path, from_frame, to_frame), TRACKER_FROM_BASE) else None
    )


@pytest.mark.parametrize("name", NAMES, ids=_ids)
def test_plus_configuration(folder, name):
    for from_frame, to_frame in ((name, "Tracker"), ("Base", name)):
        if from_frame == to_frame:
            continue
        outcome = _outcome(
            partial(
                write_plus_coordinate_definitions,
                folder / "c.xml",
                [(TRACKER_FROM_BASE, from_frame, to_frame, 0.5)],
            ),
            partial(_plus_name_read_back, from_frame, to_frame, name),
            name,
        )
        if name in ("Base", "Tracker", "MarkerA", "Probe2"):
            assert outcome == "written"


@pytest.mark.parametrize("name", NAMES, ids=_ids)
def test_slicer_transform_file_name(folder, name):
    if "/" in name or name in ("", ".", ".."):
        pytest.skip("not a file name")  # a path, not a name Slicer could show
    target = folder / f"{name}.tfm"
    try:
        path = write_slicer_transform(TRACKER_FROM_BASE, target)
    except InvalidInputError as error:
        _refused_in_one_line(error)
        return
    except OSError as error:  # e.g. a name longer than the file system allows
        assert "\n" not in str(error)
        return
    assert path.name == f"{name}.tfm" and path.stem == name
    assert np.allclose(read_slicer_transform(path), TRACKER_FROM_BASE, atol=1e-9)


class _Node:
    def __init__(self, **keywords):
        self.keywords = keywords


@pytest.fixture
def stand_in_launch(monkeypatch):
    """Modules ``launch`` and ``launch_ros.actions`` that record what the launch file builds."""
    launch = types.ModuleType("launch")
    launch.LaunchDescription = list
    launch_ros = types.ModuleType("launch_ros")
    actions = types.ModuleType("launch_ros.actions")
    actions.Node = _Node
    launch_ros.actions = actions
    for module in (launch, launch_ros, actions):
        monkeypatch.setitem(sys.modules, module.__name__, module)


@pytest.mark.parametrize("name", NAMES, ids=_ids)
def test_launch_file_rendered_from_unchecked_names_holds_only_literals(folder, stand_in_launch, name):
    arguments = ["--x", "0.1", "--frame-id", name, "--child-frame-id", f"{name}2"]
    text = render_launch_text(name, arguments, meaning=name)
    tree = ast.parse(text)
    strings = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)}
    docstring = ast.get_docstring(tree, clean=False)
    assert strings == {docstring, "tf2_ros", "static_transform_publisher", name, *arguments}
    calls = [n.func for n in ast.walk(tree) if isinstance(n, ast.Call)]
    assert sorted(c.id for c in calls if isinstance(c, ast.Name)) == ["LaunchDescription", "Node"]
    assert len(calls) == 2 and text.isascii()
    namespace: dict = {}
    exec(compile(text, "c.launch.py", "exec"), namespace)  # what ros2 launch does (with stand-ins)
    (node,) = namespace["generate_launch_description"]()
    assert node.keywords["name"] == name and node.keywords["arguments"] == arguments


@pytest.mark.parametrize("name", NAMES, ids=_ids)
def test_urdf_rendered_from_unchecked_names_is_escaped_or_refused(name):
    try:
        text = render_urdf_joint(name, "tracker", name, "0 0 0", "0 0 0", comment=name)
    except InvalidInputError as error:  # a character XML 1.0 cannot hold
        _refused_in_one_line(error)
        return
    root = ET.fromstring(f"<r>{text}</r>")
    assert [e.tag for e in root] == ["link", "joint"]
    joint = root.find("joint")
    assert joint.get("name") == name and joint.find("parent").get("link") == name
    with_comments = ET.fromstring(
        f"<r>{text}</r>", parser=ET.XMLParser(target=ET.TreeBuilder(insert_comments=True))
    )
    assert [e.tag for e in with_comments][0] is ET.Comment and len(with_comments) == 3


def _prints_as_itself(name: str) -> bool:
    return name == sanitize_for_terminal(name, 10**6)


@pytest.mark.parametrize("name", NAMES, ids=_ids)
def test_the_one_name_rule_takes_exactly_what_prints_as_itself(name):
    from spacecal.core.text import MAX_NAME_CHARS, check_name

    expected = (
        _prints_as_itself(name) and 0 < len(name) <= MAX_NAME_CHARS and name.strip() == name and name != ""
    )
    try:
        assert check_name(name, "robot name") == name
        accepted = True
    except InvalidInputError as error:
        _refused_in_one_line(error)
        assert str(error).startswith("robot name")
        accepted = False
    assert accepted == expected


@pytest.mark.parametrize(
    "character",
    [
        *map(chr, [*range(0x20), 0x7F, *range(0x80, 0xA0)]),
        *map(chr, [*range(0x202A, 0x202F), *range(0x2066, 0x206A), 0x200E, 0x200F, 0x061C]),
        "\u2028", "\u2029", "\u200b", "\u200d", "\ufeff", "\u00a0", "\u3000", "\ud800", "\ue000",
    ],
    ids=lambda c: f"U+{ord(c):04X}",
)  # fmt: skip
def test_controls_and_bidirectional_marks_are_no_part_of_a_name(character):
    from spacecal.core.text import check_name

    for name in (f"bay{character}1", f"{character}bay", f"bay{character}"):
        with pytest.raises(InvalidInputError) as refused:
            check_name(name, "robot name")
        _refused_in_one_line(refused.value)
        assert f"U+{ord(character):04X}" in str(refused.value)


@pytest.mark.parametrize("name", NAMES, ids=_ids)
def test_the_record_keeps_a_name_exactly_or_refuses_it(tmp_path, name):
    pytest.importorskip("sqlalchemy")
    from spacecal.core.text import check_name
    from spacecal.ledger import Ledger

    try:
        check_name(name, "name")
        valid = True
    except InvalidInputError:
        valid = False
    ledger = Ledger.open(str(tmp_path / "record.db"))
    try:
        for kind, add, listed in (
            ("robot", lambda: ledger.add_robot(name, "sim"), ledger.robots),
            ("tracker", lambda: ledger.add_tracker(name, "sim"), ledger.trackers),
            ("tool", lambda: ledger.add_tool(name), None),
        ):
            try:
                add()
            except InvalidInputError as error:
                _refused_in_one_line(error)
                assert not valid and str(error).startswith(f"{kind} name")
                continue
            assert valid
            if listed is not None:
                assert [row["name"] for row in listed()] == [name]
    finally:
        ledger.close()
