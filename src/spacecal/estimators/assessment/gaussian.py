"""The mean length of a Gaussian error and the chance it stays within a radius."""

from __future__ import annotations

import functools

import numpy as np
from scipy.integrate import quad
from scipy.special import ndtri
from scipy.stats import qmc

from spacecal.geometry.arrays import ArrayLike, FloatArray, as_float_array

#: Mean over RMS of the length of an isotropic 3-D Gaussian vector, sqrt(8 / (3 pi)).
MEAN_OVER_RMS_3D = float(np.sqrt(8.0 / (3.0 * np.pi)))


def mean_gaussian_length(covariance: ArrayLike) -> float:
    """Mean length E|x| of a zero-mean Gaussian vector x ~ N(0, covariance), same unit as x.

    Parameters
    ----------
    covariance : array_like, shape (3, 3)
        Covariance of x (e.g. mm^2 for a tip position error).

    Returns
    -------
    float
        E|x|: ``sqrt(8 / (3 pi))`` times the RMS for an isotropic covariance, ``sqrt(2 / pi)``
        times it for an error along one direction. With eigenvalues l_i and
        ``sqrt(q) = (4 pi)^(-1/2) int_0^inf (1 - exp(-t q)) t^(-3/2) dt``,
        ``E|x| = (4 pi)^(-1/2) int_0^inf (1 - prod_i (1 + 2 t l_i)^(-1/2)) t^(-3/2) dt``,
        integrated numerically (substituting t = u^2).
    """
    eigenvalues = np.clip(np.linalg.eigvalsh(np.asarray(covariance, dtype=float)), 0.0, None)
    scale = float(eigenvalues.sum())
    if scale <= 0.0:
        return 0.0
    relative = eigenvalues / scale

    def integrand(u: float) -> float:
        # t = u^2: dt t^(-3/2) = 2 du / u^2
        return float(2.0 * (1.0 - np.prod(1.0 + 2.0 * u * u * relative) ** -0.5) / (u * u))

    value, _ = quad(integrand, 0.0, np.inf, limit=200)
    return float(np.sqrt(scale) * value / np.sqrt(4.0 * np.pi))


#: Points (log2 of their count) of the scrambled Sobol sequence :func:`probability_within`
#: averages over: 65536 standard normal vectors, whose share within a radius is known to about
#: 1e-4 (quasi-Monte Carlo), the same on every call (a fixed scramble).
GAUSSIAN_POINTS_LOG2 = 16


@functools.cache
def _standard_normal_points() -> FloatArray:
    """Standard normal 3-vectors (2^16, 3) from a scrambled Sobol sequence (fixed seed)."""
    uniform = qmc.Sobol(d=3, scramble=True, seed=20_260_101).random_base2(GAUSSIAN_POINTS_LOG2)
    return as_float_array(ndtri(np.clip(uniform, 1e-12, 1.0 - 1e-12)))


def probability_within(covariance: ArrayLike, radius: float) -> float:
    """Chance that a zero-mean Gaussian vector x ~ N(0, covariance) is no longer than ``radius``.

    The chance an error stated by its covariance stays within an application's limit (or, as
    the benchmarks use it, how often an honest statement should still see a small error). A
    stated mean length alone does not set it: an error along one direction (a camera's depth)
    is small far more often than an isotropic one of the same mean length.

    Parameters
    ----------
    covariance : array_like, shape (3, 3)
        Covariance of x (e.g. mm^2; ``position_covariance_mm2`` of :func:`expected_error`).
    radius : float
        Same unit as x.

    Returns
    -------
    float
        ``P(|x| <= radius)``: the share of :data:`GAUSSIAN_POINTS_LOG2` quasi-random standard
        normal vectors z with ``sum_i l_i z_i^2 <= radius^2`` (l_i the eigenvalues), to about
        1e-4. (Inverting the characteristic function, Imhof 1961, needs an oscillatory
        integral whose quadrature fails at either end of the radius's range.)
    """
    eigenvalues = np.clip(np.linalg.eigvalsh(np.asarray(covariance, dtype=float)), 0.0, None)
    if radius <= 0.0:
        return 0.0
    squared_lengths = (_standard_normal_points() ** 2) @ eigenvalues
    return float(np.mean(squared_lengths <= radius * radius))
