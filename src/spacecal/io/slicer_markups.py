"""3D Slicer markups files (``.mrk.json``): needle plans and fiducials drawn on an image.

The format (Slicer's ``Modules/Loadable/Markups/Resources/Schema/markups-schema-v1.0.*.json``,
read by ``vtkMRMLMarkupsJsonStorageNode``):

* ``"@schema"`` names the schema; Slicer accepts any ``markups-schema-v1.X.Y.json`` and so do we
  (v1.0.0 to v1.0.3 are the versions Slicer has written).
* ``"markups"`` is a list; each markup has a ``"type"`` (``Fiducial`` for a point list,
  ``Line``, ...), a ``"name"``, ``"coordinateSystem"`` (``LPS`` or ``RAS``), ``"coordinateUnits"``
  (``"mm"`` or the coded entry ``["mm", "UCUM", "millimeter"]``) and ``"controlPoints"``, each
  with ``"label"``, ``"position"`` (3 numbers in the markup's system) and ``"positionStatus"``
  (``defined`` when absent; ``undefined``, ``preview`` and ``missing`` points have no usable
  position).

Choices made here (docs/slicer_plans.md):

* Points are returned in ``image_lps``: Slicer writes LPS, DICOM and ITK are LPS; a RAS markup
  has x and y negated on reading, as Slicer does.
* A markup without ``"coordinateSystem"`` is refused unless the caller states the system. Slicer
  itself assumes LPS there and always writes the field, so a file without it came from other
  software, and a wrong guess mirrors the plan left-right and front-back.
* Units other than millimetres are refused (Slicer refuses a mismatch with its scene too).

:func:`write_markups` writes a point list or a Line as Slicer 5 saves it (schema v1.0.3, each
control point with its id, orientation and ``positionStatus``), so that what spacecal writes for
a simulated CT (``spacecal phantom``) is read back as a user's Slicer file would be.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.core.text import quoted
from spacecal.geometry.anatomical import flip_lps_ras
from spacecal.io.atomic import write_text_atomic
from spacecal.io.results_json import read_json_object
from spacecal.records.needle_plan import NeedlePlan

#: Slicer's own test of a markups file's schema (vtkMRMLMarkupsJsonStorageNode.cxx,
#: ``ACCEPTED_MARKUPS_SCHEMA_REGEX``), compared in lower case.
ACCEPTED_SCHEMA = re.compile(r".*markups-schema-v1\.[0-9]+\.[0-9]+\.json#*$")
COORDINATE_SYSTEMS = ("LPS", "RAS")
#: Labels tried for the entry and the target of a point-list plan, in order, case-insensitive.
ENTRY_LABELS = ("entry", "entry point", "entrypoint", "start")
TARGET_LABELS = ("target", "target point", "targetpoint", "end")
#: The schema Slicer 5 names in the markups files it writes.
WRITTEN_SCHEMA = (
    "https://raw.githubusercontent.com/slicer/slicer/main/Modules/Loadable/Markups/Resources/Schema/"
    "markups-schema-v1.0.3.json#"
)
#: The most a markups file may be (a plan is a few kilobytes; Slicer's curves can be large).
MAX_MARKUPS_BYTES = 50 * 1024 * 1024


@dataclass(frozen=True)
class Markup:
    """One markup of a markups file, its points in ``image_lps``.

    Attributes
    ----------
    kind : str
        Slicer's ``type``: ``Fiducial`` (a point list), ``Line``, ``Curve``, ...
    name : str
    labels : tuple of str
        Each control point's label.
    points_in_image_lps : numpy.ndarray, shape (N, 3)
        Each control point's position in LPS, mm (NaN rows for points without a position).
    coordinate_system : str
        The system the file gave the points in (``LPS`` or ``RAS``).
    """

    kind: str
    name: str
    labels: tuple[str, ...]
    points_in_image_lps: np.ndarray
    coordinate_system: str

    def defined(self, index: int) -> bool:
        return bool(np.all(np.isfinite(self.points_in_image_lps[index])))


def _units_mm(markup: Mapping[str, Any], where: str) -> None:
    units = markup.get("coordinateUnits", "mm")  # the schema's default
    code = units[0] if isinstance(units, list) and len(units) == 3 else units
    scheme = units[1] if isinstance(units, list) and len(units) == 3 else "UCUM"
    if code != "mm" or scheme != "UCUM":
        raise InvalidInputError(
            f"{where}: coordinateUnits {quoted(units)}: spacecal reads markups in millimetres only "
            "(set Slicer's length unit to mm and save again)"
        )


def _system(markup: Mapping[str, Any], where: str, assumed: str | None) -> str:
    if "coordinateSystem" not in markup:
        if assumed is None:
            raise InvalidInputError(
                f"{where}: no coordinateSystem (LPS or RAS); a wrong guess mirrors the plan, so say which "
                "with --coordinate-system LPS or RAS (Slicer writes LPS)"
            )
        return assumed
    system = markup["coordinateSystem"]
    if system not in COORDINATE_SYSTEMS:
        raise InvalidInputError(
            f"{where}: coordinateSystem {quoted(system)} is not LPS or RAS (the two Slicer's schema allows)"
        )
    return str(system)


def _position(point: Mapping[str, Any], where: str) -> list[float]:
    status = point.get("positionStatus", "defined")
    if status not in ("defined", "undefined", "preview", "missing"):
        raise InvalidInputError(f"{where}: positionStatus {quoted(status)} is not one Slicer writes")
    position = point.get("position")
    if status != "defined" or position is None:
        return [math.nan] * 3
    if (
        not isinstance(position, list)
        or len(position) != 3
        or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in position)
    ):
        raise InvalidInputError(f"{where}: position must be 3 numbers, got {quoted(position)}")
    return [float(v) for v in position]


def _markup(markup: object, where: str, assumed: str | None) -> Markup:
    if not isinstance(markup, dict):
        raise InvalidInputError(f"{where}: a markup is a JSON object, not {type(markup).__name__}")
    kind = markup.get("type")
    if not isinstance(kind, str):
        raise InvalidInputError(f"{where}: no markup type (Fiducial, Line, ...)")
    system = _system(markup, where, assumed)
    _units_mm(markup, where)
    points = markup.get("controlPoints", [])
    if not isinstance(points, list):
        raise InvalidInputError(f"{where}: controlPoints must be a list")
    labels, positions = [], []
    for index, point in enumerate(points):
        at = f"{where}, control point {index + 1}"
        if not isinstance(point, dict):
            raise InvalidInputError(f"{at}: a control point is a JSON object")
        label = point.get("label", "")
        if not isinstance(label, str):
            raise InvalidInputError(f"{at}: label must be text")
        labels.append(label)
        positions.append(_position(point, at))
    in_system = np.array(positions, dtype=float).reshape(-1, 3)
    lps = in_system if system == "LPS" else flip_lps_ras(in_system)
    name = markup.get("name", "")
    return Markup(kind, name if isinstance(name, str) else "", tuple(labels), lps, system)


def read_markups(path: str | Path, coordinate_system: str | None = None) -> tuple[Markup, ...]:
    """Every markup of a Slicer markups file, with its points in ``image_lps``.

    Parameters
    ----------
    path : str or Path
        A ``.mrk.json`` file.
    coordinate_system : {"LPS", "RAS"} or None
        The system of a markup that does not state its own (refused when None); a markup that
        states one is read in its own.

    Raises
    ------
    InvalidInputError
        Not a markups file of schema v1, a markup with no or an unknown coordinate system, units
        other than mm, or a malformed control point; each one line naming the file.
    """
    if coordinate_system is not None and coordinate_system not in COORDINATE_SYSTEMS:
        raise InvalidInputError(f"--coordinate-system takes LPS or RAS, got {quoted(coordinate_system)}")
    path = Path(path)
    if path.is_file() and path.stat().st_size > MAX_MARKUPS_BYTES:
        raise InvalidInputError(f"{path}: too large for a markups file ({path.stat().st_size} bytes)")
    data = read_json_object(path, "markups")
    schema = data.get("@schema")
    if not isinstance(schema, str) or not ACCEPTED_SCHEMA.match(schema.lower()):
        raise InvalidInputError(
            f"{path}: not a Slicer markups file (its @schema must name markups-schema-v1.X.Y.json, "
            f"got {quoted(schema)})"
        )
    markups = data.get("markups")
    if not isinstance(markups, list) or not markups:
        raise InvalidInputError(f"{path}: the markups file holds no markups")
    return tuple(
        _markup(markup, f"{path}, markup {index + 1}", coordinate_system)
        for index, markup in enumerate(markups)
    )


def _chosen(markups: Sequence[Markup], name: str | None, kinds: tuple[str, ...], path: Path) -> Markup:
    usable = [m for m in markups if m.kind in kinds and (name is None or m.name == name)]
    if name is not None and not usable:
        names = ", ".join(quoted(m.name) for m in markups)
        raise InvalidInputError(
            f"{path}: no {' or '.join(kinds)} markup named {quoted(name)} (found {names})"
        )
    if not usable:
        found = ", ".join(sorted({m.kind for m in markups}))
        raise InvalidInputError(f"{path}: no {' or '.join(kinds)} markup (found {found})")
    if len(usable) > 1:
        names = ", ".join(quoted(m.name) for m in usable)
        raise InvalidInputError(
            f"{path}: {len(usable)} markups could be the plan ({names}); name one with --markup"
        )
    return usable[0]


def _index_of(markup: Markup, label: str | None, defaults: tuple[str, ...], role: str, where: str) -> int:
    wanted = (label,) if label is not None else defaults
    for candidate in wanted:
        hits = [i for i, text in enumerate(markup.labels) if text.strip().lower() == candidate.lower()]
        if len(hits) > 1:
            raise InvalidInputError(f"{where}: {len(hits)} control points are labelled {quoted(candidate)}")
        if hits:
            return hits[0]
    option = f"--{role}-label"
    raise InvalidInputError(
        f"{where}: no control point labelled {' or '.join(quoted(w) for w in wanted)} for the {role} "
        f"(labels: {', '.join(quoted(t) for t in markup.labels) or 'none'}); name it with {option}"
    )


def plan_from_markups(
    path: str | Path,
    *,
    entry_label: str | None = None,
    target_label: str | None = None,
    markup_name: str | None = None,
    coordinate_system: str | None = None,
) -> NeedlePlan:
    """A needle plan from a Slicer markups file, in ``image_lps``.

    The plan is a ``Line`` markup (its first control point is the entry, its second the target,
    as the line is drawn) or a ``Fiducial`` point list whose entry and target are chosen by label:
    by default the points labelled ``entry`` and ``target`` (case-insensitive; also ``start`` and
    ``end``), else the labels given.

    Parameters
    ----------
    path : str or Path
    entry_label, target_label : str, optional
        Labels of the entry and target points (a point list), or of a line's two ends to say which
        is which.
    markup_name : str, optional
        The markup to read when the file holds more than one Line or point list.
    coordinate_system : {"LPS", "RAS"}, optional
        For a markup that does not state its system.

    Raises
    ------
    InvalidInputError
        The file is not a markups file, holds no single usable plan, the entry or the target is
        missing, ambiguous or has no defined position.
    """
    path = Path(path)
    markup = _chosen(read_markups(path, coordinate_system), markup_name, ("Line", "Fiducial"), path)
    where = f"{path}, {markup.kind} {quoted(markup.name)}"
    if markup.kind == "Line" and entry_label is None and target_label is None:
        if len(markup.labels) != 2:
            raise InvalidInputError(f"{where}: a line has 2 control points, this one {len(markup.labels)}")
        entry, target = 0, 1
    else:
        entry = _index_of(markup, entry_label, ENTRY_LABELS, "entry", where)
        target = _index_of(markup, target_label, TARGET_LABELS, "target", where)
        if entry == target:
            raise InvalidInputError(f"{where}: the entry and the target are the same control point")
    for role, index in (("entry", entry), ("target", target)):
        if not markup.defined(index):
            raise InvalidInputError(
                f"{where}: the {role} ({quoted(markup.labels[index])}) has no defined position"
            )
    return NeedlePlan(
        entry_in_image=markup.points_in_image_lps[entry],
        target_in_image=markup.points_in_image_lps[target],
        image_frame="image_lps",
        name=markup.name,
        entry_label=markup.labels[entry],
        target_label=markup.labels[target],
    )


def fiducials_from_markups(
    path: str | Path, *, markup_name: str | None = None, coordinate_system: str | None = None
) -> dict[str, np.ndarray]:
    """Named fiducials (a ``Fiducial`` point list) in ``image_lps``: label -> position (3,), mm.

    Points without a defined position are left out; labels must be unique and not empty.
    """
    path = Path(path)
    markup = _chosen(read_markups(path, coordinate_system), markup_name, ("Fiducial",), path)
    where = f"{path}, point list {quoted(markup.name)}"
    fiducials: dict[str, np.ndarray] = {}
    for index, label in enumerate(markup.labels):
        key = label.strip()
        if not key:
            raise InvalidInputError(f"{where}: control point {index + 1} has no label to pair it by")
        if key in fiducials:
            raise InvalidInputError(f"{where}: two fiducials are labelled {quoted(key)}")
        if markup.defined(index):
            fiducials[key] = markup.points_in_image_lps[index]
    return fiducials


def _written_point(index: int, label: str, position: np.ndarray) -> dict[str, Any]:
    return {
        "id": str(index + 1),
        "label": label,
        "description": "",
        "associatedNodeID": "",
        "position": [float(v) for v in position],
        "orientation": [-1.0, -0.0, -0.0, -0.0, -1.0, -0.0, 0.0, 0.0, 1.0],
        "selected": True,
        "locked": False,
        "visibility": True,
        "positionStatus": "defined",
    }


def write_markups(
    path: str | Path,
    points_in_image_lps: Mapping[str, Any],
    kind: str = "Line",
    system: str = "LPS",
    name: str | None = None,
    units: str = "mm",
) -> Path:
    """Write a markups file as Slicer saves it (atomically); returns its path.

    Parameters
    ----------
    path : str or Path
    points_in_image_lps : mapping of str to array-like, shape (3,)
        Control points by label, in ``image_lps``, mm, in order (a Line: entry, then target).
    kind : {"Line", "Fiducial"}
        A Line (its points labelled ``L-1``, ``L-2`` as Slicer labels them) or a point list
        (``Fiducial``, labelled with the mapping's labels).
    system : {"LPS", "RAS"}
        The system the positions are written in (RAS: x and y negated, as Slicer does).
    name : str or None
        The markup's name (default: the file's name without ``.mrk.json``).
    units : str
        ``coordinateUnits`` as written (Slicer writes ``mm``).
    """
    if kind not in ("Line", "Fiducial") or system not in COORDINATE_SYSTEMS:
        raise InvalidInputError(
            f"markups are written as a Line or Fiducial in LPS or RAS, not {kind} {system}"
        )
    items = [(str(label), np.asarray(p, dtype=float)) for label, p in points_in_image_lps.items()]
    if kind == "Line" and len(items) != 2:
        raise InvalidInputError(f"a Line has two points (entry, target), not {len(items)}")
    if not all(p.shape == (3,) and np.all(np.isfinite(p)) for _, p in items):
        raise InvalidInputError("markups points must be 3 finite coordinates each")
    flip = np.array([-1.0, -1.0, 1.0]) if system == "RAS" else np.ones(3)
    labels = [f"L-{k + 1}" for k in range(len(items))] if kind == "Line" else [label for label, _ in items]
    markup = {
        "type": kind,
        "name": name if name is not None else Path(path).name.removesuffix(".mrk.json"),
        "coordinateSystem": system,
        "coordinateUnits": units,
        "locked": False,
        "fixedNumberOfControlPoints": False,
        "labelFormat": "%N-%d",
        "lastUsedControlPointNumber": len(items),
        "controlPoints": [
            _written_point(k, label, flip * p) for k, (label, (_, p)) in enumerate(zip(labels, items))
        ],
    }
    return write_text_atomic(json.dumps({"@schema": WRITTEN_SCHEMA, "markups": [markup]}, indent=4), path)
