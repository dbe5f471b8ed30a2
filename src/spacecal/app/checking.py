"""App function ``check``: does a calibration still hold before surgery? Two or three poses near
where the robot stands (simulated or real devices, with the same safety as ``acquire``), or a
recording; the result is appended to the calibration's check history."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from spacecal.app._common import calibration_motion, open_calibration
from spacecal.app.check_expectations import calibration_misfits, expected_at_check_poses
from spacecal.app.check_settings import CheckOutput, CheckSettings
from spacecal.app.gate import plan_workspace
from spacecal.app.motion_session import motion_session
from spacecal.app.record import open_record, record_check
from spacecal.app.result import CommandResult, Quality, note_lines, paths
from spacecal.core.errors import InvalidInputError
from spacecal.core.text import sanitize_for_terminal
from spacecal.io.check_history import append_history
from spacecal.io.recordings import open_calibrated_recording
from spacecal.planning.check_poses import check_plan
from spacecal.records import CheckResult
from spacecal.workflows.acquisition import SampleCallback
from spacecal.workflows.check import (
    check_thresholds,
    check_with_recording,
    judge_check,
    robot_repeatability_sd_mm,
)

__all__ = ["CheckOutput", "CheckSettings", "check", "check_result"]


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
    # the check's motion: the acquisition's defaults (speeds), on the check's devices
    motion = calibration_motion(
        calibration,
        settings.devices,
        settings.scenario,
        settings.dry_run,
        settings.confirm_robot_motion,
        settings.workspace_box,
        settings.simulated_speed,
    )
    with motion_session(motion) as session:
        world = session.world
        notes += session.calibration_notes(calibration, settings.accept_other_devices)
        model = session.ik_model(calibration)
        plan = check_plan(
            model,
            session.robot.state().joints_rad,
            settings.poses,
            motion.limits(),
            session.frame_period_s,
            settings.frames_per_pose,
        )
        gate = session.gate(
            plan,
            model=model,
            workspace=plan_workspace(model, plan, motion.workspace_box),
            visibility_note="not predicted on real devices (the check poses are within 45 mm and 10 deg "
            "of where the robot stands)",
        )
        expected, basis = expected_at_check_poses(
            field,
            unpredicted,
            plan,
            (settings.threshold_mm, settings.threshold_deg),
            settings.frames_per_pose,
            model.name,
            derived_basis,
        )
        if settings.dry_run:
            planned = (
                f"{settings.poses} check poses planned, {plan.motion_time_s:.1f} s of motion; nothing moved"
            )
            return check_result(CheckOutput(None, basis, gate), None, [*notes, planned])
        session.begin_motion()
        if on_plan is not None:
            on_plan(len(plan.moves))
        held = session.hold(
            plan, settings.frames_per_pose, session.run_settings(scenario_speeds=True), on_sample
        )
        result = judge_check(
            calibration,
            held,
            settings.threshold_mm if expected is not None else threshold_mm,
            settings.threshold_deg if expected is not None else threshold_deg,
            expected,
            robot_repeatability_sd_mm(model.name),
            basis,
        )
        identity = session.identity()
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
