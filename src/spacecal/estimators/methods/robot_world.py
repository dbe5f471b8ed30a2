"""Closed-form robot-world/hand-eye solvers for A_i X = Y B_i.

Mapping to spacecal's frames (CONVENTIONS §2)::

    A_i = base_from_tcp_stack[i]        (robot forward kinematics)
    X   = tcp_from_marker               (marker on the tool)
    Y   = base_from_tracker             (the inverse of what navigation needs)
    B_i = tracker_from_marker_stack[i]  (tracker measurement)

so both sides read ``base_from_marker``. Each solver takes ``(base_from_tcp_stack,
tracker_from_marker_stack)``, calls them A and B inside, and returns ``(X, Y)``.

* Shah 2013, "Solving the robot-world/hand-eye calibration problem using the Kronecker
  product", J. Mech. Robot. 5(3): rotation from the dominant singular vectors of
  sum_i R_Bi (x) R_Ai, translation by linear least squares.
* Li, Wang, Wu 2010, "Simultaneous robot-world and hand-eye calibration using
  dual-quaternions and Kronecker product", Int. J. Phys. Sci. 5(10): 1530-1536: rotations
  and translations from one linear system (lengths in units of the poses' RMS translation),
  rotations orthonormalised.
* Dornaika, Horaud 1998, "Simultaneous robot-world and hand-eye calibration", IEEE TRA
  14(4), closed-form part: quaternions q_A q_X = q_Y q_B, the 8-vector (q_X, q_Y) from the
  smallest eigenvector of sum_i C_i^T C_i, C_i = [L(q_A), -R(q_B)].
"""

from __future__ import annotations

import numpy as np

from spacecal.core.errors import DegenerateDataError
from spacecal.geometry.arrays import ArrayLike, FloatArray
from spacecal.geometry.rotations import nearest_rotation, quaternion_product_matrices
from spacecal.geometry.transforms import make_transform, matrix_to_quaternion_wxyz, quaternion_wxyz_to_matrix

MIN_POSES = 3
#: The robot's orientations must differ by more than this (rad) about at least two independent
#: axes: with less, the rotation about the remaining axis is free, and a closed form still
#: returns an answer, as far off as it likes (a robot that never moved: any X explains it).
MIN_ORIENTATION_SPREAD_RAD = np.radians(2.0)


def _check(
    base_from_tcp_stack: ArrayLike, tracker_from_marker_stack: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    a = np.asarray(base_from_tcp_stack, dtype=float)
    b = np.asarray(tracker_from_marker_stack, dtype=float)
    if a.shape != b.shape or a.ndim != 3 or a.shape[1:] != (4, 4):
        raise DegenerateDataError(f"need matching pose stacks (N, 4, 4); got {a.shape} and {b.shape}")
    if len(a) < MIN_POSES:
        raise DegenerateDataError(f"AX = YB needs at least {MIN_POSES} poses, got {len(a)}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise DegenerateDataError(
            "AX = YB: poses contain NaN (drop the samples where the marker was not seen)"
        )
    if not _rotates_about_two_axes(a[:, :3, :3]):
        raise DegenerateDataError(
            "AX = YB: the robot's orientations differ by less than "
            f"{np.degrees(MIN_ORIENTATION_SPREAD_RAD):.0f} deg about two independent axes "
            "(rotate the tool about at least two axes)"
        )
    return a, b


def _rotates_about_two_axes(rotations: FloatArray) -> bool:
    """Whether orientations (N, 3, 3) spread about two independent axes: their rotation vectors
    from the first one (2 sin(angle/2) axis, about the angle in rad) extend more than
    :data:`MIN_ORIENTATION_SPREAD_RAD` along their second principal direction."""
    relative = np.einsum("nij,kj->nik", rotations, rotations[0])
    vectors = 2.0 * matrix_to_quaternion_wxyz(relative)[:, 1:]
    centred = vectors - vectors.mean(axis=0)
    _, _, directions = np.linalg.svd(centred, full_matrices=False)
    if len(directions) < 2:
        return False
    along = centred @ directions[1]
    return bool(np.ptp(along) > MIN_ORIENTATION_SPREAD_RAD)


def _orthonormal_from_vec(vec9: ArrayLike) -> FloatArray:
    """A rotation from a column-major 9-vector known up to scale (and sign)."""
    m = np.asarray(vec9).reshape(3, 3, order="F")
    det = np.linalg.det(m)
    if abs(det) < 1e-12:
        raise DegenerateDataError("rotation estimate is singular: the poses do not rotate about enough axes")
    m = m * np.sign(det) / abs(det) ** (1.0 / 3.0)
    return nearest_rotation(m)


def solve_translations(
    base_from_tcp_stack: ArrayLike,
    tracker_from_marker_stack: ArrayLike,
    rotation_x: FloatArray,
    rotation_y: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """Least-squares t_X, t_Y given the rotations: R_Ai t_X - t_Y = R_Y t_Bi - t_Ai."""
    a = np.asarray(base_from_tcp_stack, dtype=float)
    b = np.asarray(tracker_from_marker_stack, dtype=float)
    n = len(a)
    design = np.zeros((3 * n, 6))
    design[:, :3] = a[:, :3, :3].reshape(3 * n, 3)
    design[:, 3:] = -np.tile(np.eye(3), (n, 1))
    rhs = (b[:, :3, 3] @ rotation_y.T - a[:, :3, 3]).reshape(-1)
    solution, *_ = np.linalg.lstsq(design, rhs, rcond=None)
    return solution[:3], solution[3:]


def solve_shah(
    base_from_tcp_stack: FloatArray, tracker_from_marker_stack: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Shah 2013 (Kronecker product). See the module docstring for the frame mapping."""
    a, b = _check(base_from_tcp_stack, tracker_from_marker_stack)
    # vec(R_A R_X R_B^T) = (R_B (x) R_A) vec(R_X) = vec(R_Y): K vec(R_X) = n vec(R_Y)
    k = np.einsum("nij,nkl->nikjl", b[:, :3, :3], a[:, :3, :3]).reshape(len(a), 9, 9).sum(axis=0)
    u, _, vt = np.linalg.svd(k)
    rotation_x = _orthonormal_from_vec(vt[0])
    rotation_y = _orthonormal_from_vec(u[:, 0])
    t_x, t_y = solve_translations(a, b, rotation_x, rotation_y)
    return make_transform(rotation_x, t_x), make_transform(rotation_y, t_y)


def characteristic_length_mm(*translation_stacks: FloatArray) -> float:
    """RMS length of the given translations (each (N, 3), mm); 1 if they are all zero.

    The unit in which the closed forms that mix rotation (unitless) and translation rows in one
    linear system measure lengths, so that neither kind swamps the other and the answer does
    not depend on whether the poses came in mm or m.
    """
    squared = np.concatenate(
        [np.sum(np.asarray(t, dtype=float) ** 2, axis=-1).ravel() for t in translation_stacks]
    )
    length = float(np.sqrt(np.mean(squared))) if len(squared) else 0.0
    return length if np.isfinite(length) and length > 0.0 else 1.0


def solve_li(
    base_from_tcp_stack: FloatArray, tracker_from_marker_stack: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Li, Wang, Wu 2010 (simultaneous Kronecker system). Frame mapping in the module docstring.

    A. Li, L. Wang, D. Wu, "Simultaneous robot-world and hand-eye calibration using
    dual-quaternions and Kronecker product", Int. J. Phys. Sci. 5(10): 1530-1536, 2010, the
    Kronecker form (eq. 19). Unknowns [vec R_X, vec R_Y, t_X, t_Y] (column-major vec) from
    (I (x) R_A) vec R_X - (R_B^T (x) I) vec R_Y = 0 and
    R_A t_X - (t_B^T (x) I) vec R_Y - t_Y = -t_A, one linear least-squares problem over every
    pose; the rotations are then orthonormalised and the translations re-solved with them.

    Lengths enter the system in units of the RMS translation of the poses
    (:func:`characteristic_length_mm`). In mm, the coefficients of the translation rows are
    hundreds of times those of the unitless rotation rows, so translation noise sets the
    rotations: OpenCV's LI, which keeps the caller's units, lands 44 mm from the authors'
    hand-eye on the Storz set (docs/methods.md). Scaled, the rotations are the same for poses
    given in mm or in m, and the translations scale with the unit.

    Parameters
    ----------
    base_from_tcp_stack : numpy.ndarray, shape (N, 4, 4)
        A_i, TCP pose per sample, mm.
    tracker_from_marker_stack : numpy.ndarray, shape (N, 4, 4)
        B_i, marker pose per sample, mm.

    Returns
    -------
    tcp_from_marker : numpy.ndarray, shape (4, 4)
        X, mm.
    base_from_tracker : numpy.ndarray, shape (4, 4)
        Y, mm.

    Raises
    ------
    DegenerateDataError
        Fewer than :data:`MIN_POSES` poses, NaN, mismatched stacks, or poses that do not
        rotate about enough axes to fix the rotations.
    """
    a, b = _check(base_from_tcp_stack, tracker_from_marker_stack)
    n = len(a)
    eye3 = np.eye(3)
    length_mm = characteristic_length_mm(a[:, :3, 3], b[:, :3, 3])
    ra, rb, ta, tb = a[:, :3, :3], b[:, :3, :3], a[:, :3, 3] / length_mm, b[:, :3, 3] / length_mm
    system = np.zeros((n, 12, 24))
    system[:, :9, :9] = np.einsum("ij,nab->niajb", eye3, ra).reshape(n, 9, 9)  # I (x) R_A
    system[:, :9, 9:18] = -np.einsum("nba,ij->naibj", rb, eye3).reshape(n, 9, 9)  # -(R_B^T (x) I)
    system[:, 9:, 9:18] = -np.einsum("nb,ij->nibj", tb, eye3).reshape(n, 3, 9)  # -(t_B^T (x) I)
    system[:, 9:, 18:21] = ra
    system[:, 9:, 21:24] = -eye3
    rhs = np.zeros((n, 12))
    rhs[:, 9:] = -ta
    solution, *_ = np.linalg.lstsq(system.reshape(12 * n, 24), rhs.reshape(-1), rcond=None)
    rotation_x = _orthonormal_from_vec(solution[:9])
    rotation_y = _orthonormal_from_vec(solution[9:18])
    t_x, t_y = solve_translations(a, b, rotation_x, rotation_y)
    return make_transform(rotation_x, t_x), make_transform(rotation_y, t_y)


def solve_dornaika(
    base_from_tcp_stack: FloatArray, tracker_from_marker_stack: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Dornaika–Horaud 1998 closed form (quaternions). Frame mapping in the module docstring.

    q and -q are the same rotation, so q_A q_X = +-q_Y q_B per pose; the signs of q_Bi are
    made consistent with the Kronecker (Shah) rotations first, then the 8x8 eigenproblem
    is solved and translations follow by least squares.
    """
    a, b = _check(base_from_tcp_stack, tracker_from_marker_stack)
    x0, y0 = solve_shah(a, b)
    q_a = matrix_to_quaternion_wxyz(a[:, :3, :3])
    q_b = matrix_to_quaternion_wxyz(b[:, :3, :3])
    left_a, _ = quaternion_product_matrices(q_a)
    q_x0 = matrix_to_quaternion_wxyz(x0[:3, :3])
    q_y0 = matrix_to_quaternion_wxyz(y0[:3, :3])
    left_y0, _ = quaternion_product_matrices(q_y0)
    sign = np.sign(np.einsum("ni,ni->n", left_a @ q_x0, q_b @ left_y0.T))
    q_b = q_b * np.where(sign == 0, 1.0, sign)[:, None]
    _, right_b = quaternion_product_matrices(q_b)
    c = np.concatenate([left_a, -right_b], axis=2)  # (n, 4, 8)
    _, vectors = np.linalg.eigh(np.einsum("nki,nkj->ij", c, c))
    z = vectors[:, 0]
    q_x, q_y = z[:4] / np.linalg.norm(z[:4]), z[4:] / np.linalg.norm(z[4:])
    rotation_x, rotation_y = quaternion_wxyz_to_matrix(q_x), quaternion_wxyz_to_matrix(q_y)
    t_x, t_y = solve_translations(a, b, rotation_x, rotation_y)
    return make_transform(rotation_x, t_x), make_transform(rotation_y, t_y)
