"""The held-out misfit: each block of frames left out, ML refitted on the rest, the block predicted."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from spacecal.core.errors import DegenerateDataError
from spacecal.estimators.methods.held_out import held_out_blocks
from spacecal.estimators.methods.ml import (
    jacobian,
    levenberg_marquardt,
    predict_spheres,
)
from spacecal.estimators.methods.observations import Observations
from spacecal.geometry.arrays import FloatArray, as_float_array
from spacecal.geometry.rotations import mean_rotation, rotation_angle

#: The fewest frames a held-out refit is done on: two motions determine AX = YB, and the
#: refit needs a margin over that to be more than an interpolation.
MINIMUM_TRAINING_FRAMES = 6


#: Frames near the site stand for the targets: TCP within this distance of the site (mm) ...
SITE_RADIUS_MM = 100.0


#: ... and within this rotation of the mean orientation of the frames there (deg).
SITE_TILT_DEG = 30.0


#: A refit: (training observations, start tracker_from_base, start tcp_from_marker)
#: -> (tracker_from_base, tcp_from_marker).
Refit = Callable[[Observations, FloatArray, FloatArray], tuple[FloatArray, FloatArray]]


def ml_refit(
    obs: Observations, tracker_from_base: FloatArray, tcp_from_marker: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Levenberg–Marquardt on ``obs`` from a warm start (the full-data solution)."""
    fit = levenberg_marquardt(obs, tracker_from_base, tcp_from_marker, max_iterations=10, tolerance=1e-6)
    return as_float_array(fit.tracker_from_base), as_float_array(fit.tcp_from_marker)


def near_site(base_from_tcp_stack: FloatArray, radius_mm: float, tilt_deg: float) -> np.ndarray:
    """Frames (N,) whose TCP lies within ``radius_mm`` of the site and ``tilt_deg`` of its orientation.

    The site is the centroid of the TCP positions; its orientation the mean orientation of the
    frames within ``radius_mm`` of it. All frames when fewer than three qualify.
    """
    positions = base_from_tcp_stack[:, :3, 3]
    close = np.linalg.norm(positions - positions.mean(axis=0), axis=1) <= radius_mm
    if close.sum() < 3:
        return np.ones(len(positions), dtype=bool)
    reference = mean_rotation(base_from_tcp_stack[close, :3, :3])
    tilt = np.degrees(rotation_angle(base_from_tcp_stack[:, :3, :3] @ reference.T))
    selected = close & (tilt <= tilt_deg)
    return selected if selected.sum() >= 3 else np.ones(len(positions), dtype=bool)


def held_out_misfit(
    obs: Observations,
    segments: np.ndarray,
    tracker_from_base: FloatArray,
    tcp_from_marker: FloatArray,
    refit: Refit = ml_refit,
) -> dict[str, Any]:
    """Squared sphere errors of held-out frames predicted by refits that left their block out.

    Parameters
    ----------
    obs : Observations
        The used frames (``base_from_tcp_stack`` is what the robot model says).
    segments : numpy.ndarray of str, shape (N,)
    tracker_from_base, tcp_from_marker : numpy.ndarray, shape (4, 4)
        The full-data solution, the warm start of every refit.
    refit : callable
        How a block's refit is done (default :func:`ml_refit`).

    Returns
    -------
    dict
        ``frame_sse_mm2`` (N,): sum over the spheres of the squared held-out error (NaN for
        frames of blocks that could not be refitted); ``frame_prediction_leverage`` (N,):
        ``tr(J_i (J_train^T J_train)^-1 J_i^T)``, the refit's own prediction variance per unit
        per-axis noise variance; ``blocks``, ``blocks_refitted``, ``block_indices``;
        ``jacobian`` (N, 3K, 12) and ``block_normal_inverses`` (per block, ``(J_train^T
        J_train)^-1`` or None where it was not refitted), from which
        :func:`spacecal.estimators.assessment.residual_noise.held_out_noise_power` gives the prediction
        variance of noise of any shape.

    Raises
    ------
    DegenerateDataError
        When fewer than two blocks could be refitted.
    """
    n = len(obs.rows)
    frame_sse = np.full(n, np.nan)
    leverage = np.full(n, np.nan)
    blocks = held_out_blocks(segments)
    inverses: list[FloatArray | None] = [None] * len(blocks)
    refitted = 0
    # the refit's own noise makes held-out predictions worse than the noise alone: by
    # sigma^2 tr(J_i (J_train^T J_train)^-1 J_i^T) for frame i (its leverage times sigma^2)
    whole = jacobian(obs, tracker_from_base, tcp_from_marker).reshape(n, -1, 12)
    for number, block in enumerate(blocks):
        keep = np.ones(n, dtype=bool)
        keep[block] = False
        if keep.sum() < MINIMUM_TRAINING_FRAMES:
            continue
        training = obs.of_frames(keep)
        try:
            fitted = refit(training, tracker_from_base, tcp_from_marker)
        except (DegenerateDataError, np.linalg.LinAlgError):
            continue
        held_out = obs.of_frames(block)
        diff = predict_spheres(held_out, *fitted) - held_out.spheres_in_tracker
        frame_sse[block] = np.sum(diff**2, axis=(1, 2))
        train = whole[keep].reshape(-1, 12)
        inverse = np.linalg.inv(train.T @ train)
        inverses[number] = inverse
        leverage[block] = np.einsum("nia,ab,nib->n", whole[block], inverse, whole[block])
        refitted += 1
    if refitted < 2:
        raise DegenerateDataError("too few blocks of the recording could be refitted to cross-validate")
    return {
        "frame_sse_mm2": frame_sse,
        "frame_prediction_leverage": leverage,
        "blocks": len(blocks),
        "blocks_refitted": refitted,
        "block_indices": blocks,
        "jacobian": whole,
        "block_normal_inverses": inverses,
    }
