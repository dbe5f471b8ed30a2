"""The UR ROS driver's kinematics calibration file (``ur_calibration`` -> ``ur_description``).

The UR ROS 2 driver's tool ``ur_calibration`` reads the controller's calibrated DH parameters
and writes a YAML file that ``ur_description`` turns into the URDF joint origins::

    kinematics:
      shoulder:  {x, y, z, roll, pitch, yaw}    # joint origin of shoulder_pan_joint
      upper_arm: {...}                          # shoulder_lift_joint
      forearm:   {...}                          # elbow_joint
      wrist_1:   {...}
      wrist_2:   {...}
      wrist_3:   {...}
      hash: calib_<number>

Each entry is the URDF ``<origin>`` of the joint: the pose of the child link (at joint angle 0)
in the parent link, metres, ``rpy`` as URDF reads it (``R = Rz(yaw) Ry(pitch) Rx(roll)``). The
chain starts at ``base_link_inertia``, which is the controller's base frame (ur_description's
``base``; spacecal's ``base``), and ``wrist_3_link`` coincides with ``tool0`` (the flange), so::

    base_from_flange(q) = O_shoulder Rz(q1) O_upper_arm Rz(q2) ... O_wrist_3 Rz(q6)

How ur_calibration gets the origins from DH (``ur_calibration/src/calibration.cpp``, followed
here): each DH link ``Rz(theta + q) Tz(d) Tx(a) Rx(alpha)`` is split into a ``d/theta`` segment
``[Rz(theta) | (0, 0, d)]`` and an ``a/alpha`` segment ``[Rx(alpha) | (a, 0, 0)]``. For joints 2
and 3 (``correctAxis(1)``, ``correctAxis(2)``) the large ``d`` a real calibration has is removed:
``d`` is set to 0, the next joint's axis is intersected with the x-y plane of the segment's start,
``theta`` becomes the intersection's polar angle (minus pi when ``a != 0``), ``a`` becomes minus
its distance, the ``a/alpha`` segment is rotated by ``Rz(theta_old - theta_new)`` and the next
joint's ``d`` is shortened by the distance moved along its axis. The six joint origins are then
``[seg1_1, seg2_1 seg1_2, ..., seg2_5 seg1_6]``; ``seg2_6`` (``a_6``, ``alpha_6``) has no place in
the description, which ends at the flange: it is folded into the tool offset, exactly
(``flange_from_tcp`` written = ``seg2_6 @ model.flange_from_tcp``), so the description's flange
plus the written tool offset is the model's TCP at every joint configuration.

Two differences from ur_calibration, on purpose:

* rpy: ur_calibration writes Eigen's ``eulerAngles(0, 1, 2)`` (``R = Rx(roll) Ry(pitch)
  Rz(yaw)``), which ``ur_description`` then reads with URDF's ``Rz(yaw) Ry(pitch) Rx(roll)``; for
  UR chains the two agree to ~1e-5 rad because every joint origin is close to a single-axis
  rotation. We write the URDF convention, so the description reproduces the DH model exactly.
* hash: the driver compares the file's ``hash`` with the controller's. We compute it the way the
  driver does (``KinematicsInfo::toHash``: theta, d, a, alpha of each joint streamed with C++'s
  default 6 significant digits, hashed with libstdc++'s ``std::hash<std::string>``), so a file
  written from the controller's own DH values carries the controller's hash; a model with
  spacecal-identified corrections gets the hash of its own values (the driver will then warn
  that the description differs from the controller's calibration, which is true).

Lengths are written in metres (spacecal's models are mm). The tool offset to configure with the
description (the controller's TCP setting: x, y, z in metres, rotation vector in rad) is written
under a ``tool_offset`` key beside ``kinematics`` (``ur_description`` reads only ``kinematics``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from spacecal.core.errors import InvalidInputError
from spacecal.core.text import quoted
from spacecal.core.units import metres_to_mm
from spacecal.geometry.transforms import make_transform
from spacecal.io.atomic import write_text_atomic
from spacecal.io.ros_common import number_field
from spacecal.io.yaml_text import load_yaml_mapping, yaml_comment, yaml_number, yaml_string
from spacecal.models.kinematics import N_JOINTS, RobotModel

#: The ``kinematics`` entries, joint 1 to 6, as ur_calibration names them.
UR_LINK_NAMES = ("shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3")
_MASK64 = (1 << 64) - 1


def _rz(angle: float) -> np.ndarray:
    out = np.eye(4)
    c, s = np.cos(angle), np.sin(angle)
    out[:2, :2] = [[c, -s], [s, c]]
    return out


def _rx(angle: float) -> np.ndarray:
    out = np.eye(4)
    c, s = np.cos(angle), np.sin(angle)
    out[1:3, 1:3] = [[c, -s], [s, c]]
    return out


def _split_chain(d_m, a_m, theta_rad, alpha_rad) -> list[np.ndarray]:
    """The 12 segments of ur_calibration's ``buildChain``: per joint ``[Rz(theta)|d]``, ``[Rx(alpha)|a]``."""
    chain = []
    for i in range(N_JOINTS):
        d_theta = _rz(theta_rad[i])
        d_theta[2, 3] = d_m[i]
        a_alpha = _rx(alpha_rad[i])
        a_alpha[0, 3] = a_m[i]
        chain += [d_theta, a_alpha]
    return chain


def _correct_axis(chain: list[np.ndarray], link: int, theta_rad, alpha_rad) -> None:
    """ur_calibration's ``correctAxis``: move joint ``link``'s ``d`` onto the next joint's axis."""
    d_theta, a_alpha = chain[2 * link], chain[2 * link + 1]
    if d_theta[2, 3] == 0.0:
        return
    a = a_alpha[0, 3]
    next_root = d_theta @ a_alpha
    root = next_root[:3, 3]
    end = (next_root @ chain[2 * link + 2])[:3, 3]
    direction = (end - root) / np.linalg.norm(end - root)
    if abs(direction[2]) < 1e-12:
        raise InvalidInputError(
            f"joint {link + 2}'s axis is parallel to joint {link + 1}'s x-y plane: not a UR-like chain"
        )
    along = -root[2] / direction[2]  # Eigen's intersectionParameter with the plane z = 0
    point = root + along * direction
    new_theta = np.arctan2(point[1], point[0]) - (np.pi if abs(a) > 0 else 0.0)
    new_length = -np.linalg.norm(point)
    correction = along * (1.0 if direction[2] > 0 else -1.0)
    chain[2 * link] = _rz(new_theta)
    corrected = _rz(theta_rad[link] - new_theta) @ _rx(alpha_rad[link])
    corrected[0, 3] = new_length
    chain[2 * link + 1] = corrected
    chain[2 * link + 2] = chain[2 * link + 2].copy()
    chain[2 * link + 2][2, 3] -= correction


def ur_joint_origins(model: RobotModel) -> np.ndarray:
    """The six URDF joint origins of a DH model, as ur_calibration computes them.

    Parameters
    ----------
    model : RobotModel
        Standard DH, mm and rad (a UR arm, possibly with identified corrections).

    Returns
    -------
    numpy.ndarray, shape (6, 4, 4)
        ``parent_link_from_child_link`` at joint angle 0 for shoulder ... wrist_3, mm.

    The last link's ``a_6`` and ``alpha_6`` are not in them: see :func:`ur_flange_from_tcp`.
    """
    theta = np.asarray(model.theta_offset_rad, dtype=float)
    alpha = np.asarray(model.alpha_rad, dtype=float)
    chain = _split_chain(np.asarray(model.d_mm) / 1000.0, np.asarray(model.a_mm) / 1000.0, theta, alpha)
    _correct_axis(chain, 1, theta, alpha)
    _correct_axis(chain, 2, theta, alpha)
    origins = np.array([chain[0]] + [chain[k] @ chain[k + 1] for k in range(1, 2 * N_JOINTS - 1, 2)])
    origins[:, :3, 3] = metres_to_mm(origins[:, :3, 3])
    return origins


def ur_flange_from_tcp(model: RobotModel) -> np.ndarray:
    """The tool offset to use with :func:`ur_joint_origins`: the model's, with the last link's
    ``a_6`` and ``alpha_6`` (which the description cannot hold) folded in.

    Returns
    -------
    numpy.ndarray, shape (4, 4)
        ``description_flange_from_tcp = [Rx(alpha_6) | (a_6, 0, 0)] @ model.flange_from_tcp``, mm.
    """
    last_link = _rx(float(model.alpha_rad[5]))
    last_link[0, 3] = float(model.a_mm[5])
    return last_link @ np.asarray(model.flange_from_tcp, dtype=float)


def folds_last_link(model: RobotModel) -> bool:
    """Whether the model has a non-zero ``a_6`` or ``alpha_6`` (folded into the tool offset)."""
    return bool(model.a_mm[5] != 0.0 or model.alpha_rad[5] != 0.0)


def tool_offset_text(flange_from_tcp) -> str:
    """A tool offset as the UR controller's TCP setting: ``x, y, z`` mm and ``rx, ry, rz`` rad."""
    tool = np.asarray(flange_from_tcp, dtype=float)
    rotvec = Rotation.from_matrix(tool[:3, :3]).as_rotvec()
    return (
        "x, y, z = "
        + ", ".join(f"{v:.4f}" for v in tool[:3, 3])
        + " mm, rx, ry, rz = "
        + ", ".join(f"{v:.6f}" for v in rotvec)
        + " rad"
    )


def urdf_chain_forward_kinematics(joint_origins, joints_rad) -> np.ndarray:
    """``base_from_flange`` through a URDF-style chain: ``O_1 Rz(q1) O_2 Rz(q2) ... O_6 Rz(q6)``.

    Parameters
    ----------
    joint_origins : array_like, shape (6, 4, 4)
        Joint origins, mm (see :func:`ur_joint_origins`).
    joints_rad : array_like, shape (6,) or (N, 6)

    Returns
    -------
    numpy.ndarray, shape (4, 4) or (N, 4, 4), mm
    """
    origins = np.asarray(joint_origins, dtype=float)
    q = np.asarray(joints_rad, dtype=float)
    single = q.ndim == 1
    q = np.atleast_2d(q)
    pose = np.broadcast_to(np.eye(4), (len(q), 4, 4)).copy()
    for i in range(N_JOINTS):
        c, s = np.cos(q[:, i]), np.sin(q[:, i])
        rotation = np.zeros((len(q), 4, 4))
        rotation[:, 0, 0], rotation[:, 0, 1], rotation[:, 1, 0], rotation[:, 1, 1] = c, -s, s, c
        rotation[:, 2, 2] = rotation[:, 3, 3] = 1.0
        pose = pose @ origins[i] @ rotation
    return pose[0] if single else pose


def _libstdcxx_hash(data: bytes) -> int:
    """libstdc++'s ``std::_Hash_bytes`` (64-bit), which ``std::hash<std::string>`` uses."""
    mul = ((0xC6A4A793 << 32) + 0x5BD1E995) & _MASK64

    def shift_mix(value: int) -> int:
        return value ^ (value >> 47)

    length = len(data)
    aligned = length & ~7
    result = (0xC70F6907 ^ (length * mul)) & _MASK64
    for start in range(0, aligned, 8):
        word = int.from_bytes(data[start : start + 8], "little")
        result ^= (shift_mix((word * mul) & _MASK64) * mul) & _MASK64
        result = (result * mul) & _MASK64
    if length & 7:
        result ^= int.from_bytes(data[aligned:], "little")
        result = (result * mul) & _MASK64
    result = (shift_mix(result) * mul) & _MASK64
    return shift_mix(result)


def ur_kinematics_hash(model: RobotModel) -> str:
    """The driver's ``calib_<n>`` hash of a model's DH values (metres, rad), as ``KinematicsInfo::toHash``.

    Verified against ur_description's ``default_kinematics.yaml`` (UR10: ``calib_17227329492635474227``).
    """
    text = "".join(
        format(float(model.theta_offset_rad[i]), "g")
        + format(float(model.d_mm[i]) / 1000.0, "g")
        + format(float(model.a_mm[i]) / 1000.0, "g")
        + format(float(model.alpha_rad[i]), "g")
        for i in range(N_JOINTS)
    )
    return f"calib_{_libstdcxx_hash(text.encode())}"


def ur_calibration_text(model: RobotModel, kinematics_hash: str | None = None) -> str:
    """The kinematics file for ``ur_description`` (``kinematics_params``) of a DH model.

    Parameters
    ----------
    model : RobotModel
        DH parameters in mm and rad.
    kinematics_hash : str, optional
        The ``hash`` entry; by default :func:`ur_kinematics_hash` of the model.
    """
    origins = ur_joint_origins(model)
    tool = ur_flange_from_tcp(model)
    lines = [
        yaml_comment(
            f"UR kinematics for ur_description, written by spacecal from the DH model of {model.name}."
        ),
        "# Each entry: URDF joint origin (child link pose in parent link at joint angle 0), metres,",
        "# rpy = fixed axes x, y, z (R = Rz(yaw) Ry(pitch) Rx(roll)); chain starts at base_link_inertia",
        "# (the controller's base frame).",
    ]
    if folds_last_link(model):
        lines += [
            f"# The model's a_6 = {float(model.a_mm[5]):.6g} mm and "
            f"alpha_6 = {float(model.alpha_rad[5]):.6g} rad",
            "# have no place in the description (it ends at the flange): they are folded into tool_offset",
            "# below, so this description plus tool_offset is the model's TCP exactly.",
        ]
    lines.append("kinematics:")
    for name, origin in zip(UR_LINK_NAMES, origins):
        roll, pitch, yaw = Rotation.from_matrix(origin[:3, :3]).as_euler("xyz")
        x, y, z = origin[:3, 3] / 1000.0
        lines.append(f"  {name}:")
        for key, value in (("x", x), ("y", y), ("z", z), ("roll", roll), ("pitch", pitch), ("yaw", yaw)):
            lines.append(f"    {key}: {yaml_number(value)}")
    lines.append(f"  hash: {yaml_string(kinematics_hash or ur_kinematics_hash(model))}")
    lines += [
        "# The tool offset to set as the controller's TCP with this description (flange -> TCP):",
        "# x, y, z metres, rx, ry, rz rotation vector in rad.",
        "tool_offset:",
    ]
    x, y, z = tool[:3, 3] / 1000.0
    rx, ry, rz = Rotation.from_matrix(tool[:3, :3]).as_rotvec()
    for key, value in (("x", x), ("y", y), ("z", z), ("rx", rx), ("ry", ry), ("rz", rz)):
        lines.append(f"  {key}: {yaml_number(value)}")
    return "\n".join(lines) + "\n"


def write_ur_calibration(path: str | Path, model: RobotModel, kinematics_hash: str | None = None) -> Path:
    """Write :func:`ur_calibration_text` to ``path``; pass it to the driver as ``kinematics_params_file``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(ur_calibration_text(model, kinematics_hash), path)
    return path


@dataclass(frozen=True)
class UrKinematics:
    """A UR kinematics file read back.

    Attributes
    ----------
    joint_origins : numpy.ndarray, shape (6, 4, 4)
        URDF joint origins shoulder ... wrist_3 (child link in parent link at q = 0), mm.
    kinematics_hash : str
        The file's ``hash`` entry ("" when absent).
    flange_from_tcp : numpy.ndarray, shape (4, 4) or None
        The file's ``tool_offset``, mm (None when absent, as in ur_calibration's files).
    """

    joint_origins: np.ndarray
    kinematics_hash: str = ""
    flange_from_tcp: np.ndarray | None = None

    def forward_kinematics(self, joints_rad) -> np.ndarray:
        """``base_from_flange`` (controller base to tool0), (4, 4) or (N, 4, 4), mm."""
        return urdf_chain_forward_kinematics(self.joint_origins, joints_rad)


def read_ur_calibration(path: str | Path) -> UrKinematics:
    """Read a ur_calibration / ``default_kinematics.yaml`` file (rpy read as URDF reads it)."""
    path = Path(path)
    data = load_yaml_mapping(path, "UR kinematics")
    kinematics = data.get("kinematics")
    if not isinstance(kinematics, dict):
        raise InvalidInputError(f"{path}: missing the 'kinematics' mapping")
    origins = []
    for name in UR_LINK_NAMES:
        where = f"{path}: kinematics.{name}"
        if not isinstance(kinematics.get(name), dict):
            raise InvalidInputError(f"{path}: missing kinematics.{name}")
        entry = kinematics[name]
        xyz = [number_field(entry, k, where) for k in ("x", "y", "z")]
        rpy = [number_field(entry, k, where) for k in ("roll", "pitch", "yaw")]
        origins.append(make_transform(Rotation.from_euler("xyz", rpy).as_matrix(), metres_to_mm(xyz)))
    kinematics_hash = kinematics.get("hash", "")
    if kinematics_hash is None:
        kinematics_hash = ""
    if isinstance(kinematics_hash, bool) or not isinstance(kinematics_hash, (str, int)):
        raise InvalidInputError(f"{path}: kinematics.hash is {quoted(kinematics_hash)}, expected text")
    tool = data.get("tool_offset")
    flange_from_tcp = None
    if tool is not None:
        if not isinstance(tool, dict):
            raise InvalidInputError(f"{path}: tool_offset is {quoted(tool)}, expected a mapping")
        where = f"{path}: tool_offset"
        xyz = [number_field(tool, k, where) for k in ("x", "y", "z")]
        rotvec = [number_field(tool, k, where) for k in ("rx", "ry", "rz")]
        flange_from_tcp = make_transform(Rotation.from_rotvec(rotvec).as_matrix(), metres_to_mm(xyz))
    return UrKinematics(np.array(origins), str(kinematics_hash), flange_from_tcp)
