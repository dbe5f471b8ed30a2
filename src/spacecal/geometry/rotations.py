"""Rotation estimation: nearest rotation, Wahba/Procrustes, averaging, angles."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from spacecal.core.errors import DegenerateDataError
from spacecal.geometry.arrays import ArrayLike, FloatArray, as_float_array


def nearest_rotation(matrix: ArrayLike) -> FloatArray:
    """Project a 3x3 matrix to the nearest proper rotation in the Frobenius norm.

    This is the orthonormalisation step of the paper's linear method (§3.1): the three
    fitted axis directions, stacked as columns, are not exactly orthogonal with noise.
    The solution is U diag(1, 1, det(U V^T)) V^T from the SVD M = U S V^T (the polar
    factor, with the reflection removed).

    Parameters
    ----------
    matrix : array_like, shape (3, 3) or (N, 3, 3)

    Returns
    -------
    numpy.ndarray, same shape, proper rotations.
    """
    m = np.asarray(matrix, dtype=float)
    if not np.all(np.isfinite(m)):
        raise DegenerateDataError("cannot orthonormalise a matrix with NaN or infinite entries")
    u, _, vt = np.linalg.svd(m)
    d = np.sign(np.linalg.det(u @ vt))
    d = np.where(d == 0, 1.0, d)
    correction = np.ones(m.shape[:-2] + (3,))
    correction[..., 2] = d
    return as_float_array((u * correction[..., None, :]) @ vt)


def wahba_rotation(
    *, directions_in_source: ArrayLike, directions_in_target: ArrayLike, weights: ArrayLike | None = None
) -> FloatArray:
    """Solve Wahba's problem: the rotation ``target_from_source`` minimising ``sum w_k |u_k - R v_k|^2``.

    Used by the paper estimator to turn fitted travel directions in the tracker frame and
    the commanded ones in the base frame into the tracker-from-base rotation. With the
    base directions equal to the TCP axes this equals the paper's nearest rotation of the
    fitted axes followed by the home TCP orientation.

    The direction sets are keyword-only, named (and ordered) as the point sets of
    :func:`spacecal.geometry.fitting.fit_rigid`.

    Parameters
    ----------
    directions_in_source : array_like, shape (K, 3)
        Directions v_k in the frame mapped from (e.g. base).
    directions_in_target : array_like, shape (K, 3)
        The matching directions u_k in the frame mapped into (e.g. tracker). Both are
        normalised here; K >= 2 and not all parallel.
    weights : array_like, shape (K,), optional

    Returns
    -------
    numpy.ndarray, shape (3, 3)
        ``target_from_source`` rotation.
    """
    target = np.asarray(directions_in_target, dtype=float)
    source = np.asarray(directions_in_source, dtype=float)
    target = target / np.linalg.norm(target, axis=1, keepdims=True)
    source = source / np.linalg.norm(source, axis=1, keepdims=True)
    if len(target) < 2 or np.linalg.matrix_rank(source, tol=1e-6) < 2:
        raise DegenerateDataError("at least two non-parallel directions are needed for a rotation")
    rotation, _ = Rotation.align_vectors(target, source, weights=weights)
    return as_float_array(rotation.as_matrix())


def mean_rotation(rotations: ArrayLike) -> FloatArray:
    """Chordal L2 mean of rotations (N, 3, 3): the nearest rotation to their average."""
    return nearest_rotation(np.mean(np.asarray(rotations, dtype=float), axis=0))


def rotation_angle(rotation: ArrayLike) -> FloatArray:
    """The angle in radians, in [0, pi], of rotations (…, 3, 3).

    Computed from the quaternion (atan2 form) rather than acos((trace - 1) / 2), which
    loses precision for small angles.
    """
    r = np.asarray(rotation, dtype=float)
    return as_float_array(np.linalg.norm(Rotation.from_matrix(r).as_rotvec(), axis=-1))


def skew(vector: ArrayLike) -> FloatArray:
    """Cross-product matrices [v]x, shape (…, 3, 3), with [v]x w = v x w."""
    v = np.asarray(vector, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def quaternion_product_matrices(quaternion_wxyz: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Left and right multiplication matrices of ``wxyz`` quaternions, shape (…, 4, 4).

    ``L(p) q = p * q`` and ``R(q) p = p * q`` (Hamilton product).
    """
    q = np.asarray(quaternion_wxyz, dtype=float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    left = np.stack(
        [
            np.stack([w, -x, -y, -z], -1),
            np.stack([x, w, -z, y], -1),
            np.stack([y, z, w, -x], -1),
            np.stack([z, -y, x, w], -1),
        ],
        -2,
    )
    right = np.stack(
        [
            np.stack([w, -x, -y, -z], -1),
            np.stack([x, w, z, -y], -1),
            np.stack([y, -z, w, x], -1),
            np.stack([z, y, -x, w], -1),
        ],
        -2,
    )
    return left, right
