"""Tracker kinds as data: what each tracker's maker states about it.

A tracker kind carries the measurement volume, the frame rate, the marker file format and the
maker's stated accuracy (3-D RMS of a single marker over the volume), read from
``data/tracker_kinds.json``. A field the maker's documents do not give here is None, and
spacecal then states nothing for it rather than guess. Adding a tracker kind is one entry in
that file.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from importlib import resources
from typing import Any

from spacecal.core.errors import InvalidInputError
from spacecal.models.tracker import PyramidVolume


@dataclass(frozen=True)
class TrackerKind:
    """One kind of tracker.

    Attributes
    ----------
    name : str
        As the tracker names itself where it does (``"Polaris Vicra"``).
    vendor, protocol : str
        The maker, and the device URL scheme spacecal reads it through (``ndi``, ``natnet``,
        ``igtl``).
    rate_hz : float or None
        The maximum frame rate, Hz.
    accuracy_rms_mm : float or None
        The maker's stated 3-D RMS accuracy of a single marker over the volume, mm.
    volume : PyramidVolume or None
        The measurement volume in the tracker's frame (along -z), mm.
    marker_format : str
        What defines a tracked tool for it.
    sources : tuple of str
        Where each number comes from.
    """

    name: str
    vendor: str
    protocol: str
    rate_hz: float | None
    accuracy_rms_mm: float | None
    volume: PyramidVolume | None
    marker_format: str
    sources: tuple[str, ...]


def _positive_or_none(entry: Mapping[str, Any], key: str, name: str) -> float | None:
    value = entry.get(key)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value < 1e6:
        raise InvalidInputError(f"tracker kind {name!r}: {key} must be a positive number or null")
    return float(value)


def _kind(name: str, entry: Mapping[str, Any]) -> TrackerKind:
    volume = entry.get("volume")
    if volume is not None:
        sizes = {
            k: _positive_or_none(volume, k, name)
            for k in ("near_mm", "far_mm", "far_width_mm", "far_height_mm")
        }
        if any(v is None for v in sizes.values()) or sizes["near_mm"] >= sizes["far_mm"]:  # type: ignore[operator]
            raise InvalidInputError(f"tracker kind {name!r}: a volume needs near < far, a width and a height")
        volume = PyramidVolume(**sizes)  # type: ignore[arg-type]
    return TrackerKind(
        name=name,
        vendor=str(entry["vendor"]),
        protocol=str(entry["protocol"]),
        rate_hz=_positive_or_none(entry, "rate_hz", name),
        accuracy_rms_mm=_positive_or_none(entry, "accuracy_rms_mm", name),
        volume=volume,
        marker_format=str(entry["marker_format"]),
        sources=tuple(str(s) for s in entry.get("sources", ())),
    )


def _load() -> dict[str, TrackerKind]:
    text = resources.files("spacecal.models").joinpath("data/tracker_kinds.json").read_text()
    return {name: _kind(name, entry) for name, entry in json.loads(text).items() if not name.startswith("_")}


#: Every tracker kind spacecal knows, by name.
TRACKER_KINDS: Mapping[str, TrackerKind] = _load()


def tracker_kind(name: str) -> TrackerKind:
    """The tracker kind ``name``.

    Raises
    ------
    InvalidInputError
        Not a known kind (the known ones are named).
    """
    if name not in TRACKER_KINDS:
        raise InvalidInputError(f"unknown tracker kind {name!r}; known: {', '.join(TRACKER_KINDS)}")
    return TRACKER_KINDS[name]


def tracker_kind_of(model: str | None) -> TrackerKind | None:
    """The kind a tracker's own model string names (an NDI sensor reports ``Polaris Vicra`` or
    ``Polaris Vega ST``, sometimes with more after it), None when it names none we know."""
    if not model:
        return None
    text = " ".join(model.split()).lower()
    matches = [kind for name, kind in TRACKER_KINDS.items() if text.startswith(name.lower())]
    return max(matches, key=lambda k: len(k.name)) if matches else None
