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
import os
from pathlib import Path

import numpy as np

from spacecal.core.errors import DegenerateDataError, InvalidInputError
from spacecal.core.ports import FRAME_OK, Robot, Tracker
from spacecal.geometry.rotations import mean_rotation, rotation_angle
from spacecal.geometry.transforms import invert_transform, make_transform
from spacecal.records import CalibrationResult, CheckResult, Recording


def pose_errors(calibration: CalibrationResult, base_from_tcp, tracker_from_marker) -> tuple[float, float]:
    """(TCP position error mm, marker rotation error deg) of one pose."""
    predicted_marker = calibration.tracker_from_base @ base_from_tcp @ calibration.tcp_from_marker
    predicted_tcp = (calibration.tracker_from_base @ base_from_tcp)[:3, 3]
    measured_tcp = (tracker_from_marker @ invert_transform(calibration.tcp_from_marker))[:3, 3]
    angle = np.degrees(rotation_angle(predicted_marker[:3, :3] @ tracker_from_marker[:3, :3].T))
    return float(np.linalg.norm(predicted_tcp - measured_tcp)), float(angle)


def check_with_robot(
    calibration: CalibrationResult,
    robot: Robot,
    tracker: Tracker,
    joints_list,
    threshold_mm: float = 1.0,
    threshold_deg: float = 1.0,
    frames_per_pose: int = 10,
    speed_rad_s: float = 0.3,
    accel_rad_s2: float = 0.5,
) -> CheckResult:
    """Move to each configuration (P, 6), average ``frames_per_pose`` tracker frames, compare."""
    errors, angles, labels = [], [], []
    for k, joints in enumerate(np.asarray(joints_list, dtype=float)):
        robot.move_joints(joints, speed_rad_s, accel_rad_s2)
        seen: list[np.ndarray] = []
        frames_read = 0
        while len(seen) < frames_per_pose:
            frame = tracker.next_frame(1.0)
            frames_read += 1
            if frame.status == FRAME_OK and frame.tracker_from_marker is not None:
                seen.append(frame.tracker_from_marker)
            elif frames_read > 10 * frames_per_pose:
                raise DegenerateDataError(f"check pose {k + 1}: the marker is not visible")
        poses = np.array(seen)
        measured = make_transform(mean_rotation(poses[:, :3, :3]), poses[:, :3, 3].mean(axis=0))
        error, angle = pose_errors(calibration, robot.state().base_from_tcp, measured)
        errors.append(error)
        angles.append(angle)
        labels.append(f"pose {k + 1}")
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
                    calibration, recording.base_from_tcp_stack[r], recording.tracker_from_marker_stack[r]
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


def append_history(calibration_path: str | Path, result: CheckResult) -> Path:
    """Append a check to the calibration's history (one JSON object per line)."""
    path = history_path(calibration_path)
    with open(path, "a", encoding="utf-8") as handle:
        handle.write(json.dumps(result.to_dict(), allow_nan=False) + "\n")
        handle.flush()
        os.fsync(handle.fileno())
    return path


def read_history(calibration_path: str | Path) -> tuple[list[CheckResult], int]:
    """The checks logged for a calibration, oldest first, and the number of lines that could
    not be read (a corrupt line is skipped, never fatal: the history is advisory)."""
    path = history_path(calibration_path)
    if not path.is_file():
        return [], 0
    checks, unreadable = [], 0
    for line in path.read_bytes().decode("utf-8", errors="replace").splitlines():
        if not line.strip():
            continue
        try:
            data = json.loads(line)
            if not isinstance(data, dict):
                raise InvalidInputError("not an object")
            checks.append(CheckResult.from_dict(data, what=str(path)))
        except (ValueError, RecursionError):
            unreadable += 1
    return checks, unreadable
