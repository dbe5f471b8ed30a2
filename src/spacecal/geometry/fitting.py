"""Least-squares fits of spheres and lines to 3-D points (paper §3.1 and §3.2)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from spacecal.core.errors import DegenerateDataError
from spacecal.geometry.arrays import ArrayLike, FloatArray, as_float_array
from spacecal.geometry.transforms import transform_points_by_stack


@dataclass(frozen=True)
class SphereFit:
    """A fitted sphere.

    Attributes
    ----------
    centre : numpy.ndarray, shape (3,)
        Centre, in the frame of the input points, mm.
    radius : float
        Radius, mm.
    residuals : numpy.ndarray, shape (N,)
        Signed geometric residuals ``|p_i - c| - R``, mm.
    rms : float
        RMS of the residuals, mm.
    """

    centre: np.ndarray
    radius: float
    residuals: np.ndarray
    rms: float


@dataclass(frozen=True)
class LineFit:
    """A fitted 3-D line.

    Attributes
    ----------
    point : numpy.ndarray, shape (3,)
        A point on the line (the centroid of the data), mm.
    direction : numpy.ndarray, shape (3,)
        Unit direction; its sign is arbitrary unless a caller signs it.
    residuals : numpy.ndarray, shape (N,)
        Perpendicular distances of the points from the line, mm.
    rms : float
        RMS of the perpendicular distances ("straightness"), mm.
    length : float
        Extent of the points along the line, mm.
    """

    point: np.ndarray
    direction: np.ndarray
    residuals: np.ndarray
    rms: float
    length: float


def _finite_points(points: ArrayLike, what: str, minimum: int) -> FloatArray:
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise DegenerateDataError(f"{what}: expected points of shape (N, 3), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise DegenerateDataError(f"{what}: points contain NaN or infinite values")
    if len(p) < minimum:
        raise DegenerateDataError(f"{what}: needs at least {minimum} points, got {len(p)}")
    return p


def fit_sphere_algebraic(points: ArrayLike) -> tuple[FloatArray, float]:
    """Algebraic (linear) sphere fit, the start for :func:`fit_sphere`.

    ``|p|^2 = 2 p.c + (R^2 - |c|^2)`` is linear in c and ``k = R^2 - |c|^2``; solved in the
    centroid frame for conditioning.

    Parameters
    ----------
    points : array_like, shape (N, 3), N >= 4, mm

    Returns
    -------
    centre : numpy.ndarray, shape (3,)
    radius : float
    """
    p = _finite_points(points, "sphere fit", 4)
    origin = p.mean(axis=0)
    q = p - origin
    design = np.column_stack([2.0 * q, np.ones(len(q))])
    rhs = np.sum(q * q, axis=1)
    solution, _, rank, singular = np.linalg.lstsq(design, rhs, rcond=None)
    if rank < 4 or singular[-1] < 1e-9 * singular[0]:
        raise DegenerateDataError(
            "sphere fit: the points do not span a sphere (they lie on a plane or a line); "
            "rotate about more than one axis"
        )
    centre_local = solution[:3]
    radius_sq = solution[3] + centre_local @ centre_local
    if radius_sq <= 0:
        raise DegenerateDataError("sphere fit: no real sphere fits these points")
    return centre_local + origin, float(np.sqrt(radius_sq))


def fit_sphere(points: ArrayLike) -> SphereFit:
    """Geometric least-squares sphere fit (paper §3.2, eqs. 7–9).

    Minimises ``sum_i (|p_i - c| - R)^2`` by Levenberg–Marquardt with the analytic Jacobian,
    started from :func:`fit_sphere_algebraic`. The paper solves the same problem with
    MATLAB's nonlinear regression.

    Parameters
    ----------
    points : array_like, shape (N, 3), N >= 4
        Points on the sphere, mm; in the paper the marker origin in the tracker frame while
        the TCP rotates about its own origin.

    Returns
    -------
    SphereFit
    """
    p = _finite_points(points, "sphere fit", 4)
    centre0, radius0 = fit_sphere_algebraic(p)
    origin = p.mean(axis=0)
    q = p - origin

    def residuals(x: FloatArray) -> FloatArray:
        return as_float_array(np.linalg.norm(q - x[:3], axis=1) - x[3])

    def jacobian(x: FloatArray) -> FloatArray:
        diff = q - x[:3]
        dist = np.linalg.norm(diff, axis=1)
        dist = np.where(dist == 0, 1.0, dist)
        return np.column_stack([-diff / dist[:, None], -np.ones(len(q))])

    x0 = np.concatenate([centre0 - origin, [radius0]])
    solution = least_squares(residuals, x0, jac=jacobian, method="lm", xtol=1e-15, ftol=1e-15)
    centre = solution.x[:3] + origin
    radius = float(abs(solution.x[3]))
    res = np.linalg.norm(p - centre, axis=1) - radius
    return SphereFit(centre=centre, radius=radius, residuals=res, rms=float(np.sqrt(np.mean(res**2))))


def fit_line(points: ArrayLike) -> LineFit:
    """Total least-squares 3-D line fit (paper §3.1, eqs. 2–6).

    The paper writes the line as two planes x = k1 z + b1, y = k2 z + b2; the principal
    axis of the centred points minimises the same perpendicular distances without singling
    out the z axis (which fails for lines perpendicular to z).

    Parameters
    ----------
    points : array_like, shape (N, 3), N >= 2, mm

    Returns
    -------
    LineFit
        ``direction`` points from the first towards the last point.
    """
    p = _finite_points(points, "line fit", 2)
    centroid = p.mean(axis=0)
    q = p - centroid
    _, singular, vt = np.linalg.svd(q, full_matrices=False)
    if singular[0] <= 0:
        raise DegenerateDataError("line fit: all points coincide")
    direction = vt[0]
    if (p[-1] - p[0]) @ direction < 0:
        direction = -direction
    along = q @ direction
    perpendicular = q - np.outer(along, direction)
    distances = np.linalg.norm(perpendicular, axis=1)
    return LineFit(
        point=centroid,
        direction=direction,
        residuals=distances,
        rms=float(np.sqrt(np.mean(distances**2))),
        length=float(along.max() - along.min()),
    )


def fit_rigid(
    *, points_in_source: ArrayLike, points_in_target: ArrayLike, weights: ArrayLike | None = None
) -> tuple[FloatArray, Any]:
    """Least-squares rigid transform ``target_from_source`` between paired point sets (Kabsch/Arun).

    Used to compute a marker's pose from its measured sphere centres, as a tracker does.
    The point sets are keyword-only and named as in
    :func:`spacecal.registration.points.register_points`, so they cannot be swapped silently.

    Parameters
    ----------
    points_in_source : array_like, shape (N, 3)
        Model points (e.g. sphere centres in the marker frame), mm.
    points_in_target : array_like, shape (N, 3) or (M, N, 3)
        Measured points (e.g. in the tracker frame), mm; a stack gives M fits at once.
    weights : array_like, shape (N,), optional

    Returns
    -------
    target_from_source : numpy.ndarray, shape (4, 4) or (M, 4, 4)
        E.g. ``tracker_from_marker``.
    rms : float or numpy.ndarray, shape (M,)
        RMS distance between transformed model points and measured points, mm.
    """
    model = np.asarray(points_in_source, dtype=float)
    measured = np.asarray(points_in_target, dtype=float)
    single = measured.ndim == 2
    if single:
        measured = measured[None]
    w = np.ones(len(model)) if weights is None else np.asarray(weights, dtype=float)
    w = w / w.sum()
    model_centroid = w @ model
    measured_centroid = np.einsum("n,mnk->mk", w, measured)
    model_c = model - model_centroid
    measured_c = measured - measured_centroid[:, None, :]
    covariance = np.einsum("n,mni,nj->mij", w, measured_c, model_c)
    u, _, vt = np.linalg.svd(covariance)
    d = np.sign(np.linalg.det(u @ vt))
    u[:, :, 2] *= d[:, None]
    rotation = u @ vt
    translation = measured_centroid - np.einsum("mij,j->mi", rotation, model_centroid)
    transform = np.zeros((len(measured), 4, 4))
    transform[:, :3, :3] = rotation
    transform[:, :3, 3] = translation
    transform[:, 3, 3] = 1.0
    fitted = transform_points_by_stack(transform, model)
    rms = np.sqrt(np.mean(np.sum((fitted - measured) ** 2, axis=2), axis=1))
    if single:
        return transform[0], float(rms[0])
    return transform, rms
