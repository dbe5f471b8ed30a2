"""Array type aliases for annotations across the package.

``ArrayLike`` is what a public function accepts (lists, tuples, arrays); ``FloatArray`` is what
it returns: a float64 array whose shape, frames and units the docstring states.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.intp]
#: Rows picked out of a stack: indices or a boolean mask.
IndexArray = NDArray[np.intp] | NDArray[np.bool_]

__all__ = ["ArrayLike", "BoolArray", "FloatArray", "IndexArray", "IntArray", "as_float_array"]


def as_float_array(value: ArrayLike) -> FloatArray:
    """``value`` as a float64 array, without a copy if it already is one.

    Also how results of untyped calls (scipy, ``np.einsum``) get their type.
    """
    return np.asarray(value, dtype=np.float64)
