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
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.core.strict_numbers import parse_floats
from spacecal.core.text import quoted
from spacecal.geometry.transforms import invert_transform, is_rigid_transform
from spacecal.io.atomic import write_text_atomic
from spacecal.io.text import read_text_file

RAS_FROM_LPS = np.diag([-1.0, -1.0, 1.0, 1.0])
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


def read_slicer_transform(path: str | Path) -> np.ndarray:
    """Read an ITK affine transform file back as the ``parent_from_child`` Slicer shows (RAS, mm)."""
    path = Path(path)
    if not path.is_file():
        raise InvalidInputError(f"{path}: no such transform file")
    lines = [line.strip() for line in read_text_file(path, "transform").splitlines() if line.strip()]
    if not lines or lines[0] != HEADER:
        raise InvalidInputError(f"{path}: not an ITK transform file (first line must be '{HEADER}')")
    fields = dict(line.split(":", 1) for line in lines[1:] if ":" in line and not line.startswith("#"))
    kind = fields.get("Transform", "").strip()
    if kind not in (TRANSFORM_TYPE, "AffineTransform_float_3_3", "MatrixOffsetTransformBase_double_3_3"):
        raise InvalidInputError(f"{path}: transform type {quoted(kind)} is not a 3-D affine transform")
    try:
        parameters = parse_floats(fields.get("Parameters", ""))
        fixed = parse_floats(fields.get("FixedParameters", "0 0 0"))
    except ValueError:
        raise InvalidInputError(
            f"{path}: Parameters and FixedParameters must be plain decimal numbers"
        ) from None
    if parameters.size != 12 or fixed.size != 3:
        raise InvalidInputError(f"{path}: expected 12 Parameters and 3 FixedParameters")
    if not (np.all(np.isfinite(parameters)) and np.all(np.isfinite(fixed))):
        raise InvalidInputError(f"{path}: a transform parameter is not finite")
    itk = np.eye(4)
    itk[:3, :3] = parameters[:9].reshape(3, 3)
    # ITK's offset includes the centre of rotation: t' = t + c - A c
    itk[:3, 3] = parameters[9:] + fixed - itk[:3, :3] @ fixed
    return invert_transform(RAS_FROM_LPS @ itk @ RAS_FROM_LPS)
