"""One motion session for every command that moves the robot (``acquire``, ``check``,
``verify``, ``guide``).

A session opens the devices (the simulated ones of a scenario, or the hardware the URLs name),
runs the robot's read-only checks and refuses a robot that is not ready, knows the kinematic
model spacecal plans with, passes every plan through the motion gate, asks for the motion's
confirmation on real devices, connects the robot's control interface only then, runs the plan
through the acquisition loop (its stop semantics and deadlines), and closes every device it
opened on every way out. Each command only says what to move and what to keep::

    with motion_session(settings) as session:
        plan = ...                              # in session.model's base frame
        gate = session.gate(plan)               # refused: nothing has moved
        if settings.dry_run:
            return ...
        session.begin_motion()                  # --confirm-robot-motion, then the control program
        held = session.hold(plan, frames_per_pose=10)
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from spacecal.app._common import other_devices
from spacecal.app.devices import (
    HardwareModel,
    close_device,
    device_identity,
    finding_line,
    open_hardware,
    refuse_when_not_ready,
    robot_findings,
    tracker_findings,
    upload_control_program,
)
from spacecal.app.gate import gate_plan, plan_workspace, world_visibility
from spacecal.app.motion_settings import COMMANDED_BY, MotionSettings
from spacecal.core.errors import InvalidInputError
from spacecal.core.ports import DeviceFinding, Robot, Tracker
from spacecal.experiments.simulation import simulation_settings
from spacecal.models.kinematics import RobotModel
from spacecal.planning.motion import MotionPlan
from spacecal.planning.motion_gate import DEFAULT_BOX_HALF_MM, MotionGateReport, Workspace
from spacecal.planning.visibility import VisibilityModel
from spacecal.records import CalibrationResult
from spacecal.sim.devices import RealClock, SimClock, SimulatedRobot, SimulatedTracker
from spacecal.sim.scenario import Scenario, load_scenario
from spacecal.sim.world import World, build_world
from spacecal.workflows.acquisition import (
    AcquisitionResult,
    AcquisitionSettings,
    FrameObserver,
    SampleCallback,
)
from spacecal.workflows.acquisition import acquire as run_acquisition
from spacecal.workflows.held_poses import HeldPose, hold_poses

#: What the gate says of visibility on real devices without a tracker pose.
NO_TRACKER_POSE = "no tracker pose (pass --prior with an earlier calibration)"
#: The further tools the simulated tracker follows (:attr:`spacecal.sim.world.World.tools`).
SIMULATED_TOOLS = ("pointer", "reference")


def simulated_devices(
    scenario: str | Scenario, start_s: float = 0.0, speed: float | None = None
) -> tuple[World, SimulatedRobot, SimulatedTracker]:
    """The simulated robot and tracker of a scenario (a name, file or the scenario itself;
    simulated time from ``start_s``, ``speed`` times real time or, None, as fast as they
    compute), and their world. The tracker follows the world's further tools as well (the
    pointer and the reference tool on the needle guide, :data:`SIMULATED_TOOLS`): their noise
    is drawn from its own stream, so the marker's frames are those it had without them."""
    world = build_world(load_scenario(scenario) if isinstance(scenario, str) else scenario)
    clock = SimClock(start_s) if speed is None else RealClock(start_s, speed)
    robot = SimulatedRobot(world, clock, stream_states=True)
    return world, robot, SimulatedTracker(world, robot, tools=SIMULATED_TOOLS)


@dataclass
class MotionSession:
    """Open devices, their checks and the model a motion is planned with.

    Attributes
    ----------
    settings : MotionSettings
    robot : Robot
    tracker : Tracker
    world : World or None
        The simulated world (its truth), None on real devices.
    hardware : HardwareModel or None
        Real devices: the controller's model and how it was found (None when simulated).
    findings : list of DeviceFinding
        The robot's read-only checks and spacecal's (model, tool); empty when simulated.
    """

    settings: MotionSettings
    robot: Robot
    tracker: Tracker
    world: World | None = None
    hardware: HardwareModel | None = None
    findings: list[DeviceFinding] = field(default_factory=list)
    started: bool = False

    @property
    def simulated(self) -> bool:
        """The devices are the simulated ones."""
        return self.world is not None

    @property
    def model(self) -> RobotModel:
        """The controller's kinematic model, in whose base frame every plan is made (the
        simulated controller's, or the one the real controller publishes or is given)."""
        if self.world is not None:
            return self.world.controller_model
        assert self.hardware is not None  # set for every hardware session
        return self.hardware.model

    @property
    def frame_period_s(self) -> float:
        """The tracker's frame period, s."""
        rate = (
            self.world.scenario.tracker_rate_hz
            if self.world is not None
            else self.settings.devices.tracker_rate_hz
        )
        return 1.0 / rate

    def device_lines(self) -> list[str]:
        """The robot's and the tracker's read-only checks, a line each (a dry run shows them)."""
        if self.world is not None:
            return []
        return [finding_line("robot", f) for f in self.findings] + [
            finding_line("tracker", f) for f in tracker_findings(self.tracker)
        ]

    def refuse_tracker_problem(self, lines: Sequence[str]) -> None:
        """A dry run refuses a tracker whose own check found a problem (``device_lines``)."""
        problem = next((line for line in lines if line.startswith("tracker") and ": PROBLEM:" in line), None)
        if problem is not None:
            raise InvalidInputError(f"the tracker is not ready: {problem}")

    def ik_model(self, calibration: CalibrationResult) -> RobotModel:
        """The model inverse kinematics is solved with: the controller's, with the kinematic
        parameters the calibration identified where it has them."""
        return calibration.robot_model_for_ik(self.model)

    def calibration_notes(self, calibration: CalibrationResult, accept_other_devices: bool) -> list[str]:
        """Refuse a calibration of other real devices than these (unless accepted: then a note)."""
        if self.world is not None:
            return []
        return other_devices(
            calibration,
            str(self.settings.devices.robot),
            str(self.settings.devices.tracker),
            self.model.name,
            accept_other_devices,
            robot_identity=device_identity(self.robot),
            tracker_identity=device_identity(self.tracker),
        )

    def identity(self) -> dict[str, str]:
        """The devices a result was measured on, as they named themselves."""
        if self.world is not None:
            return {"robot": "sim", "tracker": "sim", "scenario": self.world.scenario.name}
        devices = self.settings.devices
        return {
            "robot": str(devices.robot),
            "tracker": str(devices.tracker),
            **{f"robot_{key}": value for key, value in device_identity(self.robot).items()},
            **{f"tracker_{key}": value for key, value in device_identity(self.tracker).items()},
        }

    def workspace(self, plan: MotionPlan, half_mm: float = DEFAULT_BOX_HALF_MM) -> Workspace:
        """The box the plan is checked in (``--workspace-box``, the plan file's, else around home)."""
        return plan_workspace(self.model, plan, self.settings.workspace_box, half_mm)

    def gate(
        self,
        plan: MotionPlan,
        *,
        model: RobotModel | None = None,
        workspace: Workspace | None = None,
        visibility: VisibilityModel | None = None,
        visibility_note: str = NO_TRACKER_POSE,
        first_move: int = 0,
        resuming: bool = False,
        from_home: bool = False,
    ) -> MotionGateReport:
        """Pass ``plan`` through the motion gate from where the robot stands (``from_home``:
        from the plan's home joints, as a simulated run that starts there), or raise its
        one-line refusal; nothing has moved. ``model`` is the one the plan was made with (default
        :attr:`model`; e.g. the calibration's identified one, :meth:`ik_model`). In a simulated
        world its truth predicts the marker's visibility unless ``visibility`` is given."""
        if visibility is None and self.world is not None:
            visibility = world_visibility(self.world)
        return gate_plan(
            plan,
            model or self.model,
            None if from_home else self.robot.state(),
            self.settings.limits(),
            workspace if workspace is not None else self.workspace(plan),
            visibility=visibility,
            visibility_note=visibility_note,
            first_move=first_move,
            resuming=resuming,
            commanded_by=COMMANDED_BY,
        )

    def require_confirmation(self, before: str | None = None) -> None:
        """Refuse to move a real robot without ``--confirm-robot-motion``; ``before`` says what
        the first move does (e.g. a resumed run's approach)."""
        if self.world is None and not self.settings.confirm_robot_motion:
            first = "" if before is None else f"; {before}"
            raise InvalidInputError(
                f"moving a real robot needs --confirm-robot-motion (check the workspace is clear{first})"
            )

    def begin_motion(self, before: str | None = None) -> None:
        """Confirm the motion (:meth:`require_confirmation`) and connect the robot's control
        interface: its program is uploaded only now, after every read-only check has passed."""
        if self.settings.dry_run:
            raise InvalidInputError("a dry run moves nothing")
        self.require_confirmation(before)
        if self.world is None and not self.started:
            upload_control_program(self.robot)
        self.started = True

    def run_settings(self, scenario_speeds: bool = False) -> AcquisitionSettings:
        """How the acquisition loop drives the robot: the commanded limits, or (``scenario_speeds``,
        simulated devices only) the scenario's own, as a simulated calibration run drives them."""
        if scenario_speeds and self.world is not None:
            return simulation_settings(self.world.scenario)
        return AcquisitionSettings(
            linear_speed_mm_s=self.settings.speed_mm_s, linear_accel_mm_s2=self.settings.accel_mm_s2
        )

    def hold(
        self,
        plan: MotionPlan,
        frames_per_pose: int,
        run_settings: AcquisitionSettings | None = None,
        on_sample: SampleCallback | None = None,
        what: str = "check",
        observer: FrameObserver | None = None,
    ) -> list[HeldPose]:
        """Run a plan of holds (:func:`~spacecal.planning.held_poses.hold_plan`) and keep what the
        tracker saw at each (:func:`~spacecal.workflows.held_poses.hold_poses`); ``observer`` is
        called at every tracker frame, moving and holding (guidance streams the needle's pose to
        3D Slicer from it)."""
        self._require_started()
        return hold_poses(
            self.robot,
            self.tracker,
            plan,
            run_settings or self.run_settings(),
            frames_per_pose,
            on_sample,
            what=what,
            observer=observer,
        )

    def record(
        self,
        plan: MotionPlan,
        output: str | Path,
        metadata: dict[str, Any],
        run_settings: AcquisitionSettings | None = None,
        resume: bool = False,
        on_sample: SampleCallback | None = None,
        observer: FrameObserver | None = None,
    ) -> AcquisitionResult:
        """Run a plan and write its recording (:func:`spacecal.workflows.acquisition.acquire`)."""
        self._require_started()
        return run_acquisition(
            plan,
            self.robot,
            self.tracker,
            output,
            metadata,
            run_settings or self.run_settings(),
            resume=resume,
            on_sample=on_sample,
            observer=observer,
        )

    def _require_started(self) -> None:
        if not self.started:
            raise InvalidInputError("the motion was not confirmed (begin_motion) before it ran")


@contextlib.contextmanager
def motion_session(settings: MotionSettings) -> Iterator[MotionSession]:
    """Open the devices of ``settings`` and check them; every device opened is closed again on
    every way out (also when a check refuses the robot).

    Raises
    ------
    InvalidInputError
        The robot is not ready (its first blocking finding), or the devices are half simulated.
    DeviceError
        A device cannot be opened.
    """
    session: MotionSession
    if settings.devices.simulated:
        world, simulated_robot, simulated_tracker = simulated_devices(
            settings.scenario, settings.simulated_start_s, settings.simulated_speed
        )
        session = MotionSession(settings, simulated_robot, simulated_tracker, world)
    else:
        robot, tracker = open_hardware(settings.devices, settings.limits())
        session = MotionSession(settings, robot, tracker)
    try:
        if session.world is None:
            hardware, findings = robot_findings(
                session.robot, settings.devices.robot_model, settings.devices.tool
            )
            session.hardware, session.findings = hardware, findings
            refuse_when_not_ready(findings)
        yield session
    finally:
        for device in (session.robot, session.tracker):
            close_device(device)
