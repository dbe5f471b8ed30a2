"""Closed-form hand-eye solvers for A_k X = X B_k (relative motions).

From paired samples i, j of a recording (CONVENTIONS §2 names)::

    A_k = tcp_from_base_i @ base_from_tcp_j              (TCP motion, tcp_i <- tcp_j)
    B_k = marker_from_tracker_i @ tracker_from_marker_j  (marker motion)
    X   = tcp_from_marker

since A_i X = Y B_i for every sample gives A_i^-1 A_j X = X B_i^-1 B_j.

* Tsai, Lenz 1989, "A new technique for fully autonomous and efficient 3D robotics
  hand/eye calibration", IEEE TRA 5(3): 345-358: modified Rodrigues vectors (eq. 12-15).
* Park, Martin 1994, "Robot sensor calibration: solving AX = XB on the Euclidean group",
  IEEE TRA 10(5): 717-721: log map and (M^T M)^(-1/2) M^T (eq. 11-13).
* Daniilidis 1999, "Hand-eye calibration using dual quaternions", IJRR 18(3): 286-298:
  rotation and translation at once from the 2-D null space of a 6K x 8 system (eq. 31-35).

Translation (Tsai, Park): (R_Ak - I) t_X = R_X t_Bk - t_Ak by least squares.

Which motions: from N poses, :func:`motion_pairs` takes every pair (i, j) for N up to
:data:`ALL_PAIRS_FRAMES` and, beyond that, a spread subset of pairs that rotate far from 0 and
180 deg. Motions between consecutive samples alone waste most of what a grid of static
views holds (N - 1 motions instead of N (N - 1) / 2), which is why OpenCV's
``calibrateHandEye`` also uses all pairs.

Why the rotation step is solved twice: a measured rotation by nearly 180 deg has an axis
whose sign the noise may flip (a rotation by pi about n is the one about -n), and a flipped
motion in A but not in B corrupts Tsai's, Park's and Daniilidis' equations. The first
solve uses the motions below :data:`SIGN_SAFE_ANGLE_RAD`; the quaternions of B are then
given the sign that agrees with that rotation, and the second solve uses every motion.

Each solver takes ``(tcp_motion_stack, marker_motion_stack)``, the (A_k, B_k) of
:func:`relative_motions`, and returns X.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from spacecal.core.errors import DegenerateDataError
from spacecal.estimators.methods.robot_world import characteristic_length_mm
from spacecal.geometry.arrays import ArrayLike, FloatArray, IntArray, as_float_array
from spacecal.geometry.rotations import quaternion_product_matrices, skew
from spacecal.geometry.transforms import (
    invert_transform,
    make_transform,
    matrix_to_quaternion_wxyz,
    quaternion_wxyz_to_matrix,
)

#: Motions that rotate less than this carry no information on the rotation axis.
MIN_MOTION_ANGLE_RAD = np.radians(2.0)

#: Motions rotating more than this may have their axis sign flipped by noise; the rotation
#: step aligns their sign with a first estimate from the others (module docstring).
SIGN_SAFE_ANGLE_RAD = np.radians(150.0)

#: Tsai's rotation is solved this many times, each in the frame of the previous estimate
#: (see :func:`solve_tsai`).
TSAI_PASSES = 2

#: Daniilidis' rotation and translation rows are reweighted at most this many times.
DANIILIDIS_REWEIGHTS = 3

#: Up to this many poses, :func:`motion_pairs` takes every pair (60 poses: 1770 motions).
ALL_PAIRS_FRAMES = 60

#: Beyond :data:`ALL_PAIRS_FRAMES`, the pairs are chosen among at most this many poses spread
#: over the recording...
PAIR_CANDIDATE_FRAMES = 300

#: ...and at most this many pairs are kept (as many as all pairs of 60 poses).
MAX_MOTION_PAIRS = ALL_PAIRS_FRAMES * (ALL_PAIRS_FRAMES - 1) // 2


def motion_pairs(
    base_from_tcp_stack: ArrayLike,
    all_pairs_frames: int = ALL_PAIRS_FRAMES,
    max_pairs: int = MAX_MOTION_PAIRS,
) -> IntArray:
    """Which sample pairs (i, j) to turn into relative motions for AX = XB.

    Every pair i < j for up to ``all_pairs_frames`` samples. For more, the pairs are chosen
    among at most :data:`PAIR_CANDIDATE_FRAMES` samples spread evenly over the stack: each
    sample proposes the partners it rotates against with the largest sin(angle) (so the
    angle is far from 0 deg, where a motion says nothing about the axis, and from 180 deg,
    where the axis sign is fragile), about ``2 max_pairs / samples`` of them, so every sample
    contributes and no stretch of the recording dominates; of the proposed pairs at most
    ``max_pairs`` with the largest sin(angle) are kept. Pairs rotating less than
    :data:`MIN_MOTION_ANGLE_RAD` are never proposed.

    Parameters
    ----------
    base_from_tcp_stack : array_like, shape (N, 4, 4)
        TCP pose per sample, mm (only the rotations are used).
    all_pairs_frames : int
        Up to this many samples, every pair.
    max_pairs : int
        About this many pairs at most beyond that.

    Returns
    -------
    numpy.ndarray of int, shape (K, 2)
        Sample indices (i, j), i < j, into ``base_from_tcp_stack``.
    """
    rotations = np.asarray(base_from_tcp_stack, dtype=float)[:, :3, :3]
    n = len(rotations)
    if n <= all_pairs_frames:
        first, second = np.triu_indices(n, k=1)
        return np.column_stack([first, second]).astype(np.intp)
    frames = np.unique(np.linspace(0, n - 1, min(n, PAIR_CANDIDATE_FRAMES)).round().astype(np.intp))
    r = rotations[frames]
    # trace(R_i^T R_j) = 1 + 2 cos(angle)
    cos_angle = np.clip((np.einsum("iab,jab->ij", r, r) - 1.0) / 2.0, -1.0, 1.0)
    score = np.sqrt(1.0 - cos_angle**2)  # sin(angle), angle in [0, pi]
    np.fill_diagonal(score, -1.0)
    # a pair found from both ends counts once: ask each sample for twice its share
    per_frame = max(1, min(len(frames) - 1, 2 * max_pairs // len(frames)))
    partners = np.argsort(-score, axis=1)[:, :per_frame]
    rows = np.repeat(np.arange(len(frames)), per_frame)
    cols = partners.ravel()
    keep = score[rows, cols] > np.sin(MIN_MOTION_ANGLE_RAD)
    pairs = np.unique(np.sort(np.column_stack([rows[keep], cols[keep]]), axis=1), axis=0)
    if len(pairs) > max_pairs:
        pairs = pairs[np.sort(np.argsort(-score[pairs[:, 0], pairs[:, 1]], kind="stable")[:max_pairs])]
    return _as_pairs(frames[pairs])


def _as_pairs(pairs: ArrayLike) -> IntArray:
    """Pair indices as an int array of shape (K, 2)."""
    return np.asarray(pairs, dtype=np.intp).reshape(-1, 2)


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
        Sample indices (i, j) per motion, e.g. from :func:`motion_pairs`; by default the
        consecutive samples (i, i + 1).

    Returns
    -------
    tcp_motion_stack : numpy.ndarray, shape (K, 4, 4)
        A_k = tcp_from_base_i @ base_from_tcp_j, mm.
    marker_motion_stack : numpy.ndarray, shape (K, 4, 4)
        B_k = marker_from_tracker_i @ tracker_from_marker_j, mm.
    """
    a = np.asarray(base_from_tcp_stack, dtype=float)
    b = np.asarray(tracker_from_marker_stack, dtype=float)
    if pairs is None:
        pairs = np.column_stack([np.arange(len(a) - 1), np.arange(1, len(a))])
    index = _as_pairs(pairs)
    motion_a = invert_transform(a[index[:, 0]]) @ a[index[:, 1]]
    motion_b = invert_transform(b[index[:, 0]]) @ b[index[:, 1]]
    return motion_a, motion_b


class _Motions:
    """The rotating motions of a solver's input, as quaternions with consistent signs.

    ``q_a``, ``q_b`` (K, 4) are wxyz; q_b's sign is the one for which q_A q_X = q_X q_B
    (with scalar parts >= 0 both, right for motions well below 180 deg). ``angle`` (K,) is
    A's rotation angle in [0, pi], rad; ``t_a``, ``t_b`` (K, 3) the translations, mm.
    """

    def __init__(self, tcp_motion_stack: ArrayLike, marker_motion_stack: ArrayLike) -> None:
        motion_a = np.asarray(tcp_motion_stack, dtype=float)
        motion_b = np.asarray(marker_motion_stack, dtype=float)
        if motion_a.shape != motion_b.shape or motion_a.ndim != 3 or motion_a.shape[1:] != (4, 4):
            raise DegenerateDataError(
                f"AX = XB needs matching motion stacks (K, 4, 4); got {motion_a.shape} and {motion_b.shape}"
            )
        finite = np.all(np.isfinite(motion_a), axis=(1, 2)) & np.all(np.isfinite(motion_b), axis=(1, 2))
        if not finite.all():
            raise DegenerateDataError(
                "AX = XB: motions contain NaN (drop the samples where the marker was not seen)"
            )
        q_a = matrix_to_quaternion_wxyz(motion_a[:, :3, :3]) if len(motion_a) else np.zeros((0, 4))
        angle = 2.0 * np.arctan2(np.linalg.norm(q_a[:, 1:], axis=1), q_a[:, 0])
        keep = angle > MIN_MOTION_ANGLE_RAD
        if keep.sum() < 2:
            raise DegenerateDataError(
                "AX = XB needs at least two motions rotating more than "
                f"{np.degrees(MIN_MOTION_ANGLE_RAD):.0f} deg about different axes; got {int(keep.sum())}"
            )
        self.q_a = q_a[keep]
        self.q_b = matrix_to_quaternion_wxyz(motion_b[keep, :3, :3])
        self.angle = angle[keep]
        self.t_a = motion_a[keep, :3, 3]
        self.t_b = motion_b[keep, :3, 3]
        self.rotation_a = motion_a[keep, :3, :3]

    def __len__(self) -> int:
        return len(self.q_a)

    def subset(self, rows: ArrayLike) -> _Motions:
        out = object.__new__(_Motions)
        for name in ("q_a", "q_b", "angle", "t_a", "t_b", "rotation_a"):
            setattr(out, name, getattr(self, name)[rows])
        return out

    def align_signs(self, rotation_x: FloatArray) -> None:
        """Give q_B the sign with vec(q_A) . R_X vec(q_B) >= 0 on motions near 180 deg."""
        agreement = np.einsum("ni,ni->n", self.q_a[:, 1:], self.q_b[:, 1:] @ rotation_x.T)
        flip = (self.angle >= SIGN_SAFE_ANGLE_RAD) & (agreement < 0)
        self.q_b = np.where(flip[:, None], -self.q_b, self.q_b)


def _two_pass(motions: _Motions, solve: Callable[[_Motions], FloatArray]) -> FloatArray:
    """``solve`` on the sign-safe motions (if they determine X), align signs, solve on all.

    Returns ``solve``'s X, shape (4, 4), checked finite.
    """
    if not _spans_two_axes(motions):
        # one axis leaves the rotation about it free: a closed form would still return an X,
        # as far off as it likes
        raise DegenerateDataError("AX = XB: the motions rotate about fewer than two independent axes")
    safe = np.flatnonzero(motions.angle < SIGN_SAFE_ANGLE_RAD)
    if len(safe) < len(motions):
        first = None
        if len(safe) >= 2 and _spans_two_axes(motions.subset(safe)):
            try:
                first = solve(motions.subset(safe))
            except DegenerateDataError:  # the safe motions alone do not determine X
                first = None
        motions.align_signs((solve(motions) if first is None else first)[:3, :3])
    x = solve(motions)
    if not np.all(np.isfinite(x)):  # never a NaN answer (CONVENTIONS §5)
        raise DegenerateDataError("AX = XB: the motions do not determine X (the solution is not finite)")
    return x


def _spans_two_axes(motions: _Motions) -> bool:
    """Whether the rotation axes of A (weighted by sin(angle/2)) span at least two directions."""
    singular = np.linalg.svd(motions.q_a[:, 1:], compute_uv=False)
    return len(singular) >= 2 and bool(singular[1] > 1e-6 * max(singular[0], 1e-300))


def _translation(motions: _Motions, rotation_x: FloatArray) -> FloatArray:
    """(R_Ak - I) t_X = R_X t_Bk - t_Ak by least squares, mm."""
    n = len(motions)
    design = (motions.rotation_a - np.eye(3)).reshape(3 * n, 3)
    rhs = (motions.t_b @ rotation_x.T - motions.t_a).reshape(-1)
    solution, *_ = np.linalg.lstsq(design, rhs, rcond=None)
    return as_float_array(solution)


def _tsai_rotation(motions: _Motions) -> FloatArray:
    # Tsai-Lenz eq. 12: skew(P_A + P_B) P' = P_B - P_A with P = 2 sin(angle/2) axis = 2 vec(q),
    # then eq. 14: P_X = 2 P' / sqrt(1 + |P'|^2)
    rotation = np.eye(3)
    p_a = 2.0 * motions.q_a[:, 1:]
    for _ in range(TSAI_PASSES):
        # A X = X B with X = X' R: A X' = X' (R B R^T), whose axes are R's image of B's
        p_b = 2.0 * motions.q_b[:, 1:] @ rotation.T
        design = skew(p_a + p_b).reshape(-1, 3)
        p_prime, *_ = np.linalg.lstsq(design, (p_b - p_a).reshape(-1), rcond=None)
        p = 2.0 * p_prime / np.sqrt(1.0 + p_prime @ p_prime)
        norm_sq = p @ p
        step = (1.0 - norm_sq / 2.0) * np.eye(3) + 0.5 * (np.outer(p, p) + np.sqrt(4.0 - norm_sq) * skew(p))
        rotation = step @ rotation
    return as_float_array(rotation)


def solve_tsai(tcp_motion_stack: FloatArray, marker_motion_stack: FloatArray) -> FloatArray:
    """Tsai–Lenz 1989 (modified Rodrigues vectors); returns X = ``tcp_from_marker``.

    R. Y. Tsai, R. K. Lenz, "A new technique for fully autonomous and efficient 3D robotics
    hand/eye calibration", IEEE Trans. Robot. Autom. 5(3): 345-358, 1989. Rotation from
    eq. 12-14 over every rotating motion (signs made consistent, module docstring), then
    translation from eq. 15 by least squares.

    Eq. 12 is the quaternion equation divided by cos(angle_X / 2): its least squares weighs
    each candidate by 1 / cos^2, which pulls the answer towards smaller angles and blows up
    as R_X nears 180 deg (the Storz set's X rotates 179.4 deg; one pass lands 2.6 deg off).
    So eq. 12 is solved :data:`TSAI_PASSES` times, each time for the rotation left after the
    previous estimate (B's axes rotated by it), which is near the identity where the
    weighting is flat. On exact data the first pass is exact and the second returns it.

    Parameters
    ----------
    tcp_motion_stack : numpy.ndarray, shape (K, 4, 4)
        A_k, TCP motions (:func:`relative_motions`), mm.
    marker_motion_stack : numpy.ndarray, shape (K, 4, 4)
        B_k, marker motions, mm.

    Returns
    -------
    numpy.ndarray, shape (4, 4)
        X = ``tcp_from_marker``, mm.

    Raises
    ------
    DegenerateDataError
        Fewer than two motions rotating more than :data:`MIN_MOTION_ANGLE_RAD`, or NaN.
    """
    motions = _Motions(tcp_motion_stack, marker_motion_stack)

    def solve(subset: _Motions) -> FloatArray:
        return make_transform(_tsai_rotation(subset), np.zeros(3))

    rotation = _two_pass(motions, solve)[:3, :3]
    return make_transform(rotation, _translation(motions, rotation))


def _park_rotation(motions: _Motions) -> FloatArray:
    # log map from the (sign-aligned) quaternions: angle in [0, 2 pi), so a flipped q_B keeps
    # the same rotation vector as its A
    def log(q: FloatArray) -> FloatArray:
        norm = np.linalg.norm(q[:, 1:], axis=1, keepdims=True)
        angle = 2.0 * np.arctan2(norm, q[:, :1])
        return as_float_array(q[:, 1:] * angle / np.maximum(norm, 1e-300))

    alpha, beta = log(motions.q_a), log(motions.q_b)
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
    return as_float_array(rotation)


def solve_park(tcp_motion_stack: FloatArray, marker_motion_stack: FloatArray) -> FloatArray:
    """Park–Martin 1994 (log map on SO(3)); returns X = ``tcp_from_marker``.

    F. C. Park, B. J. Martin, "Robot sensor calibration: solving AX = XB on the Euclidean
    group", IEEE Trans. Robot. Autom. 10(5): 717-721, 1994. R_X = (M^T M)^(-1/2) M^T with
    M = sum_k beta_k alpha_k^T (eq. 12-13) over every rotating motion (signs made
    consistent, module docstring), then translation by least squares (eq. 14).

    Parameters and errors as :func:`solve_tsai`; also raises :class:`DegenerateDataError`
    when the motions rotate about one axis only or no proper rotation relates them.
    """
    motions = _Motions(tcp_motion_stack, marker_motion_stack)

    def solve(subset: _Motions) -> FloatArray:
        return make_transform(_park_rotation(subset), np.zeros(3))

    rotation = _two_pass(motions, solve)[:3, :3]
    return make_transform(rotation, _translation(motions, rotation))


def _dual_parts(q: FloatArray, translation: FloatArray) -> FloatArray:
    """q' = 1/2 t q (Daniilidis eq. 6) for rotations q (K, 4) and translations (K, 3)."""
    t = np.concatenate([np.zeros((len(q), 1)), translation], axis=1)
    left_t, _ = quaternion_product_matrices(t)
    return as_float_array(0.5 * np.einsum("nij,nj->ni", left_t, q))


def _daniilidis_grams(motions: _Motions, length_mm: float) -> tuple[FloatArray, FloatArray]:
    """Gram matrices (8, 8) of the rotation rows and of the translation rows of eq. 31.

    Each motion gives six rows acting on z = [q; q']: the rotation rows
    [a - b, [a + b]x, 0, 0] and the translation rows [a' - b', [a' + b']x, a - b, [a + b]x]
    (vector parts of the dual quaternions, translations in units of ``length_mm``). The
    squared residual of z is z^T (G_rot + G_trans) z; working with the 8 x 8 Gram matrices
    keeps every later step independent of the number of motions.
    """
    qa_dual = _dual_parts(motions.q_a, motions.t_a / length_mm)
    qb_dual = _dual_parts(motions.q_b, motions.t_b / length_mm)
    a, a_d, b, b_d = motions.q_a[:, 1:], qa_dual[:, 1:], motions.q_b[:, 1:], qb_dual[:, 1:]
    rotation_rows = np.zeros((len(a), 3, 8))
    rotation_rows[:, :, 0] = a - b
    rotation_rows[:, :, 1:4] = skew(a + b)
    translation_rows = np.zeros((len(a), 3, 8))
    translation_rows[:, :, 0] = a_d - b_d
    translation_rows[:, :, 1:4] = skew(a_d + b_d)
    translation_rows[:, :, 4] = a - b
    translation_rows[:, :, 5:8] = skew(a + b)
    rotation_gram = np.einsum("nki,nkj->ij", rotation_rows, rotation_rows)
    translation_gram = np.einsum("nki,nkj->ij", translation_rows, translation_rows)
    return as_float_array(rotation_gram), as_float_array(translation_gram)


def _dual_given_rotation(gram: FloatArray, q: FloatArray) -> FloatArray:
    """The q' orthogonal to q minimising [q; q']^T gram [q; q'] (linear least squares)."""
    _, _, vt = np.linalg.svd(q[None, :])
    orthogonal = vt[1:].T  # (4, 3), columns spanning the complement of q
    normal = orthogonal.T @ gram[4:, 4:] @ orthogonal
    coefficients = np.linalg.lstsq(normal, -orthogonal.T @ gram[4:, :4] @ q, rcond=None)[0]
    return as_float_array(orthogonal @ coefficients)


def _daniilidis_dual_quaternion(
    rotation_gram: FloatArray, translation_gram: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """The unit q and the q' orthogonal to it that best solve eq. 31 (module docstring)."""
    gram = rotation_gram + translation_gram
    # the right singular vectors of eq. 31's matrix, smallest first, are the Gram's eigenvectors
    _, vectors = np.linalg.eigh(gram)
    v7, v8 = vectors[:, 1], vectors[:, 0]
    u1, v1, u2, v2 = v7[:4], v7[4:], v8[:4], v8[4:]
    # eq. 34-35: q = l1 u1 + l2 u2 unit and orthogonal to q' = l1 v1 + l2 v2; with s = l1 / l2,
    # a s^2 + b s + c = 0. Noise can leave that quadratic without a real root: then its vertex,
    # where the pencil comes closest to q . q' = 0, stands in for the roots.
    a, b, c = u1 @ v1, u1 @ v2 + u2 @ v1, u2 @ v2
    scale = max(abs(a), abs(b), abs(c), 1e-300)
    directions = [v7]  # l2 = 0: the root at infinity when a = 0
    if abs(a) > 1e-12 * scale:
        discriminant = b * b - 4.0 * a * c
        if discriminant >= 0.0:
            roots = [(-b + np.sqrt(discriminant)) / (2.0 * a), (-b - np.sqrt(discriminant)) / (2.0 * a)]
        else:
            roots = [-b / (2.0 * a)]
        directions += [s * v7 + v8 for s in roots]
    elif abs(b) > 1e-12 * scale:
        directions.append((-c / b) * v7 + v8)
    # the null vector of the rotation rows alone (they hold q only)
    directions.append(np.concatenate([np.linalg.eigh(rotation_gram[:4, :4])[1][:, 0], np.zeros(4)]))
    best: tuple[float, FloatArray, FloatArray] | None = None
    for direction in directions:
        norm = float(np.linalg.norm(direction[:4]))
        if not norm > 1e-8:
            continue
        q = direction[:4] / norm
        q_dual = _dual_given_rotation(gram, q)
        z = np.concatenate([q, q_dual])
        cost = float(z @ gram @ z)
        if best is None or cost < best[0]:
            best = (cost, q, q_dual)
    if best is None:  # unreachable: the rotation-rows candidate always has a unit q
        raise DegenerateDataError("Daniilidis: the motions do not determine the rotation")
    return best[1], best[2]


def _daniilidis(motions: _Motions, length_mm: float) -> FloatArray:
    grams = _daniilidis_grams(motions, length_mm)
    q, q_dual = _daniilidis_dual_quaternion(*grams)
    for _ in range(DANIILIDIS_REWEIGHTS):
        # two variance components: the rotation rows and the translation rows of eq. 31 get
        # weights that make their residuals equally large (feasible weighted least squares)
        z = np.concatenate([q, q_dual])
        rotation_ss, translation_ss = float(z @ grams[0] @ z), float(z @ grams[1] @ z)
        if not (rotation_ss > 0.0 and translation_ss > 0.0):
            break
        factor = float(np.clip(np.sqrt(translation_ss / rotation_ss), 1e-3, 1e3))
        if abs(np.log(factor)) < np.log(1.1):
            break
        length_mm *= factor
        grams = _daniilidis_grams(motions, length_mm)
        q, q_dual = _daniilidis_dual_quaternion(*grams)
    conj = q * np.array([1.0, -1.0, -1.0, -1.0])
    left_dual, _ = quaternion_product_matrices(q_dual)
    translation = 2.0 * (left_dual @ conj)[1:] * length_mm  # t = 2 q' q* (eq. 6), back in mm
    return make_transform(quaternion_wxyz_to_matrix(q), translation)


def solve_daniilidis(tcp_motion_stack: FloatArray, marker_motion_stack: FloatArray) -> FloatArray:
    """Daniilidis 1999 (dual quaternions); returns X = ``tcp_from_marker``.

    K. Daniilidis, "Hand-eye calibration using dual quaternions", Int. J. Robot. Res. 18(3):
    286-298, 1999. Rotation and translation together from the two smallest right singular
    vectors of the 6K x 8 system of eq. 31 over every rotating motion (signs made
    consistent, module docstring), combined by eq. 34-35.

    The published recipe fails on real data (OpenCV's DANIILIDIS lands 30 mm to 2.5 m off
    on the benchmarks in docs/methods.md, and eq. 34 may have no real root); here:

    * lengths enter eq. 31 in a unit that weighs its rotation rows (unitless) and translation
      rows alike: first the RMS translation of the motions, then rescaled until both kinds
      of rows leave residuals of the same size (at most :data:`DANIILIDIS_REWEIGHTS` times).
      The answer does not depend on the caller's length unit;
    * the candidates are the real roots of eq. 34 (or its vertex when it has none), the
      root at infinity (the second-smallest singular vector alone) and the null vector of
      the rotation rows alone; for
      each candidate q the dual part is the least-squares q' orthogonal to q, and the
      candidate with the smallest residual of eq. 31 wins.

    On exact data the residual is zero at X, so X is returned exactly.

    Parameters and errors as :func:`solve_tsai`.
    """
    motions = _Motions(tcp_motion_stack, marker_motion_stack)
    length_mm = characteristic_length_mm(motions.t_a, motions.t_b)
    return _two_pass(motions, lambda subset: _daniilidis(subset, length_mm))
