"""``spacecal acquire``'s settings: the calibration motion's own options beside the motion
options every moving command shares (:class:`~spacecal.app.motion_settings.MotionSettings`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from spacecal.app.devices import DeviceSettings
from spacecal.app.motion_settings import MotionSettings, WorkspaceBox
from spacecal.core.errors import InvalidInputError
from spacecal.planning.motion import MotionLimits
from spacecal.planning.paper_sweeps import PaperSweepSettings
from spacecal.sim.scenario import DEFAULT_SCENARIO
from spacecal.workflows.acquisition import AcquisitionSettings

#: Accepted ranges of the sweeps' own settings, deg and mm.
SWEEP_RANGES = {
    "rotation_deg": (1.0, 180.0),
    "translation_mm": (1.0, 2000.0),
}


@dataclass(frozen=True)
class AcquireSettings:
    """``spacecal acquire``: run the calibration motion while sampling the tracker.

    Attributes
    ----------
    output : str
        Recording CSV to write (each sample flushed to disk).
    devices : DeviceSettings
        The robot and tracker: ``sim`` (the simulated system of ``scenario``) or device URLs,
        with the tracker's tool definitions and rate and the robot's model and tool.
    scenario : str
        Scenario of the simulated devices.
    dry_run : bool
        Check the plan (reach, joint limits, visibility, workspace box) without moving.
    resume : bool
        Continue a stopped acquisition of the same plan.
    confirm_robot_motion : bool
        Required to move a real robot.
    speed_mm_s, accel_mm_s2, angular_speed_deg_s : float
        TCP limits of every move.
    workspace_box : tuple of 6 floats or None
        ``xmin, xmax, ymin, ymax, zmin, zmax`` in base (mm) the TCP must stay in.
    prior : str or None
        An earlier calibration, to check marker visibility along the plan.
    rotation_deg, translation_mm : float
        Rotation sweep each way; translation sweep stroke.
    plan : str or None
        A plan file (``spacecal plan -o``) to run instead of the paper's sweeps from where the
        robot stands; the robot must stand at the plan's home.
    stop_and_go : int
        0: sample while moving. N > 0: stop at stations along each recorded move, let the arm
        settle and average N frames per station (no sample depends on the clock offset).
    live_view : int or None
        Show the marker, the sweeps and the samples in a web browser at
        ``http://127.0.0.1:PORT/`` while the motion runs (0: any free port); not on a dry run.
    simulated_speed : float or None
        Simulated devices run this many simulated seconds per real second (1: as long as the
        robot would take, as a training station shows it); None: as fast as they compute.
    """

    output: str
    devices: DeviceSettings = field(default_factory=DeviceSettings)
    scenario: str = DEFAULT_SCENARIO
    dry_run: bool = False
    resume: bool = False
    confirm_robot_motion: bool = False
    speed_mm_s: float = AcquisitionSettings.linear_speed_mm_s
    accel_mm_s2: float = AcquisitionSettings.linear_accel_mm_s2
    angular_speed_deg_s: float = float(np.degrees(MotionLimits.angular_speed_rad_s))
    workspace_box: WorkspaceBox | None = None
    prior: str | None = None
    rotation_deg: float = PaperSweepSettings.rotation_each_way_deg
    translation_mm: float = PaperSweepSettings.translation_stroke_mm
    plan: str | None = None
    stop_and_go: int = 0
    live_view: int | None = None
    simulated_speed: float | None = None

    def __post_init__(self) -> None:
        if not (
            isinstance(self.stop_and_go, int) and (self.stop_and_go == 0 or 3 <= self.stop_and_go <= 1000)
        ):
            raise InvalidInputError(f"--stop-and-go takes 3..1000 frames per station, got {self.stop_and_go}")
        self.motion()  # the shared motion options, checked as every moving command checks them
        for name, (low, high) in SWEEP_RANGES.items():
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and low <= value <= high):
                raise InvalidInputError(
                    f"--{name.replace('_', '-')} must be a positive number in {low:g}..{high:g}, got {value}"
                )

    def motion(self, simulated_start_s: float = 0.0) -> MotionSettings:
        """The motion options of this acquisition (its devices, limits, box and confirmation)."""
        return MotionSettings(
            devices=self.devices,
            scenario=self.scenario,
            dry_run=self.dry_run,
            confirm_robot_motion=self.confirm_robot_motion,
            speed_mm_s=self.speed_mm_s,
            accel_mm_s2=self.accel_mm_s2,
            angular_speed_deg_s=self.angular_speed_deg_s,
            workspace_box=self.workspace_box,
            simulated_speed=self.simulated_speed,
            simulated_start_s=simulated_start_s,
        )
