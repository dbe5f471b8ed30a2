"""Pre-operative calibration check: does the calibration still hold?

At two or three poses the tracked marker is compared with where the calibration predicts it
(``tracker_from_base @ base_from_tcp @ tcp_from_marker``). The error is reported where it
matters, at the TCP (the needle tip in the paper's set-up): the distance between the TCP
origin as the calibration places it and as the tracked marker places it, and the angle
between the two marker orientations. A bumped marker, a moved tracker or a re-mounted tool
shows up at once. Each check is appended to a history file next to the calibration.
"""

from __future__ import annotations

import json
import math
import os
from collections import defaultdict
from pathlib import Path
from typing import NamedTuple

import numpy as np

from spacecal.core.errors import DegenerateDataError, DeviceError, InvalidInputError, SpacecalError
from spacecal.core.ports import Robot, RobotState, Tracker
from spacecal.geometry.rotations import mean_rotation, rotation_angle
from spacecal.geometry.transforms import invert_transform, make_transform
from spacecal.io.results_json import read_json_object
from spacecal.models.kinematics import forward_kinematics
from spacecal.planning.motion import MotionPlan
from spacecal.records import CalibrationResult, CheckResult, Recording
from spacecal.records.integrity import content_sha256
from spacecal.workflows.acquisition import AcquisitionResult, AcquisitionSettings, RunFault, run_plan

#: A check fails beyond this many standard deviations of what a sound calibration leaves.
CHECK_SIGMAS = 3.0
#: Smallest thresholds (a check must not fail on the tracker's own noise): mm, deg.
CHECK_FLOOR_MM, CHECK_FLOOR_DEG = 0.5, 0.25
#: Thresholds used when the calibration carries no expected error (older files): mm, deg.
FALLBACK_THRESHOLD_MM, FALLBACK_THRESHOLD_DEG = 1.0, 1.0


def check_thresholds(calibration: CalibrationResult, frames_averaged: int = 1) -> tuple[float, float, str]:
    """Thresholds (mm at the TCP, deg) a sound calibration passes, from its own numbers.

    A check pose's misfit is the calibration's error there (its expected error,
    :mod:`spacecal.estimators.expected_error`) plus what its model leaves unexplained in one
    frame (its residual RMS), shrunk by the frames averaged at the pose. The marker's rotation
    residual reaches the TCP over the marker-to-TCP lever arm, so a frame's TCP misfit is the
    root sum of squares of the position residual and that lever times the rotation residual.
    The threshold is ``CHECK_SIGMAS`` times the total, at least ``CHECK_FLOOR_MM`` /
    ``CHECK_FLOOR_DEG``.

    Parameters
    ----------
    calibration : CalibrationResult
    frames_averaged : int
        Frames averaged into each checked pose (1 when single frames are compared).

    Returns
    -------
    threshold_mm, threshold_deg : float
    basis : str
        Where they came from, for the output.
    """
    expected = calibration.diagnostics.get("expected_error") or {}
    raw_numbers = [
        expected.get("position_mm"),
        expected.get("posture_deg"),
        calibration.diagnostics.get("residual_position_rms_mm"),
        calibration.diagnostics.get("residual_rotation_rms_deg"),
    ]
    if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in raw_numbers):
        return FALLBACK_THRESHOLD_MM, FALLBACK_THRESHOLD_DEG, "fixed (the calibration has no expected error)"
    position, posture, residual_mm, residual_deg = (float(v) for v in raw_numbers)  # type: ignore[arg-type]
    lever_mm = float(np.linalg.norm(calibration.tcp_from_marker[:3, 3]))
    frame_mm = math.hypot(residual_mm, lever_mm * math.radians(residual_deg))
    shrink = math.sqrt(max(1, frames_averaged))
    threshold_mm = max(CHECK_FLOOR_MM, CHECK_SIGMAS * math.hypot(position, frame_mm / shrink))
    threshold_deg = max(CHECK_FLOOR_DEG, CHECK_SIGMAS * math.hypot(posture, residual_deg / shrink))
    return (
        threshold_mm,
        threshold_deg,
        f"{CHECK_SIGMAS:g} sigma of the calibration's expected error ({position:.2f} mm, {posture:.2f} deg) "
        f"and its one-frame misfit ({frame_mm:.2f} mm, {residual_deg:.2f} deg) "
        f"over {frames_averaged} frame(s)",
    )


def robot_pose(
    calibration: CalibrationResult, state_pose: np.ndarray, joints_rad: np.ndarray | None
) -> np.ndarray:
    """The TCP pose the calibration pairs with the marker: from its identified kinematics at the
    joints when it has them (``--method kinematic``), else the pose the controller reported."""
    if calibration.robot_model is not None and joints_rad is not None and np.all(np.isfinite(joints_rad)):
        return forward_kinematics(calibration.robot_model, joints_rad)
    return np.asarray(state_pose, dtype=float)


def pose_errors(calibration: CalibrationResult, base_from_tcp, tracker_from_marker) -> tuple[float, float]:
    """(TCP position error mm, marker rotation error deg) of one pose."""
    predicted_marker = calibration.tracker_from_base @ base_from_tcp @ calibration.tcp_from_marker
    predicted_tcp = (calibration.tracker_from_base @ base_from_tcp)[:3, 3]
    measured_tcp = (tracker_from_marker @ invert_transform(calibration.tcp_from_marker))[:3, 3]
    angle = np.degrees(rotation_angle(predicted_marker[:3, :3] @ tracker_from_marker[:3, :3].T))
    return float(np.linalg.norm(predicted_tcp - measured_tcp)), float(angle)


class _CheckSink:
    """Keeps the frames and robot states of each check pose's hold."""

    def __init__(self) -> None:
        self.frames: dict[str, list[np.ndarray]] = defaultdict(list)
        self.states: dict[str, list[RobotState]] = defaultdict(list)

    def append(self, time_s, segment, joints_rad, base_from_tcp, tracker_from_marker=None, *_, **__) -> None:
        if tracker_from_marker is not None:
            self.frames[segment].append(np.asarray(tracker_from_marker, dtype=float))

    def add_robot_states(self, states: list[RobotState], segment: str) -> None:
        self.states[segment].extend(states)


def check_with_robot(
    calibration: CalibrationResult,
    robot: Robot,
    tracker: Tracker,
    plan: MotionPlan,
    threshold_mm: float,
    threshold_deg: float,
    settings: AcquisitionSettings,
    frames_per_pose: int = 10,
) -> CheckResult:
    """Run the check plan (:func:`spacecal.planning.check_poses.check_plan`), average the
    frames held at each pose, and compare with the calibration's prediction.

    The plan runs through the acquisition loop: a safety stop, a lost tracker or a move past
    its deadline stops the robot and raises :class:`~spacecal.core.errors.DeviceError`.

    Raises
    ------
    DegenerateDataError
        When the marker was seen in fewer than half the frames at a check pose.
    DeviceError
        On a device fault (the robot was stopped; nothing is logged).
    """
    sink = _CheckSink()
    progress = AcquisitionResult(Path("check"), 0, 0, 0, len(plan.moves))
    try:
        run_plan(plan, robot, tracker, sink, settings, progress)
    except (RunFault, SpacecalError, KeyboardInterrupt) as exc:
        robot.stop()
        reason = "interrupted by the user (Ctrl-C)" if isinstance(exc, KeyboardInterrupt) else str(exc)
        raise DeviceError(f"check stopped: {reason}; the robot was stopped and nothing was logged") from None
    errors, angles, labels = [], [], []
    for move in plan.moves:
        if move.sample_period_s <= 0 or move.label in labels:
            continue
        seen, states = sink.frames.get(move.label, []), sink.states.get(move.label, [])
        if len(seen) < max(3, frames_per_pose // 2) or not states:
            raise DegenerateDataError(
                f"check {move.label}: the marker was seen in {len(seen)} frames; "
                "make sure the tracker sees it"
            )
        poses = np.array(seen)
        measured = make_transform(mean_rotation(poses[:, :3, :3]), poses[:, :3, 3].mean(axis=0))
        at_rest = states[-1]
        base_from_tcp = robot_pose(calibration, at_rest.base_from_tcp, at_rest.joints_rad)
        error, angle = pose_errors(calibration, base_from_tcp, measured)
        errors.append(error)
        angles.append(angle)
        labels.append(move.label)
    return CheckResult(np.array(errors), np.array(angles), threshold_mm, threshold_deg, labels)


def check_with_recording(
    calibration: CalibrationResult,
    recording: Recording,
    threshold_mm: float = 1.0,
    threshold_deg: float = 1.0,
) -> CheckResult:
    """Check against the visible frames of a recording, one result per segment label."""
    errors, angles, labels = [], [], []
    for label in dict.fromkeys(recording.segment.tolist()):
        rows = np.flatnonzero((recording.segment == label) & recording.visible)
        if len(rows) == 0:
            continue
        per_frame = np.array(
            [
                pose_errors(
                    calibration,
                    robot_pose(calibration, recording.base_from_tcp_stack[r], recording.joints_rad[r]),
                    recording.tracker_from_marker_stack[r],
                )
                for r in rows
            ]
        )
        errors.append(float(np.median(per_frame[:, 0])))
        angles.append(float(np.median(per_frame[:, 1])))
        labels.append(str(label))
    if not labels:
        raise DegenerateDataError("the recording has no frame with the marker visible to check against")
    return CheckResult(np.array(errors), np.array(angles), threshold_mm, threshold_deg, labels)


def history_path(calibration_path: str | Path) -> Path:
    """``cal.json`` -> ``cal.checks.jsonl``."""
    path = Path(calibration_path)
    return path.with_name(path.stem + ".checks.jsonl")


#: The key of a history line that binds it to the content hash of the calibration it checked.
CALIBRATION_HASH_KEY = "calibration_sha256"


class History(NamedTuple):
    """The checks of one calibration, oldest first, and the lines left out: unreadable ones,
    and those of another calibration (one replaced at the same path, or lines written before
    checks recorded the calibration's hash)."""

    checks: list[CheckResult]
    unreadable: int
    other_calibrations: int


def calibration_content_sha256(calibration_path: str | Path) -> str:
    """The content hash of the calibration file as it stands (see :mod:`spacecal.records.integrity`)."""
    return content_sha256(read_json_object(calibration_path, "calibration"))


def append_history(
    calibration_path: str | Path, result: CheckResult, calibration_sha256: str | None = None
) -> Path:
    """Append a check to the calibration's history (one JSON object per line), bound to the
    content hash of the calibration checked (by default, of the file as it stands)."""
    if calibration_sha256 is None:
        calibration_sha256 = calibration_content_sha256(calibration_path)
    path = history_path(calibration_path)
    line = {**result.to_dict(), CALIBRATION_HASH_KEY: calibration_sha256}
    with open(path, "a", encoding="utf-8") as handle:
        handle.write(json.dumps(line, allow_nan=False) + "\n")
        handle.flush()
        os.fsync(handle.fileno())
    return path


def read_history(calibration_path: str | Path, calibration_sha256: str | None = None) -> History:
    """The checks logged for the calibration of content hash ``calibration_sha256`` (by
    default, of the file as it stands), oldest first; lines of any other calibration and lines
    that could not be read are counted, not returned (a corrupt line is never fatal: the
    history is advisory). A calibration replaced at the same path thus never shows the checks
    of the one before it."""
    path = history_path(calibration_path)
    if not path.is_file():
        return History([], 0, 0)
    if calibration_sha256 is None:
        calibration_sha256 = calibration_content_sha256(calibration_path)
    checks, unreadable, others = [], 0, 0
    for line in path.read_bytes().decode("utf-8", errors="replace").splitlines():
        if not line.strip():
            continue
        try:
            data = json.loads(line)
            if not isinstance(data, dict):
                raise InvalidInputError("not an object")
            check = CheckResult.from_dict(data, what=str(path))
        except (ValueError, RecursionError):
            unreadable += 1
            continue
        if data.get(CALIBRATION_HASH_KEY) != calibration_sha256:
            others += 1
        else:
            checks.append(check)
    return History(checks, unreadable, others)
