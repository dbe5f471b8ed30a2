"""The two anatomical coordinate conventions of image space: LPS and RAS.

DICOM, ITK and the files 3D Slicer writes give image coordinates in LPS (x to the patient's
left, y posterior, z superior); Slicer's world is RAS (x right, y anterior, z superior). The
same point has its x and y negated from one to the other, so the map is a reflection and its
own inverse (Slicer documentation, "Coordinate systems").
"""

from __future__ import annotations

import numpy as np

from spacecal.geometry.arrays import ArrayLike, FloatArray, as_float_array

#: ``image_ras_from_image_lps`` (4, 4), equal to its inverse ``image_lps_from_image_ras``.
RAS_FROM_LPS: FloatArray = as_float_array(np.diag([-1.0, -1.0, 1.0, 1.0]))
RAS_FROM_LPS.setflags(write=False)


def flip_lps_ras(points: ArrayLike) -> FloatArray:
    """Points (..., 3) given in LPS as RAS, or in RAS as LPS (x and y negated), mm."""
    flipped = np.array(points, dtype=float)
    flipped[..., :2] *= -1.0
    return as_float_array(flipped)
