"""A tracker noise model learned from the residuals: variance components, re-weighted ML.

Optical trackers are anisotropic: the error along the line of sight is several times the
lateral one (Wiles et al., IEEE TMI 27(3), 2008). And many sources give only marker poses
(OpenIGTLink, PLUS), whose orientation may be far more precise than a small marker's sphere
noise implies. So instead of one isotropic sigma, every residual block m is weighted by

    Sigma_m = sum_c theta_c Q_cm,     W_m = Sigma_m^-1,

a few variance components theta_c with known cofactor matrices Q_cm:

* raw spheres (block = one sphere, 3 residuals): ``lateral`` Q = I - u u^T and ``depth``
  Q = u u^T, u the unit line of sight from the tracker origin to the observed sphere.
* marker poses (block = one frame, 6 residuals: the position of the spheres' centroid c,
  then the rotation vector log(R_pred R_obs^T), both in the tracker frame): ``lateral`` and
  ``depth`` as above on the position, ``rotation`` Q = I_3 on the rotation (an orientation
  noise of its own), and ``sphere_fit`` Q = R_obs M^-1 R_obs^T on the rotation, with
  M = sum_k [s_k - c]_x^T [s_k - c]_x: the orientation noise of a rigid fit of spheres with
  per-axis noise sqrt(theta) (at the centroid it is uncorrelated with the position). Under
  white isotropic sphere noise sigma the model holds the truth (lateral = depth = sigma^2/K,
  sphere_fit = sigma^2, rotation = 0), so nothing is lost where the isotropic model was right.

The components are estimated from the residuals by least-squares variance component
estimation (LS-VCE; Teunissen and Amiri-Simkooei, J. Geodesy 82, 2008; see
:func:`update_components`), whose fixed point is that of Förstner's iteration (Förstner
1979; Koch, *Parameter Estimation and Hypothesis Testing in Linear Models*, 1999, §3.6):

    theta_c = theta_c * (v^T W Q_c W v) / tr(W Q_c R),    R = I - J (J^T W J)^-1 J^T W,

v the residuals and J the Jacobian of the 12 calibration parameters: the REML estimate. For
components that split each block into disjoint parts (lateral/depth) this is Helmert's
theta_c = sum of squared residuals of c / sum of their redundancy numbers. It alternates
with Levenberg–Marquardt on sum_m v_m^T W_m v_m, warm-started from the isotropic fit, until
no component changes by more than 1e-3 of the variance it describes between refits.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from spacecal.core.errors import DegenerateDataError
from spacecal.estimators.methods.ml import jacobian, predict_spheres
from spacecal.estimators.methods.observations import Observations
from spacecal.geometry.arrays import FloatArray, as_float_array
from spacecal.geometry.rotations import skew
from spacecal.geometry.transforms import matrix_to_rotvec
from spacecal.models.kinematics import apply_pose_step, pose_point_jacobian

SPHERE_COMPONENTS = ("lateral", "depth")
POSE_COMPONENTS = ("lateral", "depth", "rotation", "sphere_fit")

#: Smallest variance of a position component, mm^2 (noise-free data stays well-posed).
MINIMUM_POSITION_VARIANCE_MM2 = 1e-8
#: Smallest variance of the rotation component, rad^2 (1e-4 mm at 100 mm).
MINIMUM_ROTATION_VARIANCE_RAD2 = 1e-12

#: Components that change less than this (relative) between two refits have converged.
COMPONENT_TOLERANCE = 1e-3
#: Refits of the calibration (each followed by re-estimating the components).
MAX_REFITS = 8
#: Component updates per refit (cheap: the residuals and Jacobian are fixed meanwhile).
MAX_COMPONENT_UPDATES = 50


@dataclass
class Residuals:
    """Residual blocks of one problem at given transforms.

    Attributes
    ----------
    values : numpy.ndarray, shape (M, b)
        Predicted minus observed, per block: mm for positions, rad for rotations.
    jacobian : numpy.ndarray, shape (M, b, 12)
        d values / d (12 perturbation parameters of :func:`apply_pose_step`).
    """

    values: FloatArray
    jacobian: FloatArray


@dataclass
class NoiseModel:
    """Estimated variance components and the fit they weight.

    Attributes
    ----------
    observations : str
        ``"spheres"`` or ``"poses"``.
    names : tuple of str
        Component names (:data:`SPHERE_COMPONENTS` or :data:`POSE_COMPONENTS`).
    variances : numpy.ndarray, shape (C,)
        theta_c: mm^2 for lateral, depth and sphere_fit; rad^2 for rotation.
    tracker_from_base, tcp_from_marker : numpy.ndarray, shape (4, 4)
        The ML fit under this noise model.
    information : numpy.ndarray, shape (12, 12)
        J^T W J at the fit: the inverse covariance of the 12 parameters.
    refits : int
    converged : bool
    """

    observations: str
    names: tuple[str, ...]
    variances: FloatArray
    tracker_from_base: FloatArray
    tcp_from_marker: FloatArray
    information: FloatArray
    refits: int
    converged: bool
    sphere_fit_rotation_shape: FloatArray | None = None

    def summary(self) -> dict[str, Any]:
        """``diagnostics["noise_model"]``: per-axis standard deviations, mm and deg."""
        theta = dict(zip(self.names, self.variances))
        out: dict[str, Any] = {
            "observations": self.observations,
            "method": "variance components from the residuals (LS-VCE), alternating with ML",
            "lateral_mm": float(np.sqrt(theta["lateral"])),
            "depth_mm": float(np.sqrt(theta["depth"])),
            "depth_to_lateral": float(np.sqrt(theta["depth"] / theta["lateral"])),
            "refits": self.refits,
            "converged": self.converged,
        }
        if self.observations == "spheres":
            out["note"] = "per-axis s.d. of each sphere centre, across and along the line of sight"
            return out
        shape = self.sphere_fit_rotation_shape
        mean_shape = 0.0 if shape is None else float(np.trace(shape)) / 3.0
        out.update(
            {
                "rotation_deg": float(
                    np.degrees(np.sqrt(theta["rotation"] + theta["sphere_fit"] * mean_shape))
                ),
                "rotation_isotropic_deg": float(np.degrees(np.sqrt(theta["rotation"]))),
                "sphere_fit_mm": float(np.sqrt(theta["sphere_fit"])),
                "note": "per-axis s.d. of the marker position (at the spheres' centroid) across and along "
                "the line of sight, and of its orientation (RMS over axes: an isotropic part plus "
                "the part a rigid fit of spheres with per-axis noise sphere_fit_mm gives)",
            }
        )
        return out


def _line_of_sight_projectors(points: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(I - u u^T, u u^T) for the unit lines of sight u to points (M, 3) in the tracker frame."""
    sight = points / np.linalg.norm(points, axis=-1, keepdims=True)
    along = sight[..., :, None] * sight[..., None, :]
    return np.eye(3) - along, along


def _inverse_left_jacobian(rotation_vectors: FloatArray) -> FloatArray:
    """J_l^-1(phi) = I - [phi]x / 2 + (1/a^2 - (1 + cos a) / (2 a sin a)) [phi]x^2, a = |phi|;
    shape (N, 3, 3) for rotation vectors (N, 3)."""
    angle = np.linalg.norm(rotation_vectors, axis=1)
    small = angle < 1e-4
    safe = np.where(small, 1.0, angle)
    coefficient = np.where(
        small, 1.0 / 12.0, 1.0 / safe**2 - (1.0 + np.cos(safe)) / (2.0 * safe * np.sin(safe))
    )
    cross = skew(rotation_vectors)
    return as_float_array(np.eye(3) - 0.5 * cross + coefficient[:, None, None] * (cross @ cross))


class NoiseProblem:
    """Residuals, Jacobian and cofactor matrices Q_cm of one recording's observations.

    Raw spheres (``obs.dof_per_frame > 6``, or no poses given) give one block per sphere,
    poses one block per frame (see the module docstring).
    """

    def __init__(self, obs: Observations, tracker_from_marker_stack: FloatArray | None):
        self.obs = obs
        self.names: tuple[str, ...]
        if obs.dof_per_frame > 6 or tracker_from_marker_stack is None:
            self.kind, self.names = "spheres", SPHERE_COMPONENTS
            lateral, depth = _line_of_sight_projectors(obs.spheres_in_tracker.reshape(-1, 3))
            self.cofactors = np.stack([lateral, depth])
            self.rotation_shape: FloatArray | None = None
            return
        self.kind, self.names = "poses", POSE_COMPONENTS
        self.observed = np.asarray(tracker_from_marker_stack, dtype=float)
        spheres = obs.spheres_in_marker
        self.centroid = spheres.mean(axis=0)
        centred = skew(spheres - self.centroid)
        moment = np.einsum("kji,kjl->il", centred, centred)
        if np.linalg.eigvalsh(moment).min() <= 1e-9 * np.linalg.eigvalsh(moment).max():
            raise DegenerateDataError("the marker's spheres are collinear: no orientation noise model")
        self.rotation_shape = as_float_array(np.linalg.inv(moment))
        rotations = self.observed[:, :3, :3]
        centroid_in_tracker = rotations @ self.centroid + self.observed[:, :3, 3]
        self.observed_centroid = centroid_in_tracker
        lateral, depth = _line_of_sight_projectors(centroid_in_tracker)
        n = len(rotations)
        cofactors = np.zeros((4, n, 6, 6))
        cofactors[0, :, :3, :3] = lateral
        cofactors[1, :, :3, :3] = depth
        cofactors[2, :, 3:, 3:] = np.eye(3)
        cofactors[3, :, 3:, 3:] = rotations @ self.rotation_shape @ np.swapaxes(rotations, 1, 2)
        self.cofactors = cofactors

    @property
    def cofactor_traces(self) -> FloatArray:
        """Mean trace of each component's cofactor over the blocks."""
        return as_float_array(np.trace(self.cofactors, axis1=2, axis2=3).mean(axis=1))

    def is_rotation(self) -> FloatArray:
        """Per component: True for rad^2 components."""
        return np.array([name == "rotation" for name in self.names])

    def residuals(self, tracker_from_base: FloatArray, tcp_from_marker: FloatArray) -> Residuals:
        obs = self.obs
        if self.kind == "spheres":
            diff = predict_spheres(obs, tracker_from_base, tcp_from_marker) - obs.spheres_in_tracker
            jac = jacobian(obs, tracker_from_base, tcp_from_marker)
            return Residuals(diff.reshape(-1, 3), jac.reshape(-1, 3, 12))
        chain = tracker_from_base @ obs.base_from_tcp_stack @ tcp_from_marker
        predicted = chain[:, :3, :3] @ self.centroid + chain[:, :3, 3]
        rotation = matrix_to_rotvec(chain[:, :3, :3] @ np.swapaxes(self.observed[:, :3, :3], 1, 2))
        jac = np.zeros((len(chain), 6, 12))
        jac[:, :3] = pose_point_jacobian(
            obs.base_from_tcp_stack, tracker_from_base, tcp_from_marker, self.centroid[None]
        )[:, 0]
        # exp(w_t) R_t R_A R_x exp(w_x) = exp(w_t + R_pred w_x) R_pred to first order, and
        # log(exp(d) E) = log(E) + J_l^-1(log E) d (the inverse left Jacobian of SO(3))
        inverse_left = _inverse_left_jacobian(rotation)
        jac[:, 3:, 3:6] = inverse_left
        jac[:, 3:, 9:12] = inverse_left @ chain[:, :3, :3]
        values = np.concatenate([predicted - self.observed_centroid, rotation], axis=1)
        return Residuals(as_float_array(values), as_float_array(jac))

    def change(self, old: FloatArray, new: FloatArray) -> float:
        """Largest relative change of a component, weighted by its share of the variance of
        the residuals it describes (a component shrinking towards nothing beside another one
        that explains that subspace does not hold up convergence)."""
        size = self.cofactor_traces * old
        rotation_part = np.array([name in ("rotation", "sphere_fit") for name in self.names])
        share = np.where(
            rotation_part, size / max(size[rotation_part].sum(), 1e-300), size / size[~rotation_part].sum()
        )
        return float(np.max(np.abs(new - old) / old * share))

    def weights(self, variances: FloatArray) -> FloatArray:
        """W_m = (sum_c theta_c Q_cm)^-1, shape (M, b, b)."""
        covariance = np.einsum("c,cmij->mij", variances, self.cofactors)
        return as_float_array(np.linalg.inv(covariance))

    def floors(self) -> FloatArray:
        return np.where(self.is_rotation(), MINIMUM_ROTATION_VARIANCE_RAD2, MINIMUM_POSITION_VARIANCE_MM2)

    def start(self, residuals: Residuals) -> FloatArray:
        """Starting components: the residuals' mean power in each component's subspace."""
        v = residuals.values
        power = np.einsum("mi,cmij,mj->c", v, self.cofactors, v)
        theta = power / np.maximum(np.trace(self.cofactors, axis1=2, axis2=3).sum(axis=1), 1e-12)
        if self.kind == "poses" and self.rotation_shape is not None:
            # split the rotation residual's power (rad^2 per axis) evenly between its two components
            power_per_axis = float(np.mean(v[:, 3:] ** 2))
            theta[2] = 0.5 * power_per_axis
            theta[3] = 0.5 * power_per_axis / (np.trace(self.rotation_shape) / 3.0)
        return as_float_array(np.maximum(theta, self.floors()))


def normal_equations(residuals: Residuals, weights: FloatArray) -> tuple[FloatArray, FloatArray, float]:
    """J^T W J, J^T W v and v^T W v."""
    weighted_jac = weights @ residuals.jacobian
    weighted_values = np.einsum("mij,mj->mi", weights, residuals.values)
    normal = residuals.jacobian.reshape(-1, 12).T @ weighted_jac.reshape(-1, 12)
    gradient = weighted_jac.reshape(-1, 12).T @ residuals.values.reshape(-1)
    return as_float_array(normal), as_float_array(gradient), float(np.sum(residuals.values * weighted_values))


def _solve_non_negative(system: FloatArray, right: FloatArray, floors: FloatArray) -> FloatArray:
    """Solve ``system theta = right`` with theta >= floors: components that would fall below
    their floor are held there and the others solved again (an active set)."""
    free = np.ones(len(right), dtype=bool)
    theta = np.array(floors, dtype=float)
    for _ in range(len(right)):
        rhs = right - system[:, ~free] @ floors[~free]
        solution = np.linalg.lstsq(system[np.ix_(free, free)], rhs[free], rcond=None)[0]
        low = solution < floors[free]
        theta[free] = np.maximum(solution, floors[free])
        if not low.any():
            break
        free[np.flatnonzero(free)[low]] = False
        theta[~free] = floors[~free]
        if not free.any():
            break
    return as_float_array(theta)


def update_components(problem: NoiseProblem, residuals: Residuals, variances: FloatArray) -> FloatArray:
    """Re-estimate the components at fixed residuals and Jacobian, to their fixed point.

    Each step solves the least-squares VCE normal equations (Teunissen and Amiri-Simkooei,
    J. Geodesy 82, 2008) with the weights of the previous step: the expectation of
    q_c = v^T W Q_c W v is tr(W Q_c W Q_vv), Q_vv = Sigma - J N^-1 J^T, so

        sum_l tr(W Q_c W Q_l) theta_l = q_c + tr(N^-1 J^T W Q_c W J).

    Its fixed point is that of Förstner's iteration (the REML estimate); it converges in a few
    steps even where two components overlap (the two orientation components of poses).
    """
    theta = np.array(variances, dtype=float)
    floors = problem.floors()
    for _ in range(MAX_COMPONENT_UPDATES):
        weights = problem.weights(theta)
        normal, _, _ = normal_equations(residuals, weights)
        normal_inverse = np.linalg.inv(normal)
        weighted_values = np.einsum("mij,mj->mi", weights, residuals.values)
        weighted_jac = weights @ residuals.jacobian
        quadratic = np.einsum("mi,cmij,mj->c", weighted_values, problem.cofactors, weighted_values)
        # tr(N^-1 J^T W Q_c W J), summed element-wise (BLAS products, no 4-index einsum)
        propagated = (weighted_jac.reshape(-1, 12) @ normal_inverse).reshape(weighted_jac.shape)
        explained = np.einsum("mia,cmia->c", propagated, problem.cofactors @ weighted_jac)
        weighted_cofactors = weights @ problem.cofactors
        system = np.einsum("kmij,lmji->kl", weighted_cofactors, weighted_cofactors)
        new = _solve_non_negative(system, quadratic + explained, floors)
        change = problem.change(theta, new)
        theta = new
        if change < COMPONENT_TOLERANCE * 0.1:
            break
    return as_float_array(theta)


def _weighted_levenberg_marquardt(
    problem: NoiseProblem,
    weights: FloatArray,
    tracker_from_base: FloatArray,
    tcp_from_marker: FloatArray,
    max_iterations: int = 30,
    tolerance: float = 1e-12,
) -> tuple[FloatArray, FloatArray, Residuals]:
    """Minimise sum_m v_m^T W_m v_m over the 12 parameters (weights fixed)."""
    damping = 1e-3
    residuals = problem.residuals(tracker_from_base, tcp_from_marker)
    normal, gradient, cost = normal_equations(residuals, weights)
    for _ in range(max_iterations):
        while True:
            step = np.linalg.solve(normal + damping * np.diag(np.diag(normal)), -gradient)
            trial = apply_pose_step(tracker_from_base, tcp_from_marker, step)
            trial_residuals = problem.residuals(*trial)
            trial_normal, trial_gradient, trial_cost = normal_equations(trial_residuals, weights)
            if trial_cost <= cost:
                break
            damping *= 10.0
            if damping > 1e12:
                return tracker_from_base, tcp_from_marker, residuals
        improvement = cost - trial_cost
        tracker_from_base, tcp_from_marker = trial
        residuals, normal, gradient, cost = trial_residuals, trial_normal, trial_gradient, trial_cost
        damping = max(damping / 10.0, 1e-12)
        if np.max(np.abs(step)) < tolerance or improvement <= tolerance * max(cost, 1.0):
            break
    return tracker_from_base, tcp_from_marker, residuals


def fit_with_noise_model(
    obs: Observations,
    tracker_from_marker_stack: FloatArray | None,
    tracker_from_base: FloatArray,
    tcp_from_marker: FloatArray,
) -> NoiseModel:
    """ML under the variance-component noise model, components estimated from the residuals.

    Parameters
    ----------
    obs : Observations
        Raw spheres (``dof_per_frame > 6``) use the sphere model; otherwise the marker poses
        ``tracker_from_marker_stack`` (N, 4, 4) of ``obs.rows`` use the pose model.
    tracker_from_base, tcp_from_marker : numpy.ndarray, shape (4, 4)
        Start (the isotropic ML fit).
    """
    problem = NoiseProblem(obs, tracker_from_marker_stack)
    residuals = problem.residuals(tracker_from_base, tcp_from_marker)
    theta = update_components(problem, residuals, problem.start(residuals))
    converged = False
    refits = 0
    while refits < MAX_REFITS:
        refits += 1
        tracker_from_base, tcp_from_marker, residuals = _weighted_levenberg_marquardt(
            problem, problem.weights(theta), tracker_from_base, tcp_from_marker
        )
        new = update_components(problem, residuals, theta)
        change = problem.change(theta, new)
        theta = new
        if change < COMPONENT_TOLERANCE:
            converged = True
            break
    # the information (and so the covariance) at the final components and fit
    normal, _, _ = normal_equations(residuals, problem.weights(theta))
    return NoiseModel(
        problem.kind,
        problem.names,
        theta,
        tracker_from_base,
        tcp_from_marker,
        normal,
        refits,
        converged,
        problem.rotation_shape,
    )
