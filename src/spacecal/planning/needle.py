"""Needle planning: a CT-planned path (entry and target in image space) to a robot pose.

Chain (CONVENTIONS §2)::

    base_from_image = base_from_tracker @ tracker_from_image
    tracker_from_image = tracker_from_reference @ reference_from_image   (patient registration)

The needle frame has its origin at the tip and its z axis along the needle, pointing from
entry to target. The robot first holds the needle ``standoff_mm`` before the entry, on the
line; insertion ends with the tip at the target.

Predicted errors combine independent sources in quadrature at the entry and the target:
the registration's TRE (Fitzpatrick–West–Maurer), the calibration's predicted TRE (its
covariance), and the robot's positioning scatter. Direction error follows from the two
point errors over the path length.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spacecal.core.errors import DegenerateDataError, UnreachableError
from spacecal.geometry.transforms import (
    MEASURED_TRANSFORM_ATOL,
    apply_transform,
    check_transform,
    invert_transform,
    make_transform,
)
from spacecal.models.kinematics import RobotModel, forward_kinematics, inverse_kinematics
from spacecal.planning.visibility import VisibilityModel


def needle_pose(tip_in_frame, direction_in_frame, roll_reference=(1.0, 0.0, 0.0)) -> np.ndarray:
    """``frame_from_needle`` (4, 4): origin at the tip, z along the (unit) needle direction.

    The x axis is the component of ``roll_reference`` perpendicular to the needle (a fixed
    roll, so that planned and reached poses are comparable).
    """
    z = np.asarray(direction_in_frame, dtype=float)
    z = z / np.linalg.norm(z)
    x = np.asarray(roll_reference, dtype=float) - z * (z @ np.asarray(roll_reference, dtype=float))
    if np.linalg.norm(x) < 1e-6:
        x = np.array([0.0, 1.0, 0.0]) - z * z[1]
    x /= np.linalg.norm(x)
    return make_transform(np.column_stack([x, np.cross(z, x), z]), tip_in_frame)


@dataclass
class NeedlePlan:
    """A needle path mapped to the robot.

    Attributes
    ----------
    base_from_needle_standoff, base_from_needle_target : numpy.ndarray, shape (4, 4)
        The needle before the entry and at the end of insertion, mm.
    joints_standoff_rad, joints_target_rad : numpy.ndarray, shape (6,)
    path_length_mm : float
    predicted_error : dict
        ``entry_mm``, ``target_mm``, ``direction_deg`` and the contributions.
    """

    base_from_needle_standoff: np.ndarray
    base_from_needle_target: np.ndarray
    joints_standoff_rad: np.ndarray
    joints_target_rad: np.ndarray
    path_length_mm: float
    predicted_error: dict


def plan_needle(
    entry_in_image,
    target_in_image,
    tracker_from_image,
    tracker_from_base,
    robot_model: RobotModel,
    reference_joints_rad,
    standoff_mm: float = 20.0,
    tcp_from_needle=None,
    registration_tre_mm=(0.0, 0.0),
    calibration_tre_mm=(0.0, 0.0),
    robot_position_sd_mm: float = 0.0,
    visibility: VisibilityModel | None = None,
) -> NeedlePlan:
    """Map an image-space needle path to robot poses and predict how well it will land.

    Parameters
    ----------
    entry_in_image, target_in_image : array_like, shape (3,), mm
    tracker_from_image : array_like, shape (4, 4)
        The patient registration.
    tracker_from_base : array_like, shape (4, 4)
        The calibration.
    robot_model : RobotModel
        Model IK is solved with; its TCP is the needle tip unless ``tcp_from_needle`` says otherwise.
    reference_joints_rad : array_like, shape (6,)
        IK picks the branch nearest this configuration.
    standoff_mm : float
    registration_tre_mm, calibration_tre_mm : tuple of float
        Predicted RMS errors at (entry, target) from each source.
    robot_position_sd_mm : float
        Per-axis s.d. of the robot's positioning at the target.
    visibility : VisibilityModel, optional
        If given, the marker must be visible to the tracker at both poses (navigation needs it).

    Raises
    ------
    DegenerateDataError
        If entry and target coincide.
    UnreachableError
        If either pose is outside the robot's reach or joint limits, or hides the marker.
    """
    entry = np.asarray(entry_in_image, dtype=float)
    target = np.asarray(target_in_image, dtype=float)
    length = float(np.linalg.norm(target - entry))
    if length < 1e-6:
        raise DegenerateDataError("entry and target coincide: no needle direction")
    tracker_from_image = check_transform(
        tracker_from_image, "tracker_from_image", atol=MEASURED_TRANSFORM_ATOL
    )
    tracker_from_base = check_transform(tracker_from_base, "tracker_from_base", atol=MEASURED_TRANSFORM_ATOL)
    base_from_image = invert_transform(tracker_from_base) @ tracker_from_image
    direction_in_base = base_from_image[:3, :3] @ ((target - entry) / length)
    entry_in_base = apply_transform(base_from_image, entry)
    target_in_base = apply_transform(base_from_image, target)
    needle_from_tcp = np.eye(4) if tcp_from_needle is None else invert_transform(tcp_from_needle)
    # The roll about the needle is free: keep it nearest the tool's current orientation, so the
    # marker keeps facing the tracker as it did.
    current = forward_kinematics(
        robot_model, np.asarray(reference_joints_rad, dtype=float)
    ) @ invert_transform(needle_from_tcp)
    roll = current[:3, 0]
    at_target = needle_pose(target_in_base, direction_in_base, roll)
    standoff = needle_pose(entry_in_base - standoff_mm * direction_in_base, direction_in_base, roll)
    try:
        joints_standoff = inverse_kinematics(robot_model, standoff @ needle_from_tcp, reference_joints_rad)
        joints_target = inverse_kinematics(robot_model, at_target @ needle_from_tcp, joints_standoff)
    except UnreachableError as exc:
        raise UnreachableError(f"needle path cannot be reached: {exc}") from None
    if visibility is not None:
        tcp_poses = np.array([standoff @ needle_from_tcp, at_target @ needle_from_tcp])
        seen = visibility.visible(tcp_poses)
        if not seen.all():
            where = "at the stand-off" if not seen[0] else "at the target"
            raise UnreachableError(f"needle path: the marker is not visible to the tracker {where}")
    robot_3d = np.sqrt(3.0) * robot_position_sd_mm
    entry_error = float(np.sqrt(registration_tre_mm[0] ** 2 + calibration_tre_mm[0] ** 2 + robot_3d**2))
    target_error = float(np.sqrt(registration_tre_mm[1] ** 2 + calibration_tre_mm[1] ** 2 + robot_3d**2))
    direction = float(np.degrees(np.sqrt(entry_error**2 + target_error**2) / length))
    predicted = {
        "entry_mm": entry_error,
        "target_mm": target_error,
        "direction_deg": direction,
        "contributions": {
            "registration_mm": list(registration_tre_mm),
            "calibration_mm": list(calibration_tre_mm),
            "robot_mm": robot_3d,
        },
    }
    return NeedlePlan(standoff, at_target, joints_standoff, joints_target, length, predicted)
