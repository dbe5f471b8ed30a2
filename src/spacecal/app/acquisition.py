"""App function ``acquire``: run the calibration motion on a robot while sampling the tracker.

This is where devices are chosen: ``sim`` gives the simulated robot and tracker of a scenario
(running in simulated time), URLs give hardware adapters (``ur://HOST``, ``ndi://PORT_OR_HOST``,
``igtl://HOST:PORT``). Every device opened is closed on every way out.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from spacecal.app._common import open_calibration, refuse_overwriting_inputs
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
from spacecal.app.gate import acquisition_gate, approach_line, resumed_move
from spacecal.app.result import CommandResult, note_lines
from spacecal.app.run_plan import hardware_plan, motion_limits, planned_motion
from spacecal.app.simulation import DEFAULT_SCENARIO
from spacecal.core.errors import InvalidInputError
from spacecal.core.ports import (
    Robot,
    Tracker,
)
from spacecal.io.recordings import last_time_s, raw_stream_paths
from spacecal.planning.motion import MotionLimits
from spacecal.planning.motion_gate import MotionGateReport
from spacecal.planning.paper_sweeps import PaperSweepSettings
from spacecal.planning.stop_and_go import stop_and_go_plan
from spacecal.records import robot_model_to_dict
from spacecal.sim.devices import RealClock, SimClock, SimulatedRobot, SimulatedTracker
from spacecal.sim.motion import plan_for_world, recording_metadata
from spacecal.sim.scenario import Scenario, load_scenario
from spacecal.sim.world import World, build_world
from spacecal.workflows.acquisition import (
    AcquisitionResult,
    AcquisitionSettings,
    FrameObserver,
    SampleCallback,
)
from spacecal.workflows.acquisition import acquire as run_acquisition

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
    workspace_box: tuple[float, float, float, float, float, float] | None = None
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
        speed = self.simulated_speed
        if speed is not None and not (
            isinstance(speed, (int, float)) and math.isfinite(speed) and 0.1 <= speed <= 1000
        ):
            raise InvalidInputError(
                f"the simulated devices' speed must be 0.1..1000 times real time, got {speed}"
            )


@dataclass
class AcquireOutput:
    """The plan that was checked or run and, unless a dry run, the acquisition's result."""

    moves: int
    motion_time_s: float
    dry_run: bool = False
    result: AcquisitionResult | None = None
    simulated: bool = True
    #: What the motion gate checked before anything moved (None: nothing was left to run).
    gate: MotionGateReport | None = None
    #: A resumed run: the move back onto the plan it makes first (see ``app.gate.approach_line``).
    approach: str | None = None


def simulated_devices(
    scenario: str | Scenario, start_s: float = 0.0, speed: float | None = None
) -> tuple[World, SimulatedRobot, SimulatedTracker]:
    """The simulated robot and tracker of a scenario (a name, file or the scenario itself;
    simulated time from ``start_s``, ``speed`` times real time or, None, as fast as they
    compute), and their world."""
    world = build_world(load_scenario(scenario) if isinstance(scenario, str) else scenario)
    clock = SimClock(start_s) if speed is None else RealClock(start_s, speed)
    robot = SimulatedRobot(world, clock, stream_states=True)
    return world, robot, SimulatedTracker(world, robot)


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
        world, robot, tracker = simulated_devices(
            scenario or settings.scenario, start, settings.simulated_speed
        )
    else:
        robot, tracker = open_hardware(settings.devices, motion_limits(settings))
        world = None
    try:
        yield robot, tracker, world
    finally:
        for device in (robot, tracker):
            close_device(device)


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
    on_sample: SampleCallback | None = None,
    observer: FrameObserver | None = None,
    on_plan: Callable[[int], None] | None = None,
    on_line: Callable[[str], None] | None = None,
) -> CommandResult[AcquireOutput]:
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
        with a warning. ``settings.live_view`` opens such a view itself.
    on_line : callable, optional
        Called with each line to show at once while the command runs (where the live view is).

    Returns
    -------
    CommandResult of AcquireOutput
        The plan checked or run and, unless a dry run, the acquisition's result; the recording
        and raw streams written.
    """
    view = None
    if settings.live_view is not None and not settings.dry_run:
        from spacecal.report.live import LiveView

        view = LiveView(settings.live_view)
        if view.start():
            if on_line is not None:
                on_line(f"live view: {view.url} (open it in a web browser)")
            observer = view.observe
        else:
            view = None
    try:
        output, notes = _acquire(settings, on_sample, observer, on_plan)
    finally:
        if view is not None:
            view.close()
    return acquire_result(output, notes)


def acquire_result(output: AcquireOutput, notes: tuple[str, ...] = ()) -> CommandResult[AcquireOutput]:
    """The result of ``acquire`` from what it planned and ran, and its notes (the dry run's
    device checks, the plan's messages)."""
    lines = [
        f"plan: {output.moves} moves, {output.motion_time_s:.1f} s of motion"
        + (" (simulated devices, simulated time)" if output.simulated else ""),
        *note_lines(notes),
        *([output.approach] if output.approach else []),
    ]
    files: tuple[Path, ...] = ()
    if output.dry_run:
        lines += [*(output.gate.lines() if output.gate is not None else []), "dry run: nothing moved"]
    else:
        if output.gate is not None:
            lines.append(output.gate.summary())
        r = output.result
        assert r is not None
        files = (r.recording_path, *(r.raw_paths or ()))
        lines += [
            "",
            f"wrote {r.recording_path}: {r.samples_written} samples, {r.visible_written} with the marker "
            f"seen; {r.moves_completed}/{r.moves_total} moves",
        ]
    return CommandResult(output, files, notes, tuple(lines))


def _acquire(
    settings: AcquireSettings,
    on_sample: SampleCallback | None,
    observer: FrameObserver | None,
    on_plan: Callable[[int], None] | None,
) -> tuple[AcquireOutput, tuple[str, ...]]:
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
        state = robot.state()
        gate = acquisition_gate(settings, plan, model, state, motion_limits(settings), world)
        output = AcquireOutput(len(plan.moves), plan.motion_time_s, simulated=world is not None, gate=gate)
        resumed = resumed_move(settings, plan)
        if gate is not None and resumed is not None:
            # a stop mid-move left the arm between two poses of the plan: the run first moves
            # back onto it (the gate checked that move with the rest)
            output.approach = approach_line(plan, resumed, state.base_from_tcp, motion_limits(settings))
        notes = (*checks, *plan.messages)
        if settings.dry_run:
            output.dry_run = True
            return output, notes
        if world is None and not settings.confirm_robot_motion:
            first = "" if output.approach is None else f"; {output.approach}"
            raise InvalidInputError(
                f"moving a real robot needs --confirm-robot-motion (check the workspace is clear{first})"
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
        return output, notes
