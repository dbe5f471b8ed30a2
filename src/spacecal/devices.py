"""Device interfaces: what workflows need from a robot, a tracker and a reference instrument.

Simulated devices (:mod:`spacecal.sim`) and hardware adapters implement these; workflows
talk to devices only through them.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Robot(Protocol):
    """A position-controlled 6-joint arm."""

    def joint_positions(self) -> np.ndarray:
        """Current joint angles (6,), rad."""

    def reported_base_from_tcp(self) -> np.ndarray:
        """The TCP pose (4, 4) the controller reports from its own kinematic model, mm."""

    def move_joints(self, joints_rad: np.ndarray, speed_rad_s: float, accel_rad_s2: float) -> None:
        """Move to joint angles (6,) and return when there."""


@runtime_checkable
class PoseReference(Protocol):
    """An instrument measuring the needle pose independently (the paper's laser tracker).

    It reports in the tracker frame: the paper gives its targets and measures the reached
    poses in one "surgical space".
    """

    def measure_tracker_from_needle(self) -> np.ndarray:
        """The needle pose (4, 4) in the tracker frame, mm."""
