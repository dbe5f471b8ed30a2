"""What a check expects at its poses: the misfit the calibration left at the frames of its
recording, carried to the check poses, and the basis of the check's thresholds."""

from __future__ import annotations

from spacecal.core.errors import DegenerateDataError, SpacecalError
from spacecal.io.recordings import open_calibrated_recording
from spacecal.planning.motion import MotionPlan
from spacecal.records import CalibrationResult
from spacecal.workflows.check import (
    FALSE_ALARM_RATE,
    ExpectedMisfit,
    MisfitField,
    expected_misfits,
    misfit_field,
    tolerance_factor,
)


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
    thresholds_given: tuple[float | None, float | None],
    frames_per_pose: int,
    robot_model: str,
    fallback_basis: str,
) -> tuple[list[ExpectedMisfit] | None, str]:
    """The misfit expected at each check pose and the thresholds' basis; None and the basis of
    :func:`~spacecal.workflows.check.check_thresholds` (saying why) when it cannot be predicted."""
    given = [value is not None for value in thresholds_given]
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
        f"recorded scatter, the tracker's over {frames_per_pose} frames, the {robot_model}'s "
        f"ISO 9283 repeatability): a sound set-up fails at most {FALSE_ALARM_RATE:.0%} of checks"
    )
    return expected, basis + ("; partly given on the command line" if any(given) else "")
