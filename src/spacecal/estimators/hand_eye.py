"""Closed-form hand-eye solvers for A_k X = X B_k (relative motions).

From paired samples i, j of a recording (CONVENTIONS §2 names)::

    A_k = tcp_from_base_i @ base_from_tcp_j              (TCP motion, tcp_i <- tcp_j)
    B_k = marker_from_tracker_i @ tracker_from_marker_j  (marker motion)
    X   = tcp_from_marker

since A_i X = Y B_i for every sample gives A_i^-1 A_j X = X B_i^-1 B_j.

* Tsai, Lenz 1989, "A new technique for fully autonomous and efficient 3D robotics
  hand/eye calibration", IEEE TRA 5(3): modified Rodrigues vectors.
* Park, Martin 1994, "Robot sensor calibration: solving AX = XB on the Euclidean group",
  IEEE TRA 10(5): log map and (M^T M)^(-1/2) M^T.
* Daniilidis 1999, "Hand-eye calibration using dual quaternions", IJRR 18(3).

Translation (Tsai, Park): (R_Ak - I) t_X = R_X t_Bk - t_Ak by least squares.

Each solver takes ``(tcp_motion_stack, marker_motion_stack)``, the (A_k, B_k) of
:func:`relative_motions`, and returns X.
"""

from __future__ import annotations

import numpy as np

from spacecal.core.errors import DegenerateDataError
from spacecal.geometry.arrays import ArrayLike, FloatArray, as_float_array
from spacecal.geometry.rotations import quaternion_product_matrices, skew
from spacecal.geometry.transforms import (
    invert_transform,
    make_transform,
    matrix_to_quaternion_wxyz,
    matrix_to_rotvec,
    quaternion_wxyz_to_matrix,
)

#: Motions that rotate less than this carry no information on the rotation axis.
MIN_MOTION_ANGLE_RAD = np.radians(2.0)


def relative_motions(
    base_from_tcp_stack: ArrayLike, tracker_from_marker_stack: ArrayLike, pairs: ArrayLike | None = None
) -> tuple[FloatArray, FloatArray]:
    """Relative motions (A_k, B_k) for sample pairs (default: consecutive samples).

    Parameters
    ----------
    base_from_tcp_stack : array_like, shape (N, 4, 4)
        TCP pose per sample, mm.
    tracker_from_marker_stack : array_like, shape (N, 4, 4)
        Marker pose per sample, mm.
    pairs : array_like of int, shape (K, 2), optional

    Returns
    -------
    tcp_motion_stack : numpy.ndarray, shape (K, 4, 4)
        A_k = tcp_from_base_i @ base_from_tcp_j.
    marker_motion_stack : numpy.ndarray, shape (K, 4, 4)
        B_k = marker_from_tracker_i @ tracker_from_marker_j.
    """
    a = np.asarray(base_from_tcp_stack, dtype=float)
    b = np.asarray(tracker_from_marker_stack, dtype=float)
    if pairs is None:
        pairs = np.column_stack([np.arange(len(a) - 1), np.arange(1, len(a))])
    pairs = np.asarray(pairs)
    motion_a = invert_transform(a[pairs[:, 0]]) @ a[pairs[:, 1]]
    motion_b = invert_transform(b[pairs[:, 0]]) @ b[pairs[:, 1]]
    return motion_a, motion_b


def _rotating(motion_a: FloatArray, motion_b: FloatArray) -> tuple[FloatArray, FloatArray]:
    angle = np.linalg.norm(matrix_to_rotvec(motion_a[:, :3, :3]), axis=1)
    keep = angle > MIN_MOTION_ANGLE_RAD
    if keep.sum() < 2:
        raise DegenerateDataError(
            "AX = XB needs at least two motions rotating more than "
            f"{np.degrees(MIN_MOTION_ANGLE_RAD):.0f} deg about different axes; got {int(keep.sum())}"
        )
    return motion_a[keep], motion_b[keep]


def _translation(motion_a: FloatArray, motion_b: FloatArray, rotation_x: FloatArray) -> FloatArray:
    n = len(motion_a)
    design = (motion_a[:, :3, :3] - np.eye(3)).reshape(3 * n, 3)
    rhs = (motion_b[:, :3, 3] @ rotation_x.T - motion_a[:, :3, 3]).reshape(-1)
    solution, *_ = np.linalg.lstsq(design, rhs, rcond=None)
    return as_float_array(solution)


def solve_tsai(tcp_motion_stack: FloatArray, marker_motion_stack: FloatArray) -> FloatArray:
    """Tsai–Lenz 1989; returns X = ``tcp_from_marker``."""
    rot_a, rot_b = _rotating(tcp_motion_stack, marker_motion_stack)
    rv_a = matrix_to_rotvec(rot_a[:, :3, :3])
    rv_b = matrix_to_rotvec(rot_b[:, :3, :3])

    def modified_rodrigues(rv: FloatArray) -> FloatArray:
        angle = np.linalg.norm(rv, axis=1, keepdims=True)
        return as_float_array(2.0 * np.sin(angle / 2.0) * rv / angle)

    p_a, p_b = modified_rodrigues(rv_a), modified_rodrigues(rv_b)
    # skew(P_A + P_B) P' = P_B - P_A; P = 2 P' / sqrt(1 + |P'|^2)
    design = skew(p_a + p_b).reshape(-1, 3)
    p_prime, *_ = np.linalg.lstsq(design, (p_b - p_a).reshape(-1), rcond=None)
    p = 2.0 * p_prime / np.sqrt(1.0 + p_prime @ p_prime)
    norm_sq = p @ p
    rotation = (1.0 - norm_sq / 2.0) * np.eye(3) + 0.5 * (np.outer(p, p) + np.sqrt(4.0 - norm_sq) * skew(p))
    return make_transform(rotation, _translation(tcp_motion_stack, marker_motion_stack, rotation))


def solve_park(tcp_motion_stack: FloatArray, marker_motion_stack: FloatArray) -> FloatArray:
    """Park–Martin 1994; returns X = ``tcp_from_marker``."""
    rot_a, rot_b = _rotating(tcp_motion_stack, marker_motion_stack)
    alpha = matrix_to_rotvec(rot_a[:, :3, :3])
    beta = matrix_to_rotvec(rot_b[:, :3, :3])
    m = np.einsum("ni,nj->ij", beta, alpha)
    eigenvalues, eigenvectors = np.linalg.eigh(m.T @ m)
    if eigenvalues.min() <= 1e-12 * eigenvalues.max():
        raise DegenerateDataError("AX = XB: the motions rotate about fewer than two independent axes")
    inverse_sqrt = eigenvectors @ np.diag(eigenvalues**-0.5) @ eigenvectors.T
    rotation = inverse_sqrt @ m.T
    # (M^T M)^(-1/2) M^T is orthogonal; on motions that no rotation relates (e.g. the tracker's
    # poses inverted or transposed) it is a reflection, which is no answer
    if np.linalg.det(rotation) < 0:
        raise DegenerateDataError(
            "AX = XB: no rotation relates the robot's and the tracker's motions (the best fit is a "
            "reflection): check the pose conventions"
        )
    return make_transform(rotation, _translation(tcp_motion_stack, marker_motion_stack, rotation))


def _dual_quaternion(transform: FloatArray) -> tuple[FloatArray, FloatArray]:
    q = matrix_to_quaternion_wxyz(transform[:, :3, :3])
    t = np.concatenate([np.zeros((len(transform), 1)), transform[:, :3, 3]], axis=1)
    left_t, _ = quaternion_product_matrices(t)
    return q, 0.5 * np.einsum("nij,nj->ni", left_t, q)


def solve_daniilidis(tcp_motion_stack: FloatArray, marker_motion_stack: FloatArray) -> FloatArray:
    """Daniilidis 1999 (dual quaternions); returns X = ``tcp_from_marker``."""
    rot_a, rot_b = _rotating(tcp_motion_stack, marker_motion_stack)
    qa, qa_dual = _dual_quaternion(rot_a)
    qb, qb_dual = _dual_quaternion(rot_b)
    # Equal rotation angles: make the scalar parts agree in sign (q ~ -q).
    flip = np.sign(qa[:, 0]) != np.sign(qb[:, 0])
    qb[flip] *= -1
    qb_dual[flip] *= -1
    a, a_d, b, b_d = qa[:, 1:], qa_dual[:, 1:], qb[:, 1:], qb_dual[:, 1:]
    n = len(a)
    system = np.zeros((6 * n, 8))
    system[0::6, 0], system[1::6, 0], system[2::6, 0] = (a - b).T
    system.reshape(n, 6, 8)[:, :3, 1:4] = skew(a + b)
    view = system.reshape(n, 6, 8)
    view[:, 3:, 0] = a_d - b_d
    view[:, 3:, 1:4] = skew(a_d + b_d)
    view[:, 3:, 4] = a - b
    view[:, 3:, 5:8] = skew(a + b)
    _, _, vt = np.linalg.svd(view.reshape(6 * n, 8))
    v7, v8 = vt[-2], vt[-1]
    u1, v1, u2, v2 = v7[:4], v7[4:], v8[:4], v8[4:]
    # lambda1 u1 + lambda2 u2 is unit and orthogonal to lambda1 v1 + lambda2 v2
    coeffs = [u1 @ v1, u1 @ v2 + u2 @ v1, u2 @ v2]
    roots = np.roots(coeffs) if abs(coeffs[0]) > 1e-15 else np.array([-coeffs[2] / coeffs[1]])
    roots = np.real(roots[np.isreal(roots)])
    if len(roots) == 0:
        raise DegenerateDataError("Daniilidis: no real solution (motions too small or inconsistent)")
    values = [s**2 * (u1 @ u1) + 2 * s * (u1 @ u2) + u2 @ u2 for s in roots]
    best = int(np.argmax(values))
    s = roots[best]
    lambda2 = np.sqrt(1.0 / values[best])
    lambda1 = s * lambda2
    q = lambda1 * u1 + lambda2 * u2
    q_dual = lambda1 * v1 + lambda2 * v2
    conj = q * np.array([1.0, -1.0, -1.0, -1.0])
    left_dual, _ = quaternion_product_matrices(q_dual)
    translation = 2.0 * (left_dual @ conj)[1:]
    return make_transform(quaternion_wxyz_to_matrix(q), translation)
