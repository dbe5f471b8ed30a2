"""App functions that move a robot: ``acquire``, ``check``, and ``plan`` (which plans motions).

This is where devices are chosen: ``sim`` gives the simulated robot and tracker of a scenario
(running in simulated time), URLs give hardware adapters (``ur://HOST``, ``ndi://PORT_OR_HOST``,
``igtl://HOST:PORT``). Every device opened is closed on every way out.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from spacecal.app._common import open_calibration, other_devices, refuse_overwriting_inputs
from spacecal.app.devices import (
    DeviceSettings,
    HardwareModel,
    close_device,
    device_identity,
    finding_line,
    marker_in_use,
    open_hardware,
    refuse_when_not_ready,
    robot_findings,
    tracker_findings,
    upload_control_program,
)
from spacecal.app.gate import COMMANDED_BY, acquisition_gate, gate_plan, plan_workspace, world_visibility
from spacecal.app.simulation import DEFAULT_SCENARIO
from spacecal.core.errors import DegenerateDataError, InvalidInputError, SpacecalError
from spacecal.core.ports import (
    Robot,
    Tracker,
)
from spacecal.experiments.simulation import simulation_settings
from spacecal.geometry.rotations import rotation_angle
from spacecal.io.acquisition_progress import resume_home_joints
from spacecal.io.check_history import append_history, history_path
from spacecal.io.ndi_rom import read_rom_marker
from spacecal.io.raw_streams import raw_stream_paths
from spacecal.io.recording_csv import last_time_s
from spacecal.io.recording_source import open_calibrated_recording
from spacecal.io.results_json import read_json_object, write_json
from spacecal.models.kinematics import RobotModel
from spacecal.models.marker import ndi_8700339_like
from spacecal.models.tracker import TrackerModel
from spacecal.planning.check_poses import check_plan
from spacecal.planning.motion import MotionLimits, MotionPlan, motion_plan_from_record, planned_moves
from spacecal.planning.motion_gate import MotionGateReport
from spacecal.planning.optimal import PlannerSettings, needle_site, paper_sweep_site_error, plan_for_site
from spacecal.planning.paper_sweeps import PaperSweepSettings, plan_paper_sweeps
from spacecal.planning.stop_and_go import stop_and_go_plan
from spacecal.planning.visibility import VisibilityModel
from spacecal.records import CalibrationResult, CheckResult, PlanRecord, robot_model_to_dict
from spacecal.sim.devices import SimClock, SimulatedRobot, SimulatedTracker
from spacecal.sim.motion import plan_for_world, recording_metadata
from spacecal.sim.scenario import Scenario, load_scenario
from spacecal.sim.world import World, build_world
from spacecal.workflows.acquisition import AcquisitionResult, AcquisitionSettings, FrameObserver
from spacecal.workflows.acquisition import acquire as run_acquisition
from spacecal.workflows.check import (
    FALSE_ALARM_RATE,
    ExpectedMisfit,
    MisfitField,
    check_thresholds,
    check_with_recording,
    check_with_robot,
    expected_misfits,
    misfit_field,
    robot_repeatability_sd_mm,
    tolerance_factor,
)

#: Accepted ranges of the acquisition's numeric settings (a tiny speed would never finish).
ACQUIRE_RANGES = {
    "speed_mm_s": (1.0, 1000.0),
    "accel_mm_s2": (1.0, 10_000.0),
    "angular_speed_deg_s": (0.5, 180.0),
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
    workspace_box: tuple[float, float, float, float, float, float] | None = None
    prior: str | None = None
    rotation_deg: float = PaperSweepSettings.rotation_each_way_deg
    translation_mm: float = PaperSweepSettings.translation_stroke_mm
    plan: str | None = None
    stop_and_go: int = 0

    def __post_init__(self) -> None:
        if not (
            isinstance(self.stop_and_go, int) and (self.stop_and_go == 0 or 3 <= self.stop_and_go <= 1000)
        ):
            raise InvalidInputError(f"--stop-and-go takes 3..1000 frames per station, got {self.stop_and_go}")
        for name, (low, high) in ACQUIRE_RANGES.items():
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and low <= value <= high):
                raise InvalidInputError(
                    f"--{name.replace('_', '-')} must be a positive number in {low:g}..{high:g}, got {value}"
                )
        if self.workspace_box is not None:
            box = np.asarray(self.workspace_box, dtype=float)
            if box.shape != (6,) or not np.all(np.isfinite(box)) or np.any(box[0::2] >= box[1::2]):
                raise InvalidInputError(
                    "--workspace-box takes xmin,xmax,ymin,ymax,zmin,zmax in mm, each min < max"
                )
            if np.any(np.abs(box) > 1e5):
                raise InvalidInputError("--workspace-box: each limit must be within +-100000 mm")


@dataclass
class AcquireOutput:
    """The plan that was checked or run and, unless a dry run, the acquisition's result."""

    moves: int
    motion_time_s: float
    messages: list[str] = field(default_factory=list)
    dry_run: bool = False
    result: AcquisitionResult | None = None
    simulated: bool = True
    #: What the motion gate checked before anything moved (None: nothing was left to run).
    gate: MotionGateReport | None = None


def simulated_devices(
    scenario: str | Scenario, start_s: float = 0.0
) -> tuple[World, SimulatedRobot, SimulatedTracker]:
    """The simulated robot and tracker of a scenario (a name, file or the scenario itself;
    simulated time from ``start_s``), and their world."""
    world = build_world(load_scenario(scenario) if isinstance(scenario, str) else scenario)
    robot = SimulatedRobot(world, SimClock(start_s), stream_states=True)
    return world, robot, SimulatedTracker(world, robot)


def motion_limits(settings: AcquireSettings) -> MotionLimits:
    return MotionLimits(
        linear_speed_mm_s=settings.speed_mm_s,
        linear_accel_mm_s2=settings.accel_mm_s2,
        angular_speed_rad_s=np.radians(settings.angular_speed_deg_s),
    )


@contextlib.contextmanager
def opened_devices(
    settings: AcquireSettings, scenario: Scenario | None = None
) -> Iterator[tuple[Robot, Tracker, World | None]]:
    """The devices of the settings (simulated ones of ``scenario`` when given, else of the
    settings' scenario), closed again on every way out."""
    world: World | None
    robot: Robot
    tracker: Tracker
    if settings.devices.simulated:
        # a resumed simulated run continues the recording's time (a real clock just goes on)
        last = last_time_s(raw_stream_paths(settings.output)[0]) if settings.resume else None
        start = 0.0 if last is None else float(np.ceil(last + 1.0))
        world, robot, tracker = simulated_devices(scenario or settings.scenario, start)
    else:
        robot, tracker = open_hardware(settings.devices, motion_limits(settings))
        world = None
    try:
        yield robot, tracker, world
    finally:
        for device in (robot, tracker):
            close_device(device)


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
        does not stand at its home (nothing has moved).
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
    if joints_off > PLAN_HOME_RAD or tcp_off > PLAN_HOME_MM:
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


def hardware_metadata(
    settings: AcquireSettings, hardware: HardwareModel, robot: object, tracker: object
) -> dict[str, Any]:
    """Metadata of a recording made on real devices: the robot's model as it was used, and
    what each device says it is (serial number, firmware), so that a calibration names the one
    robot and tracker it belongs to."""
    model = hardware.model
    robot_identity = device_identity(robot)
    return {
        "robot": {
            "model": model.name,
            "url": settings.devices.robot,
            **{key: robot_identity[key] for key in ("serial", "firmware") if key in robot_identity},
            "flange_from_tcp": model.flange_from_tcp.tolist(),
            **(
                {"kinematic_model": robot_model_to_dict(model)}
                if hardware.published
                else {"identify_kinematics_from_poses": True}
            ),
            "kinematics_source": hardware.source,
        },
        "tracker": {
            "url": settings.devices.tracker,
            "rate_hz": settings.devices.tracker_rate_hz,
            **device_identity(tracker),
        },
        "marker": marker_in_use(settings.devices.rom),
        "units": {"length": "mm", "angle": "rad", "time": "s"},
        "source": "spacecal acquire",
        "simulated": False,
    }


def _known(hardware: HardwareModel | None) -> HardwareModel:
    assert hardware is not None  # set for every hardware run
    return hardware


def acquire(
    settings: AcquireSettings,
    on_sample: Callable[[int, int, int, str], None] | None = None,
    observer: FrameObserver | None = None,
    on_plan: Callable[[int], None] | None = None,
) -> AcquireOutput:
    """Plan, check and (unless a dry run) run the calibration motion, writing the recording.

    Parameters
    ----------
    settings : AcquireSettings
    on_sample : callable, optional
        Progress callback ``on_sample(samples, visible, move_index, label)``.
    on_plan : callable, optional
        Called with the number of moves once the plan is made (a progress display's total).
    observer : FrameObserver, optional
        Sees every tracker frame, e.g. ``LiveView(...).observe`` of
        :mod:`spacecal.report.live`; it must return at once, and a failing one is detached
        with a warning.
    """
    # the recording itself: the acquisition refuses an existing one unless resuming it
    refuse_overwriting_inputs(
        settings.output,
        settings.prior,
        settings.scenario,
        settings.plan,
        *settings.devices.rom,
        recordings=False,
    )
    if settings.prior:
        open_calibration(settings.prior, "acquire --prior")  # refused before any device is opened
    with opened_devices(settings) as (robot, tracker, world):
        checks: list[str] = []
        hardware = None
        if world is None:
            hardware, findings = robot_findings(robot, settings.devices.robot_model, settings.devices.tool)
            if settings.dry_run:
                checks = [finding_line("robot", f) for f in findings]
                checks += [finding_line("tracker", f) for f in tracker_findings(tracker)]
            refuse_when_not_ready(findings)
            if settings.dry_run and any(
                line.startswith("tracker") and ": PROBLEM:" in line for line in checks
            ):
                raise InvalidInputError(
                    "the tracker is not ready: "
                    + next(line for line in checks if line.startswith("tracker") and ": PROBLEM:" in line)
                )
        model = world.controller_model if world is not None else _known(hardware).model
        if settings.plan is not None:
            plan = planned_motion(settings, robot, model)
        elif world is not None:
            plan = plan_for_world(world)
        else:
            plan = hardware_plan(settings, robot, model)
        frame_period_s = 1.0 / (
            world.scenario.tracker_rate_hz if world is not None else settings.devices.tracker_rate_hz
        )
        if settings.stop_and_go:
            plan = stop_and_go_plan(
                plan, model, motion_limits(settings), frame_period_s, settings.stop_and_go
            )
        if on_plan is not None:
            on_plan(len(plan.moves))
        gate = acquisition_gate(settings, plan, model, robot.state(), motion_limits(settings), world)
        output = AcquireOutput(
            len(plan.moves),
            plan.motion_time_s,
            checks + list(plan.messages),
            simulated=world is not None,
            gate=gate,
        )
        if settings.dry_run:
            output.dry_run = True
            return output
        if world is None and not settings.confirm_robot_motion:
            raise InvalidInputError(
                "moving a real robot needs --confirm-robot-motion (check the workspace is clear)"
            )
        metadata = (
            recording_metadata(world)
            if world is not None
            else hardware_metadata(settings, _known(hardware), robot, tracker)
        )
        metadata["sampling"] = (
            {
                "mode": "stop-and-go",
                "frames_per_station": settings.stop_and_go,
                "frame_period_s": frame_period_s,
            }
            if settings.stop_and_go
            else {"mode": "continuous"}
        )
        metadata["plan"] = {
            **plan.summary(),
            "file": None if settings.plan is None else str(Path(settings.plan).resolve()),
            "motion_gate": None if gate is None else gate.to_dict(),
        }
        if world is None:
            upload_control_program(robot)
        run_settings = AcquisitionSettings(
            linear_speed_mm_s=settings.speed_mm_s, linear_accel_mm_s2=settings.accel_mm_s2
        )
        output.result = run_acquisition(
            plan,
            robot,
            tracker,
            settings.output,
            metadata,
            run_settings,
            resume=settings.resume,
            on_sample=on_sample,
            observer=observer,
        )
        return output


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
    """The check's result and history file (None after a dry run), and how the thresholds came."""

    result: CheckResult | None
    history: Path | None
    threshold_basis: str = ""
    messages: list[str] = field(default_factory=list)
    #: What the motion gate checked before the robot moved (None: checked against a recording).
    gate: MotionGateReport | None = None


def check(settings: CheckSettings) -> CheckOutput:
    """Check a calibration at two or three poses near where the robot stands (simulated or real
    devices, with the same safety as ``acquire``) or against a recording; the result, whether
    real or simulated and on which devices, is appended to the calibration's check history."""
    from spacecal.app.simulation import scenario_of_calibration

    calibration, notes = open_calibration(settings.calibration, "check", settings.accept_edited)
    averaged = 1 if settings.recording else settings.frames_per_pose
    derived_mm, derived_deg, basis = check_thresholds(calibration, averaged)
    field, unpredicted = (None, "") if settings.recording else calibration_misfits(calibration)
    derived_basis = basis
    threshold_mm = settings.threshold_mm if settings.threshold_mm is not None else derived_mm
    threshold_deg = settings.threshold_deg if settings.threshold_deg is not None else derived_deg
    if settings.threshold_mm is not None or settings.threshold_deg is not None:
        basis = (
            "given on the command line"
            if None not in (settings.threshold_mm, settings.threshold_deg)
            else (basis + "; partly given on the command line")
        )
    if settings.recording:
        opened = open_calibrated_recording(calibration, settings.recording)
        if opened is None:
            raise InvalidInputError(f"{settings.recording}: no such recording")
        result = check_with_recording(calibration, opened.recording, threshold_mm, threshold_deg)
        result = _with(
            result,
            simulated=None,
            devices={"recording": str(Path(settings.recording).resolve())},
            basis=basis,
        )
        history = append_history(settings.calibration, result, calibration.content_sha256)
        return CheckOutput(result, history, basis, notes)
    scenario: Scenario | None = None
    if settings.devices.simulated:
        scenario = (
            load_scenario(settings.scenario)
            if settings.scenario is not None
            else scenario_of_calibration(calibration)[0]
        )
        if scenario is None:
            raise InvalidInputError("no scenario given and none found with the calibration; pass --scenario")
    # the check's motion: the acquisition's defaults (speeds), on the check's devices
    moving = AcquireSettings(
        output=str(history_path(settings.calibration)),
        devices=settings.devices,
        workspace_box=settings.workspace_box,
        dry_run=settings.dry_run,
    )
    devices = settings.devices
    robot_identity: dict[str, str] = {}
    tracker_identity: dict[str, str] = {}
    with opened_devices(moving, scenario) as (robot, tracker, world):
        if world is None:
            hardware, findings = robot_findings(robot, devices.robot_model, devices.tool)
            refuse_when_not_ready(findings)
            model = hardware.model
            robot_identity, tracker_identity = device_identity(robot), device_identity(tracker)
            notes += other_devices(
                calibration,
                str(devices.robot),
                str(devices.tracker),
                model.name,
                settings.accept_other_devices,
                robot_identity=robot_identity,
                tracker_identity=tracker_identity,
            )
        else:
            model = world.controller_model
        model = calibration.robot_model_for_ik(model)
        frame_period = (
            1.0 / world.scenario.tracker_rate_hz if world is not None else 1.0 / devices.tracker_rate_hz
        )
        plan = check_plan(
            model,
            robot.state().joints_rad,
            settings.poses,
            motion_limits(moving),
            frame_period,
            settings.frames_per_pose,
        )
        gate = gate_plan(
            plan,
            model,
            robot.state(),
            motion_limits(moving),
            plan_workspace(model, plan, moving.workspace_box),
            visibility=None if world is None else world_visibility(world),
            visibility_note="not predicted on real devices (the check poses are within 45 mm and 10 deg "
            "of where the robot stands)",
            commanded_by=COMMANDED_BY,
        )
        expected, basis = expected_at_check_poses(
            field, unpredicted, plan, settings, model.name, derived_basis
        )
        if settings.dry_run:
            return CheckOutput(
                None,
                None,
                basis,
                [
                    *notes,
                    f"{settings.poses} check poses planned, {plan.motion_time_s:.1f} s of motion; "
                    "nothing moved",
                ],
                gate,
            )
        if world is None and not settings.confirm_robot_motion:
            raise InvalidInputError(
                "moving a real robot needs --confirm-robot-motion (check the workspace is clear)"
            )
        if world is None:
            upload_control_program(robot)
        run_settings = (
            simulation_settings(world.scenario)
            if world is not None
            else AcquisitionSettings(
                linear_speed_mm_s=moving.speed_mm_s, linear_accel_mm_s2=moving.accel_mm_s2
            )
        )
        result = check_with_robot(
            calibration,
            robot,
            tracker,
            plan,
            settings.threshold_mm if expected is not None else threshold_mm,
            settings.threshold_deg if expected is not None else threshold_deg,
            run_settings,
            settings.frames_per_pose,
            expected=expected,
            robot_sd_mm=robot_repeatability_sd_mm(model.name),
            basis=basis,
        )
    identity = (
        {"robot": "sim", "tracker": "sim", "scenario": world.scenario.name}
        if world is not None
        else {
            "robot": devices.robot,
            "tracker": devices.tracker,
            # the check history names the devices it ran on as they named themselves
            **{f"robot_{key}": value for key, value in robot_identity.items()},
            **{f"tracker_{key}": value for key, value in tracker_identity.items()},
        }
    )
    result = _with(result, simulated=world is not None, devices=identity)
    history = append_history(settings.calibration, result, calibration.content_sha256)
    return CheckOutput(result, history, basis, notes, gate=gate)


def calibration_misfits(calibration: CalibrationResult) -> tuple[MisfitField | None, str]:
    """The misfits the calibration left at the frames of its recording (opened as the calibration
    paired it: :func:`~spacecal.io.recording_source.open_calibrated_recording`), or None and why
    not."""
    try:
        opened = open_calibrated_recording(calibration)
        if opened is None:
            named = calibration.provenance.recording
            return (
                None,
                f"its recording {named} is not there" if named else "the calibration names no recording",
            )
        return misfit_field(calibration, opened.recording, str(opened.path)), ""
    except (SpacecalError, OSError) as exc:
        return None, str(exc)


def expected_at_check_poses(
    field: MisfitField | None,
    unpredicted: str,
    plan: MotionPlan,
    settings: CheckSettings,
    robot_model: str,
    fallback_basis: str,
) -> tuple[list[ExpectedMisfit] | None, str]:
    """The misfit expected at each check pose and the thresholds' basis; None and the basis of
    :func:`~spacecal.workflows.check.check_thresholds` (saying why) when it cannot be predicted."""
    given = [settings.threshold_mm is not None, settings.threshold_deg is not None]
    expected = None
    if field is not None:
        try:
            expected = expected_misfits(field, plan)
        except DegenerateDataError as exc:
            unpredicted = str(exc)
    if expected is None:
        if all(given):
            return None, "given on the command line"
        basis = f"{fallback_basis}, as no misfit can be expected at the poses ({unpredicted})"
        return None, basis + ("; partly given on the command line" if any(given) else "")
    if all(given):
        return expected, "departures from the misfit left at each pose, thresholds given on the command line"
    frames = len(field) if field is not None else 0
    basis = (
        f"departures from the misfit the calibration left at each pose (from {frames} frames of its "
        f"recording) within {tolerance_factor(len(expected)):.2f} s.d. of the repeatability there (the "
        f"recorded scatter, the tracker's over {settings.frames_per_pose} frames, the {robot_model}'s "
        f"ISO 9283 repeatability): a sound set-up fails at most {FALSE_ALARM_RATE:.0%} of checks"
    )
    return expected, basis + ("; partly given on the command line" if any(given) else "")


def _with(result: CheckResult, **changes: Any) -> CheckResult:

    return dataclasses.replace(result, **changes)


@dataclass(frozen=True)
class PlanSettings:
    """``spacecal plan``: a calibration motion for the smallest predicted error at the site.

    Attributes
    ----------
    budget_s : float
        Motion time allowed, s.
    scenario : str
        The (simulated) set-up to plan for: tracker placement, marker, robot and its home.
    frames_per_station : int
        Tracker frames held at each station.
    site_mm : (x, y, z) or None
        Where the needle tip will work, mm in the robot base; default the TCP at home.
    needle_path_mm : (entry x, y, z, target x, y, z) or None
        A planned needle path in the robot base, mm: the site is its target, with the needle
        along the path (instead of ``site_mm``).
    paper_sweeps : bool
        Write the paper's six sweeps (paper §4) from home as the plan instead.
    output : str or None
        Plan JSON to write (``docs/formats.md``); ``acquire --plan`` and ``simulate --plan`` run it.
    """

    budget_s: float = PlannerSettings.budget_s
    scenario: str = DEFAULT_SCENARIO
    frames_per_station: int = PlannerSettings.frames_per_station
    site_mm: tuple[float, float, float] | None = None
    paper_sweeps: bool = False
    output: str | None = None
    force: bool = False
    needle_path_mm: tuple[float, float, float, float, float, float] | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.budget_s) and 1 <= self.budget_s <= 3600):
            raise InvalidInputError(f"--budget must be between 0 and 3600 s, got {self.budget_s}")
        if not 1 <= self.frames_per_station <= 1000:
            raise InvalidInputError(f"--frames-per-station must be 1..1000, got {self.frames_per_station}")
        if self.site_mm is not None:
            site = np.asarray(self.site_mm, dtype=float)
            if site.shape != (3,) or not np.all(np.isfinite(site)) or np.any(np.abs(site) > 5000):
                raise InvalidInputError("--site takes finite x,y,z in mm (robot base), each within +-5000 mm")
        if self.needle_path_mm is not None:
            path = np.asarray(self.needle_path_mm, dtype=float)
            if path.shape != (6,) or not np.all(np.isfinite(path)) or np.any(np.abs(path) > 5000):
                raise InvalidInputError(
                    "--needle-path takes the entry and target x,y,z in mm (robot base), each within +-5000 mm"
                )
            if self.site_mm is not None:
                raise InvalidInputError("give --site or --needle-path, not both")


def plan(settings: PlanSettings) -> tuple[PlanRecord, Path | None]:
    """Plan the motion and compare it with the paper's sweeps; returns the plan and the file."""
    refuse_overwriting_inputs(settings.output, settings.scenario, force=settings.force, any_file=True)
    world = build_world(load_scenario(settings.scenario))
    visibility = VisibilityModel(world.tracker, world.marker, world.tracker_from_base, world.tcp_from_marker)
    planner = PlannerSettings(
        budget_s=settings.budget_s,
        frames_per_station=settings.frames_per_station,
        sphere_sigma_mm=world.scenario.white_noise_rms_mm / np.sqrt(3) or 0.1,
    )
    paper = plan_for_world(world)
    site: np.ndarray | None = None
    if settings.site_mm is not None:
        site = np.asarray(settings.site_mm, dtype=float)
    elif settings.needle_path_mm is not None:
        needle = np.asarray(settings.needle_path_mm, dtype=float)
        site = needle_site(world.nominal_model, world.home_joints_rad, needle[:3], needle[3:])
    paper_error = paper_sweep_site_error(world.nominal_model, paper, visibility, planner, site_in_base=site)
    common = dict(
        home_joints_rad=world.home_joints_rad,
        home_base_from_tcp=paper.home_base_from_tcp,
        robot_model=world.nominal_model.name,
        flange_from_tcp=world.nominal_model.flange_from_tcp,
        site_in_base=None if site is None else (site[:3, 3] if site.shape == (4, 4) else site),
        site_base_from_tcp=site if site is not None and site.shape == (4, 4) else None,
        paper_sweep={"motion_time_s": paper.motion_time_s, "predicted_error_mm": paper_error},
        scenario=world.scenario.name,
    )
    if settings.paper_sweeps:
        record = PlanRecord(
            kind="paper-sweeps",
            motion_time_s=paper.motion_time_s,
            moves=planned_moves(paper),
            predicted_error_mm=paper_error,
            **common,  # type: ignore[arg-type]
        )
    else:
        planned = plan_for_site(
            world.nominal_model,
            world.home_joints_rad,
            visibility,
            np.random.default_rng([world.scenario.seed, 7]),
            planner,
            site_in_base=site,
        )
        record = PlanRecord(
            kind="site-optimal",
            motion_time_s=planned.motion_time_s,
            moves=planned_moves(planned.plan),
            budget_s=planner.budget_s,
            predicted_error_mm=planned.predicted_error_mm,
            station_joints_rad=planned.station_joints_rad,
            **common,  # type: ignore[arg-type]
        )
    path = write_json(record.to_dict(), settings.output) if settings.output else None
    return record, path
