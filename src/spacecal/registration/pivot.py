"""Pivot calibration of a tracked needle or pointer tip, on the same fitting core.

The pointer pivots about its tip in a fixed divot, so for every frame i

    tracker_from_marker_i @ tip_in_marker = pivot_in_tracker.

* ``aos``, algebraic one-step (Yaniv 2015, "Which pivot calibration?", SPIE 9415):
  [R_i  -I] [tip; pivot] = -t_i, solved by linear least squares.
* ``sphere``: the marker origin moves on a sphere about the pivot; the geometric sphere
  fit (:func:`spacecal.geometry.fitting.fit_sphere`) gives the pivot, and the tip in the
  marker frame is the mean of R_i^T (pivot - t_i).

The residual reported is the ordinary 3-D RMS of ``|R_i tip + t_i - pivot|``. The tip's error
covariance is that of the linear least-squares model at the solution, ``s^2 (A^T A)^-1`` (its
tip block) with ``s^2`` the residuals' sum of squares over ``3N - 6`` degrees of freedom: what
the tracker's scatter leaves in the tip, not a divot that slips or a tracker's bias over the
pivot's cone.
scikit-surgerycalibration reports sqrt(mean of the 3N squared components), the per-axis
RMS, which is the 3-D RMS divided by sqrt(3); we give both.
"""

from __future__ import annotations

import numpy as np

from spacecal.core.errors import DegenerateDataError, InvalidInputError, UnknownMethodError
from spacecal.core.units import METRES_BELOW_MM
from spacecal.geometry.arrays import ArrayLike, FloatArray, as_float_array
from spacecal.geometry.fitting import fit_sphere
from spacecal.geometry.transforms import MEASURED_TRANSFORM_ATOL, check_transform, transform_points_by_stack
from spacecal.records import PivotResult


def _check_poses(tracker_from_marker_stack: ArrayLike) -> FloatArray:
    """The tracked poses (rows of NaN, frames without the marker, dropped), checked rigid."""
    poses = check_transform(
        tracker_from_marker_stack,
        "tracker_from_marker_stack",
        stack=True,
        allow_missing=True,
        atol=MEASURED_TRANSFORM_ATOL,
    )
    poses = poses[~np.isnan(poses[:, 0, 0])]
    if len(poses) < 4:
        raise DegenerateDataError(f"pivot calibration needs at least 4 tracked poses, got {len(poses)}")
    distance_mm = float(np.median(np.linalg.norm(poses[:, :3, 3], axis=1)))
    if distance_mm < METRES_BELOW_MM:
        # no tracker sees a marker within 20 mm of its origin: these are metres (the fit
        # would still succeed, with a tip and residuals a thousand times too small)
        raise InvalidInputError(
            f"the marker is {distance_mm:.3g} mm from the tracker (median): the poses look like metres; "
            "pivot calibration reads millimetres"
        )
    return poses


def _residuals(poses: FloatArray, tip: FloatArray, pivot: FloatArray) -> FloatArray:
    return as_float_array(np.linalg.norm(transform_points_by_stack(poses, tip) - pivot, axis=1))


def _design(poses: FloatArray) -> FloatArray:
    """The one-step model's matrix ``[R_i  -I]``, (3N, 6)."""
    n = len(poses)
    return as_float_array(
        np.concatenate([poses[:, :3, :3], -np.broadcast_to(np.eye(3), (n, 3, 3))], axis=2).reshape(3 * n, 6)
    )


def tip_covariance(poses: FloatArray, tip: FloatArray, pivot: FloatArray) -> FloatArray:
    """The tip's error covariance (3, 3) in the marker frame, mm^2 (see the module)."""
    design = _design(poses)
    misfit = transform_points_by_stack(poses, tip) - pivot
    dof = max(design.shape[0] - 6, 1)
    scale = float(np.sum(misfit**2)) / dof
    return as_float_array(scale * np.linalg.inv(design.T @ design)[:3, :3])


def pivot_algebraic_one_step(tracker_from_marker_stack: FloatArray) -> PivotResult:
    """Algebraic one-step pivot calibration (Yaniv 2015)."""
    poses = _check_poses(tracker_from_marker_stack)
    design = _design(poses)
    solution, _, rank, _ = np.linalg.lstsq(design, -poses[:, :3, 3].reshape(-1), rcond=None)
    if rank < 6:
        raise DegenerateDataError("pivot calibration: the pointer did not rotate about two or more axes")
    tip, pivot = as_float_array(solution[:3]), as_float_array(solution[3:])
    return PivotResult(
        "aos", tip, pivot, _residuals(poses, tip, pivot), tip_covariance_mm2=tip_covariance(poses, tip, pivot)
    )


def pivot_sphere_fit(tracker_from_marker_stack: FloatArray) -> PivotResult:
    """Pivot from the geometric sphere fit of the marker origins; tip by averaging."""
    poses = _check_poses(tracker_from_marker_stack)
    pivot = fit_sphere(poses[:, :3, 3]).centre
    tip = np.mean(np.einsum("nji,nj->ni", poses[:, :3, :3], pivot - poses[:, :3, 3]), axis=0)
    if np.linalg.matrix_rank(_design(poses)) < 6:
        raise DegenerateDataError("pivot calibration: the pointer did not rotate about two or more axes")
    return PivotResult(
        "sphere",
        tip,
        pivot,
        _residuals(poses, tip, pivot),
        tip_covariance_mm2=tip_covariance(poses, tip, pivot),
    )


PIVOT_METHODS = {"aos": pivot_algebraic_one_step, "sphere": pivot_sphere_fit}


def pivot_calibration(tracker_from_marker_stack: FloatArray, method: str = "aos") -> PivotResult:
    """Pivot calibration by a named method (``aos`` or ``sphere``)."""
    if method not in PIVOT_METHODS:
        raise UnknownMethodError(
            f"unknown pivot method {method!r}; valid methods: {', '.join(PIVOT_METHODS)}"
        )
    return PIVOT_METHODS[method](tracker_from_marker_stack)
