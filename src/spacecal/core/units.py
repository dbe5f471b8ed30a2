"""Units: millimetres and radians inside; conversions and plausibility checks at the edges."""

from __future__ import annotations

import numpy as np

from spacecal.core.errors import InvalidInputError

MM_PER_M = 1000.0

#: A stack of poses whose median translation is below this (mm) may be in metres: no robot TCP
#: or tracked marker is within 20 mm of its frame's origin in use.
METRES_BELOW_MM = 20.0
#: A stack of poses whose median translation is above this (mm) may have been scaled by 1000
#: twice: no robot reaches, nor tracker sees, 20 m.
MILLIMETRES_TWICE_ABOVE_MM = 20_000.0


def metres_to_mm(value_m):
    """Convert metres to millimetres (arrays welcome)."""
    return np.asarray(value_m, dtype=float) * MM_PER_M


def mm_to_metres(value_mm):
    """Convert millimetres to metres (arrays welcome)."""
    return np.asarray(value_mm, dtype=float) / MM_PER_M


def check_lengths_in_mm(values_mm, what: str, smallest_plausible_extent_mm: float = 5.0) -> None:
    """Raise if lengths that must be millimetres look like metres.

    A robot's TCP positions or a tracker's marker positions span tens to hundreds of
    millimetres; read as metres the same data spans less than a few units. A 1.3 m reach
    read as 1.3 mm is the classic silent failure, so we refuse it.

    Parameters
    ----------
    values_mm : array_like, shape (N, 3)
        Positions that should be in mm.
    what : str
        Name used in the error message (e.g. the column names).
    smallest_plausible_extent_mm : float
        If every coordinate's magnitude is below this, the data is taken to be metres.
    """
    values = np.asarray(values_mm, dtype=float)
    if values.size == 0:
        return
    largest = float(np.max(np.abs(values)))
    if largest < smallest_plausible_extent_mm:
        raise InvalidInputError(
            f"{what} look like metres (largest magnitude {largest:.3g}); "
            "spacecal expects millimetres: multiply by 1000"
        )
