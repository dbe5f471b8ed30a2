"""What a calibration's fit rests on, as others read it: the paper method's sphere and line fits, the noise.

Typed fields of :class:`~spacecal.records.CalibrationResult`. A calibration file stores them where
earlier versions did, as keys of its ``diagnostics`` object (``sphere``, ``lines``, ``noise``),
so every file reads.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.records.fields import ReadOnlyMapping, plain

#: The keys of a calibration file's ``diagnostics`` object these records are stored in.
FIT_EVIDENCE_KEYS = ("sphere", "lines", "noise")


def _number(data: Mapping[str, Any], name: str, what: str, optional: bool = False) -> float | None:
    value = data.get(name)
    if value is None and optional:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InvalidInputError(f"{what}: {name} must be a finite number, got {value!r}")
    return float(value)


def _point(value: Any, name: str, what: str) -> np.ndarray:
    point = np.array(value, dtype=float) if isinstance(value, (list, tuple, np.ndarray)) else np.zeros(0)
    if point.shape != (3,) or not np.all(np.isfinite(point)):
        raise InvalidInputError(f"{what}: {name} must be three finite numbers")
    point.flags.writeable = False
    return point


@dataclass(frozen=True)
class SphereFit:
    """The sphere the marker origin traced over the rotation sweeps (the paper's eqs. 2-4).

    Attributes
    ----------
    centre_in_tracker_mm : numpy.ndarray, shape (3,)
        Its centre, the TCP origin, in the tracker frame, mm (read-only).
    radius_mm : float
    rms_mm : float
        RMS distance of the marker origins from it, mm.
    samples : int
    radius_minus_marker_offset_mm : float or None
        The radius less the marker's distance from the TCP the calibration found, mm.
    """

    centre_in_tracker_mm: np.ndarray
    radius_mm: float
    rms_mm: float
    samples: int
    radius_minus_marker_offset_mm: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "centre_in_tracker_mm", _point(self.centre_in_tracker_mm, "centre_in_tracker_mm", "sphere")
        )

    def __eq__(self, other: object) -> bool:
        # by content: the arrays compare element by element
        return type(other) is type(self) and self.to_dict() == other.to_dict()

    __hash__ = None  # type: ignore[assignment]

    def to_dict(self) -> dict[str, Any]:
        content: dict[str, Any] = {
            "centre_in_tracker_mm": self.centre_in_tracker_mm,
            "radius_mm": self.radius_mm,
            "rms_mm": self.rms_mm,
            "samples": self.samples,
        }
        if self.radius_minus_marker_offset_mm is not None:
            content["radius_minus_marker_offset_mm"] = self.radius_minus_marker_offset_mm
        return plain(content)

    @classmethod
    def from_dict(cls, data: Any, what: str = "sphere") -> SphereFit:
        if not isinstance(data, Mapping):
            raise InvalidInputError(f"{what} must be an object")
        return cls(
            _point(data.get("centre_in_tracker_mm"), "centre_in_tracker_mm", what),
            float(_number(data, "radius_mm", what) or 0.0),
            float(_number(data, "rms_mm", what) or 0.0),
            int(_number(data, "samples", what) or 0),
            _number(data, "radius_minus_marker_offset_mm", what, optional=True),
        )


@dataclass(frozen=True)
class LineFit:
    """The line the marker origin traced over one translation sweep (the paper's eqs. 5-7).

    Attributes
    ----------
    straightness_rms_mm : float
        RMS distance of the marker origins from the line, mm.
    length_mm : float
    direction_in_tracker : numpy.ndarray, shape (3,)
        Its unit direction in the tracker frame (read-only).
    samples : int
    """

    straightness_rms_mm: float
    length_mm: float
    direction_in_tracker: np.ndarray
    samples: int

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "direction_in_tracker", _point(self.direction_in_tracker, "direction_in_tracker", "line")
        )

    def __eq__(self, other: object) -> bool:
        # by content: the arrays compare element by element
        return type(other) is type(self) and self.to_dict() == other.to_dict()

    __hash__ = None  # type: ignore[assignment]

    def to_dict(self) -> dict[str, Any]:
        return plain(
            {
                "straightness_rms_mm": self.straightness_rms_mm,
                "length_mm": self.length_mm,
                "direction_in_tracker": self.direction_in_tracker,
                "samples": self.samples,
            }
        )

    @classmethod
    def from_dict(cls, data: Any, what: str = "line") -> LineFit:
        if not isinstance(data, Mapping):
            raise InvalidInputError(f"{what} must be an object")
        return cls(
            float(_number(data, "straightness_rms_mm", what) or 0.0),
            float(_number(data, "length_mm", what) or 0.0),
            _point(data.get("direction_in_tracker"), "direction_in_tracker", what),
            int(_number(data, "samples", what) or 0),
        )


@dataclass(frozen=True)
class SweepFits:
    """The paper method's fits to its six sweeps.

    Attributes
    ----------
    sphere : SphereFit or None
    lines : mapping of str to LineFit
        Per translation sweep label (read-only).
    """

    sphere: SphereFit | None = None
    lines: Mapping[str, LineFit] = field(default_factory=lambda: ReadOnlyMapping({}))

    def __post_init__(self) -> None:
        object.__setattr__(self, "lines", ReadOnlyMapping(dict(self.lines)))

    def to_diagnostics(self) -> dict[str, Any]:
        content: dict[str, Any] = {}
        if self.sphere is not None:
            content["sphere"] = self.sphere.to_dict()
        if self.lines:
            content["lines"] = {label: line.to_dict() for label, line in self.lines.items()}
        return content

    @classmethod
    def from_diagnostics(cls, stored: Mapping[str, Any], what: str = "calibration") -> SweepFits | None:
        """The fits stored in a ``diagnostics`` object, None when it holds neither."""
        sphere, lines = stored.get("sphere"), stored.get("lines")
        if sphere is None and lines is None:
            return None
        if lines is not None and not isinstance(lines, Mapping):
            raise InvalidInputError(f"{what}: lines must be an object of sweeps")
        return cls(
            None if sphere is None else SphereFit.from_dict(sphere, f"{what}: sphere"),
            {str(k): LineFit.from_dict(v, f"{what}: line {k}") for k, v in (lines or {}).items()},
        )


@dataclass(frozen=True)
class NoiseSummary:
    """The tracker noise a likelihood fit was weighted with.

    Attributes
    ----------
    sigma_per_axis_mm : float or None
        Per-axis sphere noise, mm; None when the recording gave none (the covariance is then
        scaled by the residuals).
    source : str
        Where it came from.
    observations : str
        What was fitted: raw spheres, or model spheres placed by the measured marker pose.
    """

    sigma_per_axis_mm: float | None
    source: str = ""
    observations: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {
            "sigma_per_axis_mm": self.sigma_per_axis_mm,
            "source": self.source,
            "observations": self.observations,
        }

    @classmethod
    def from_dict(cls, data: Any, what: str = "noise") -> NoiseSummary:
        if not isinstance(data, Mapping):
            raise InvalidInputError(f"{what} must be an object")
        sigma = _number(data, "sigma_per_axis_mm", what, optional=True)
        if sigma is not None and sigma <= 0.0:
            raise InvalidInputError(f"{what}: sigma_per_axis_mm must be positive")
        return cls(sigma, str(data.get("source", "")), str(data.get("observations", "")))
