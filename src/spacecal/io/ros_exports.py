"""A calibration as ROS 2 static transforms, written without ROS: command line, launch file, URDF joint.

Frames in ROS point the same way as ours once read right: a ROS transform from parent frame
``P`` to child frame ``C`` (``--frame-id P --child-frame-id C``, a URDF joint with parent link
``P`` and child link ``C``) is the *pose of C in P*, i.e. our ``p_from_c``: it maps coordinates
given in C into P. For the calibration the natural edge is robot base (parent) -> tracker
(child), carrying ``base_from_tracker = invert(tracker_from_base)``; see
:func:`calibration_static_transform`.

Boundary conversions: translations are written in metres (ours are mm), rotations as
quaternions ``x, y, z, w`` (ours are ``w, x, y, z``) or, in URDF, as ``rpy`` = fixed-axis
roll about x, then pitch about y, then yaw about z (``R = Rz(yaw) Ry(pitch) Rx(roll)``).
Numbers are written in shortest round-trip form, so each reader gives back the same 4x4 to
well below 1e-9 mm.

Note on UR robots: spacecal's ``base`` is the controller's base frame, which ``ur_description``
calls ``base`` (= ``base_link`` turned by pi about z). Use ``base`` as the parent frame, or
compose with ``base_link_from_base`` if you attach to ``base_link``.
"""

from __future__ import annotations

import ast
import shlex
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from spacecal.core.errors import InvalidInputError
from spacecal.core.strict_numbers import parse_float, parse_floats
from spacecal.core.text import double_quoted_ascii, one_line_ascii, quoted, sanitize_for_terminal
from spacecal.geometry.transforms import invert_transform, is_rigid_transform, make_transform
from spacecal.io.atomic import write_text_atomic
from spacecal.io.names import check_ros_frame_name, check_ros_node_name, check_xml_text
from spacecal.io.ros_common import number_text, transform_from_ros, transform_to_ros
from spacecal.io.text import read_text_file, refuse_dtd

#: ur_description: ``base`` is ``base_link`` rotated by pi about z (joint ``base_link-base_fixed_joint``).
BASE_LINK_FROM_BASE = make_transform(Rotation.from_euler("z", np.pi).as_matrix(), np.zeros(3))


@dataclass(frozen=True)
class StaticTransform:
    """One edge of a ROS tf tree.

    Attributes
    ----------
    parent_frame, child_frame : str
        ROS frame names (``header.frame_id`` and ``child_frame_id``).
    parent_from_child : numpy.ndarray, shape (4, 4)
        The pose of the child frame in the parent frame, mm (maps child coordinates into the parent).
    """

    parent_frame: str
    child_frame: str
    parent_from_child: np.ndarray

    def __post_init__(self):
        for name, value in (("parent_frame", self.parent_frame), ("child_frame", self.child_frame)):
            if not isinstance(value, str) or not value.strip() or any(c.isspace() for c in value):
                raise InvalidInputError(f"{name} {quoted(value)}: expected a ROS frame name without spaces")
        if self.parent_frame == self.child_frame:
            raise InvalidInputError(f"parent and child frame are both {quoted(self.parent_frame)}")
        matrix = np.asarray(self.parent_from_child, dtype=float)
        if matrix.shape != (4, 4) or not is_rigid_transform(matrix):
            raise InvalidInputError(
                f"{quoted(self.parent_frame)} -> {quoted(self.child_frame)}: not a rigid 4x4 transform"
            )
        object.__setattr__(self, "parent_from_child", matrix)

    def inverted(self) -> StaticTransform:
        """The same edge seen from the other end (child becomes parent)."""
        return StaticTransform(self.child_frame, self.parent_frame, invert_transform(self.parent_from_child))


def calibration_static_transform(
    tracker_from_base, base_frame: str = "base", tracker_frame: str = "tracker", parent: str = "base"
) -> StaticTransform:
    """The calibration as a tf edge.

    Parameters
    ----------
    tracker_from_base : array_like, shape (4, 4)
        The calibration (maps base coordinates into the tracker frame), mm.
    base_frame, tracker_frame : str
        ROS names of the robot base frame and the tracker frame.
    parent : {"base", "tracker"}
        Which frame is the parent in the tf tree. ``"base"`` (default) gives the edge
        base -> tracker carrying ``base_from_tracker``; ``"tracker"`` the edge tracker -> base
        carrying ``tracker_from_base`` (use it when the robot is attached below the tracker).
    """
    tracker_from_base = np.asarray(tracker_from_base, dtype=float)
    if parent == "base":
        return StaticTransform(base_frame, tracker_frame, invert_transform(tracker_from_base))
    if parent == "tracker":
        return StaticTransform(tracker_frame, base_frame, tracker_from_base)
    raise InvalidInputError(f"parent {parent!r}: expected 'base' or 'tracker'")


def _meaning(edge: StaticTransform) -> str:
    return (
        f"parent frame {edge.parent_frame!r}, child frame {edge.child_frame!r}: the pose of "
        f"{edge.child_frame} in {edge.parent_frame} ({edge.parent_frame}_from_{edge.child_frame}, maps "
        f"{edge.child_frame} coordinates into {edge.parent_frame}); metres, quaternion x y z w"
    )


def checked_frames(edge: StaticTransform) -> tuple[str, str]:
    """The edge's parent and child frame names, refused with one line unless both are ROS frame
    names (:func:`spacecal.io.names.check_ros_frame_name`); every writer here calls it first."""
    return (
        check_ros_frame_name(edge.parent_frame, "parent frame"),
        check_ros_frame_name(edge.child_frame, "child frame"),
    )


def static_transform_publisher_arguments(edge: StaticTransform) -> list[str]:
    """The ROS 2 (Humble and later) ``static_transform_publisher`` arguments for an edge."""
    checked_frames(edge)
    translation_m, quaternion_xyzw = transform_to_ros(edge.parent_from_child)
    arguments = []
    for flag, value in zip(("--x", "--y", "--z"), translation_m):
        arguments += [flag, number_text(value)]
    for flag, value in zip(("--qx", "--qy", "--qz", "--qw"), quaternion_xyzw):
        arguments += [flag, number_text(value)]
    return arguments + ["--frame-id", edge.parent_frame, "--child-frame-id", edge.child_frame]


def static_transform_publisher_command(edge: StaticTransform) -> str:
    """A shell command publishing the edge with ``ros2 run tf2_ros static_transform_publisher``.

    The line is preceded by a ``#`` comment saying which frame is the parent and what the
    transform means, so it can be pasted into a shell script as it is.
    """
    arguments = static_transform_publisher_arguments(edge)
    command = shlex.join(["ros2", "run", "tf2_ros", "static_transform_publisher"])
    return f"# {one_line_ascii(_meaning(edge))}\n{command} {shlex.join(arguments)}\n"


def _edge_from_arguments(arguments: list[str], where: str) -> StaticTransform:
    """Parse ``static_transform_publisher`` arguments: the ``--flag value`` form, or the old positional
    ``x y z qx qy qz qw parent child`` / ``x y z yaw pitch roll parent child`` forms."""
    arguments = [a for a in arguments if a not in ("--ros-args",)]
    if any(a.startswith("--") for a in arguments):
        values: dict[str, str] = {}
        k = 0
        while k < len(arguments):
            flag = arguments[k]
            if not flag.startswith("--") or k + 1 >= len(arguments):
                raise InvalidInputError(f"{where}: unexpected argument {quoted(flag)}")
            values[flag[2:].replace("_", "-")] = arguments[k + 1]
            k += 2
        known = {"x", "y", "z", "qx", "qy", "qz", "qw", "roll", "pitch", "yaw", "frame-id", "child-frame-id"}
        unknown = sorted(set(values) - known)
        if unknown:
            raise InvalidInputError(
                f"{where}: unknown argument(s) {', '.join(quoted('--' + u) for u in unknown[:5])}"
            )
        for frame in ("frame-id", "child-frame-id"):
            if frame not in values:
                raise InvalidInputError(f"{where}: missing --{frame}")

        def number(name, default):
            text = values.get(name, default)
            try:
                return parse_float(text)
            except ValueError:
                raise InvalidInputError(f"{where}: --{name} {quoted(text)} is not a number") from None

        translation = [number(n, "0") for n in ("x", "y", "z")]
        if {"qx", "qy", "qz", "qw"} & set(values):
            if {"roll", "pitch", "yaw"} & set(values):
                raise InvalidInputError(f"{where}: give either a quaternion or roll/pitch/yaw, not both")
            quaternion = [number(n, "0") for n in ("qx", "qy", "qz")] + [number("qw", "1")]
            matrix = transform_from_ros(translation, quaternion, where)
        else:
            rpy = [number(n, "0") for n in ("roll", "pitch", "yaw")]
            matrix = make_transform(
                Rotation.from_euler("xyz", rpy).as_matrix(), np.array(translation) * 1000.0
            )
        return StaticTransform(values["frame-id"], values["child-frame-id"], matrix)
    if len(arguments) not in (8, 9):
        raise InvalidInputError(
            f"{where}: expected --x .. --child-frame-id, or 8/9 positional arguments; got {len(arguments)}"
        )
    try:
        numbers = [parse_float(a) for a in arguments[:-2]]
    except ValueError:
        raise InvalidInputError(f"{where}: the leading positional arguments must be numbers") from None
    if len(numbers) == 7:
        matrix = transform_from_ros(numbers[:3], numbers[3:], where)
    else:
        yaw, pitch, roll = numbers[3:]
        rotation = Rotation.from_euler("xyz", [roll, pitch, yaw]).as_matrix()
        matrix = make_transform(rotation, np.array(numbers[:3]) * 1000.0)
    return StaticTransform(arguments[-2], arguments[-1], matrix)


def parse_static_transform_publisher(text: str) -> StaticTransform:
    """Read back a ``static_transform_publisher`` command line.

    ``#`` comment lines, a ``ros2 run tf2_ros`` prefix and backslash line continuations are allowed.
    """
    lines = [line.strip() for line in text.splitlines()]
    lines = [line for line in lines if line and not line.startswith("#")]
    if not lines:
        raise InvalidInputError("static_transform_publisher command: the text is empty")
    words = shlex.split(" ".join(line.rstrip("\\") for line in lines))
    if "static_transform_publisher" in words:
        words = words[words.index("static_transform_publisher") + 1 :]
    return _edge_from_arguments(words, "static_transform_publisher command")


_LAUNCH_TEMPLATE = '''"""Publish the robot-tracker calibration as a static transform. Written by spacecal."""

# {meaning}

from launch import LaunchDescription
from launch_ros.actions import Node


def generate_launch_description():
    return LaunchDescription(
        [
            Node(
                package="tf2_ros",
                executable="static_transform_publisher",
                name={name},
                arguments=[
{arguments}
                ],
            )
        ]
    )
'''


def render_launch_text(node_name: str, arguments: list[str], meaning: str) -> str:
    """The launch file's text with every value a Python literal that evaluates to exactly it.

    Strings enter the code only as double-quoted, escaped, printable-ASCII literals
    (:func:`spacecal.core.text.double_quoted_ascii`: no content can close one early), and
    ``meaning`` only as one comment line of printable ASCII; nothing else in the file depends on
    the values. The callers check the names first; this layer holds even for names that were
    never checked.
    """
    if not all(isinstance(v, str) for v in [node_name, meaning, *arguments]):
        raise InvalidInputError("a launch file is written from text values only")
    pairs = [arguments[k : k + 2] for k in range(0, len(arguments), 2)]
    body = "\n".join(
        "                    " + " ".join(f"{double_quoted_ascii(v)}," for v in pair) for pair in pairs
    )
    return _LAUNCH_TEMPLATE.format(
        meaning=one_line_ascii(meaning), name=double_quoted_ascii(node_name), arguments=body
    )


def ros2_launch_text(edge: StaticTransform, node_name: str | None = None) -> str:
    """A ROS 2 Python launch file that starts a ``static_transform_publisher`` for the edge.

    The frame names must be ROS frame names and ``node_name`` a ROS node name (by default
    ``<parent>_to_<child>_calibration`` with ``/`` as ``_``); anything else is refused.
    """
    parent, child = checked_frames(edge)
    node_name = check_ros_node_name(
        node_name or f"{parent}_to_{child}_calibration".replace("/", "_"), "launch node name"
    )
    return render_launch_text(node_name, static_transform_publisher_arguments(edge), _meaning(edge))


def write_ros2_launch(path: str | Path, edge: StaticTransform, node_name: str | None = None) -> Path:
    """Write :func:`ros2_launch_text` to ``path`` (conventionally ``*.launch.py``); returns the path."""
    path = Path(path)
    write_text_atomic(ros2_launch_text(edge, node_name), path)
    return path


def read_ros2_launch(path: str | Path) -> StaticTransform:
    """Read the static transform back from a launch file: the ``arguments`` list of its
    ``static_transform_publisher`` node (parsed as Python, never executed)."""
    path = Path(path)
    if not path.is_file():
        raise InvalidInputError(f"{path}: no such launch file")
    try:
        tree = ast.parse(read_text_file(path, "launch"), filename=str(path))
    except SyntaxError as exc:
        raise InvalidInputError(f"{path}: not a Python launch file (line {exc.lineno}: {exc.msg})") from None
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        keywords = {k.arg: k.value for k in node.keywords}
        executable = keywords.get("executable")
        if not (isinstance(executable, ast.Constant) and executable.value == "static_transform_publisher"):
            continue
        arguments = keywords.get("arguments")
        try:
            values = ast.literal_eval(arguments) if arguments is not None else None
        except ValueError:
            raise InvalidInputError(
                f"{path}: the static_transform_publisher arguments are not literals"
            ) from None
        if not isinstance(values, (list, tuple)):
            raise InvalidInputError(f"{path}: the static_transform_publisher node has no arguments list")
        found.append([str(v) for v in values])
    if len(found) != 1:
        raise InvalidInputError(f"{path}: expected one static_transform_publisher node, found {len(found)}")
    return _edge_from_arguments(found[0], str(path))


def _rpy_of(rotation: np.ndarray) -> np.ndarray:
    """URDF ``rpy`` (fixed axes x, y, z: ``R = Rz(yaw) Ry(pitch) Rx(roll)``) of a rotation matrix."""
    return Rotation.from_matrix(rotation).as_euler("xyz")


def rotation_from_rpy(rpy) -> np.ndarray:
    """Rotation matrix (3, 3) of URDF ``rpy`` angles (rad): ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    return Rotation.from_euler("xyz", np.asarray(rpy, dtype=float)).as_matrix()


def _xml_comment(text: str) -> ET.Element[Any]:
    """An XML comment of ``text`` that cannot end early: one line of printable ASCII without
    ``--`` (which XML forbids inside a comment), padded with spaces so it cannot end in ``-``."""
    text = one_line_ascii(text)
    while "--" in text:
        text = text.replace("--", "- -")
    return ET.Comment(f" {text} ")


def render_urdf_joint(
    parent_link: str,
    child_link: str,
    joint_name: str,
    xyz_text: str,
    rpy_text: str,
    comment: str,
    with_child_link: bool = True,
) -> str:
    """The URDF snippet, built with ElementTree: every attribute escaped (quotes, ``<``, ``&``,
    line breaks), a value XML cannot hold at all (NUL, other control characters) refused."""
    for what, value in (
        ("parent link", parent_link),
        ("child link", child_link),
        ("joint name", joint_name),
        ("origin xyz", xyz_text),
        ("origin rpy", rpy_text),
    ):
        check_xml_text(value, what)
    elements = [_xml_comment(comment)]
    if with_child_link:
        elements.append(ET.Element("link", {"name": child_link}))
    joint = ET.Element("joint", {"name": joint_name, "type": "fixed"})
    ET.SubElement(joint, "parent", {"link": parent_link})
    ET.SubElement(joint, "child", {"link": child_link})
    ET.SubElement(joint, "origin", {"xyz": xyz_text, "rpy": rpy_text})
    ET.indent(joint, "  ")
    elements.append(joint)
    return "\n".join(ET.tostring(element, encoding="unicode") for element in elements) + "\n"


def urdf_joint_text(
    edge: StaticTransform, joint_name: str | None = None, with_child_link: bool = True
) -> str:
    """A URDF snippet: a fixed joint from the parent link to the child link carrying the edge.

    ``<origin xyz rpy>`` of a URDF joint is the pose of the child link in the parent link, so it
    holds ``parent_from_child`` (metres; rpy as URDF defines it). The child link element is
    included unless ``with_child_link`` is false (when the URDF already has that link). The link
    names must be ROS frame names and ``joint_name`` (by default
    ``<parent>_to_<child>_calibration``) one too, of up to 255 characters.
    """
    parent, child = checked_frames(edge)
    joint_name = check_ros_frame_name(
        joint_name or f"{parent}_to_{child}_calibration", "URDF joint name", max_chars=255
    )
    xyz_m, _ = transform_to_ros(edge.parent_from_child)
    rpy = _rpy_of(edge.parent_from_child[:3, :3])
    comment = (
        "Robot-tracker calibration written by spacecal. "
        + _meaning(edge).replace("quaternion x y z w", "rpy in rad (fixed axes x, y, z)")
        + "."
    )
    return render_urdf_joint(
        parent,
        child,
        joint_name,
        " ".join(number_text(v) for v in xyz_m),
        " ".join(number_text(v) for v in rpy),
        comment,
        with_child_link,
    )


def write_urdf_joint(path: str | Path, edge: StaticTransform, joint_name: str | None = None) -> Path:
    """Write :func:`urdf_joint_text` to ``path`` (an XML fragment to paste or ``xacro:include``)."""
    path = Path(path)
    write_text_atomic(urdf_joint_text(edge, joint_name), path)
    return path


def _floats(text: str | None, count: int, where: str) -> np.ndarray:
    if text is None:
        return np.zeros(count)
    try:
        values = parse_floats(text)
    except ValueError:
        raise InvalidInputError(f"{where}: {quoted(text)} is not {count} plain decimal numbers") from None
    if values.shape != (count,):
        raise InvalidInputError(f"{where}: {quoted(text)} is not {count} numbers")
    return values


def parse_urdf_joint(text: str, child_frame: str | None = None, where: str = "URDF") -> StaticTransform:
    """Read a fixed joint's edge from a URDF (or a snippet of one, several elements allowed).

    Parameters
    ----------
    text : str
    child_frame : str, optional
        Which joint to take, by child link; needed when the text has more than one fixed joint.
    """
    refuse_dtd(text, where)
    try:
        root = ET.fromstring(f"<spacecal_snippet>{text}</spacecal_snippet>")
    except ET.ParseError:
        try:
            root = ET.fromstring(text.split("?>", 1)[-1] if text.lstrip().startswith("<?xml") else text)
        except ET.ParseError as exc:
            raise InvalidInputError(f"{where}: not valid XML ({exc})") from None
    joints = [j for j in root.iter("joint") if j.get("type") == "fixed"]
    if child_frame is not None:
        joints = [j for j in joints if _child_link(j) == child_frame]
    if len(joints) != 1:
        children = [link for link in (_child_link(j) for j in joints) if link]
        raise InvalidInputError(
            f"{where}: expected one fixed joint"
            + ("" if child_frame is None else f" with child {quoted(child_frame)}")
            + f", found {len(joints)}"
            + (
                f" (children: {', '.join(sanitize_for_terminal(c, 60) for c in children[:10])})"
                if children
                else ""
            )
        )
    joint = joints[0]
    parent, child = joint.find("parent"), joint.find("child")
    parent_link = None if parent is None else parent.get("link")
    child_link = None if child is None else child.get("link")
    if not parent_link or not child_link:
        raise InvalidInputError(f"{where}: joint {quoted(joint.get('name'))} lacks a parent or child link")
    origin = joint.find("origin")
    name = quoted(joint.get("name"))
    xyz = _floats(None if origin is None else origin.get("xyz"), 3, f"{where}: joint {name} xyz")
    rpy = _floats(None if origin is None else origin.get("rpy"), 3, f"{where}: joint {name} rpy")
    return StaticTransform(parent_link, child_link, make_transform(rotation_from_rpy(rpy), xyz * 1000.0))


def _child_link(joint: ET.Element) -> str | None:
    child = joint.find("child")
    return None if child is None else child.get("link")


def read_urdf_joint(path: str | Path, child_frame: str | None = None) -> StaticTransform:
    """:func:`parse_urdf_joint` of a file."""
    path = Path(path)
    if not path.is_file():
        raise InvalidInputError(f"{path}: no such URDF file")
    return parse_urdf_joint(read_text_file(path, "URDF"), child_frame, str(path))
