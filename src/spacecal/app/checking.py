"""App function ``check``: does a calibration still hold before surgery? Two or three poses near
where the robot stands (simulated or real devices, with the same safety as ``acquire``), or a
recording; the result is appended to the calibration's check history."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from spacecal.app._common import open_calibration, other_devices
from spacecal.app.acquisition import AcquireSettings, opened_devices
from spacecal.app.check_expectations import calibration_misfits, expected_at_check_poses
from spacecal.app.devices import (
    DeviceSettings,
    device_identity,
    refuse_when_not_ready,
    robot_findings,
    upload_control_program,
)
from spacecal.app.gate import COMMANDED_BY, gate_plan, plan_workspace, world_visibility
from spacecal.app.record import open_record, record_check
from spacecal.app.result import CommandResult, Quality, note_lines, paths
from spacecal.app.run_plan import motion_limits
from spacecal.core.errors import InvalidInputError
from spacecal.core.text import sanitize_for_terminal
from spacecal.experiments.simulation import simulation_settings
from spacecal.io.check_history import append_history, history_path
from spacecal.io.recordings import open_calibrated_recording
from spacecal.planning.check_poses import check_plan
from spacecal.planning.motion_gate import MotionGateReport
from spacecal.records import CheckResult
from spacecal.sim.scenario import Scenario, load_scenario
from spacecal.workflows.acquisition import (
    AcquisitionSettings,
    SampleCallback,
)
from spacecal.workflows.check import (
    check_thresholds,
    check_with_recording,
    check_with_robot,
    robot_repeatability_sd_mm,
)


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


def check(
    settings: CheckSettings,
    on_sample: SampleCallback | None = None,
    on_plan: Callable[[int], None] | None = None,
) -> CommandResult[CheckOutput]:
    """Check a calibration at two or three poses near where the robot stands (simulated or real
    devices, with the same safety as ``acquire``) or against a recording; the result, whether
    real or simulated and on which devices, is appended to the calibration's check history.

    ``on_plan(moves)`` and ``on_sample(samples, visible, move_index, label)`` follow the robot's
    check as they follow an acquisition (:func:`spacecal.app.acquire`): the plan's length once
    it has passed its gate, then every sample.

    Returns
    -------
    CommandResult of CheckOutput
        The check (None after a dry run) and the basis of its thresholds; the check history
        written; a quality that fails when the calibration no longer holds.
    """
    ledger = open_record(settings.record) if settings.record else None
    try:
        out = _check(settings, on_sample, on_plan)
        if ledger is not None:
            record_check(ledger, settings.calibration, out, source="cli")
    finally:
        if ledger is not None:
            ledger.close()
    return out


def _check(
    settings: CheckSettings,
    on_sample: SampleCallback | None = None,
    on_plan: Callable[[int], None] | None = None,
) -> CommandResult[CheckOutput]:
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
        opened = open_calibrated_recording(calibration, settings.recording, bool(settings.accept_edited))
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
        return check_result(CheckOutput(result, basis), history, notes)
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
        simulated_speed=settings.simulated_speed,
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
            planned = (
                f"{settings.poses} check poses planned, {plan.motion_time_s:.1f} s of motion; nothing moved"
            )
            return check_result(CheckOutput(None, basis, gate), None, [*notes, planned])
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
        if on_plan is not None:
            on_plan(len(plan.moves))
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
            on_sample=on_sample,
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
    return check_result(CheckOutput(result, basis, gate), history, notes)


def check_result(
    out: CheckOutput, history: Path | None, notes: Sequence[str] = ()
) -> CommandResult[CheckOutput]:
    """The result of ``check`` from its check, the history file it was appended to (None after
    a dry run) and its notes: one line per pose and the verdict, and a quality that fails when
    the calibration no longer holds."""
    lines = []
    if out.gate is not None:
        # a dry run (no result) shows every check; a run that moved, the verdict
        lines += out.gate.lines() if out.result is None else [out.gate.summary()]
    lines += note_lines(notes)
    r = out.result
    if r is None:
        return CommandResult(out, paths(history), tuple(notes), tuple(lines))
    for k, (label, error, angle) in enumerate(zip(r.labels, r.tcp_error_mm, r.rotation_error_deg)):
        label = sanitize_for_terminal(label, 60)
        if r.misfit_mm is None or r.expected_misfit_mm is None or r.tolerance_mm is None:
            lines.append(f"  {label:>10}: TCP {error:.3f} mm, rotation {angle:.3f} deg")
            continue
        assert r.misfit_deg is not None and r.expected_misfit_deg is not None and r.tolerance_deg is not None
        lines.append(
            f"  {label:>10}: TCP {math.hypot(*r.misfit_mm[k]):.3f} mm off "
            f"({math.hypot(*r.expected_misfit_mm[k]):.3f} expected), departs {error:.3f} mm "
            f"(tolerance {r.tolerance_mm[k]:.2f}); rotation {math.hypot(*r.misfit_deg[k]):.3f} deg "
            f"({math.hypot(*r.expected_misfit_deg[k]):.3f} expected), departs {angle:.3f} deg "
            f"(tolerance {r.tolerance_deg[k]:.2f})"
        )
    where = {True: "simulated robot and tracker", False: "real robot and tracker", None: "recording"}[
        r.simulated
    ]
    limits = "tolerances up to" if r.has_expectations else "thresholds"
    verdict = (
        f"{'PASS' if r.passed else 'FAIL'} ({where}): {limits} {r.threshold_mm:.2f} mm and "
        f"{r.threshold_deg:.2f} deg, {out.threshold_basis} (history: {history})"
    )
    lines.append(verdict)
    quality = Quality(
        bool(r.passed),
        verdict,
        "the calibration no longer holds: recalibrate (marker bumped, tracker moved?)",
    )
    return CommandResult(out, paths(history), tuple(notes), tuple(lines), quality)


def _with(result: CheckResult, **changes: Any) -> CheckResult:

    return dataclasses.replace(result, **changes)
