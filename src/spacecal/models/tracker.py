"""Optical tracker descriptions: measurement volume and line-of-sight visibility.

The NDI Polaris frame has its origin at the position sensor and its measurement volume
along -z (reported z values are negative). The Vicra's pyramid volume runs from 557 mm to
1336 mm from the sensor, 936 mm x 887 mm at its far face (NDI Polaris Vicra specification);
we model it as a frustum with the near face scaled by depth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spacecal.geometry.arrays import ArrayLike, BoolArray, FloatArray
from spacecal.geometry.transforms import transform_points_by_stack


@dataclass(frozen=True)
class PyramidVolume:
    """A pyramid-shaped measurement volume along the tracker's -z axis.

    Attributes
    ----------
    near_mm, far_mm : float
        Depth range (distance along -z) of the volume.
    far_width_mm, far_height_mm : float
        Extent in x and y at the far face; the sides are planes through the sensor
        origin, so the extent scales with depth.
    """

    near_mm: float = 557.0
    far_mm: float = 1336.0
    far_width_mm: float = 936.0
    far_height_mm: float = 887.0

    def contains(self, points_in_tracker: ArrayLike) -> BoolArray:
        """Boolean (N,): which points (N, 3), mm, lie inside the volume."""
        p = np.atleast_2d(np.asarray(points_in_tracker, dtype=float))
        depth = -p[:, 2]
        scale = depth / self.far_mm
        inside_depth = (depth >= self.near_mm) & (depth <= self.far_mm)
        inside_x = np.abs(p[:, 0]) <= 0.5 * self.far_width_mm * scale
        inside_y = np.abs(p[:, 1]) <= 0.5 * self.far_height_mm * scale
        return inside_depth & inside_x & inside_y

    def centre(self) -> FloatArray:
        """A point in the middle of the volume (3,), mm."""
        return np.array([0.0, 0.0, -0.5 * (self.near_mm + self.far_mm)])


def view_angles_rad(tracker_from_marker: ArrayLike, face_normal_in_marker: ArrayLike) -> FloatArray:
    """Angle between a marker's face normal and its line of sight to the sensor, (N,) rad.

    Passive spheres are seen from the front of the marker only; trackers lose them, or
    measure them poorly, as the marker turns away. The sensor sits at the tracker origin.

    Parameters
    ----------
    tracker_from_marker : array_like, shape (N, 4, 4)
    face_normal_in_marker : array_like, shape (3,)
        Unit normal of the marker face, pointing out of the front.
    """
    t = np.asarray(tracker_from_marker, dtype=float).reshape(-1, 4, 4)
    normal = t[:, :3, :3] @ np.asarray(face_normal_in_marker, dtype=float)
    to_sensor = -t[:, :3, 3]
    to_sensor /= np.linalg.norm(to_sensor, axis=1, keepdims=True)
    return np.arccos(np.clip(np.sum(normal * to_sensor, axis=1), -1.0, 1.0))


@dataclass(frozen=True)
class TrackerModel:
    """What limits where and how a tracker measures.

    Attributes
    ----------
    name : str
    volume : PyramidVolume
    rate_hz : float
        Maximum frame rate (Vicra: 20 Hz).
    max_view_angle_deg : float
        Marker faces turned further than this from the line of sight are not tracked.
    """

    name: str = "Polaris Vicra"
    volume: PyramidVolume = PyramidVolume()
    rate_hz: float = 20.0
    max_view_angle_deg: float = 70.0

    def visible(
        self,
        tracker_from_marker: ArrayLike,
        sphere_positions_in_marker: ArrayLike,
        face_normal_in_marker: ArrayLike,
    ) -> BoolArray:
        """Boolean (N,): the marker is tracked (all spheres in the volume and facing the sensor).

        Parameters
        ----------
        tracker_from_marker : array_like, shape (N, 4, 4)
        sphere_positions_in_marker : array_like, shape (K, 3), mm
        face_normal_in_marker : array_like, shape (3,)
        """
        t = np.asarray(tracker_from_marker, dtype=float).reshape(-1, 4, 4)
        spheres = transform_points_by_stack(t, sphere_positions_in_marker)
        in_volume = self.volume.contains(spheres.reshape(-1, 3)).reshape(len(t), -1).all(axis=1)
        facing = view_angles_rad(t, face_normal_in_marker) <= np.radians(self.max_view_angle_deg)
        return in_volume & facing
