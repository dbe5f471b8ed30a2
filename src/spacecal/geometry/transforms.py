"""Rigid transforms as 4x4 homogeneous matrices, and conversions between rotation forms.

All functions accept a single transform, shape (4, 4), or a stack, shape (N, 4, 4).
Translations are in millimetres. Quaternions are ``wxyz`` (scalar first, as NDI reports
them) unless a name says ``xyzw`` (scipy's order).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from spacecal.core.errors import InvalidInputError
from spacecal.geometry.arrays import ArrayLike, FloatArray, as_float_array
from spacecal.geometry.rotations import mean_rotation

#: Default tolerance of :func:`check_transform`: largest ``|R^T R - I|`` and ``|det R - 1|``.
RIGID_ATOL = 1e-6

#: Tolerance for matrices measured by devices or read from text files, which carry about six
#: significant digits (NDI's and scikit-surgery's pose files, for instance); estimators check
#: their inputs with it.
MEASURED_TRANSFORM_ATOL = 1e-4


def _as_float_array(value: ArrayLike, name: str) -> FloatArray:
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise InvalidInputError(f"{name}: not an array of numbers ({error})") from None


def check_transform(
    matrix: ArrayLike,
    name: str = "transform",
    *,
    stack: bool = False,
    allow_missing: bool = False,
    atol: float = RIGID_ATOL,
) -> FloatArray:
    """Check that ``matrix`` is a proper rigid transform (or a stack of them) and return it.

    Modelled on pytransform3d's ``check_transform``: one call at a public entry point turns
    a malformed input into one readable line instead of a wrong answer later.

    Parameters
    ----------
    matrix : array_like, shape (4, 4), or (N, 4, 4) with ``stack=True``
        Homogeneous transform(s), mm.
    name : str
        How the caller calls it (e.g. ``"tracker_from_base"``); starts the error message.
    stack : bool
        Expect a stack (N, 4, 4) instead of a single (4, 4).
    allow_missing : bool
        In a stack, rows that are entirely NaN pass (the package's mark for a frame where the
        marker was not seen); a partly NaN or infinite row is still an error.
    atol : float
        Largest accepted entry of ``|R^T R - I|`` and ``|det R - 1|``; the bottom row must be
        0 0 0 1 to the same tolerance.

    Returns
    -------
    numpy.ndarray of float64, the same shape
        A new array if the input was not already float64.

    Raises
    ------
    InvalidInputError
        One line naming ``name``, the shape it got and what is wrong: not (4, 4) /
        (N, 4, 4), non-finite values, a rotation that is not orthonormal or has det -1 (a
        reflection), or a bottom row other than 0 0 0 1.
    """
    m = _as_float_array(matrix, name)
    expected = "(N, 4, 4)" if stack else "(4, 4)"
    if (m.ndim != (3 if stack else 2)) or m.shape[-2:] != (4, 4):
        raise InvalidInputError(f"{name}: expected shape {expected}, got {m.shape}")
    rows = m.reshape(-1, 4, 4)
    finite = np.all(np.isfinite(rows), axis=(1, 2))
    if allow_missing and stack:
        missing = np.all(np.isnan(rows), axis=(1, 2))
    else:
        missing = np.zeros(len(rows), dtype=bool)
    bad = np.flatnonzero(~finite & ~missing)
    if len(bad):
        hint = " (only whole rows may be NaN)" if allow_missing and stack else ""
        raise InvalidInputError(
            f"{_located(name, m.shape, int(bad[0]), stack)}: non-finite values (NaN or infinite){hint}"
        )
    present = rows[finite]
    bottom_error = np.max(np.abs(present[:, 3, :] - [0.0, 0.0, 0.0, 1.0]), axis=1, initial=0.0)
    bad = np.flatnonzero(bottom_error > atol)
    if len(bad):
        index = int(np.flatnonzero(finite)[bad[0]])
        raise InvalidInputError(
            f"{_located(name, m.shape, index, stack)}: bottom row is not 0 0 0 1 "
            f"(got {np.array2string(rows[index, 3], precision=6)})"
        )
    rotation = present[:, :3, :3]
    gram_error = np.max(np.abs(np.swapaxes(rotation, 1, 2) @ rotation - np.eye(3)), axis=(1, 2), initial=0.0)
    bad = np.flatnonzero(gram_error > atol)
    if len(bad):
        index = int(np.flatnonzero(finite)[bad[0]])
        raise InvalidInputError(
            f"{_located(name, m.shape, index, stack)}: rotation block is not orthonormal "
            f"(max |R^T R - I| = {gram_error[bad[0]]:.2g} > {atol:g})"
        )
    determinant = np.linalg.det(rotation) if len(rotation) else np.ones(0)
    bad = np.flatnonzero(np.abs(determinant - 1.0) > atol)
    if len(bad):
        index = int(np.flatnonzero(finite)[bad[0]])
        raise InvalidInputError(
            f"{_located(name, m.shape, index, stack)}: rotation has det {determinant[bad[0]]:+.3g}, "
            "not +1 (a reflection: mirrored axes or a left-handed frame)"
        )
    return m


def _located(name: str, shape: tuple[int, ...], index: int, stack: bool) -> str:
    return f"{name} {shape}, matrix {index}" if stack else f"{name} {shape}"


def check_points(points: ArrayLike, name: str = "points") -> FloatArray:
    """Check that ``points`` is an (N, 3) array of finite coordinates and return it as float64.

    Parameters
    ----------
    points : array_like, shape (N, 3)
        Points, one per row, mm.
    name : str
        How the caller calls them (e.g. ``"points_in_source"``); starts the error message.

    Raises
    ------
    InvalidInputError
        One line naming ``name``, the shape it got and what is wrong.
    """
    p = _as_float_array(points, name)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InvalidInputError(f"{name}: expected shape (N, 3), got {p.shape}")
    bad = np.flatnonzero(~np.all(np.isfinite(p), axis=1))
    if len(bad):
        raise InvalidInputError(f"{name} {p.shape}, row {bad[0]}: non-finite coordinates (NaN or infinite)")
    return p


def make_transform(rotation: ArrayLike, translation_mm: ArrayLike) -> FloatArray:
    """Build homogeneous transforms from rotations and translations.

    Parameters
    ----------
    rotation : array_like, shape (3, 3) or (N, 3, 3)
    translation_mm : array_like, shape (3,) or (N, 3)

    Returns
    -------
    numpy.ndarray, shape (4, 4) or (N, 4, 4)
    """
    rotation = np.asarray(rotation, dtype=float)
    translation_mm = np.asarray(translation_mm, dtype=float)
    shape = np.broadcast_shapes(rotation.shape[:-2], translation_mm.shape[:-1])
    out = np.zeros(shape + (4, 4))
    out[..., :3, :3] = rotation
    out[..., :3, 3] = translation_mm
    out[..., 3, 3] = 1.0
    return out


def invert_transform(a_from_b: ArrayLike) -> FloatArray:
    """Invert rigid transforms exactly (R^T, -R^T t): ``b_from_a = invert_transform(a_from_b)``.

    Parameters
    ----------
    a_from_b : array_like, shape (4, 4) or (N, 4, 4)
    """
    a_from_b = np.asarray(a_from_b, dtype=float)
    rotation_t = np.swapaxes(a_from_b[..., :3, :3], -1, -2)
    translation = -np.einsum("...ij,...j->...i", rotation_t, a_from_b[..., :3, 3])
    return make_transform(rotation_t, translation)


def apply_transform(a_from_b: ArrayLike, points_in_b: ArrayLike) -> FloatArray:
    """Map points given in frame b into frame a.

    Parameters
    ----------
    a_from_b : array_like, shape (4, 4) or (N, 4, 4)
    points_in_b : array_like, shape (3,), (M, 3), or (N, 3) paired with a stack
        With a stack, point n goes through transform n only; to place the same points by
        every transform of a stack use :func:`transform_points_by_stack`.

    Returns
    -------
    numpy.ndarray
        ``points_in_a`` with the broadcast shape of the inputs.
    """
    a_from_b = np.asarray(a_from_b, dtype=float)
    points_in_b = np.asarray(points_in_b, dtype=float)
    if a_from_b.ndim == 2:
        return as_float_array(points_in_b @ a_from_b[:3, :3].T + a_from_b[:3, 3])
    return as_float_array(np.einsum("nij,nj->ni", a_from_b[:, :3, :3], points_in_b) + a_from_b[:, :3, 3])


def transform_points_by_stack(a_from_b_stack: ArrayLike, points_in_b: ArrayLike) -> FloatArray:
    """Place the same model points by each of N poses: every point through every transform.

    This is how a marker's sphere centres (given once, in the marker frame) appear at each
    of N measured or predicted poses. Unlike :func:`apply_transform` with a stack, the
    points are not paired with the transforms: all of them go through each one.

    Parameters
    ----------
    a_from_b_stack : array_like, shape (N, 4, 4)
        Poses of frame b in frame a, mm.
    points_in_b : array_like, shape (K, 3) or (3,)
        Model points in frame b, mm.

    Returns
    -------
    numpy.ndarray, shape (N, K, 3) or (N, 3)
        ``points_in_a``: row n holds the points placed by transform n (one point per row if
        a single point (3,) was given).
    """
    a_from_b_stack = np.asarray(a_from_b_stack, dtype=float)
    points_in_b = np.asarray(points_in_b, dtype=float)
    if points_in_b.ndim == 1:
        return as_float_array(
            np.einsum("nij,j->ni", a_from_b_stack[:, :3, :3], points_in_b) + a_from_b_stack[:, :3, 3]
        )
    rotated = np.einsum("nij,kj->nki", a_from_b_stack[:, :3, :3], points_in_b)
    return as_float_array(rotated + a_from_b_stack[:, None, :3, 3])


def interpolate_transforms(
    start_a_from_b: ArrayLike, end_a_from_b: ArrayLike, fraction: ArrayLike
) -> FloatArray:
    """Transforms part-way from ``start`` to ``end``: position linearly, rotation along the geodesic.

    The rotation turns about the fixed axis of the relative rotation ``R_start^T R_end`` at a
    constant rate (slerp, expressed in the moving frame), so ``fraction`` 0 gives ``start``,
    1 gives ``end``. A UR ``movel`` moves its TCP this way; it is also how a pose is
    interpolated between two timestamps.

    Parameters
    ----------
    start_a_from_b, end_a_from_b : array_like, shape (4, 4) or (N, 4, 4)
        The end poses, mm; stacks are interpolated pairwise.
    fraction : array_like, shape (M,), or (N,) paired with stacks
        Where along the way, usually in [0, 1].

    Returns
    -------
    numpy.ndarray, shape (M, 4, 4) or (N, 4, 4)
    """
    start = np.asarray(start_a_from_b, dtype=float)
    end = np.asarray(end_a_from_b, dtype=float)
    fraction = np.asarray(fraction, dtype=float)
    relative = matrix_to_rotvec(np.swapaxes(start[..., :3, :3], -1, -2) @ end[..., :3, :3])
    rotation = start[..., :3, :3] @ rotvec_to_matrix(fraction[..., None] * relative)
    position = start[..., :3, 3] + fraction[..., None] * (end[..., :3, 3] - start[..., :3, 3])
    return make_transform(rotation, position)


def rotation_part(transform: ArrayLike) -> FloatArray:
    """The (…, 3, 3) rotation block of transforms."""
    return np.asarray(transform, dtype=float)[..., :3, :3]


def translation_part(transform: ArrayLike) -> FloatArray:
    """The (…, 3) translation column of transforms, in mm."""
    return np.asarray(transform, dtype=float)[..., :3, 3]


def quaternion_wxyz_to_matrix(quaternion_wxyz: ArrayLike) -> FloatArray:
    """Rotation matrices from unit quaternions, scalar first.

    Parameters
    ----------
    quaternion_wxyz : array_like, shape (4,) or (N, 4)
        Need not be exactly unit; scipy normalises. Callers that must reject
        non-unit input check it first (as the recording readers in :mod:`spacecal.io`
        do: :mod:`spacecal.io.csv_core`).
    """
    q = np.asarray(quaternion_wxyz, dtype=float)
    return as_float_array(Rotation.from_quat(np.roll(q, -1, axis=-1)).as_matrix())


def matrix_to_quaternion_wxyz(rotation: ArrayLike) -> FloatArray:
    """Unit quaternions, scalar first and non-negative, from rotation matrices (…, 3, 3)."""
    q_xyzw = Rotation.from_matrix(np.asarray(rotation, dtype=float)).as_quat(canonical=True)
    return np.roll(q_xyzw, 1, axis=-1)


def rotvec_to_matrix(rotation_vector: ArrayLike) -> FloatArray:
    """Rotation matrices from rotation vectors (axis times angle in radians), (…, 3)."""
    return as_float_array(Rotation.from_rotvec(np.asarray(rotation_vector, dtype=float)).as_matrix())


def matrix_to_rotvec(rotation: ArrayLike) -> FloatArray:
    """Rotation vectors (axis times angle in radians) from rotation matrices (…, 3, 3)."""
    return as_float_array(Rotation.from_matrix(np.asarray(rotation, dtype=float)).as_rotvec())


def transform_from_position_quaternion(position_mm: ArrayLike, quaternion_wxyz: ArrayLike) -> FloatArray:
    """Transforms from positions (…, 3) in mm and ``wxyz`` quaternions (…, 4)."""
    return make_transform(quaternion_wxyz_to_matrix(quaternion_wxyz), position_mm)


def transform_to_position_quaternion(transform: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Split transforms into positions (…, 3) in mm and ``wxyz`` quaternions (…, 4)."""
    return translation_part(transform).copy(), matrix_to_quaternion_wxyz(rotation_part(transform))


def axis_angle_transform(
    axis: ArrayLike, angle_rad: ArrayLike, translation_mm: ArrayLike = (0.0, 0.0, 0.0)
) -> FloatArray:
    """A transform rotating by ``angle_rad`` about unit ``axis`` (3,), then translating."""
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    angle = np.asarray(angle_rad, dtype=float)
    return make_transform(rotvec_to_matrix(angle[..., None] * axis), translation_mm)


def is_rigid_transform(transform: ArrayLike, atol: float = 1e-6) -> bool:
    """True if every matrix is a proper rigid transform (orthonormal, det +1, last row 0 0 0 1)."""
    t = np.asarray(transform, dtype=float)
    if t.shape[-2:] != (4, 4) or not np.all(np.isfinite(t)):
        return False
    r = t[..., :3, :3]
    eye = np.broadcast_to(np.eye(3), r.shape)
    orthonormal = np.allclose(np.swapaxes(r, -1, -2) @ r, eye, atol=atol)
    proper = np.allclose(np.linalg.det(r), 1.0, atol=atol)
    last_row = np.allclose(t[..., 3, :], [0.0, 0.0, 0.0, 1.0], atol=atol)
    return bool(orthonormal and proper and last_row)


#: How far a pose's rotation may be from a rotation (the largest entry of ``R^T R - I``, and
#: ``abs(det R - 1)``) and still be one: single-precision matrices and 6-decimal files are off by
#: ~1e-6; a scaled, sheared or mirrored matrix by 1e-2 and more.
NEARLY_RIGID_TOLERANCE = 1e-3


def check_nearly_rigid(stack: ArrayLike, what: str = "a transform") -> None:
    """Refuse transforms (N, 4, 4) whose rotation is not nearly one (scaled, sheared or mirrored
    by more than :data:`NEARLY_RIGID_TOLERANCE`); rows holding NaN (frames without a valid pose)
    are passed over.

    Raises
    ------
    InvalidInputError
        Naming ``what``, the first such frame (1-based) and how far it is off.
    """
    stack = np.asarray(stack, dtype=float)
    finite = np.all(np.isfinite(stack.reshape(len(stack), -1)), axis=1)
    rotations = stack[finite, :3, :3]
    off = np.max(np.abs(np.swapaxes(rotations, -1, -2) @ rotations - np.eye(3)), axis=(-2, -1), initial=0.0)
    off = np.maximum(off, np.abs(np.linalg.det(rotations) - 1.0))
    bad = np.flatnonzero(off > NEARLY_RIGID_TOLERANCE)
    if bad.size:
        frame = int(np.flatnonzero(finite)[bad[0]]) + 1
        more = f" (and {bad.size - 1} more)" if bad.size > 1 else ""
        raise InvalidInputError(
            f"{what}: frame {frame}{more} is not a rigid transform (its rotation is off by "
            f"{off[bad[0]]:.3g}: scaled, sheared or mirrored); a pose must be a rotation and a translation"
        )


def orthonormalize_transforms(stack: ArrayLike, what: str = "a transform") -> FloatArray:
    """Transforms (N, 4, 4) with each rotation replaced by its nearest proper rotation.

    Trackers and robots often write single-precision matrices that are not quite
    orthonormal; rows holding NaN (frames without a valid pose) stay NaN. A matrix that is
    not nearly a rotation is not a pose, and is refused (:func:`check_nearly_rigid`), not made
    into one.
    """
    from spacecal.geometry.rotations import nearest_rotation

    check_nearly_rigid(stack, what)
    stack = np.asarray(stack, dtype=float)
    out = np.full_like(stack, np.nan)
    finite = np.all(np.isfinite(stack.reshape(len(stack), -1)), axis=1)
    out[finite] = make_transform(nearest_rotation(stack[finite, :3, :3]), stack[finite, :3, 3])
    return out


def mean_transform(poses: ArrayLike) -> FloatArray:
    """The mean (4, 4) of rigid transforms (K, 4, 4): the mean translation (mm) and the chordal
    mean rotation (:func:`~spacecal.geometry.rotations.mean_rotation`)."""
    stack = as_float_array(poses)
    return make_transform(mean_rotation(stack[:, :3, :3]), stack[:, :3, 3].mean(axis=0))
