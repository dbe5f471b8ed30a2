"""The rigid part of a field of displacements at a marker's points: what one pose change explains."""

from __future__ import annotations

import numpy as np

from spacecal.geometry.arrays import FloatArray, as_float_array


def rigid_coordinates(displacements: FloatArray, points: FloatArray) -> FloatArray:
    """Each frame's point displacements as the small rigid motion that explains them best.

    Parameters
    ----------
    displacements : numpy.ndarray, shape (N, K, 3) or (N, K, 3, M), mm
        Per frame, the displacement of each of K points (M sets of them, e.g. Jacobian columns).
    points : numpy.ndarray, shape (N, K, 3), mm
        Where the points are.

    Returns
    -------
    numpy.ndarray, shape (N, 6, M) (M = 1 for one set), mm and rad
        The least-squares translation of the points' centroid and rotation about it (tracker
        frame), ``(v, w)``.
    """
    centred = points - points.mean(axis=1, keepdims=True)
    n, k, _ = points.shape
    basis = np.zeros((n, k, 3, 6))
    basis[..., :3] = np.eye(3)
    # the rotation w moves a point p by w x p = -[p]x w
    x, y, z = centred[..., 0], centred[..., 1], centred[..., 2]
    basis[..., 0, 4], basis[..., 0, 5] = z, -y
    basis[..., 1, 3], basis[..., 1, 5] = -z, x
    basis[..., 2, 3], basis[..., 2, 4] = y, -x
    design = basis.reshape(n, 3 * k, 6)
    return as_float_array(np.linalg.pinv(design) @ displacements.reshape(n, 3 * k, -1))


def rigid_part(displacements: FloatArray, points: FloatArray) -> FloatArray:
    """Each frame's point displacements projected on the rigid motions of its points.

    Parameters
    ----------
    displacements, points : numpy.ndarray, shape (N, K, 3), mm
        Per frame, the displacement of each of K points and where the point is.

    Returns
    -------
    numpy.ndarray, shape (N, K, 3), mm
        The displacements a small rigid motion (translation and rotation) of each frame's
        points explains best, by least squares.
    """
    motion = rigid_coordinates(displacements, points)[..., 0]
    rotation = motion[:, 3:]
    centred = points - points.mean(axis=1, keepdims=True)
    return motion[:, None, :3] + np.cross(rotation[:, None, :], centred)
