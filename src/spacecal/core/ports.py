"""Device interfaces: what workflows need from a robot, a tracker and a reference instrument.

Simulated devices (:mod:`spacecal.sim.devices`) and hardware adapters
(:mod:`spacecal.adapters`) implement these; workflows talk to devices only through them.
Units at this boundary are spacecal's: mm, rad, seconds.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

#: Robot safety states, as the workflows understand them.
SAFETY_NORMAL = "normal"
SAFETY_PROTECTIVE_STOP = "protective_stop"
SAFETY_EMERGENCY_STOP = "emergency_stop"

#: Tracker frame status values.
FRAME_OK = "ok"
FRAME_MISSING = "missing"
FRAME_OUT_OF_VOLUME = "out_of_volume"


@dataclass(frozen=True)
class RobotState:
    """One controller state.

    Attributes
    ----------
    time_s : float
        Controller timestamp, s (its own clock).
    joints_rad : numpy.ndarray, shape (6,)
    base_from_tcp : numpy.ndarray, shape (4, 4)
        TCP pose from the controller's own kinematics, mm.
    safety : str
        ``normal``, ``protective_stop`` or ``emergency_stop``.
    moving : bool
        A motion command is still executing.
    """

    time_s: float
    joints_rad: np.ndarray
    base_from_tcp: np.ndarray
    safety: str = SAFETY_NORMAL
    moving: bool = False


@dataclass(frozen=True)
class TrackerFrame:
    """One tracker frame for one tool.

    Attributes
    ----------
    time_s : float
        Tracker timestamp, s (its own clock).
    frame_number : int
    status : str
        ``ok``, ``missing`` or ``out_of_volume``.
    tracker_from_marker : numpy.ndarray, shape (4, 4), or None when not ``ok``
    rms_mm : float
        The tracker's RMS fit error, NaN when not ``ok``.
    spheres_in_tracker : numpy.ndarray, shape (K, 3), or None
        Raw sphere centres where the device reports them, mm.
    """

    time_s: float
    frame_number: int
    status: str
    tracker_from_marker: np.ndarray | None
    rms_mm: float = float("nan")
    spheres_in_tracker: np.ndarray | None = None


@runtime_checkable
class Robot(Protocol):
    """A position-controlled 6-joint arm."""

    def state(self) -> RobotState:
        """The newest controller state."""

    def move_joints(self, joints_rad: np.ndarray, speed_rad_s: float, accel_rad_s2: float) -> None:
        """Move to joint angles (6,) and return when there."""

    def move_linear(
        self, base_from_tcp: np.ndarray, speed_mm_s: float, accel_mm_s2: float, asynchronous: bool = False
    ) -> None:
        """Straight-line TCP move to a pose (4, 4), mm; return at once when ``asynchronous``."""

    def stop(self) -> None:
        """Decelerate and stop any motion now."""


@runtime_checkable
class Tracker(Protocol):
    """An optical tracker following one marker."""

    def next_frame(self, timeout_s: float) -> TrackerFrame:
        """Block until a frame newer than the last one returned, at most ``timeout_s``.

        Raises
        ------
        spacecal.core.errors.DeviceError
            When no new frame arrives in time (unplugged, stalled stream).
        """


@runtime_checkable
class PoseReference(Protocol):
    """An instrument measuring the needle pose independently (the paper's laser tracker).

    It reports in the tracker frame: the paper gives its targets and measures the reached
    poses in one "surgical space".
    """

    def measure_tracker_from_needle(self) -> np.ndarray:
        """The needle pose (4, 4) in the tracker frame, mm."""
