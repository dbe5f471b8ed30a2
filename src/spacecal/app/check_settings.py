"""``spacecal check``'s settings and output: what a pre-operative check is asked, and what it
gives (the check, how its thresholds came, and what the motion gate checked)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from spacecal.app.devices import DeviceSettings
from spacecal.core.errors import InvalidInputError
from spacecal.planning.motion_gate import MotionGateReport
from spacecal.records import CheckResult


@dataclass(frozen=True)
class CheckSettings:
    """``spacecal check``: does a calibration still hold before surgery?

    Attributes
    ----------
    calibration : str
        Calibration JSON.
    recording : str or None
        A recording to check against instead of moving the robot.
    devices : DeviceSettings
        The robot and tracker, as for ``acquire``: ``sim`` (the simulated system of
        ``scenario``) or device URLs.
    scenario : str or None
        Simulated devices only; default: the scenario the calibration's data came from.
    poses : int
        Two or three poses near where the robot stands (the site).
    threshold_mm, threshold_deg : float or None
        Largest TCP and rotation errors that pass: departures from the misfit the calibration
        left at each pose (predicted from its recording), or the whole misfit where that cannot
        be predicted. By default each pose's tolerance from the repeatability the recording
        shows (:func:`spacecal.workflows.check.pose_tolerances`), else from the calibration's
        expected error and residuals (:func:`spacecal.workflows.check.check_thresholds`).
    dry_run : bool
        Plan and check the poses (reach, joint limits) without moving.
    confirm_robot_motion : bool
        Required to move a real robot.
    workspace_box : tuple of 6 floats or None
        ``xmin, xmax, ymin, ymax, zmin, zmax`` in base (mm) the TCP must stay in.
    frames_per_pose : int
        Tracker frames averaged at each pose.
    accept_edited : bool
        Check a calibration edited since it was written (its content hash differs).
    accept_other_devices : bool
        Check on real devices other than those the calibration records (URLs, robot model).
    record : str or None
        Also write the check to this record (an SQLite file or a database URL), opened before
        anything moves.
    simulated_speed : float or None
        Simulated devices only: their speed in times real time (None: as fast as they
        compute), as :attr:`AcquireSettings.simulated_speed`.
    """

    calibration: str
    recording: str | None = None
    devices: DeviceSettings = field(default_factory=DeviceSettings)
    scenario: str | None = None
    poses: int = 3
    threshold_mm: float | None = None
    threshold_deg: float | None = None
    dry_run: bool = False
    confirm_robot_motion: bool = False
    workspace_box: tuple[float, float, float, float, float, float] | None = None
    frames_per_pose: int = 10
    accept_edited: bool = False
    accept_other_devices: bool = False
    record: str | None = None
    simulated_speed: float | None = None

    def __post_init__(self) -> None:
        if self.poses not in (2, 3):
            raise InvalidInputError(f"--poses takes 2 or 3, got {self.poses}")
        for name in ("threshold_mm", "threshold_deg"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and 1e-3 <= value <= 1e3):
                raise InvalidInputError(f"--{name.replace('_', '-')} must be a positive number, got {value}")
        if not 3 <= self.frames_per_pose <= 1000:
            raise InvalidInputError(f"--frames-per-pose must be 3..1000, got {self.frames_per_pose}")


@dataclass(frozen=True)
class CheckOutput:
    """The check's result (None after a dry run), and how the thresholds came."""

    result: CheckResult | None
    threshold_basis: str = ""
    #: What the motion gate checked before the robot moved (None: checked against a recording).
    gate: MotionGateReport | None = None
