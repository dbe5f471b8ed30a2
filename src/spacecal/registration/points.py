"""Paired-point rigid registration with its error figures.

* Registration: Arun/Umeyama least squares (SVD), the rigid transform ``target_from_source``
  that maps fiducials given in a source frame onto their partners in a target frame (e.g.
  ``reference_from_phantom``: landmarks defined in the phantom, touched in the reference).
* FRE: fiducial registration error, the residual distances after registration; reported as
  RMS and as mean (the figure PLUS calls "Error").
* Predicted TRE at a target (Fitzpatrick, West, Maurer 1998, "Predicting error in rigid-body
  point-based registration", IEEE TMI 17(5)):
  TRE^2(r) ~ FLE^2 / N (1 + 1/3 sum_k d_k^2 / f_k^2), with d_k the target's distance from
  principal axis k of the fiducial configuration and f_k the RMS distance of the fiducials
  from it. FLE (fiducial localisation error, RMS) is estimated from FRE: FLE^2 ~ FRE^2 N / (N - 2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spacecal.core.errors import DegenerateDataError, InvalidInputError
from spacecal.geometry.arrays import ArrayLike, FloatArray
from spacecal.geometry.fitting import fit_rigid
from spacecal.geometry.transforms import apply_transform, check_points


@dataclass
class PointRegistration:
    """A paired-point registration.

    Attributes
    ----------
    target_from_source : numpy.ndarray, shape (4, 4)
        Maps points given in the source frame into the target frame, mm.
    residuals_mm : numpy.ndarray, shape (N,)
        Distances between the registered source points and their target partners.
    fle_rms_mm : float
        Fiducial localisation error estimated from the residuals.
    points_in_source : numpy.ndarray, shape (N, 3)
        The fiducials in the source frame (where predicted TRE is evaluated), mm.
    """

    target_from_source: np.ndarray
    residuals_mm: np.ndarray
    fle_rms_mm: float
    points_in_source: np.ndarray

    @property
    def fre_rms_mm(self) -> float:
        return float(np.sqrt(np.mean(self.residuals_mm**2)))

    @property
    def fre_mean_mm(self) -> float:
        """Mean residual: PLUS's "Error"."""
        return float(np.mean(self.residuals_mm))

    def predicted_tre_mm(self, targets_in_source: FloatArray, fle_rms_mm: float | None = None) -> FloatArray:
        """Fitzpatrick–West–Maurer predicted RMS TRE at targets (M, 3) given in the source frame."""
        return predicted_tre(
            self.points_in_source, targets_in_source, self.fle_rms_mm if fle_rms_mm is None else fle_rms_mm
        )


def register_points(*, points_in_source: ArrayLike, points_in_target: ArrayLike) -> PointRegistration:
    """Rigid ``target_from_source`` from paired points by least squares (Arun/Umeyama).

    The point sets are keyword-only and named as in :func:`spacecal.geometry.fitting.fit_rigid`,
    so a call reads which frame is which and cannot swap them silently.

    Parameters
    ----------
    points_in_source : array_like, shape (N, 3)
        Fiducials in the frame mapped from (e.g. landmarks defined in the phantom), mm.
    points_in_target : array_like, shape (N, 3)
        The same fiducials, in the same order, in the frame mapped into (e.g. as touched in
        the reference marker frame), mm.

    Raises
    ------
    InvalidInputError
        For point sets that are not (N, 3), hold non-finite values, or differ in length.
    DegenerateDataError
        For fewer than 3 pairs, or collinear fiducials.
    """
    source = check_points(points_in_source, "points_in_source")
    target = check_points(points_in_target, "points_in_target")
    if source.shape != target.shape:
        raise InvalidInputError(
            f"registration needs paired (N, 3) points, got source {source.shape} and target {target.shape}"
        )
    if len(source) < 3:
        raise DegenerateDataError(f"registration needs at least 3 point pairs, got {len(source)}")
    if np.linalg.svd(source - source.mean(axis=0), compute_uv=False)[1] < 1e-6:
        raise DegenerateDataError("the fiducials are collinear: a rigid registration is not determined")
    target_from_source, _ = fit_rigid(points_in_source=source, points_in_target=target)
    residuals = np.linalg.norm(apply_transform(target_from_source, source) - target, axis=1)
    n = len(source)
    fle = float(np.sqrt(np.sum(residuals**2) / max(n - 2, 1))) if n > 2 else 0.0
    return PointRegistration(target_from_source, residuals, fle, source)


def predicted_tre(fiducials: ArrayLike, targets: ArrayLike, fle_rms_mm: float) -> FloatArray:
    """Fitzpatrick–West–Maurer 1998 predicted RMS TRE (M,) at targets (M, 3), same frame as fiducials."""
    fiducials = np.asarray(fiducials, dtype=float)
    targets = np.atleast_2d(np.asarray(targets, dtype=float))
    centroid = fiducials.mean(axis=0)
    centred = fiducials - centroid
    _, _, axes = np.linalg.svd(centred, full_matrices=False)
    n = len(fiducials)
    ratio = np.zeros(len(targets))
    for axis in axes:
        # distance from the principal axis: the component perpendicular to it
        f_perp = centred - np.outer(centred @ axis, axis)
        f_sq = np.mean(np.sum(f_perp**2, axis=1))
        t = targets - centroid
        d_perp = t - np.outer(t @ axis, axis)
        ratio += np.sum(d_perp**2, axis=1) / f_sq
    return fle_rms_mm * np.sqrt((1.0 + ratio / 3.0) / n)
