"""The motion an acquisition runs on real devices: the paper's sweeps from where the robot
stands, or a plan file checked against the robot, its tool and where it stands; and the
commanded motion limits of ``acquire`` and ``check``."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from spacecal.app._common import open_calibration
from spacecal.core.errors import InvalidInputError
from spacecal.core.ports import (
    Robot,
)
from spacecal.geometry.rotations import rotation_angle
from spacecal.io.acquisition_progress import read_progress, resume_home_joints
from spacecal.io.ndi_rom import read_rom_marker
from spacecal.io.results_json import read_json_object
from spacecal.models.kinematics import RobotModel
from spacecal.models.marker import ndi_8700339_like
from spacecal.models.tracker import TrackerModel
from spacecal.planning.motion import MotionLimits, MotionPlan, motion_plan_from_record
from spacecal.planning.paper_sweeps import PaperSweepSettings, plan_paper_sweeps
from spacecal.planning.visibility import VisibilityModel
from spacecal.records import PlanRecord
from spacecal.workflows.acquisition import plan_fingerprint

if TYPE_CHECKING:
    from spacecal.app.acquire_settings import AcquireSettings


def motion_limits(settings: AcquireSettings) -> MotionLimits:
    """The commanded TCP limits of an acquisition's every move."""
    return settings.motion().limits()


def hardware_plan(settings: AcquireSettings, robot: Robot, model: RobotModel) -> MotionPlan:
    """The paper's sweeps from the robot's current configuration (its home), planned with the
    controller's own kinematic model."""
    state = robot.state()
    home_joints = resume_home_joints(settings.output) if settings.resume else None
    visibility = None
    prior_notes: list[str] = []
    if settings.prior:
        prior, prior_notes = open_calibration(settings.prior, "acquire --prior")
        # the marker in use when its tool definition is given, else the nominal layout: the
        # visibility prediction needs only its face and extent
        marker = read_rom_marker(settings.devices.rom[0]) if settings.devices.rom else ndi_8700339_like()
        visibility = VisibilityModel(TrackerModel(), marker, prior.tracker_from_base, prior.tcp_from_marker)
    sweep = PaperSweepSettings(
        rotation_each_way_deg=settings.rotation_deg,
        translation_stroke_mm=settings.translation_mm,
        limits=motion_limits(settings),
    )
    # On resume the plan is rebuilt from the home it was made from, not from where the robot stopped.
    start = state.joints_rad if home_joints is None else home_joints
    plan = plan_paper_sweeps(model, start, sweep, visibility)
    if visibility is None:
        plan.messages.append("no --prior calibration: marker visibility was not checked")
    else:
        plan.messages.extend(prior_notes)
    return plan


#: How far (joints, rad; TCP, mm) the robot may stand from a plan's home and still run it.
PLAN_HOME_RAD, PLAN_HOME_MM = 0.01, 1.0
#: Largest difference between the plan's tool and the configured one (mm, and rad).
PLAN_TOOL_MM, PLAN_TOOL_RAD = 0.1, 1e-3


def planned_motion(settings: AcquireSettings, robot: Robot, model: RobotModel) -> MotionPlan:
    """The plan file of ``settings.plan``, checked against the robot, its tool and where it stands.

    Raises
    ------
    InvalidInputError
        The file holds no runnable plan, was made for another robot or tool, or the robot
        does not stand at its home, unless a stopped run of it is resumed (nothing has moved).
    """
    assert settings.plan is not None
    record = PlanRecord.from_dict(read_json_object(settings.plan, "plan"), what=settings.plan)
    plan = motion_plan_from_record(record)
    if record.robot_model not in (model.name, "unknown"):
        raise InvalidInputError(
            f"{settings.plan} was planned for a {record.robot_model}, not this {model.name}; "
            "plan again for this robot"
        )
    tool_difference = np.linalg.inv(record.flange_from_tcp) @ model.flange_from_tcp
    if (
        np.linalg.norm(tool_difference[:3, 3]) > PLAN_TOOL_MM
        or rotation_angle(tool_difference[:3, :3]) > PLAN_TOOL_RAD
    ):
        raise InvalidInputError(
            f"{settings.plan} was planned for another tool (TCP in flange "
            f"{np.round(record.flange_from_tcp[:3, 3], 1).tolist()} mm) than the one configured "
            f"({np.round(model.flange_from_tcp[:3, 3], 1).tolist()} mm); plan again with this tool"
        )
    state = robot.state()
    joints_off = float(np.max(np.abs(state.joints_rad - record.home_joints_rad)))
    tcp_off = float(np.linalg.norm(state.base_from_tcp[:3, 3] - record.home_base_from_tcp[:3, 3]))
    # a resumed run of this plan starts where it stopped, which may be anywhere along it: the
    # motion gate checks the way back onto it from where the robot stands
    resuming = settings.resume and _resumes(settings.output, plan)
    if not resuming and (joints_off > PLAN_HOME_RAD or tcp_off > PLAN_HOME_MM):
        raise InvalidInputError(
            f"the robot stands {tcp_off:.1f} mm (joints up to {np.degrees(joints_off):.1f} deg) "
            "from the plan's home; "
            f"move it to the home joints {np.round(np.degrees(record.home_joints_rad), 2).tolist()} deg, "
            "or plan from where it stands"
        )
    if record.simulated_setup and not settings.devices.simulated:
        plan.messages.append(
            f"the plan was made for the simulated set-up '{record.scenario}': marker visibility "
            "was predicted there, not for this tracker"
        )
    return plan


def _resumes(recording: str, plan: MotionPlan) -> bool:
    """Whether ``recording`` has a progress file of ``plan`` (a run of it to resume)."""
    progress = read_progress(recording)
    return progress is not None and progress.plan_fingerprint == plan_fingerprint(plan)
