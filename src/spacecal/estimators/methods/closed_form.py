"""Registry methods wrapping the closed-form solvers (robot-world AX = YB, hand-eye AX = XB)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from spacecal.estimators.methods.hand_eye import motion_pairs, relative_motions
from spacecal.estimators.methods.samples import (
    motion_spread,
    sample_counts,
    tracker_from_base_from_samples,
)
from spacecal.geometry.arrays import FloatArray, IntArray
from spacecal.geometry.transforms import invert_transform
from spacecal.records import CalibrationResult, Recording

#: A closed form for A_i X = Y B_i: ``(base_from_tcp_stack, tracker_from_marker_stack) -> (X, Y)``
#: with X = ``tcp_from_marker`` and Y = ``base_from_tracker``
#: (:mod:`spacecal.estimators.methods.robot_world`).
RobotWorldSolver = Callable[[FloatArray, FloatArray], tuple[FloatArray, FloatArray]]

#: A closed form for A_k X = X B_k: ``(tcp_motion_stack, marker_motion_stack) -> X``
#: (:mod:`spacecal.estimators.methods.hand_eye`).
HandEyeSolver = Callable[[FloatArray, FloatArray], FloatArray]

#: Hand-eye methods use the motions between every pair of up to this many visible frames; with
#: more, a spread subset of pairs that rotate far from 0 and 180 deg (hand_eye.motion_pairs).
HAND_EYE_FRAMES = 60


def _first_line(text: str | None) -> str:
    return (text or "").strip().splitlines()[0] if text and text.strip() else ""


def closed_form_result(
    method: str,
    recording: Recording,
    tracker_from_base: FloatArray,
    tcp_from_marker: FloatArray,
    used_rows: IntArray,
    extra: dict[str, Any] | None = None,
) -> CalibrationResult:
    """Package a closed-form estimate with the motion's spread (its residuals are the
    assessment's, :mod:`spacecal.estimators.assessment`)."""
    diagnostics = {
        "motion_spread": motion_spread(recording.base_from_tcp_stack[used_rows]),
        **(extra or {}),
    }
    return CalibrationResult(
        method, tracker_from_base, tcp_from_marker, sample_counts(recording, used_rows), diagnostics
    )


def robot_world_method(name: str, solver: RobotWorldSolver) -> Callable[[Recording], CalibrationResult]:
    """A registry function solving AX = YB with ``solver`` on all visible frames; its results
    are named ``name``."""

    def calibrate_robot_world(recording: Recording) -> CalibrationResult:
        rows = np.flatnonzero(recording.visible)
        tcp_from_marker, base_from_tracker = solver(
            recording.base_from_tcp_stack[rows], recording.tracker_from_marker_stack[rows]
        )
        return closed_form_result(name, recording, invert_transform(base_from_tracker), tcp_from_marker, rows)

    calibrate_robot_world.__doc__ = f"AX = YB by {_first_line(solver.__doc__)}"
    return calibrate_robot_world


def hand_eye_method(name: str, solver: HandEyeSolver) -> Callable[[Recording], CalibrationResult]:
    """A registry function solving AX = XB with ``solver`` from relative motions, then
    tracker_from_base by averaging; its results are named ``name``.

    The motions are those between the pairs of visible frames :func:`motion_pairs` picks (all
    pairs up to :data:`HAND_EYE_FRAMES` frames); their number is reported as the diagnostic
    ``hand_eye_motions``.
    """

    def calibrate_hand_eye(recording: Recording) -> CalibrationResult:
        visible = np.flatnonzero(recording.visible)
        base_from_tcp_stack = recording.base_from_tcp_stack[visible]
        pairs = motion_pairs(base_from_tcp_stack, all_pairs_frames=HAND_EYE_FRAMES)
        motions = relative_motions(base_from_tcp_stack, recording.tracker_from_marker_stack[visible], pairs)
        tcp_from_marker = solver(*motions)
        tracker_from_base = tracker_from_base_from_samples(recording, tcp_from_marker, visible)
        return closed_form_result(
            name,
            recording,
            tracker_from_base,
            tcp_from_marker,
            visible,
            {"hand_eye_motions": len(pairs)},
        )

    calibrate_hand_eye.__doc__ = f"AX = XB by {_first_line(solver.__doc__)}"
    return calibrate_hand_eye
