"""Error metrics (paper §5.2): position error and posture error."""

from __future__ import annotations

import numpy as np

from spacecal.geometry.arrays import ArrayLike, FloatArray, as_float_array
from spacecal.geometry.rotations import rotation_angle
from spacecal.geometry.transforms import apply_transform, rotation_part, translation_part


def position_error(desired_transform: ArrayLike, reached_transform: ArrayLike) -> FloatArray:
    """``|ΔP| = |P_d - P_r|`` in mm, for transforms of shape (…, 4, 4) in one frame."""
    return as_float_array(
        np.linalg.norm(translation_part(desired_transform) - translation_part(reached_transform), axis=-1)
    )


def posture_error_rad(desired_transform: ArrayLike, reached_transform: ArrayLike) -> FloatArray:
    """Δφ = angle of ΔR = R_d R_r^-1 in radians (paper §5.2), for (…, 4, 4) transforms."""
    r_d = rotation_part(desired_transform)
    r_r = rotation_part(reached_transform)
    return rotation_angle(r_d @ np.swapaxes(r_r, -1, -2))


def target_registration_errors(
    estimated_a_from_b: ArrayLike, true_a_from_b: ArrayLike, points_in_b: ArrayLike
) -> FloatArray:
    """Distances ``|T_est p - T_true p|`` in mm for target points (N, 3) given in frame b."""
    return as_float_array(
        np.linalg.norm(
            apply_transform(estimated_a_from_b, points_in_b) - apply_transform(true_a_from_b, points_in_b),
            axis=-1,
        )
    )


def cube_grid(centre_mm: ArrayLike, side_mm: float = 200.0, points_per_side: int = 5) -> FloatArray:
    """Points on a regular grid filling a cube, shape (points_per_side**3, 3), mm."""
    offsets = np.linspace(-side_mm / 2.0, side_mm / 2.0, points_per_side)
    grid = np.stack(np.meshgrid(offsets, offsets, offsets, indexing="ij"), axis=-1).reshape(-1, 3)
    return as_float_array(grid + np.asarray(centre_mm, dtype=float))


def summary_statistics(values: ArrayLike) -> dict[str, float]:
    """min / mean / max / RMS of a 1-D array, as plain floats."""
    v = np.asarray(values, dtype=float)
    return {
        "min": float(v.min()),
        "mean": float(v.mean()),
        "max": float(v.max()),
        "rms": float(np.sqrt(np.mean(v**2))),
    }
