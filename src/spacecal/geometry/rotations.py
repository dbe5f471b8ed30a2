"""Rotation estimation: nearest rotation, Wahba/Procrustes, averaging, angles."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import DegenerateDataError


def nearest_rotation(matrix) -> np.ndarray:
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
    return (u * correction[..., None, :]) @ vt


def wahba_rotation(directions_in_a, directions_in_b, weights=None) -> np.ndarray:
    """Solve Wahba's problem: the rotation ``a_from_b`` minimising sum w_k |u_k - R v_k|^2.

    Used by the paper estimator to turn fitted travel directions in the tracker frame and
    the commanded ones in the base frame into the tracker-from-base rotation. With the
    base directions equal to the TCP axes this equals the paper's nearest rotation of the
    fitted axes followed by the home TCP orientation.

    Parameters
    ----------
    directions_in_a : array_like, shape (K, 3)
    directions_in_b : array_like, shape (K, 3)
        Matching directions; normalised here. K >= 2 and not all parallel.
    weights : array_like, shape (K,), optional

    Returns
    -------
    numpy.ndarray, shape (3, 3)
    """
    a = np.asarray(directions_in_a, dtype=float)
    b = np.asarray(directions_in_b, dtype=float)
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    if len(a) < 2 or np.linalg.matrix_rank(b, tol=1e-6) < 2:
        raise DegenerateDataError("at least two non-parallel directions are needed for a rotation")
    rotation, _ = Rotation.align_vectors(a, b, weights=weights)
    return rotation.as_matrix()


def mean_rotation(rotations) -> np.ndarray:
    """Chordal L2 mean of rotations (N, 3, 3): the nearest rotation to their average."""
    return nearest_rotation(np.mean(np.asarray(rotations, dtype=float), axis=0))


def rotation_angle(rotation) -> np.ndarray:
    """The angle in radians, in [0, pi], of rotations (…, 3, 3).

    Computed from the quaternion (atan2 form) rather than acos((trace - 1) / 2), which
    loses precision for small angles.
    """
    r = np.asarray(rotation, dtype=float)
    return np.linalg.norm(Rotation.from_matrix(r).as_rotvec(), axis=-1)
