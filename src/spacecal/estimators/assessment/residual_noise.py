"""The white noise's covariance per frame, from the residuals of a linear fit, whatever its shape.

A camera's pose noise is not the isotropic, independent sphere noise a count of residual
degrees of freedom assumes. Measured on KinHEC's static camera views (virtual spheres of a
target pose), nearly all of it lies in three of a frame's twelve sphere coordinates: the
target's position along and across the line of sight. The fitted pose and DH errors move the
spheres mostly the same way, so they absorb several times more of that noise per parameter
than the average coordinate holds, and ``RSS / (m - rank)`` then understates the noise (3.2
against 3.7 mm per sphere there), and the held-out misfit beyond it was called systematic.

Here one covariance ``Sigma`` (D x D, the same at every frame, D = 3 x spheres) is estimated
so that the residuals' expected second moments match what they show: for residuals
``r = P e`` of a least-squares fit (``P`` the projection off the design's columns) and
independent frames ``e_i ~ N(0, Sigma)``,

    E[sum_i r_i r_i^T] = sum_{i,j} P_ij Sigma P_ij^T,

linear in ``Sigma`` (the unbiased quadratic estimate of the variance components, MINQUE; Rao
1971; :mod:`spacecal.estimators.methods.noise_model` estimates a few such components iteratively for
the ML fit). With ``Sigma = sigma^2 I`` it reduces to ``RSS / (m - rank)``. A systematic error
the design cannot describe still counts as noise, as it does in that count.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from spacecal.core.errors import DegenerateDataError
from spacecal.geometry.arrays import FloatArray

#: Singular values below this share of the largest count as zero when residuals are split by
#: their shape (DH columns nearly redundant with the pose).
RANK_RCOND = 1e-8


def frame_noise_covariance(design: FloatArray, residual: FloatArray) -> dict[str, Any]:
    """The noise covariance of one frame's stacked coordinates, from a fit's residuals.

    Parameters
    ----------
    design : numpy.ndarray, shape (M, D, P)
        The fitted parameters' Jacobian at each of the M frames (e.g. the sphere coordinates'
        derivatives by the 12 pose parameters and the arm's DH errors, mm per unit).
    residual : numpy.ndarray, shape (M, D)
        Residuals, mm, at a solution that fitted some or all of the design's columns; the
        part still in the design's span is taken off.

    Returns
    -------
    dict
        ``covariance_mm2`` (D, D): the per-frame noise covariance (positive semi-definite);
        ``power_mm2``: its trace, the noise's power per frame; ``dof``: the residual sum of
        squares' effective degrees of freedom under that covariance (Satterthwaite,
        ``tr(P S)^2 / tr((P S)^2)``), which sets the power's relative standard error
        ``sqrt(2 / dof)``.

    Raises
    ------
    DegenerateDataError
        When the design leaves no residual degrees of freedom.
    """
    frames, width, _ = design.shape
    stacked = design.reshape(frames * width, -1)
    u, s, _ = np.linalg.svd(stacked, full_matrices=False)
    rank = int(np.sum(s > RANK_RCOND * s[0])) if s.size and s[0] > 0 else 0
    if rank >= stacked.shape[0]:
        raise DegenerateDataError("the fit leaves no residual degrees of freedom")
    basis = u[:, :rank]
    projection = np.eye(stacked.shape[0]) - basis @ basis.T
    blocks = projection.reshape(frames, width, frames, width).transpose(0, 2, 1, 3)
    # E[S]_xy = sum_ij sum_ab P_ij[x, a] Sigma_ab P_ij[y, b]
    flat = blocks.reshape(frames * frames, width * width)
    mapping = (flat.T @ flat).reshape(width, width, width, width).transpose(0, 2, 1, 3)
    # what the fit leaves: the residuals off every column (a fit of part of the columns, as
    # the pose alone, leaves some in the others' span)
    left = (projection @ residual.reshape(-1)).reshape(frames, width)
    observed = left.T @ left
    solution, *_ = np.linalg.lstsq(
        mapping.reshape(width * width, width * width), observed.reshape(-1), rcond=None
    )
    raw = solution.reshape(width, width)
    values, vectors = np.linalg.eigh(0.5 * (raw + raw.T))
    covariance = (vectors * np.clip(values, 0.0, None)) @ vectors.T
    # P (I_M (x) Sigma): its trace is E[RSS], twice the trace of its square Var[RSS]
    weighted = (projection.reshape(frames, width, frames, width) @ covariance).reshape(
        frames * width, frames * width
    )
    expected_rss = float(np.trace(weighted))
    spread = float(np.sum(weighted * weighted.T))
    dof = expected_rss**2 / spread if spread > 0 else 0.0
    return {"covariance_mm2": covariance, "power_mm2": float(np.trace(covariance)), "dof": dof}


def held_out_noise_power(misfit: dict[str, Any], covariance: FloatArray) -> float:
    """The mean held-out squared error per frame that noise of ``covariance`` alone would give.

    A held-out frame's error is its own noise plus the refit's: ``tr(Sigma) + tr(J_i A^-1 B
    A^-1 J_i^T)`` with ``A = sum J_j^T J_j`` and ``B = sum J_j^T Sigma J_j`` over the block's
    training frames (the refit weighs every coordinate alike); with ``Sigma = sigma^2 I`` the
    second term is ``sigma^2`` times the frame's leverage.

    Parameters
    ----------
    misfit : dict
        :func:`spacecal.estimators.assessment.held_out_misfit.held_out_misfit`'s result: its
        ``frame_sse_mm2``, ``block_indices``, ``jacobian`` (N, D, 12) and
        ``block_normal_inverses`` (one (12, 12) ``A^-1`` per block, None where not refitted).
    covariance : numpy.ndarray, shape (D, D)
        The noise covariance of one frame's stacked coordinates, mm^2.

    Returns
    -------
    float
        mm^2, averaged over the frames that were scored.
    """
    jac = misfit["jacobian"]
    scored = np.isfinite(misfit["frame_sse_mm2"])
    variance = np.full(len(jac), np.nan)
    # J_j^T Sigma J_j of every frame once; a block's training sum is the whole less its own
    per_frame = np.einsum("nda,de,neb->nab", jac, covariance, jac)
    whole = per_frame.sum(axis=0)
    for block, inverse in zip(misfit["block_indices"], misfit["block_normal_inverses"], strict=True):
        if inverse is None:
            continue
        spread = inverse @ (whole - per_frame[block].sum(axis=0)) @ inverse
        variance[block] = np.einsum("nda,ab,ndb->n", jac[block], spread, jac[block])
    return float(np.trace(covariance) + np.mean(variance[scored]))
