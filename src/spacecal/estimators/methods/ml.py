"""Maximum-likelihood calibration from all samples, with covariance and predicted TRE.

Model (paper eq. 1, for every visible frame i and sphere k)::

    sphere_ik_in_tracker = tracker_from_base @ base_from_tcp_i @ tcp_from_marker @ sphere_k_in_marker + noise

with isotropic Gaussian noise of per-axis s.d. sigma. The 12 unknowns are perturbations
around the current estimate, re-linearised every iteration:

    tracker_from_base = [exp(w_t) R_t | t_t + v_t]     (w_t, v_t in the tracker frame)
    tcp_from_marker   = [R_x exp(w_x) | t_x + v_x]     (w_x in the marker frame)

so the Jacobian is analytic: d q / d v_t = I, d q / d w_t = -[R_t p_base]x,
d q / d v_x = R_t R_A, d q / d w_x = -R_t R_A R_x [s_k]x. The convention, the step and the
Jacobian live in :mod:`spacecal.models.kinematics` (``apply_pose_step``,
``pose_point_jacobian``), shared with kinematic identification and motion planning.

Levenberg–Marquardt minimises the (optionally robustly weighted) sum of squared whitened
residuals. The covariance of the 12 parameters is s^2 (J^T J)^-1, with s^2 the a-posteriori
variance factor, and the target registration error is propagated to points given in base.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spacecal.core.errors import DegenerateDataError
from spacecal.estimators.methods.observations import Observations
from spacecal.geometry.arrays import ArrayLike, FloatArray, as_float_array
from spacecal.geometry.rotations import skew
from spacecal.models.kinematics import (
    POSE_PARAMETER_NAMES,
    apply_pose_step,
    chain_points_in_tracker,
    pose_point_jacobian,
)

#: The 12 perturbation parameters of the covariance, in order (the convention is
#: :func:`spacecal.models.kinematics.apply_pose_step`).
PARAMETER_NAMES = POSE_PARAMETER_NAMES


def predict_spheres(
    obs: Observations, tracker_from_base: FloatArray, tcp_from_marker: FloatArray
) -> FloatArray:
    """Predicted sphere centres (N, K, 3) in the tracker frame."""
    return chain_points_in_tracker(
        obs.base_from_tcp_stack, tracker_from_base, tcp_from_marker, obs.spheres_in_marker
    )


def jacobian(obs: Observations, tracker_from_base: FloatArray, tcp_from_marker: FloatArray) -> FloatArray:
    """d(predicted spheres)/d(12 parameters), shape (N, K, 3, 12), unwhitened (mm per unit).

    The analytic :func:`spacecal.models.kinematics.pose_point_jacobian` at the observed poses.
    """
    return pose_point_jacobian(
        obs.base_from_tcp_stack, tracker_from_base, tcp_from_marker, obs.spheres_in_marker
    )


def frame_errors(obs: Observations, tracker_from_base: FloatArray, tcp_from_marker: FloatArray) -> FloatArray:
    """Per-frame RMS sphere residual (N,), mm."""
    diff = predict_spheres(obs, tracker_from_base, tcp_from_marker) - obs.spheres_in_tracker
    return as_float_array(np.sqrt(np.mean(np.sum(diff**2, axis=2), axis=1)))


def cauchy_weights(normalised_error: ArrayLike, scale: float = 2.5) -> FloatArray:
    """IRLS weights of the Cauchy loss for per-frame errors in units of their expected size."""
    return 1.0 / (1.0 + (np.asarray(normalised_error) / scale) ** 2)


@dataclass
class Fit:
    """Outcome of :func:`levenberg_marquardt`."""

    tracker_from_base: np.ndarray
    tcp_from_marker: np.ndarray
    iterations: int
    converged: bool


def levenberg_marquardt(
    obs: Observations,
    tracker_from_base: ArrayLike,
    tcp_from_marker: ArrayLike,
    frame_weights: ArrayLike | None = None,
    max_iterations: int = 50,
    tolerance: float = 1e-12,
) -> Fit:
    """Minimise ``sum_i w_i sum_k |predicted_ik - observed_ik|^2 / sigma^2``.

    Parameters
    ----------
    obs : Observations
    tracker_from_base, tcp_from_marker : numpy.ndarray, shape (4, 4)
        Starting point (e.g. a closed-form solution).
    frame_weights : array_like, shape (N,), optional
        Fixed per-frame weights (robust IRLS passes them in).
    """
    weights = np.ones(len(obs.rows)) if frame_weights is None else np.asarray(frame_weights, float)
    damping = 1e-3
    tracker_from_base = np.array(tracker_from_base, float)
    tcp_from_marker = np.array(tcp_from_marker, float)

    def cost_of(
        trial_tracker_from_base: FloatArray, trial_tcp_from_marker: FloatArray
    ) -> tuple[float, FloatArray]:
        diff = predict_spheres(obs, trial_tracker_from_base, trial_tcp_from_marker) - obs.spheres_in_tracker
        return float(np.sum(weights[:, None, None] * diff**2)) / obs.sigma_mm**2, diff

    cost, diff = cost_of(tracker_from_base, tcp_from_marker)
    for iteration in range(1, max_iterations + 1):
        # flattened products run on BLAS (einsum over four indices does not)
        jac = jacobian(obs, tracker_from_base, tcp_from_marker).reshape(-1, 12)
        weighted = jac * np.repeat(weights, jac.shape[0] // len(weights))[:, None]
        normal = weighted.T @ jac / obs.sigma_mm**2
        gradient = weighted.T @ diff.reshape(-1) / obs.sigma_mm**2
        while True:
            step = np.linalg.solve(normal + damping * np.diag(np.diag(normal)), -gradient)
            trial_tracker_from_base, trial_tcp_from_marker = apply_pose_step(
                tracker_from_base, tcp_from_marker, step
            )
            cost_try, diff_try = cost_of(trial_tracker_from_base, trial_tcp_from_marker)
            if cost_try <= cost:
                break
            damping *= 10.0
            if damping > 1e12:
                return Fit(tracker_from_base, tcp_from_marker, iteration, True)
        tracker_from_base, tcp_from_marker, diff = trial_tracker_from_base, trial_tcp_from_marker, diff_try
        improvement = cost - cost_try
        cost = cost_try
        damping = max(damping / 10.0, 1e-12)
        if np.max(np.abs(step)) < tolerance or improvement <= tolerance * max(cost, 1.0):
            return Fit(tracker_from_base, tcp_from_marker, iteration, True)
    return Fit(tracker_from_base, tcp_from_marker, max_iterations, False)


def information_matrix(
    obs: Observations,
    tracker_from_base: FloatArray,
    tcp_from_marker: FloatArray,
    sigma_mm: FloatArray | None = None,
    frame_weights: ArrayLike | None = None,
) -> FloatArray:
    """Fisher information (12, 12) of the two transforms under the sphere noise model.

    With raw spheres each component is an independent observation. With poses fitted from
    K spheres the K model points placed by the pose carry exactly the pose's information
    (J^T J of the rigid fit), so the same formula holds.
    """
    sigma = obs.sigma_mm if sigma_mm is None else sigma_mm
    jac = jacobian(obs, tracker_from_base, tcp_from_marker).reshape(-1, 12)
    w = np.ones(len(obs.rows)) if frame_weights is None else np.asarray(frame_weights, float)
    weighted = jac * np.repeat(w, jac.shape[0] // len(w))[:, None]
    return as_float_array(weighted.T @ jac / sigma**2)


def covariance_from_information(information: FloatArray) -> FloatArray:
    """Invert an information matrix, refusing an unidentifiable problem."""
    eigenvalues = np.linalg.eigvalsh(information)
    if eigenvalues.min() <= eigenvalues.max() * 1e-14:
        raise DegenerateDataError(
            "the recording does not determine all 12 calibration parameters (rotate about more axes)"
        )
    return as_float_array(np.linalg.inv(information))


def point_covariances(
    tracker_from_base: FloatArray, covariance_tracker_from_base: FloatArray, points_in_base: ArrayLike
) -> FloatArray:
    """Covariances (M, 3, 3), mm^2, of base points mapped into the tracker frame.

    q = R_t p + t_t; with the left perturbation, dq = v - [R_t p]x w.
    """
    rotated = np.asarray(points_in_base, float) @ tracker_from_base[:3, :3].T
    g = np.concatenate([np.broadcast_to(np.eye(3), rotated.shape[:-1] + (3, 3)), -skew(rotated)], axis=-1)
    return as_float_array(g @ covariance_tracker_from_base @ np.swapaxes(g, -1, -2))


def predicted_tre_mm(
    tracker_from_base: FloatArray, covariance: ArrayLike, points_in_base: FloatArray
) -> FloatArray:
    """Predicted RMS target registration error (M,), mm: sqrt(trace) of each point covariance."""
    cov = point_covariances(tracker_from_base, np.asarray(covariance)[:6, :6], points_in_base)
    return as_float_array(np.sqrt(np.trace(cov, axis1=-2, axis2=-1)))
