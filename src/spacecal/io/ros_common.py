"""Conversions at the boundary with ROS: metres and ``x, y, z, w`` quaternions outside, mm and 4x4 inside.

ROS messages (``geometry_msgs/Transform``, ``Pose``) and the files of ROS tools carry
translations in metres and quaternions in the order ``x, y, z, w``. A ROS transform with
``header.frame_id = P`` and ``child_frame_id = C`` is the pose of C in P, i.e. our
``p_from_c`` (it maps coordinates given in C into P). These helpers convert exactly that and
nothing else; which frames a file or message names is decided by the caller.
"""

from __future__ import annotations

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.core.strict_numbers import number_shown, number_value
from spacecal.core.text import quoted
from spacecal.core.units import metres_to_mm, mm_to_metres
from spacecal.geometry.transforms import make_transform, matrix_to_quaternion_wxyz, quaternion_wxyz_to_matrix

#: Largest deviation of a quaternion's norm from 1 accepted in a file (ROS tools write 1e-9 or better).
#: Joint names the UR ROS drivers (ur_robot_driver) publish, joint 1 to 6, without a prefix.
UR_JOINT_NAMES = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
QUATERNION_NORM_TOLERANCE = 1e-6
#: Largest translation of a pose along an axis accepted, m: no robot or optical tracker of a
#: calibration set-up spans this; a larger value (1e300, a flipped exponent bit, mm written as
#: m) is a damaged message or file.
MAX_TRANSLATION_M = 100.0
#: Largest magnitude of a quaternion component read (its norm is checked after): it only keeps
#: absurd values (1e300) from overflowing the norm into a message about infinity.
MAX_QUATERNION_COMPONENT = 2.0


def transform_from_ros(translation_m, quaternion_xyzw, what: str = "transform") -> np.ndarray:
    """4x4 transforms (mm) from ROS translations (m) and ``x, y, z, w`` quaternions.

    Parameters
    ----------
    translation_m : array_like, shape (3,) or (N, 3)
        Translation of the child frame's origin in the parent frame, metres.
    quaternion_xyzw : array_like, shape (4,) or (N, 4)
        Rotation of the child frame in the parent frame, scalar last (ROS order).
    what : str
        Named in the error when a quaternion is not a unit quaternion.

    Returns
    -------
    numpy.ndarray, shape (4, 4) or (N, 4, 4)
        ``parent_from_child`` in mm.
    """
    translation_m = np.asarray(translation_m, dtype=float)
    quaternion_xyzw = np.asarray(quaternion_xyzw, dtype=float)
    norms = np.linalg.norm(quaternion_xyzw, axis=-1)
    bad = ~np.isfinite(norms) | (np.abs(norms - 1.0) > QUATERNION_NORM_TOLERANCE)
    if np.any(bad):
        first = float(np.atleast_1d(norms)[np.flatnonzero(np.atleast_1d(bad))[0]])
        raise InvalidInputError(
            f"{what}: quaternion norm {first:.6g}, expected a unit quaternion (x, y, z, w)"
        )
    quaternion_wxyz = np.roll(quaternion_xyzw / norms[..., None], 1, axis=-1)
    return make_transform(quaternion_wxyz_to_matrix(quaternion_wxyz), metres_to_mm(translation_m))


def transform_to_ros(parent_from_child) -> tuple[np.ndarray, np.ndarray]:
    """Split a transform (4, 4) in mm into a ROS translation (3,) in m and a quaternion ``x, y, z, w`` (4,).

    The quaternion has a non-negative ``w`` (the sign is free; this makes files reproducible).
    """
    parent_from_child = np.asarray(parent_from_child, dtype=float)
    if parent_from_child.shape != (4, 4) or not np.all(np.isfinite(parent_from_child)):
        raise InvalidInputError(f"expected a finite 4x4 transform, got shape {parent_from_child.shape}")
    quaternion_wxyz = matrix_to_quaternion_wxyz(parent_from_child[:3, :3])
    return mm_to_metres(parent_from_child[:3, 3]), np.roll(quaternion_wxyz, -1)


def number_text(value: float) -> str:
    """A float written so that reading it back gives the same double (shortest round-trip form)."""
    value = float(value)
    if not np.isfinite(value):
        raise InvalidInputError(f"cannot write the non-finite number {value!r}")
    return repr(value + 0.0)  # + 0.0 turns -0.0 into 0.0


def field(mapping, key: str, where: str):
    """``mapping[key]`` or an InvalidInputError naming the missing field and where it was expected."""
    if not isinstance(mapping, dict) or key not in mapping:
        raise InvalidInputError(f"{where}: missing field {key!r}")
    return mapping[key]


def number_field(mapping, key: str, where: str, max_abs: float | None = None) -> float:
    """A finite number from ``mapping[key]`` (no larger in magnitude than ``max_abs`` when given);
    one clear line naming ``where`` and the field otherwise.

    An integer of any size is refused without being converted first
    (:func:`~spacecal.core.strict_numbers.number_value`).
    """
    value = field(mapping, key, where)
    try:
        return number_value(value, max_abs)
    except ValueError:
        number = isinstance(value, (int, float)) and not isinstance(value, bool)
        shown = number_shown(value) if number else quoted(value)
        bound = "" if max_abs is None else f" of magnitude at most {max_abs:g}"
        raise InvalidInputError(
            f"{where}: field {key!r} is {shown}, expected a finite number{bound}"
        ) from None
