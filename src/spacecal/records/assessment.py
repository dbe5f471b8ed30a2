"""The assessment of a calibration: the error to expect at a target, residuals, thresholds, verdict.

One :class:`Assessment` is built for a calibration, by
:mod:`spacecal.estimators.assessment`, from its solution and the recording; the command line's
verdict line and exit code, the report's headline, the station's colour and the ledger's grade
only display it.

In a calibration file it is stored where earlier versions stored it, as keys of the
``diagnostics`` object (``expected_error``, ``verdict``, ``residual_position_rms_mm``,
``residual_rotation_rms_deg``, ``per_sample_residuals``, ``thresholds_mm``), so every file
written before reads, and a file written now reads in those versions too.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.records.fields import ReadOnlyMapping, plain
from spacecal.records.verdict import Verdict

#: The keys of a calibration file's ``diagnostics`` object an assessment is stored in.
ASSESSMENT_KEYS = (
    "expected_error",
    "verdict",
    "residual_position_rms_mm",
    "residual_rotation_rms_deg",
    "per_sample_residuals",
    "thresholds_mm",
)


def read_only(value: Any) -> Any:
    """Nested mappings as read-only views and lists as tuples (a record's content stays as built)."""
    if isinstance(value, Mapping):
        return ReadOnlyMapping({str(k): read_only(v) for k, v in value.items()})
    if isinstance(value, (list, tuple)):
        return tuple(read_only(v) for v in value)
    return value


def _number(value: Any, name: str, what: str) -> float | None:
    """A finite number or None (absent); anything else is refused with one line."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InvalidInputError(f"{what}: {name} must be a finite number, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class ErrorThresholds:
    """Upper limits (mm) of the expected position error at a target for each grade.

    Above ``poor_mm`` a calibration is ``unusable``.
    """

    good_mm: float = 0.5
    acceptable_mm: float = 1.0
    poor_mm: float = 2.0

    def __post_init__(self) -> None:
        values = (self.good_mm, self.acceptable_mm, self.poor_mm)
        if not all(np.isfinite(v) and v > 0 for v in values) or not (
            self.good_mm <= self.acceptable_mm <= self.poor_mm
        ):
            raise InvalidInputError(
                f"error thresholds must be positive and increasing (good <= acceptable <= poor), got {values}"
            )

    @classmethod
    def parse(cls, text: str) -> ErrorThresholds:
        """From ``"good,acceptable,poor"`` in mm, e.g. ``"0.5,1,2"``."""
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            values = []
        if len(values) != 3:
            raise InvalidInputError(f"thresholds take good,acceptable,poor in mm, got {text!r}")
        return cls(*values)

    def to_dict(self) -> dict[str, float]:
        return {"good_mm": self.good_mm, "acceptable_mm": self.acceptable_mm, "poor_mm": self.poor_mm}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], what: str = "thresholds_mm") -> ErrorThresholds:
        default = cls()
        values = []
        for name in ("good_mm", "acceptable_mm", "poor_mm"):
            value = _number(data.get(name), name, what)
            values.append(getattr(default, name) if value is None else value)
        return cls(*values)


@dataclass(frozen=True)
class ExpectedError:
    """The error to expect at a target near the site
    (:func:`spacecal.estimators.assessment.expected_error.expected_error`).

    Attributes
    ----------
    position_mm : float or None
        Mean position error at the tip, mm; None when it was not estimated (a refusal).
    posture_deg : float or None
        Mean posture error there, deg.
    position_range_mm : tuple of float or None
        ``(low, high)`` mm: ``position_mm`` with the systematic misfit one standard error lower
        and higher; None where the arm's error scale was given.
    position_covariance_mm2 : numpy.ndarray, shape (3, 3), or None
        The tip error's covariance in the tracker frame, mm^2 (read-only).
    basis : str
        One sentence: what the number rests on.
    components : mapping
        The parts it was combined from (read-only; see the function above).
    refusal : str or None
        Why the data cannot support a calibration, when they cannot.
    """

    position_mm: float | None
    posture_deg: float | None = None
    position_range_mm: tuple[float, float] | None = None
    position_covariance_mm2: np.ndarray | None = None
    basis: str = ""
    components: Mapping[str, Any] = field(default_factory=lambda: ReadOnlyMapping({}))
    refusal: str | None = None

    def __post_init__(self) -> None:
        if self.position_covariance_mm2 is not None:
            covariance = np.array(self.position_covariance_mm2, dtype=float)
            if covariance.shape != (3, 3) or not np.all(np.isfinite(covariance)):
                raise InvalidInputError(
                    "expected error: position_covariance_mm2 must be a finite 3 x 3 matrix"
                )
            covariance.flags.writeable = False
            object.__setattr__(self, "position_covariance_mm2", covariance)
        object.__setattr__(self, "components", read_only(self.components))

    def __eq__(self, other: object) -> bool:
        # by content: the arrays compare element by element
        return type(other) is type(self) and self.to_dict() == other.to_dict()

    __hash__ = None  # type: ignore[assignment]

    @property
    def stated(self) -> bool:
        """A number is stated (not refused)."""
        return self.refusal is None and self.position_mm is not None

    def to_dict(self) -> dict[str, Any]:
        """As the expected error function returns it and a calibration file stores it."""
        content: dict[str, Any] = {}
        if self.position_mm is not None:
            content = {
                "position_mm": self.position_mm,
                "position_range_mm": None if self.position_range_mm is None else list(self.position_range_mm),
                "posture_deg": self.posture_deg,
                "position_covariance_mm2": self.position_covariance_mm2,
                "basis": self.basis,
                "components": self.components,
            }
        else:
            content = {"basis": self.basis}
        if self.refusal is not None:
            content["refusal"] = self.refusal
        return plain(content)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], what: str = "expected error") -> ExpectedError:
        """From a calibration file's ``expected_error`` object (any version: keys it lacks are None)."""
        if not isinstance(data, Mapping):
            raise InvalidInputError(f"{what} must be an object")
        span = data.get("position_range_mm")
        if span is not None and (not isinstance(span, (list, tuple)) or len(span) != 2):
            raise InvalidInputError(f"{what}: position_range_mm must be [low, high]")
        low_high = None
        if span is not None:
            low, high = (_number(v, "position_range_mm", what) for v in span)
            low_high = None if low is None or high is None else (low, high)
        components = data.get("components", {})
        refusal = data.get("refusal")
        basis = data.get("basis", "")
        if not isinstance(components, Mapping) or not isinstance(basis, str):
            raise InvalidInputError(f"{what}: components must be an object and basis a sentence")
        if refusal is not None and not isinstance(refusal, str):
            raise InvalidInputError(f"{what}: refusal must be a sentence")
        covariance = data.get("position_covariance_mm2")
        return cls(
            position_mm=_number(data.get("position_mm"), "position_mm", what),
            posture_deg=_number(data.get("posture_deg"), "posture_deg", what),
            position_range_mm=low_high,
            position_covariance_mm2=None if covariance is None else np.asarray(covariance, dtype=float),
            basis=basis,
            components=components,
            refusal=refusal,
        )


@dataclass(frozen=True)
class ResidualRow:
    """One visible frame's marker residual: the measured pose against the one the calibration
    predicts from the robot's.

    Attributes
    ----------
    row : int
        The recording's row.
    time_s : float
    segment : str
    position_mm : float
        Distance of the marker origins, mm.
    rotation_deg : float
        Angle between the orientations, deg.
    outlier : bool
        The method rejected the frame.
    """

    row: int
    time_s: float
    segment: str
    position_mm: float
    rotation_deg: float
    outlier: bool = False

    def to_dict(self) -> dict[str, Any]:
        return {
            "row": self.row,
            "time_s": self.time_s,
            "segment": self.segment,
            "position_mm": self.position_mm,
            "rotation_deg": self.rotation_deg,
            "outlier": self.outlier,
        }

    @classmethod
    def from_dict(cls, data: Any, what: str = "per_sample_residuals") -> ResidualRow:
        if not isinstance(data, Mapping):
            raise InvalidInputError(f"{what}: each row must be an object")
        try:
            return cls(
                int(data["row"]),
                float(data["time_s"]),
                str(data["segment"]),
                float(data["position_mm"]),
                float(data["rotation_deg"]),
                bool(data.get("outlier", False)),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise InvalidInputError(f"{what}: a row lacks or garbles {exc}") from exc


@dataclass(frozen=True)
class Residuals:
    """What the calibration leaves of the marker poses it was fitted to.

    Attributes
    ----------
    position_rms_mm : float or None
        RMS over the used frames of the marker position residual, mm.
    rotation_rms_deg : float or None
        RMS of the rotation residual, deg.
    per_sample : tuple of ResidualRow or None
        Every visible frame's residual; None when the calibration did not store them (the
        report then computes them from the recording).
    """

    position_rms_mm: float | None
    rotation_rms_deg: float | None
    per_sample: tuple[ResidualRow, ...] | None = None

    def __post_init__(self) -> None:
        if self.per_sample is not None:
            object.__setattr__(self, "per_sample", tuple(self.per_sample))


@dataclass(frozen=True)
class Assessment:
    """One calibration's assessment: what to expect, what it leaves, what it was graded against, the grade.

    Attributes
    ----------
    expected_error : ExpectedError or None
        None when none was stated (a method run without its uncertainty).
    residuals : Residuals or None
        The marker residuals.
    verdict : Verdict or None
        The grade and its reasons.
    thresholds : ErrorThresholds
        The thresholds in force when it was graded (``--thresholds-mm``, else the defaults).
    """

    expected_error: ExpectedError | None = None
    residuals: Residuals | None = None
    verdict: Verdict | None = None
    thresholds: ErrorThresholds = field(default_factory=ErrorThresholds)

    @property
    def position_mm(self) -> float | None:
        """The stated expected position error at a target near the site, mm (None if none)."""
        return None if self.expected_error is None else self.expected_error.position_mm

    @property
    def posture_deg(self) -> float | None:
        """The stated expected posture error there, deg (None if none)."""
        return None if self.expected_error is None else self.expected_error.posture_deg

    def to_diagnostics(self) -> dict[str, Any]:
        """The keys of a calibration file's ``diagnostics`` object that hold it."""
        content: dict[str, Any] = {}
        if self.expected_error is not None:
            content["expected_error"] = self.expected_error.to_dict()
        if self.verdict is not None:
            content["verdict"] = self.verdict.to_dict()
        if self.residuals is not None:
            content["residual_position_rms_mm"] = self.residuals.position_rms_mm
            content["residual_rotation_rms_deg"] = self.residuals.rotation_rms_deg
            if self.residuals.per_sample is not None:
                content["per_sample_residuals"] = [row.to_dict() for row in self.residuals.per_sample]
        content["thresholds_mm"] = self.thresholds.to_dict()
        return plain(content)

    @classmethod
    def from_diagnostics(
        cls, stored: Mapping[str, Any], what: str = "calibration"
    ) -> tuple[Assessment | None, dict[str, Any]]:
        """The assessment stored in a ``diagnostics`` object (any version), and the rest of it.

        Returns
        -------
        assessment : Assessment or None
            None when the object holds none of :data:`ASSESSMENT_KEYS`.
        rest : dict
            The method's own diagnostics.
        """
        rest = {k: v for k, v in stored.items() if k not in ASSESSMENT_KEYS}
        if not any(k in stored for k in ASSESSMENT_KEYS):
            return None, rest
        expected = stored.get("expected_error")
        position = _number(stored.get("residual_position_rms_mm"), "residual_position_rms_mm", what)
        rotation = _number(stored.get("residual_rotation_rms_deg"), "residual_rotation_rms_deg", what)
        rows = stored.get("per_sample_residuals")
        if rows is not None and not isinstance(rows, (list, tuple)):
            raise InvalidInputError(f"{what}: per_sample_residuals must be a list of rows")
        residuals = None
        if position is not None or rotation is not None or rows is not None:
            per_sample = None if rows is None else tuple(ResidualRow.from_dict(r, what) for r in rows)
            residuals = Residuals(position, rotation, per_sample)
        thresholds = stored.get("thresholds_mm")
        if thresholds is not None and not isinstance(thresholds, Mapping):
            raise InvalidInputError(f"{what}: thresholds_mm must be an object")
        assessment = cls(
            expected_error=None
            if expected is None
            else ExpectedError.from_dict(expected, f"{what}: expected_error"),
            residuals=residuals,
            verdict=Verdict.from_value(stored.get("verdict"), what),
            thresholds=ErrorThresholds()
            if thresholds is None
            else ErrorThresholds.from_dict(thresholds, what),
        )
        return assessment, rest
