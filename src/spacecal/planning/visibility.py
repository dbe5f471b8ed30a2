"""Predict from a prior set-up whether the tracker will see the marker at planned poses."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spacecal.models.marker import MarkerGeometry
from spacecal.models.tracker import TrackerModel


@dataclass(frozen=True)
class VisibilityModel:
    """A tracker, a marker, and rough prior poses of the two unknowns.

    Planning happens before calibration, so visibility is predicted from a prior (a rough
    earlier calibration, a measured set-up, or in simulation the scenario's layout).

    Attributes
    ----------
    tracker : TrackerModel
    marker : MarkerGeometry
    tracker_from_base : numpy.ndarray, shape (4, 4), mm
    tcp_from_marker : numpy.ndarray, shape (4, 4), mm
    """

    tracker: TrackerModel
    marker: MarkerGeometry
    tracker_from_base: np.ndarray
    tcp_from_marker: np.ndarray

    def visible(self, base_from_tcp_stack) -> np.ndarray:
        """Boolean (N,): predicted visibility at TCP poses (N, 4, 4)."""
        tracker_from_marker = self.tracker_from_base @ np.asarray(base_from_tcp_stack) @ self.tcp_from_marker
        return self.tracker.visible(
            tracker_from_marker, self.marker.spheres_in_marker, self.marker.face_normal_in_marker
        )
