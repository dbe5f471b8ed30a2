"""The paper's linear–rotation calibration (Space calibration of the cranial and maxillofacial
robotic system in surgery, §3).

* Rotation method (§3.2, eqs. 7–9): while the TCP rotates about its own origin, the marker
  origin moves on a sphere centred on the TCP origin; the sphere fit gives the TCP origin
  in the tracker frame.
* Linear method (§3.1, eqs. 2–6): while the TCP translates along its own axes, the marker
  origin moves on lines parallel to them; line fits give the TCP axes in the tracker frame,
  orthonormalised by the nearest rotation.
* Combination (end of §3.2): tracker_from_tcp(home) = [R | c], and
  tracker_from_base = tracker_from_tcp(home) @ tcp_from_base(home).

We solve the orientation as Wahba's problem between the fitted travel directions (tracker)
and the travel directions the robot reports (base). When the robot travels exactly along
its home TCP axes this is the paper's nearest rotation of [d_x d_y d_z] followed by the
home orientation; it stays right when a sweep was shrunk or the axes were not exact.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations
from typing import Any

import numpy as np

from spacecal.core.errors import DegenerateDataError
from spacecal.estimators.methods.samples import sample_counts
from spacecal.geometry.arrays import ArrayLike, BoolArray, FloatArray, IndexArray
from spacecal.geometry.fitting import LineFit, fit_line, fit_sphere
from spacecal.geometry.rotations import mean_rotation, nearest_rotation, rotation_angle, wahba_rotation
from spacecal.geometry.transforms import invert_transform, make_transform, matrix_to_rotvec, mean_transform
from spacecal.records import (
    ROTATION_SEGMENTS,
    TRANSLATION_SEGMENTS,
    CalibrationResult,
    Recording,
    fit_evidence,
)


@dataclass(frozen=True)
class PaperThresholds:
    """Limits beyond which the data is called degenerate (documented in docs/methods.md).

    Attributes
    ----------
    min_samples_per_segment : int
        Visible samples needed in each of the six sweeps.
    min_rotation_span_deg : float
        Rotation each rotation sweep must cover, as seen by the tracker.
    max_tcp_origin_drift_mm : float
        How far the reported TCP origin may move during the rotation sweeps.
    min_line_length_mm : float
        Travel each translation sweep must cover.
    max_line_rms_mm : float
        Straightness: RMS distance of the marker origin from its fitted line.
    max_orientation_drift_deg : float
        How far the reported TCP orientation may turn during a translation sweep.
    max_axis_angle_error_deg : float
        Largest difference between a pair of fitted axes' angle and the commanded one.
    """

    min_samples_per_segment: int = 5
    min_rotation_span_deg: float = 20.0
    max_tcp_origin_drift_mm: float = 1.0
    min_line_length_mm: float = 50.0
    max_line_rms_mm: float = 1.0
    max_orientation_drift_deg: float = 0.5
    max_axis_angle_error_deg: float = 5.0


def _segment_rows(recording: Recording, label: str, thresholds: PaperThresholds) -> BoolArray:
    rows = recording.segment == label
    if not rows.any():
        raise DegenerateDataError(
            f"sweep segment {label!r} is missing; the paper method needs "
            f"{', '.join(ROTATION_SEGMENTS + TRANSLATION_SEGMENTS)}"
        )
    used = rows & recording.visible
    if used.sum() < thresholds.min_samples_per_segment:
        raise DegenerateDataError(
            f"sweep segment {label!r} has {int(used.sum())} samples with the marker visible "
            f"(of {int(rows.sum())}); at least {thresholds.min_samples_per_segment} are needed"
        )
    return np.asarray(used, dtype=np.bool_)


def rotation_span_deg(rotations: ArrayLike) -> float:
    """Range of rotation angle covered about the dominant axis by rotations (N, 3, 3), deg."""
    rotations = np.asarray(rotations)
    reference = mean_rotation(rotations)
    rotvecs = matrix_to_rotvec(rotations @ reference.T)
    _, _, vt = np.linalg.svd(rotvecs - 0.0, full_matrices=False)
    angles = rotvecs @ vt[0]
    return float(np.degrees(angles.max() - angles.min()))


def _rotation_origin(
    recording: Recording, rot_rows: BoolArray, thresholds: PaperThresholds, diagnostics: dict[str, Any]
) -> tuple[FloatArray, FloatArray]:
    """Sphere fit of the marker origin over all rotation sweeps -> TCP origin in tracker and base."""
    spans = {}
    for label in ROTATION_SEGMENTS:
        rows = rot_rows & (recording.segment == label)
        spans[label] = rotation_span_deg(recording.tracker_from_marker_stack[rows, :3, :3])
        if spans[label] < thresholds.min_rotation_span_deg:
            raise DegenerateDataError(
                f"sweep {label!r} covers only {spans[label]:.1f} deg of rotation; at least "
                f"{thresholds.min_rotation_span_deg:.0f} deg are needed to fit the TCP origin"
            )
    all_rot = np.isin(recording.segment, ROTATION_SEGMENTS)
    tcp_positions = recording.base_from_tcp_stack[all_rot, :3, 3]
    tcp_origin_in_base = tcp_positions.mean(axis=0)
    drift = float(np.max(np.linalg.norm(tcp_positions - tcp_origin_in_base, axis=1)))
    if drift > thresholds.max_tcp_origin_drift_mm:
        raise DegenerateDataError(
            f"the reported TCP origin moved {drift:.2f} mm during the rotation sweeps (limit "
            f"{thresholds.max_tcp_origin_drift_mm} mm): the robot must rotate about the TCP origin"
        )
    sphere = fit_sphere(recording.tracker_from_marker_stack[rot_rows, :3, 3])
    diagnostics["sphere"] = {
        "centre_in_tracker_mm": sphere.centre.tolist(),
        "radius_mm": sphere.radius,
        "rms_mm": sphere.rms,
        "samples": int(rot_rows.sum()),
    }
    diagnostics["rotation_span_deg"] = spans
    diagnostics["tcp_origin_drift_mm"] = drift
    return sphere.centre, tcp_origin_in_base


def _signed_direction(
    points: FloatArray, reference_points: FloatArray, label: str, thresholds: PaperThresholds
) -> tuple[FloatArray, FloatArray, LineFit]:
    """Line fit of ``points`` signed to agree with the travel of ``reference_points``."""
    line = fit_line(points)
    reference = fit_line(reference_points)
    travel = (reference_points - reference.point) @ reference.direction
    along = (points - line.point) @ line.direction
    direction = line.direction if travel @ along >= 0 else -line.direction
    if line.length < thresholds.min_line_length_mm:
        raise DegenerateDataError(
            f"sweep {label!r} travels only {line.length:.1f} mm; at least "
            f"{thresholds.min_line_length_mm:.0f} mm are needed to fit its axis"
        )
    if line.rms > thresholds.max_line_rms_mm:
        raise DegenerateDataError(
            f"sweep {label!r} is not straight: the marker's RMS distance from the fitted line is "
            f"{line.rms:.2f} mm (limit {thresholds.max_line_rms_mm} mm)"
        )
    return direction, reference.direction, line


def _translation_axes(
    recording: Recording, thresholds: PaperThresholds, diagnostics: dict[str, Any]
) -> tuple[FloatArray, FloatArray]:
    """Line fits of the translation sweeps -> matching travel directions in tracker and base."""
    tracker_directions: list[FloatArray] = []
    base_directions: list[FloatArray] = []
    lines: dict[str, Any] = {}
    for label in TRANSLATION_SEGMENTS:
        rows = _segment_rows(recording, label, thresholds)
        orientations = recording.base_from_tcp_stack[recording.segment == label, :3, :3]
        drift = float(np.degrees(rotation_angle(orientations @ orientations[0].T).max()))
        if drift > thresholds.max_orientation_drift_deg:
            raise DegenerateDataError(
                f"the reported TCP orientation turned {drift:.2f} deg during sweep {label!r} (limit "
                f"{thresholds.max_orientation_drift_deg} deg): translation sweeps must keep it fixed"
            )
        d_tracker, d_base, line = _signed_direction(
            recording.tracker_from_marker_stack[rows, :3, 3],
            recording.base_from_tcp_stack[rows, :3, 3],
            label,
            thresholds,
        )
        tracker_directions.append(d_tracker)
        base_directions.append(d_base)
        lines[label] = {
            "straightness_rms_mm": line.rms,
            "length_mm": line.length,
            "direction_in_tracker": d_tracker.tolist(),
            "samples": int(rows.sum()),
        }
    in_tracker, in_base = np.array(tracker_directions), np.array(base_directions)
    angles = {}
    for i, j in combinations(range(3), 2):
        fitted = np.degrees(np.arccos(np.clip(in_tracker[i] @ in_tracker[j], -1, 1)))
        commanded = np.degrees(np.arccos(np.clip(in_base[i] @ in_base[j], -1, 1)))
        pair = f"{TRANSLATION_SEGMENTS[i]}-{TRANSLATION_SEGMENTS[j]}"
        angles[pair] = {"fitted_deg": fitted, "commanded_deg": commanded}
        if abs(fitted - commanded) > thresholds.max_axis_angle_error_deg:
            raise DegenerateDataError(
                f"fitted axes {pair} are {fitted:.1f} deg apart where the robot moved "
                f"{commanded:.1f} deg apart (limit {thresholds.max_axis_angle_error_deg} deg)"
            )
    diagnostics["lines"] = lines
    diagnostics["axis_angles_before_orthonormalising"] = angles
    return in_tracker, in_base


def estimate_tcp_from_marker(
    recording: Recording, tracker_from_base: FloatArray, rows: IndexArray
) -> FloatArray:
    """Average tcp_from_marker = tcp_from_base @ base_from_tracker @ tracker_from_marker over rows."""
    base_from_tracker = invert_transform(tracker_from_base)
    each = (
        invert_transform(recording.base_from_tcp_stack[rows])
        @ base_from_tracker
        @ recording.tracker_from_marker_stack[rows]
    )
    return mean_transform(each)


def calibrate_paper(recording: Recording, thresholds: PaperThresholds | None = None) -> CalibrationResult:
    """Calibrate by the paper's linear–rotation method.

    Parameters
    ----------
    recording : Recording
        Must hold the six sweeps ``rot_x, rot_y, rot_z`` (TCP rotating about its origin) and
        ``lin_x, lin_y, lin_z`` (TCP translating, orientation fixed).
    thresholds : PaperThresholds, optional

    Returns
    -------
    CalibrationResult
        ``diagnostics`` holds: sphere radius, RMS and centre; rotation span per sweep;
        TCP origin drift; per-line straightness, length and direction; the angles between
        fitted axes before orthonormalising, beside the commanded ones; the angle the
        orthonormalisation moved each axis; sphere radius versus ``|tcp_from_marker|`` offset.

    Raises
    ------
    DegenerateDataError
        For a missing sweep, too few visible samples, too little rotation or travel, a
        bent line, a drifting TCP, or axes far from the commanded angles.
    """
    thresholds = thresholds or PaperThresholds()
    diagnostics: dict[str, Any] = {}
    rot_rows = np.zeros(len(recording), dtype=bool)
    for label in ROTATION_SEGMENTS:
        rot_rows |= _segment_rows(recording, label, thresholds)
    tcp_origin_in_tracker, tcp_origin_in_base = _rotation_origin(recording, rot_rows, thresholds, diagnostics)
    d_tracker, d_base = _translation_axes(recording, thresholds, diagnostics)

    rotation = wahba_rotation(directions_in_source=d_base, directions_in_target=d_tracker)
    translation = tcp_origin_in_tracker - rotation @ tcp_origin_in_base
    tracker_from_base = make_transform(rotation, translation)

    predicted = d_base @ rotation.T
    diagnostics["orthonormalisation_correction_deg"] = {
        label: float(np.degrees(np.arccos(np.clip(p @ d, -1, 1))))
        for label, p, d in zip(TRANSLATION_SEGMENTS, predicted, d_tracker)
    }
    # The paper's own form, for comparison: nearest rotation of the stacked fitted axes.
    diagnostics["paper_axes_rotation_in_tracker"] = nearest_rotation(d_tracker.T).tolist()

    used = rot_rows | (np.isin(recording.segment, TRANSLATION_SEGMENTS) & recording.visible)
    tcp_from_marker = estimate_tcp_from_marker(recording, tracker_from_base, used)
    offset = float(np.linalg.norm(tcp_from_marker[:3, 3]))
    diagnostics["sphere"]["radius_minus_marker_offset_mm"] = diagnostics["sphere"]["radius_mm"] - offset

    in_sweeps = np.isin(recording.segment, ROTATION_SEGMENTS + TRANSLATION_SEGMENTS)
    counts = sample_counts(
        recording,
        used,
        considered=in_sweeps,
        extra_rejections={"other_segment": int((~in_sweeps).sum())},
        per_segment=ROTATION_SEGMENTS + TRANSLATION_SEGMENTS,
    )
    # the sphere and the lines are the typed evidence others read (the report draws them)
    fits = fit_evidence.SweepFits(
        fit_evidence.SphereFit.from_dict(diagnostics.pop("sphere")),
        {label: fit_evidence.LineFit.from_dict(line) for label, line in diagnostics.pop("lines").items()},
    )
    return CalibrationResult(
        method="paper",
        tracker_from_base=tracker_from_base,
        tcp_from_marker=tcp_from_marker,
        sample_counts=counts,
        diagnostics=diagnostics,
        sweep_fits=fits,
    )
