"""A serial arm's kinematics from its URDF (the ROS robot description), in standard DH form.

A URDF describes an arm as a tree of links joined by joints, each joint at a fixed origin in
its parent link with an axis in its own frame; spacecal's :class:`RobotModel` is a chain of
standard DH links ``Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``. The conversion walks
the chain from a base link to a tool link, places every moving joint's axis as a line in the
base frame at q = 0, and builds the DH frames on those lines along their common normals:

* joint axes that cross: the normal through the crossing point (a = 0);
* parallel axes: the normal through the previous frame's origin (d = 0), the choice of the
  published tables (a UR arm's shoulder, elbow and wrist 1);
* skew axes: the unique common normal.

Of the two senses of each normal the one nearer the previous frame's x axis is taken, so that
the joint-zero offsets are small and a link length may be negative, as in Universal Robots'
own tables. The offsets ``theta_offset_rad`` make q = 0 of the model q = 0 of the URDF, and
the sense of every DH z axis is the URDF axis, so positive angles turn the same way. The last
DH frame lies on the last joint's axis at the foot of the tool link's origin, its x axis the
tool link's x axis where that is square to the axis; what remains, the fixed transform from
the last DH frame to the tool link, is the model's ``flange_from_tcp``.

DH frame 0 is the base link's frame itself: :class:`RobotModel` carries no base offset, so a
base link whose z axis is not joint 1's axis (same sense) through its origin is refused; name
the link the arm stands on (e.g. a UR arm's ``base`` or ``base_link``, a Panda's
``panda_link0``), not a world frame the arm is mounted in.

Lengths are in mm (URDF is metres), angles in rad. Parsing uses the optional ``yourdfpy``
package (``pip install 'spacecal[urdf]'``), imported when a URDF is read.
"""

from __future__ import annotations

import io
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

import numpy as np

from spacecal.core.errors import InvalidInputError, MissingExtraError
from spacecal.geometry.arrays import FloatArray
from spacecal.models.kinematics import RobotModel, forward_kinematics

#: Below this sine of the angle between two joint axes they are taken as parallel: the common
#: normal of nearly parallel axes lies metres to kilometres away (DH's known singularity), and
#: a URDF's rounded angles (11 digits) leave parallel axes misaligned by ~1e-11. Taking them as
#: parallel moves a point 1 m along the chain by at most 1e-6 mm; between 1e-9 and 1e-8 either
#: choice is off by a few 1e-6 mm (the d's of the true normal reach 1e10 mm and cancel in double
#: precision), the limit of any standard DH table of such an arm.
PARALLEL_SINE = 1e-9
#: A point closer than this to a line (mm) is on it (URDF lengths are given to ~1e-4 mm).
ON_AXIS_MM = 1e-6
#: Joint limits of a continuous joint (the model needs finite limits): two full turns.
CONTINUOUS_LIMIT_RAD = 2 * np.pi

#: Largest URDF file read (an arm's description is tens of kB; meshes are separate files).
MAX_URDF_BYTES = 20_000_000

_MOVING = ("revolute", "continuous")
_DTD = re.compile(rb"<!\s*(?:DOCTYPE|ENTITY)", re.IGNORECASE)


def _yourdfpy() -> Any:
    try:
        import yourdfpy
    except ImportError as exc:
        raise MissingExtraError(
            "reading a URDF needs the yourdfpy package: pip install 'spacecal[urdf]'"
        ) from exc
    return yourdfpy


def _load(source: str | os.PathLike[str] | bytes) -> Any:
    """The parsed URDF (``yourdfpy.URDF``, no meshes, no scene graph) of a file or XML text."""
    if isinstance(source, bytes):
        data, label = source, "the URDF text"
    elif isinstance(source, str) and source.lstrip().startswith("<"):
        data, label = source.encode("utf-8"), "the URDF text"
    else:
        path = Path(source)
        if not path.is_file():
            raise InvalidInputError(f"URDF file {str(path)!r} does not exist")
        if path.stat().st_size > MAX_URDF_BYTES:
            raise InvalidInputError(f"URDF file {path.name!r} is larger than {MAX_URDF_BYTES} bytes")
        data, label = path.read_bytes(), f"URDF file {path.name!r}"
    if len(data) > MAX_URDF_BYTES:
        raise InvalidInputError(f"{label} is larger than {MAX_URDF_BYTES} bytes")
    # no URDF needs a DTD; refused before any parser sees it (entities expand without bound,
    # external ones read other files)
    if _DTD.search(data):
        raise InvalidInputError(f"{label} declares a DTD or entities (<!DOCTYPE, <!ENTITY): refused")
    # strict XML next: yourdfpy falls back to lxml's recovering parser, which reads a cut-off
    # or damaged file as whatever part of it parses
    try:
        root = ElementTree.fromstring(data)
    except ElementTree.ParseError as exc:
        raise InvalidInputError(f"{label} is not a readable URDF: not well-formed XML ({exc})") from exc
    if root.tag != "robot":
        raise InvalidInputError(f"{label} is not a URDF: its root element is <{root.tag}>, not <robot>")
    if any(element.tag.startswith("{") and "xacro" in element.tag for element in root.iter()):
        raise InvalidInputError(
            f"{label} is a xacro file: expand it to a plain URDF first (xacro robot.urdf.xacro > robot.urdf)"
        )
    yourdfpy = _yourdfpy()
    try:
        urdf = yourdfpy.URDF.load(
            io.BytesIO(data), build_scene_graph=False, load_meshes=False, load_collision_meshes=False
        )
    except KeyError as exc:
        raise InvalidInputError(
            f"{label} is not a readable URDF: an element lacks its {exc.args[0]!r} attribute"
        ) from exc
    except (AttributeError, TypeError, IndexError) as exc:
        raise InvalidInputError(
            f"{label} is not a readable URDF: a required element is missing "
            "(e.g. a <joint> without <parent> or <child>)"
        ) from exc
    except Exception as exc:  # ValueError on a malformed number, lxml's own errors
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InvalidInputError(f"{label} is not a readable URDF: {reason}") from exc
    if not urdf.robot.links:
        raise InvalidInputError(f"{label} is not a URDF: its <robot> has no <link> elements")
    return urdf


@dataclass(frozen=True)
class _Axis:
    """A moving joint at q = 0: its line in the base frame (m) and its limits (rad)."""

    name: str
    point_m: FloatArray
    direction: FloatArray
    lower_rad: float
    upper_rad: float


def _upward(parents: dict[str, list[Any]], link: str) -> tuple[list[str], list[Any], str | None]:
    """The links from ``link`` up to the root (``link`` first) and the joints between them;
    the walk stops at a link with more than one parent joint (a closed loop), named third."""
    links: list[str] = [link]
    joints: list[Any] = []
    while True:
        above = parents.get(links[-1], [])
        if len(above) > 1:
            return links, joints, links[-1]
        if not above:
            return links, joints, None
        if above[0].parent in links:
            return links, joints, links[-1]
        joints.append(above[0])
        links.append(above[0].parent)


def _chain(urdf: Any, base_link: str, tool_link: str) -> list[tuple[Any, bool]]:
    """The joints on the path from ``base_link`` to ``tool_link``, in order, each with whether
    the path runs up it (child to parent), checked to be serial."""
    links = {link.name for link in urdf.robot.links}
    for role, name in (("base_link", base_link), ("tool_link", tool_link)):
        if name not in links:
            raise InvalidInputError(f"the URDF has no link {name!r} ({role})")
    parents: dict[str, list[Any]] = {}
    for joint in urdf.robot.joints:
        parents.setdefault(joint.child, []).append(joint)
    base_up, base_joints, base_loop = _upward(parents, base_link)
    tool_up, tool_joints, tool_loop = _upward(parents, tool_link)
    common = [link for link in base_up if link in tool_up]
    if not common:
        loop = base_loop or tool_loop
        if loop is not None:
            names = ", ".join(repr(j.name) for j in parents[loop])
            raise InvalidInputError(
                f"link {loop!r} is the child of joints {names}: a closed loop, not a serial chain"
            )
        raise InvalidInputError(
            f"no kinematic chain joins base_link {base_link!r} and tool_link {tool_link!r} in the URDF"
        )
    # up from the base to the lowest common link, then down to the tool
    meet = common[0]
    chain = [(joint, True) for joint in base_joints[: base_up.index(meet)]]
    chain += [(joint, False) for joint in reversed(tool_joints[: tool_up.index(meet)])]
    for joint, _ in chain:
        if joint.mimic is not None:
            raise InvalidInputError(
                f"joint {joint.name!r} mimics {joint.mimic.joint!r}: coupled joints are not "
                "a serial chain of independent joints"
            )
        if joint.type == "prismatic":
            raise InvalidInputError(
                f"joint {joint.name!r} is prismatic: spacecal models revolute joints only"
            )
        if joint.type not in _MOVING + ("fixed",):
            raise InvalidInputError(
                f"joint {joint.name!r} is of type {joint.type!r}: an arm's chain has revolute, "
                "continuous and fixed joints"
            )
    if not any(joint.type in _MOVING for joint, _ in chain):
        raise InvalidInputError(f"no moving joint between {base_link!r} and {tool_link!r}")
    return chain


def _limits(joint: Any, up: bool) -> tuple[float, float]:
    """The joint's limits (rad); up a joint the angle is the URDF's (only the sense of the
    model's axis is reversed), so the limits are the URDF's too."""
    if joint.type == "continuous":
        return -CONTINUOUS_LIMIT_RAD, CONTINUOUS_LIMIT_RAD
    limit = joint.limit
    if limit is None or limit.lower is None or limit.upper is None:
        raise InvalidInputError(f"revolute joint {joint.name!r} has no <limit lower=... upper=...>")
    lower, upper = float(limit.lower), float(limit.upper)
    if not (np.isfinite(lower) and np.isfinite(upper) and lower <= upper):
        raise InvalidInputError(f"joint {joint.name!r}: limits {lower} to {upper} rad")
    return lower, upper


def _axes_at_zero(chain: list[tuple[Any, bool]]) -> tuple[list[_Axis], FloatArray]:
    """The moving joints' lines in the base frame at q = 0, and ``base_from_tool`` (m)."""
    pose = np.eye(4)
    axes = []
    for joint, up in chain:
        origin = np.eye(4) if joint.origin is None else np.asarray(joint.origin, dtype=float)
        if origin.shape != (4, 4) or not np.all(np.isfinite(origin)):
            raise InvalidInputError(f"joint {joint.name!r}: its <origin> is not a finite pose")
        if not up:
            pose = pose @ origin
        if joint.type in _MOVING:
            axis = np.asarray(joint.axis, dtype=float).reshape(-1)
            norm = float(np.linalg.norm(axis)) if axis.shape == (3,) else 0.0
            if not (np.isfinite(norm) and norm > 1e-12):
                raise InvalidInputError(f"joint {joint.name!r}: axis {axis.tolist()} is not a direction")
            # the axis is given in the joint frame, the child link's frame at q = 0 (where the
            # walk is before a joint it runs up, after one it runs down); up a joint, the parent
            # turns against the child: the opposite sense
            direction = pose[:3, :3] @ (axis / norm) * (-1.0 if up else 1.0)
            axes.append(_Axis(joint.name, pose[:3, 3].copy(), direction, *_limits(joint, up)))
        if up:
            pose = pose @ np.linalg.inv(origin)
    return axes, pose


def _unit(vector: FloatArray) -> FloatArray:
    return vector / np.linalg.norm(vector)


def _frame(origin: FloatArray, x: FloatArray, z: FloatArray) -> FloatArray:
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = x, np.cross(z, x), z, origin
    return pose


def _next_frame(previous: FloatArray, axis: _Axis, tol_m: float) -> FloatArray:
    """DH frame i (4, 4) on joint i+1's axis, from frame i-1 on joint i's axis (base frame, m)."""
    o0, x0, z0 = previous[:3, 3], previous[:3, 0], previous[:3, 2]
    z1, p1 = axis.direction, axis.point_m
    normal = np.cross(z0, z1)
    sine = float(np.linalg.norm(normal))
    if sine > PARALLEL_SINE:
        normal = normal / sine
        # the foot on the new axis of the common normal: p1 + t z1 with (p1 + t z1 - o0) . (z0 x n) = 0
        # (the normal leaves the old axis square to it, in the plane of z0 and n)
        side = np.cross(z0, normal)
        origin = p1 + z1 * (-((p1 - o0) @ side) / (z1 @ side))
        x = normal
    else:
        # parallel: the normal through the previous origin, so d = 0
        offset = p1 - o0
        offset = offset - (offset @ z0) * z0
        origin = o0 + offset
        if np.linalg.norm(offset) > tol_m:
            x = _unit(offset)
        else:  # the same line: keep the previous x
            x = x0
        x = _unit(x - (x @ z1) * z1)
    if x @ x0 < -1e-12:
        x = -x
    return _frame(origin, x, z1)


def _last_frame(previous: FloatArray, base_from_tool: FloatArray) -> FloatArray:
    """The last DH frame: on the last joint's axis at the foot of the tool origin, alpha = a = 0,
    its x axis the tool's x (or y) axis made square to the joint axis."""
    o0, z0 = previous[:3, 3], previous[:3, 2]
    tool = base_from_tool[:3, 3]
    origin = o0 + ((tool - o0) @ z0) * z0
    for candidate in (base_from_tool[:3, 0], base_from_tool[:3, 1]):
        x = candidate - (candidate @ z0) * z0
        if np.linalg.norm(x) > 1e-6:
            return _frame(origin, _unit(x), z0)
    raise AssertionError("the tool frame's x and y axes are both along the joint axis")


def _dh_of(frame_from: FloatArray, frame_to: FloatArray) -> tuple[float, float, float, float]:
    """(theta, d, a, alpha) of ``Rz(theta) Tz(d) Tx(a) Rx(alpha)`` between two DH frames (m)."""
    link = np.linalg.solve(frame_from, frame_to)
    theta = float(np.arctan2(link[1, 0], link[0, 0]))
    alpha = float(np.arctan2(link[2, 1], link[2, 2]))
    d = float(link[2, 3])
    a = float(link[0, 3] * np.cos(theta) + link[1, 3] * np.sin(theta))
    return theta, d, a, alpha


def robot_model_from_urdf(
    source: str | os.PathLike[str] | bytes,
    base_link: str,
    tool_link: str,
    name: str | None = None,
) -> RobotModel:
    """The standard-DH model of the serial chain from ``base_link`` to ``tool_link`` of a URDF.

    Parameters
    ----------
    source : str, path-like or bytes
        A URDF file, or its XML text (a str starting with ``<``, or bytes). Plain URDF: expand
        xacro files first (``xacro robot.urdf.xacro > robot.urdf``).
    base_link : str
        The link DH frame 0 is: its z axis must be joint 1's axis (same sense) and its origin
        on that axis (see the module notes).
    tool_link : str
        The link the model ends in (e.g. ``tool0``, ``panda_link8``); it must lie below
        ``base_link`` in the URDF tree. Side branches (a gripper's fingers, sensors) are ignored.
    name : str, optional
        The model's name; the URDF's robot name if omitted.

    Returns
    -------
    RobotModel
        One DH link per revolute or continuous joint of the chain (fixed joints folded in), in
        mm and rad; ``forward_kinematics(model, q)`` is ``base_from_tool`` of the URDF at the
        joint angles q (J,) in the chain's order. Joint limits are the URDF's (continuous
        joints +-2 pi); ``flange_from_tcp`` (4, 4, mm) is the fixed transform from the last DH
        frame to ``tool_link``.

    Raises
    ------
    InvalidInputError
        Not a readable URDF; a link missing; no chain from base to tool; a closed loop, a mimic,
        prismatic or floating joint in the chain; no moving joint; a base link DH frame 0
        cannot be.
    MissingExtraError
        ``yourdfpy`` is not installed.
    """
    urdf = _load(source)
    chain = _chain(urdf, base_link, tool_link)
    axes, base_from_tool = _axes_at_zero(chain)
    tol_m = ON_AXIS_MM / 1000.0
    first = axes[0]
    lateral = first.point_m[:2]
    tilted = np.linalg.norm(first.direction[:2]) > PARALLEL_SINE or first.direction[2] <= 0.0
    if tilted or np.linalg.norm(lateral) > tol_m:
        raise InvalidInputError(
            f"base_link {base_link!r} cannot be DH frame 0: joint {first.name!r} does not turn "
            f"about its z axis through its origin (axis {np.round(first.direction, 6).tolist()} "
            f"through {np.round(first.point_m * 1000.0, 3).tolist()} mm); spacecal models carry "
            "no base offset, name the link the arm stands on"
        )
    frames = [np.eye(4)]
    for axis in axes[1:]:
        frames.append(_next_frame(frames[-1], axis, tol_m))
    frames.append(_last_frame(frames[-1], base_from_tool))
    dh = np.array([_dh_of(frames[i], frames[i + 1]) for i in range(len(axes))])
    # rounding residue (1e-17 m, -0.0) is written as the zero it stands for
    dh[np.abs(dh) < 1e-13] = 0.0
    model = RobotModel(
        name=name if name is not None else str(urdf.robot.name),
        a_mm=dh[:, 2] * 1000.0,
        d_mm=dh[:, 1] * 1000.0,
        alpha_rad=dh[:, 3],
        theta_offset_rad=dh[:, 0],
        joint_lower_rad=np.array([axis.lower_rad for axis in axes]),
        joint_upper_rad=np.array([axis.upper_rad for axis in axes]),
    )
    # the tool offset from the DH chain's own flange at q = 0, so the zero pose is exact even
    # where nearly parallel axes were taken as parallel
    base_from_tool_mm = base_from_tool.copy()
    base_from_tool_mm[:3, 3] *= 1000.0
    flange = forward_kinematics(model, np.zeros(len(axes)), to_tcp=False)
    flange_from_tcp = np.linalg.solve(flange, base_from_tool_mm)
    flange_from_tcp[3] = [0.0, 0.0, 0.0, 1.0]
    return model.with_tcp(flange_from_tcp)


def joint_speed_limits_from_urdf(
    source: str | os.PathLike[str] | bytes, base_link: str, tool_link: str
) -> FloatArray:
    """The velocity limits (J,) of the moving joints of the chain, rad/s, in the model's order.

    The ``velocity`` of each joint's ``<limit>`` (what a robot kind's joint speeds are made
    from); the chain is the one :func:`robot_model_from_urdf` converts, checked the same way.

    Raises
    ------
    InvalidInputError
        As :func:`robot_model_from_urdf`, and when a moving joint states no positive velocity.
    """
    chain = _chain(_load(source), base_link, tool_link)
    speeds = []
    for joint, _ in chain:
        if joint.type not in _MOVING:
            continue
        velocity = None if joint.limit is None else joint.limit.velocity
        if velocity is None or not (np.isfinite(velocity) and velocity > 0.0):
            raise InvalidInputError(f"joint {joint.name!r} states no positive velocity limit")
        speeds.append(float(velocity))
    return np.array(speeds)
