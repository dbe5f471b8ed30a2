"""The options every command that moves the robot shares (``acquire``, ``check``, ``verify``,
``guide``): which devices, how fast, inside which box, and whether motion is confirmed.

They are checked here once, so that every motion is refused the same way for the same bad
value, before any device is opened.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from spacecal.app.devices import DeviceSettings
from spacecal.core.errors import InvalidInputError
from spacecal.planning.motion import MotionLimits
from spacecal.sim.scenario import DEFAULT_SCENARIO, Scenario
from spacecal.workflows.acquisition import AcquisitionSettings

#: Accepted ranges of the motion's numeric settings (a tiny speed would never finish).
MOTION_RANGES = {
    "speed_mm_s": (1.0, 1000.0),
    "accel_mm_s2": (1.0, 10_000.0),
    "angular_speed_deg_s": (0.5, 180.0),
}

#: Accepted speeds of simulated devices, in times real time.
SIMULATED_SPEED_RANGE = (0.1, 1000.0)

#: Where the commanded limits come from (named in a refusal of the motion gate).
COMMANDED_BY = "--speed-mm-s, --accel-mm-s2, --angular-speed-deg-s"

WorkspaceBox = tuple[float, float, float, float, float, float]


@dataclass(frozen=True)
class MotionSettings:
    """How a command moves the robot.

    Attributes
    ----------
    devices : DeviceSettings
        The robot and tracker: ``sim`` (the simulated system of ``scenario``) or device URLs.
    scenario : str or Scenario
        The simulated devices' world (a preset, a scenario file or the scenario itself).
    dry_run : bool
        Check the motion (reach, joint limits, visibility, workspace box) without moving.
    confirm_robot_motion : bool
        Required to move a real robot.
    speed_mm_s, accel_mm_s2, angular_speed_deg_s : float
        TCP limits of every move (mm/s, mm/s^2, deg/s).
    workspace_box : tuple of 6 floats or None
        ``xmin, xmax, ymin, ymax, zmin, zmax`` in the robot base frame (mm) the TCP must stay in.
    simulated_speed : float or None
        Simulated devices run this many simulated seconds per real second; None: as fast as
        they compute.
    simulated_start_s : float
        The simulated clock's start (a resumed simulated run continues its recording's time).
    """

    devices: DeviceSettings = field(default_factory=DeviceSettings)
    scenario: str | Scenario = DEFAULT_SCENARIO
    dry_run: bool = False
    confirm_robot_motion: bool = False
    speed_mm_s: float = AcquisitionSettings.linear_speed_mm_s
    accel_mm_s2: float = AcquisitionSettings.linear_accel_mm_s2
    angular_speed_deg_s: float = float(np.degrees(MotionLimits.angular_speed_rad_s))
    workspace_box: WorkspaceBox | None = None
    simulated_speed: float | None = None
    simulated_start_s: float = 0.0

    def __post_init__(self) -> None:
        check_motion_options(self.speed_mm_s, self.accel_mm_s2, self.angular_speed_deg_s)
        check_workspace_box(self.workspace_box)
        check_simulated_speed(self.simulated_speed)

    def limits(self) -> MotionLimits:
        """The commanded TCP limits of every move."""
        return MotionLimits(
            linear_speed_mm_s=self.speed_mm_s,
            linear_accel_mm_s2=self.accel_mm_s2,
            angular_speed_rad_s=np.radians(self.angular_speed_deg_s),
        )


def check_motion_options(speed_mm_s: object, accel_mm_s2: object, angular_speed_deg_s: object) -> None:
    """Refuse a speed, acceleration or angular speed outside :data:`MOTION_RANGES` in one line."""
    values = {
        "speed_mm_s": speed_mm_s,
        "accel_mm_s2": accel_mm_s2,
        "angular_speed_deg_s": angular_speed_deg_s,
    }
    for name, (low, high) in MOTION_RANGES.items():
        value = values[name]
        if not (isinstance(value, (int, float)) and math.isfinite(value) and low <= value <= high):
            raise InvalidInputError(
                f"--{name.replace('_', '-')} must be a positive number in {low:g}..{high:g}, got {value}"
            )


def check_workspace_box(workspace_box: object) -> None:
    """Refuse a ``--workspace-box`` that is not six finite limits, each min below its max."""
    if workspace_box is None:
        return
    box = np.asarray(workspace_box, dtype=float)
    if box.shape != (6,) or not np.all(np.isfinite(box)) or np.any(box[0::2] >= box[1::2]):
        raise InvalidInputError("--workspace-box takes xmin,xmax,ymin,ymax,zmin,zmax in mm, each min < max")
    if np.any(np.abs(box) > 1e5):
        raise InvalidInputError("--workspace-box: each limit must be within +-100000 mm")


def check_simulated_speed(speed: object) -> None:
    """Refuse a simulated devices' speed outside :data:`SIMULATED_SPEED_RANGE`."""
    low, high = SIMULATED_SPEED_RANGE
    if speed is not None and not (
        isinstance(speed, (int, float)) and math.isfinite(speed) and low <= speed <= high
    ):
        raise InvalidInputError(
            f"the simulated devices' speed must be {low:g}..{high:g} times real time, got {speed}"
        )
