"""Points touched with a tracked pointer, by label: a small CSV of the pointer tip's positions.

Layout (the frame and the unit are in the column names, CONVENTIONS §3)::

    label,x_in_tracker_mm,y_in_tracker_mm,z_in_tracker_mm
    F-1,12.5,-40.2,-1510.3
    ...

``_in_reference_mm`` columns say the tip positions are in a reference marker's frame instead.
Lines starting with ``#`` are comments. Each label appears once; the labels pair the points
with the fiducials of the image (:mod:`spacecal.registration.image_fiducials`).
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.core.text import quoted
from spacecal.core.units import METRES_BELOW_MM
from spacecal.io.csv_core import parse_number
from spacecal.io.text import read_text_file

#: The frames touched points may be given in.
TOUCHED_FRAMES = ("tracker", "reference")
MAX_TOUCHED_BYTES = 10 * 1024 * 1024


def touched_columns(frame: str) -> list[str]:
    """The header of a touched-points file in ``frame``."""
    return ["label", *(f"{axis}_in_{frame}_mm" for axis in "xyz")]


def read_touched_points(path: str | Path) -> tuple[str, dict[str, np.ndarray]]:
    """The frame of a touched-points file and its points: label -> position (3,), mm.

    Raises
    ------
    InvalidInputError
        Another header, a missing, repeated or empty label, a cell that is not a finite number,
        or points that look like metres; each one line naming the file and line.
    """
    path = Path(path)
    text = read_text_file(path, "touched points", max_bytes=MAX_TOUCHED_BYTES)
    rows = [
        (number, row)
        for number, row in enumerate(csv.reader(io.StringIO(text)), start=1)
        if row and not row[0].lstrip().startswith("#")
    ]
    if not rows:
        raise InvalidInputError(f"{path}: an empty touched-points file")
    header = [cell.strip() for cell in rows[0][1]]
    frames = [frame for frame in TOUCHED_FRAMES if header == touched_columns(frame)]
    if not frames:
        raise InvalidInputError(
            f"{path}: the header must be {','.join(touched_columns('tracker'))} "
            f"(or _in_reference_mm), got {quoted(','.join(header))}"
        )
    points: dict[str, np.ndarray] = {}
    for number, row in rows[1:]:
        if len(row) != 4:
            raise InvalidInputError(f"{path}: line {number}: {len(row)} cells where 4 are expected")
        label = row[0].strip()
        if not label:
            raise InvalidInputError(f"{path}: line {number}: no label")
        if label in points:
            raise InvalidInputError(f"{path}: line {number}: {quoted(label)} is touched twice")
        points[label] = np.array(
            [parse_number(cell.strip(), number, header[k + 1], path) for k, cell in enumerate(row[1:])]
        )
    if (
        frames[0] == "tracker"
        and points
        and float(np.median([np.linalg.norm(p) for p in points.values()])) < METRES_BELOW_MM
    ):
        # a tracker sees nothing within 20 mm of its origin: these are metres, not mm
        raise InvalidInputError(
            f"{path}: the points are within {METRES_BELOW_MM:g} mm of the origin: metres?"
        )
    return frames[0], points
