"""Compare a calibration with the simulated ground truth."""

from __future__ import annotations

import numpy as np

from spacecal.geometry.metrics import cube_grid, posture_error_rad, target_registration_errors
from spacecal.records import CalibrationResult
from spacecal.sim.world import World


def calibration_error(result: CalibrationResult, world: World, cube_side_mm: float = 200.0) -> dict:
    """Errors of a calibration against the truth.

    TRE: for points on a 5x5x5 grid filling a cube of ``cube_side_mm`` around the surgical
    site (given in base), the distance between where the estimated and the true
    ``tracker_from_base`` put them.

    Returns
    -------
    dict
        ``tre_rms_mm``, ``tre_max_mm``, ``rotation_error_deg`` (of tracker_from_base),
        ``tcp_from_marker_position_error_mm``, ``tcp_from_marker_rotation_error_deg``.
    """
    grid_in_base = cube_grid(world.site_in_base, cube_side_mm)
    tre = target_registration_errors(result.tracker_from_base, world.tracker_from_base, grid_in_base)
    return {
        "tre_rms_mm": float(np.sqrt(np.mean(tre**2))),
        "tre_max_mm": float(tre.max()),
        "rotation_error_deg": float(
            np.degrees(posture_error_rad(result.tracker_from_base, world.tracker_from_base))
        ),
        "tcp_from_marker_position_error_mm": float(
            np.linalg.norm(result.tcp_from_marker[:3, 3] - world.tcp_from_marker[:3, 3])
        ),
        "tcp_from_marker_rotation_error_deg": float(
            np.degrees(posture_error_rad(result.tcp_from_marker, world.tcp_from_marker))
        ),
    }
