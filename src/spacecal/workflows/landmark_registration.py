"""Register a phantom (or patient image) to a reference marker from a tracked-stylus recording.

The stylus tip is brought into the reference frame frame by frame
(``reference_from_tip = reference_from_tracker @ tracker_from_stylus @ stylus_from_tip``),
the landmark touches are detected (:mod:`spacecal.registration.landmarks`), and the defined
landmark positions are registered to them (``reference_from_phantom``).
"""

from __future__ import annotations

import numpy as np

from spacecal.core.errors import DegenerateDataError
from spacecal.geometry.transforms import invert_transform, orthonormalize_transforms
from spacecal.records import LandmarkRegistrationResult
from spacecal.registration.landmarks import LandmarkDetectionSettings, detect_landmarks
from spacecal.registration.points import register_points


def register_landmarks_from_stylus(
    timestamps_s,
    tracker_from_reference_stack,
    tracker_from_stylus_stack,
    stylus_from_tip,
    landmarks_in_phantom,
    settings: LandmarkDetectionSettings | None = None,
) -> LandmarkRegistrationResult:
    """Detect the landmark touches and register the phantom to the reference marker.

    Parameters
    ----------
    timestamps_s : array_like, shape (N,)
        Frames with a repeated timestamp are dropped (as PLUS does).
    tracker_from_reference_stack, tracker_from_stylus_stack : array_like, shape (N, 4, 4), mm
    stylus_from_tip : array_like, shape (4, 4)
        The stylus tip calibration (a pivot calibration's tip, with the tip frame's x axis
        along the shaft as PLUS defines it).
    landmarks_in_phantom : array_like, shape (M, 3), mm
        Defined landmark positions, in the order they are touched.
    settings : LandmarkDetectionSettings, optional
        Default: PLUS's, with the rate from the first two frames and the spacing from the
        landmark definition (as PLUS's own test does).
    """
    times = np.asarray(timestamps_s, dtype=float)
    keep = np.concatenate([[True], np.diff(times) != 0])
    phantom = np.asarray(landmarks_in_phantom, dtype=float)
    # frames are counted as in the sequence: each pose is checked before any frame is dropped
    tracker_from_reference = orthonormalize_transforms(tracker_from_reference_stack, "the reference's poses")
    tracker_from_stylus = orthonormalize_transforms(tracker_from_stylus_stack, "the stylus's poses")
    tracker_from_reference, tracker_from_stylus = tracker_from_reference[keep], tracker_from_stylus[keep]
    reference_from_tip = (
        invert_transform(tracker_from_reference)
        @ tracker_from_stylus
        @ np.asarray(stylus_from_tip, dtype=float)
    )
    if settings is None:
        kept_times = times[keep]
        spacing = float(min(np.linalg.norm(a - b) for i, a in enumerate(phantom) for b in phantom[i + 1 :]))
        settings = LandmarkDetectionSettings(
            acquisition_rate_hz=1.0 / (kept_times[1] - kept_times[0]), min_landmark_spacing_mm=spacing
        )
    detected, ends = detect_landmarks(reference_from_tip, settings, expected=len(phantom))
    if len(detected) < len(phantom):
        raise DegenerateDataError(
            f"found {len(detected)} landmark touches of the {len(phantom)} defined: hold the tip still "
            "in each divot and pivot the stylus for at least a second"
        )
    registration = register_points(points_in_source=phantom, points_in_target=detected)
    return LandmarkRegistrationResult(
        reference_from_phantom=registration.target_from_source,
        detected_in_reference=detected,
        detected_at_s=[float(times[keep][i]) for i in ends],
        residuals_mm=registration.residuals_mm,
        fre_rms_mm=registration.fre_rms_mm,
        fre_mean_mm=registration.fre_mean_mm,
        fle_rms_mm=registration.fle_rms_mm,
    )
