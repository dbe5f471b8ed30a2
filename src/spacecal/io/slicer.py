"""3D Slicer: calibrations as ITK transform files that Slicer loads as linear transforms.

Conventions (the part that silently goes wrong):

* ITK files store *resampling* transforms in LPS: the matrix maps points from the parent
  frame to the child frame (``child_from_parent``), with x and y negated relative to RAS.
* Slicer shows a linear transform's *modelling* matrix in RAS (``parent_from_child``, its
  "To parent" matrix) and converts on load: ``to_parent_RAS = S inv(M_itk) S`` with
  ``S = diag(-1, -1, 1, 1)``.
* Tracker coordinates are not anatomical; SlicerIGT treats tracker millimetres as Slicer's
  RAS world as they arrive over OpenIGTLink, and we do the same. So a ``tracker_from_base``
  saved here appears in Slicer as a "BaseToTracker" transform whose matrix is exactly ours.

File layout::

    #Insight Transform File V1.0
    #Transform 0
    Transform: AffineTransform_double_3_3
    Parameters: m11 m12 m13 m21 m22 m23 m31 m32 m33 tx ty tz
    FixedParameters: 0 0 0

Reading takes the linear types ITK and the tools around Slicer write: the 12-parameter matrix
types (``AffineTransform``, ``MatrixOffsetTransformBase``, ``Rigid3DTransform``),
``Euler3DTransform`` (angles about x, y, z and a translation; rotation ``Rz Rx Ry``, or
``Rz Ry Rx`` when its fourth fixed parameter is 1) and ``VersorRigid3DTransform`` (the vector
part of a unit quaternion and a translation), each about the centre in ``FixedParameters``
(ITK's ``MatrixOffsetTransformBase``: offset = t + c - A c). A file holding more than one
transform (a composite, a list) is refused rather than composed, and so is a non-linear one.
The HDF5 form (``.h5``) is read with SimpleITK (the ``slicer`` extra).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from spacecal.core.errors import InvalidInputError, MissingExtraError
from spacecal.core.strict_numbers import parse_floats
from spacecal.core.text import quoted
from spacecal.geometry.anatomical import RAS_FROM_LPS
from spacecal.geometry.arrays import FloatArray
from spacecal.geometry.rotations import nearest_rotation
from spacecal.geometry.transforms import (
    NEARLY_RIGID_TOLERANCE,
    invert_transform,
    is_rigid_transform,
    make_transform,
)
from spacecal.io.atomic import write_text_atomic
from spacecal.io.text import read_text_file

__all__ = [
    "RAS_FROM_LPS",
    "read_slicer_rigid_transform",
    "read_slicer_transform",
    "write_slicer_transform",
]

HEADER = "#Insight Transform File V1.0"
TRANSFORM_TYPE = "AffineTransform_double_3_3"


def write_slicer_transform(parent_from_child, path: str | Path) -> Path:
    """Write ``parent_from_child`` (4, 4), mm, as an ITK transform file for Slicer.

    Slicer will show ``parent_from_child`` as the transform's "To parent" matrix.
    """
    matrix = np.asarray(parent_from_child, dtype=float)
    if matrix.shape != (4, 4) or not is_rigid_transform(matrix):
        raise InvalidInputError("a Slicer transform export needs a 4x4 rigid transform")
    itk = RAS_FROM_LPS @ invert_transform(matrix) @ RAS_FROM_LPS  # resampling, LPS
    parameters = list(itk[:3, :3].ravel()) + list(itk[:3, 3])
    path = Path(path)
    write_text_atomic(
        f"{HEADER}\n#Transform 0\nTransform: {TRANSFORM_TYPE}\n"
        f"Parameters: {' '.join(repr(float(v)) for v in parameters)}\nFixedParameters: 0 0 0\n",
        path,
    )
    return path


#: The 12-parameter types: a 3x3 matrix, row-major, then a translation.
MATRIX_TYPES = ("AffineTransform", "MatrixOffsetTransformBase", "Rigid3DTransform")
#: The 6-parameter rigid types: 3 rotation parameters, then a translation.
RIGID_TYPES = ("Euler3DTransform", "VersorRigid3DTransform")
#: Largest text transform file read (a linear transform is a few hundred bytes).
MAX_TRANSFORM_BYTES = 1024 * 1024


def _euler_rotation(angles_rad: FloatArray, zyx: bool) -> FloatArray:
    """ITK ``Euler3DTransform::ComputeMatrix``: ``Rz Rx Ry`` (or ``Rz Ry Rx`` when ``zyx``)."""
    cx, cy, cz = np.cos(angles_rad)
    sx, sy, sz = np.sin(angles_rad)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx if zyx else rz @ rx @ ry


def _versor_rotation(vector: FloatArray, where: str) -> FloatArray:
    """ITK ``Versor``: the unit quaternion whose vector part is ``vector`` (w >= 0)."""
    norm_sq = float(vector @ vector)
    if norm_sq > 1.0 + 1e-9:
        raise InvalidInputError(
            f"{where}: a versor's vector part must have length at most 1, got {norm_sq**0.5:.6g}"
        )
    x, y, z = vector
    w = np.sqrt(max(0.0, 1.0 - norm_sq))
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _itk_matrix(kind: str, parameters: FloatArray, fixed: FloatArray, where: str) -> FloatArray:
    """The ITK (resampling, LPS) 4x4 of one transform of a type in MATRIX_TYPES or RIGID_TYPES."""
    family = kind.rsplit("_", 3)[0]
    if family in MATRIX_TYPES:
        count = 12
    elif family in RIGID_TYPES:
        count = 6
    else:
        raise InvalidInputError(
            f"{where}: transform type {quoted(kind)} is not a 3-D affine (linear) transform; "
            "spacecal reads linear transforms only"
        )
    if not kind.endswith("_3_3"):
        raise InvalidInputError(f"{where}: transform type {quoted(kind)} is not a 3-D affine transform")
    centre_count = 4 if family == "Euler3DTransform" else 3
    if parameters.size != count or fixed.size not in (3, centre_count):
        raise InvalidInputError(
            f"{where}: a {family} has {count} Parameters and 3 FixedParameters, got "
            f"{parameters.size} and {fixed.size}"
        )
    if family in MATRIX_TYPES:
        rotation = parameters[:9].reshape(3, 3)
    elif family == "Euler3DTransform":
        rotation = _euler_rotation(parameters[:3], zyx=fixed.size == 4 and fixed[3] != 0)
    else:
        rotation = _versor_rotation(parameters[:3], where)
    centre = fixed[:3]
    itk = np.eye(4)
    itk[:3, :3] = rotation
    # ITK's offset includes the centre of rotation: t' = t + c - A c
    itk[:3, 3] = parameters[count - 3 :] + centre - rotation @ centre
    return itk


def _text_blocks(path: Path) -> list[dict[str, str]]:
    """The ``Transform``/``Parameters``/``FixedParameters`` fields of each transform in the file."""
    text = read_text_file(path, "transform", max_bytes=MAX_TRANSFORM_BYTES)
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    if not lines or lines[0] != HEADER:
        raise InvalidInputError(f"{path}: not an ITK transform file (first line must be '{HEADER}')")
    blocks: list[dict[str, str]] = []
    for line in lines[1:]:
        if line.startswith("#"):
            continue
        key, _, value = line.partition(":")
        key = key.strip()
        if key == "Transform":
            blocks.append({})
        if not blocks:
            raise InvalidInputError(f"{path}: {quoted(key)} before any 'Transform:' line")
        blocks[-1][key] = value.strip()
    # a composite's first entry is the composite itself; its components follow
    if blocks and blocks[0].get("Transform", "").startswith("CompositeTransform"):
        blocks = blocks[1:]
    return blocks


def _read_text_itk(path: Path) -> FloatArray:
    blocks = _text_blocks(path)
    if len(blocks) != 1:
        raise InvalidInputError(
            f"{path}: holds {len(blocks)} transforms; spacecal reads one linear transform "
            "(harden the transforms in Slicer and save the result)"
        )
    fields = blocks[0]
    try:
        parameters = parse_floats(fields.get("Parameters", ""))
        fixed = parse_floats(fields.get("FixedParameters", "0 0 0"))
    except ValueError:
        raise InvalidInputError(
            f"{path}: Parameters and FixedParameters must be plain decimal numbers"
        ) from None
    if not (np.all(np.isfinite(parameters)) and np.all(np.isfinite(fixed))):
        raise InvalidInputError(f"{path}: a transform parameter is not finite")
    return _itk_matrix(fields.get("Transform", ""), parameters, fixed, str(path))


def _read_hdf5_itk(path: Path) -> FloatArray:
    """An ITK HDF5 transform file, through SimpleITK; one linear transform only."""
    try:
        import SimpleITK as sitk
    except ImportError as exc:
        raise MissingExtraError(
            f"{path}: reading .h5 transform files needs SimpleITK: pip install 'spacecal[slicer]'"
        ) from exc
    try:
        transform = sitk.ReadTransform(str(path))
    except RuntimeError:
        raise InvalidInputError(f"{path}: not an ITK transform file SimpleITK reads") from None
    if transform.GetTransformEnum() == sitk.sitkComposite:
        composite = sitk.CompositeTransform(transform)
        count = composite.GetNumberOfTransforms()
        if count != 1:
            raise InvalidInputError(
                f"{path}: holds {count} transforms; spacecal reads one linear transform "
                "(harden the transforms in Slicer and save the result)"
            )
        transform = composite.GetNthTransform(0)
    if transform.GetDimension() != 3 or not transform.IsLinear():
        raise InvalidInputError(
            f"{path}: transform type {quoted(transform.GetName())} is not a 3-D affine (linear) transform; "
            "spacecal reads linear transforms only"
        )
    # a linear transform is its images of the origin and the unit vectors, whatever its type
    origin = np.array(transform.TransformPoint((0.0, 0.0, 0.0)))
    itk = np.eye(4)
    for axis in range(3):
        unit = np.zeros(3)
        unit[axis] = 1.0
        itk[:3, axis] = np.array(transform.TransformPoint(tuple(unit))) - origin
    itk[:3, 3] = origin
    if not np.all(np.isfinite(itk)):
        raise InvalidInputError(f"{path}: a transform parameter is not finite")
    return itk


def read_slicer_transform(path: str | Path) -> np.ndarray:
    """Read an ITK linear transform file as the ``parent_from_child`` Slicer shows (RAS, mm).

    Parameters
    ----------
    path : str or Path
        ``.tfm`` or ``.txt`` (ITK's text form), or ``.h5`` (its HDF5 form, with SimpleITK).

    Returns
    -------
    numpy.ndarray, shape (4, 4)
        Slicer's "To parent" matrix: maps the child's coordinates into the parent's, RAS, mm.
        Affine: scaled or sheared matrices are returned as they are
        (:func:`read_slicer_rigid_transform` refuses them).
    """
    path = Path(path)
    if not path.is_file():
        raise InvalidInputError(f"{path}: no such transform file")
    itk = _read_hdf5_itk(path) if path.suffix.lower() in (".h5", ".hdf5") else _read_text_itk(path)
    if abs(np.linalg.det(itk[:3, :3])) < 1e-12:
        raise InvalidInputError(f"{path}: the transform is singular (it flattens space), not a pose")
    # the full inverse: an affine file may be scaled or sheared (a rigid-only inverse would
    # silently turn a scale s into 1/s)
    return np.linalg.inv(RAS_FROM_LPS @ itk @ RAS_FROM_LPS)


def read_slicer_rigid_transform(path: str | Path) -> np.ndarray:
    """:func:`read_slicer_transform`, refused unless rigid; its rotation made exactly orthonormal.

    A file written with few decimals (or in single precision) is a rotation only to its last
    digit; a matrix off by more than :data:`~spacecal.geometry.transforms.NEARLY_RIGID_TOLERANCE`
    is scaled, sheared or mirrored, and refused in one line.
    """
    parent_from_child = read_slicer_transform(path)
    rotation = parent_from_child[:3, :3]
    off = max(
        float(np.max(np.abs(rotation.T @ rotation - np.eye(3)))), abs(float(np.linalg.det(rotation)) - 1.0)
    )
    if off > NEARLY_RIGID_TOLERANCE:
        raise InvalidInputError(
            f"{path}: the transform is not rigid (its rotation is off by {off:.3g}: scaled, sheared or "
            "mirrored); a registration must be a rotation and a translation"
        )
    return make_transform(nearest_rotation(rotation), parent_from_child[:3, 3])
