"""Points touched with a tracked pointer, by label: a small CSV of the pointer tip's positions.

Layout (the frame and the unit are in the column names, CONVENTIONS §3)::

    label,x_in_tracker_mm,y_in_tracker_mm,z_in_tracker_mm
    F-1,12.5,-40.2,-1510.3
    ...

``_in_reference_mm`` columns say the tip positions are in a reference marker's frame instead.
An optional fifth column, ``tip_accuracy_mm``, states the pointer tip's RMS 3-D accuracy at
each touch (``spacecal touch --pointer-tip-accuracy-mm``): a Type-B term the registration's
predicted error takes, as the FRE cannot show a tip error common to every touch.
Lines starting with ``#`` are comments. Each label appears once; the labels pair the points
with the fiducials of the image (:mod:`spacecal.registration.image_fiducials`).
"""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.core.text import quoted
from spacecal.core.units import METRES_BELOW_MM
from spacecal.io.atomic import write_text_atomic
from spacecal.io.csv_core import parse_number
from spacecal.io.text import read_text_file
from spacecal.records.needle_plan import MAX_TIP_ACCURACY_MM

#: The frames touched points may be given in.
TOUCHED_FRAMES = ("tracker", "reference")
MAX_TOUCHED_BYTES = 10 * 1024 * 1024


#: The optional column of the pointer tip's stated accuracy, mm.
TIP_ACCURACY_COLUMN = "tip_accuracy_mm"


def touched_columns(frame: str, with_tip_accuracy: bool = False) -> list[str]:
    """The header of a touched-points file in ``frame`` (with the tip accuracy column or not)."""
    return ["label", *(f"{axis}_in_{frame}_mm" for axis in "xyz")] + (
        [TIP_ACCURACY_COLUMN] if with_tip_accuracy else []
    )


@dataclass(frozen=True)
class TouchedPoints:
    """A touched-points file's content.

    Attributes
    ----------
    frame : str
        One of :data:`TOUCHED_FRAMES`.
    points : dict of str to numpy.ndarray, shape (3,)
        Label -> the pointer tip's position, mm, in the order touched.
    tip_accuracy_mm : float or None
        The largest stated tip accuracy of the touches (RMS 3-D, mm); None without the column.
    """

    frame: str
    points: dict[str, np.ndarray]
    tip_accuracy_mm: float | None = None


def read_touched_points(path: str | Path) -> tuple[str, dict[str, np.ndarray]]:
    """The frame of a touched-points file and its points: label -> position (3,), mm
    (:func:`read_touched_file` without the stated tip accuracy)."""
    touched = read_touched_file(path)
    return touched.frame, touched.points


def read_touched_file(path: str | Path) -> TouchedPoints:
    """A touched-points file: its frame, its points and the pointer tip's stated accuracy.

    Raises
    ------
    InvalidInputError
        Another header, a missing, repeated or empty label, a cell that is not a finite number,
        a tip accuracy that is negative or above :data:`MAX_TIP_ACCURACY_MM`, or points that
        look like metres; each one line naming the file and line.
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
    with_accuracy = bool(header) and header[-1] == TIP_ACCURACY_COLUMN
    frames = [frame for frame in TOUCHED_FRAMES if header == touched_columns(frame, with_accuracy)]
    if not frames:
        raise InvalidInputError(
            f"{path}: the header must be {','.join(touched_columns('tracker'))} "
            f"(or _in_reference_mm; optionally ,{TIP_ACCURACY_COLUMN}), got {quoted(','.join(header))}"
        )
    points: dict[str, np.ndarray] = {}
    accuracies: list[float] = []
    for number, row in rows[1:]:
        if len(row) != len(header):
            raise InvalidInputError(
                f"{path}: line {number}: {len(row)} cells where {len(header)} are expected"
            )
        label = row[0].strip()
        if not label:
            raise InvalidInputError(f"{path}: line {number}: no label")
        if label in points:
            raise InvalidInputError(f"{path}: line {number}: {quoted(label)} is touched twice")
        points[label] = np.array(
            [parse_number(cell.strip(), number, header[k + 1], path) for k, cell in enumerate(row[1:4])]
        )
        if with_accuracy:
            accuracy = parse_number(row[4].strip(), number, TIP_ACCURACY_COLUMN, path)
            if not 0.0 <= accuracy <= MAX_TIP_ACCURACY_MM:
                raise InvalidInputError(
                    f"{path}: line {number}: {TIP_ACCURACY_COLUMN} {accuracy:g} is not 0 to "
                    f"{MAX_TIP_ACCURACY_MM:g} mm"
                )
            accuracies.append(accuracy)
    if (
        frames[0] == "tracker"
        and points
        and float(np.median([np.linalg.norm(p) for p in points.values()])) < METRES_BELOW_MM
    ):
        # a tracker sees nothing within 20 mm of its origin: these are metres, not mm
        raise InvalidInputError(
            f"{path}: the points are within {METRES_BELOW_MM:g} mm of the origin: metres?"
        )
    return TouchedPoints(frames[0], points, max(accuracies) if accuracies else None)


def write_touched_points(
    path: str | Path,
    points: Mapping[str, np.ndarray],
    frame: str = "tracker",
    comments: Sequence[str] = (),
    tip_accuracy_mm: float | None = None,
) -> Path:
    """Write touched points (label -> position (3,), mm, in ``frame``) in the layout
    :func:`read_touched_points` reads, atomically; returns the path.

    Parameters
    ----------
    path : str or Path
    points : mapping of str to array_like, shape (3,)
        In the order touched.
    frame : str
        One of :data:`TOUCHED_FRAMES`.
    comments : sequence of str
        Lines written first, each as a ``#`` comment (where the points came from).
    tip_accuracy_mm : float, optional
        The pointer tip's stated RMS 3-D accuracy, mm, written in the ``tip_accuracy_mm``
        column of every row; no column if None.

    Raises
    ------
    InvalidInputError
        A tip accuracy that is not 0 to :data:`MAX_TIP_ACCURACY_MM` mm, another frame, no
        points, a label that is empty, starts with ``#`` or spans lines, a
        position that is not 3 finite numbers, or tracker points that look like metres.
    """
    if frame not in TOUCHED_FRAMES:
        raise InvalidInputError(f"touched points are in {' or '.join(TOUCHED_FRAMES)}, not {quoted(frame)}")
    if not points:
        raise InvalidInputError("no touched points to write")
    if tip_accuracy_mm is not None and not (
        np.isfinite(tip_accuracy_mm) and 0.0 <= tip_accuracy_mm <= MAX_TIP_ACCURACY_MM
    ):
        raise InvalidInputError(
            f"the pointer tip's accuracy must be 0 to {MAX_TIP_ACCURACY_MM:g} mm, got {tip_accuracy_mm}"
        )
    extra = [] if tip_accuracy_mm is None else [f"{tip_accuracy_mm:.4f}"]
    rows = []
    for label, point in points.items():
        text = str(label).strip()
        if not text or text.startswith("#") or any(c in text for c in "\r\n"):
            raise InvalidInputError(
                f"a touched point's label must be one line not starting with '#', got {quoted(str(label))}"
            )
        position = np.asarray(point, dtype=float)
        if position.shape != (3,) or not np.all(np.isfinite(position)):
            raise InvalidInputError(f"touched point {quoted(text)} is not 3 finite numbers (mm)")
        rows.append([text, *(f"{value:.4f}" for value in position), *extra])
    if (
        frame == "tracker"
        and float(np.median([np.linalg.norm(np.asarray(p, float)) for p in points.values()]))
        < METRES_BELOW_MM
    ):
        raise InvalidInputError(f"the points are within {METRES_BELOW_MM:g} mm of the tracker: metres?")
    out = io.StringIO()
    for comment in comments:
        for line in str(comment).splitlines() or [""]:
            out.write(f"# {line}\n")
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(touched_columns(frame, tip_accuracy_mm is not None))
    writer.writerows(rows)
    return write_text_atomic(out.getvalue(), path)
