"""PLUS device-set configuration files: coordinate definitions and phantom landmarks (read),
and a ``CoordinateDefinitions`` transform for a calibration (write).

PLUS names transforms by ``From``/``To`` frames; ``Matrix`` maps From coordinates into To,
i.e. our ``to_from_from`` (``From="Base" To="Tracker"`` is ``tracker_from_base``).
"""

from __future__ import annotations

import datetime
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.core.strict_numbers import parse_floats
from spacecal.core.text import quoted
from spacecal.geometry.transforms import check_nearly_rigid
from spacecal.io.atomic import write_text_atomic
from spacecal.io.names import check_plus_frame_names
from spacecal.io.ros_common import number_text
from spacecal.io.text import read_text_file, refuse_dtd


def _parse(path: str | Path) -> ElementTree.Element:
    path = Path(path)
    if not path.is_file():
        raise InvalidInputError(f"{path}: no such PLUS configuration file")
    text = refuse_dtd(read_text_file(path, "PLUS configuration"), str(path))
    try:
        return ElementTree.fromstring(text)
    except ElementTree.ParseError as exc:
        raise InvalidInputError(f"{path}: not valid XML ({exc})") from None


def read_plus_transform(path: str | Path, from_frame: str, to_frame: str) -> np.ndarray:
    """The ``From``->``To`` transform of a PLUS configuration, as ``to_from_from`` (4, 4)."""
    for element in _parse(path).iter("Transform"):
        if element.get("From") == from_frame and element.get("To") == to_frame:
            try:
                numbers = parse_floats(element.get("Matrix", ""))
            except ValueError:
                numbers = np.array([])
            if numbers.size != 16 or not np.all(np.isfinite(numbers)) or np.max(np.abs(numbers)) > 1e5:
                raise InvalidInputError(
                    f"{path}: {from_frame}To{to_frame} Matrix does not hold 16 finite numbers (mm)"
                )
            check_nearly_rigid(numbers.reshape(1, 4, 4), f"{path}: {from_frame}To{to_frame}")
            return numbers.reshape(4, 4)
    raise InvalidInputError(f"{path}: no {from_frame}To{to_frame} transform in CoordinateDefinitions")


#: Two landmarks of a phantom closer than this (mm) are one point given twice: a stylus cannot
#: tell them apart, and the registration would pair one touch with two positions.
DUPLICATE_LANDMARK_MM = 1.0


def read_plus_landmarks(path: str | Path) -> tuple[list[str], np.ndarray]:
    """Names and positions (M, 3), mm, of the ``<Landmarks>`` of a PLUS phantom definition."""
    names: list[str] = []
    positions: list[list[float]] = []
    for element in _parse(path).iter("Landmark"):
        names.append(element.get("Name", str(len(names) + 1)))
        position = element.get("Position", "")
        try:
            values = list(parse_floats(position))
        except ValueError:
            values = []
        if len(values) != 3 or not all(abs(v) <= 1e5 for v in values):
            raise InvalidInputError(
                f"{path}: landmark {quoted(names[-1])}: Position {quoted(position, 40)} is not three finite "
                "numbers in mm"
            )
        positions.append(values)
    if not positions:
        raise InvalidInputError(f"{path}: no <Landmark> elements")
    points = np.array(positions)
    seen: dict[str, int] = {}
    for index, name in enumerate(names):
        if name in seen:
            raise InvalidInputError(f"{path}: landmark {quoted(name)} is defined twice; each name once")
        seen[name] = index
    gaps = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=2)
    gaps[np.diag_indices(len(points))] = np.inf
    first, second = sorted(int(k) for k in np.unravel_index(np.argmin(gaps), gaps.shape))
    if gaps[first, second] < DUPLICATE_LANDMARK_MM:
        raise InvalidInputError(
            f"{path}: landmarks {quoted(names[first])} and {quoted(names[second])} are "
            f"{gaps[first, second]:.2f} mm apart: the same point twice (landmarks must be distinct points)"
        )
    return names, points


def _transform_element(
    a_from_b, from_frame: str, to_frame: str, error_mm: float | None, date: datetime.datetime | None
) -> ElementTree.Element:
    check_plus_frame_names(from_frame, to_frame)
    matrix = np.asarray(a_from_b, dtype=float)
    if matrix.shape != (4, 4) or not np.all(np.isfinite(matrix)):
        raise InvalidInputError(f"{from_frame}To{to_frame}: expected a finite 4x4 matrix")
    attributes = {
        "From": from_frame,
        "To": to_frame,
        "Matrix": "  ".join(" ".join(number_text(v) for v in row) for row in matrix),
    }
    if error_mm is not None and np.isfinite(error_mm):
        attributes["Error"] = f"{error_mm:.6g}"
    attributes["Date"] = (date or datetime.datetime.now()).strftime("%m%d%y_%H%M%S")
    return ElementTree.Element("Transform", attributes)


def plus_coordinate_definition(
    a_from_b,
    from_frame: str,
    to_frame: str,
    error_mm: float | None = None,
    date: datetime.datetime | None = None,
) -> str:
    """A PLUS ``<Transform From=.. To=.. Matrix=.. Error=.. Date=..>`` element as XML text.

    The frame names must be PLUS frame names (:func:`spacecal.io.names.check_plus_frame_names`);
    the element is built with ElementTree, so every attribute is escaped. The matrix is written
    row after row in shortest round-trip form; PLUS writes dates as ``mmddyy_HHMMSS``.
    """
    return ElementTree.tostring(_transform_element(a_from_b, from_frame, to_frame, error_mm, date), "unicode")


def write_plus_coordinate_definitions(path: str | Path, transforms: list[tuple]) -> Path:
    """Write ``<CoordinateDefinitions>`` with (a_from_b, from, to, error_mm) entries, to paste into
    (or include in) a PLUS device-set configuration."""
    root = ElementTree.Element("PlusConfiguration", {"version": "2.1"})
    definitions = ElementTree.SubElement(root, "CoordinateDefinitions")
    for a_from_b, from_frame, to_frame, error_mm in transforms:
        definitions.append(_transform_element(a_from_b, from_frame, to_frame, error_mm, None))
    ElementTree.indent(root, "  ")
    path = Path(path)
    write_text_atomic(ElementTree.tostring(root, encoding="unicode") + "\n", path)
    return path
