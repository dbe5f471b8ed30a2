"""The verdict on a calibration: its grade, the expected error it was graded by, and why.

Stored in a calibration file as ``diagnostics["verdict"]``, an object with the fields below
and ``text``, the sentence a person reads. Files written before the verdict was a record hold
only the sentence; :meth:`Verdict.from_value` reads both, taking the grade from the sentence's
first word.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from spacecal.core.errors import InvalidInputError

#: The grades, best first.
GRADES = ("good", "acceptable", "poor", "unusable")
#: Grade words of older files and the grade they stand for.
LEGACY_GRADES = {"check": "poor"}


@dataclass(frozen=True)
class Verdict:
    """A calibration's grade and the reasons for it.

    Attributes
    ----------
    grade : str
        One of :data:`GRADES`.
    expected_error_mm : float or None
        The expected position error at a target near the site it was graded by, mm; None
        when it could not be estimated (the grade is then ``unusable``).
    expected_posture_deg : float or None
        The expected posture error there, deg.
    limit_mm : float or None
        The threshold of the grade, mm (the upper limit of ``good``/``acceptable``/``poor``,
        or the ``poor`` limit an ``unusable`` error is above).
    reasons : tuple of str
        The sentences that explain the grade and what to do, most important first.
    tolerable_mm : float or None
        The largest error the application tolerates (the ``poor`` limit), mm.
    chance_within_tolerable : float or None
        The chance, in [0, 1], that the error at a target near the site is within
        ``tolerable_mm``, from the expected error's covariance: an error mostly along one
        direction (a camera's depth) is small more often than an even one of the same mean.
    expected_error_range_mm : tuple of float or None
        ``(low, high)`` mm: the expected error with the systematic misfit it rests on taken one
        standard error lower and higher. How far the statement itself can be off on the
        frames it had; None where it was not estimated.
    """

    grade: str
    expected_error_mm: float | None = None
    expected_posture_deg: float | None = None
    limit_mm: float | None = None
    reasons: tuple[str, ...] = ()
    tolerable_mm: float | None = None
    chance_within_tolerable: float | None = None
    expected_error_range_mm: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if self.grade not in GRADES:
            raise InvalidInputError(f"verdict grade must be one of {', '.join(GRADES)}, got {self.grade!r}")
        for name in ("expected_error_mm", "expected_posture_deg", "limit_mm", "tolerable_mm"):
            value = getattr(self, name)
            if value is not None and not (isinstance(value, (int, float)) and math.isfinite(value)):
                raise InvalidInputError(f"verdict {name} must be a finite number or null, got {value!r}")
        chance = self.chance_within_tolerable
        if chance is not None and not (isinstance(chance, (int, float)) and 0.0 <= chance <= 1.0):
            raise InvalidInputError(
                f"verdict chance_within_tolerable must be in [0, 1] or null, got {chance!r}"
            )
        span = self.expected_error_range_mm
        if span is not None and not (
            isinstance(span, tuple)
            and len(span) == 2
            and all(isinstance(v, (int, float)) and math.isfinite(v) and v >= 0 for v in span)
            and span[0] <= span[1]
        ):
            raise InvalidInputError(
                "verdict expected_error_range_mm must be [low, high] in mm with low <= high, or null, "
                f"got {span!r}"
            )

    @property
    def usable(self) -> bool:
        """False for ``unusable``."""
        return self.grade != "unusable"

    @property
    def alarming(self) -> bool:
        """True for ``poor`` and ``unusable``: the grades a report flags red."""
        return self.grade in ("poor", "unusable")

    @property
    def headline(self) -> str:
        """What every display of the calibration says first, the same words everywhere (the
        command line's verdict, the report's headline, the station's page): the grade and what it
        means for use at the thresholds the calibration was graded against."""
        within = f" {self.tolerable_mm:g} mm" if self.tolerable_mm is not None else ""
        return {
            "good": "Good",
            "acceptable": "Acceptable",
            "poor": f"Poor: use only where an error up to{within or ' the tolerable limit'} is tolerable",
            "unusable": "Do not use: unusable",
        }[self.grade]

    @property
    def level(self) -> str:
        """How a display colours it: ``ok`` (good, acceptable) or ``alarm`` (poor, unusable)."""
        return "alarm" if self.alarming else "ok"

    @property
    def text(self) -> str:
        """The sentence a person reads: ``<grade>: <reason>; <reason>...``."""
        return f"{self.grade}: " + "; ".join(self.reasons) if self.reasons else self.grade

    def to_dict(self) -> dict[str, Any]:
        return {
            "grade": self.grade,
            "expected_error_mm": self.expected_error_mm,
            "expected_posture_deg": self.expected_posture_deg,
            "limit_mm": self.limit_mm,
            "reasons": list(self.reasons),
            "text": self.text,
            "tolerable_mm": self.tolerable_mm,
            "chance_within_tolerable": self.chance_within_tolerable,
            "expected_error_range_mm": (
                None if self.expected_error_range_mm is None else list(self.expected_error_range_mm)
            ),
        }

    @classmethod
    def from_value(cls, value: object, what: str = "calibration") -> Verdict | None:
        """The verdict stored in a file: an object as written by :meth:`to_dict`, or the
        sentence older files hold; None when there is none.

        Raises
        ------
        InvalidInputError
            For a value that is neither.
        """
        if value is None:
            return None
        if isinstance(value, str):
            head, _, rest = value.partition(":")
            grade = head.split(";")[0].strip().lower()
            # the first files graded a doubtful calibration "check" (before use): poor today
            grade = LEGACY_GRADES.get(grade, grade)
            if grade not in GRADES:
                raise InvalidInputError(f"{what}: verdict {value[:60]!r} does not start with a grade")
            reasons = tuple(part.strip() for part in rest.split(";") if part.strip())
            return cls(grade, reasons=reasons)
        if isinstance(value, Mapping):
            reasons = value.get("reasons", ())
            if not isinstance(reasons, (list, tuple)) or not all(isinstance(r, str) for r in reasons):
                raise InvalidInputError(f"{what}: verdict reasons must be a list of sentences")
            span = value.get("expected_error_range_mm")
            if span is not None:
                if not isinstance(span, (list, tuple)):
                    raise InvalidInputError(f"{what}: verdict expected_error_range_mm must be [low, high]")
                span = tuple(span)
            try:
                return cls(
                    str(value.get("grade")),
                    value.get("expected_error_mm"),
                    value.get("expected_posture_deg"),
                    value.get("limit_mm"),
                    tuple(reasons),
                    value.get("tolerable_mm"),
                    value.get("chance_within_tolerable"),
                    span,
                )
            except TypeError as exc:
                raise InvalidInputError(f"{what}: verdict is malformed ({exc})") from exc
        raise InvalidInputError(f"{what}: verdict must be an object or a sentence")
