"""Calibrations as files of other versions hold them, for tests and benchmarks."""

from __future__ import annotations

from typing import Any

from spacecal.records import CalibrationResult
from spacecal.records.assessment import Assessment


def with_stored(calibration: CalibrationResult, **stored: Any) -> CalibrationResult:
    """``calibration`` with some keys of its file's ``diagnostics`` object replaced, as a file
    that stored them so would read (e.g. ``verdict`` as an older file's sentence,
    ``per_sample_residuals`` as a version before the kinematic method stated its own).

    Only the assessment's keys (:data:`spacecal.records.assessment.ASSESSMENT_KEYS`) are
    taken; they are read as :meth:`CalibrationResult.from_dict` reads them.
    """
    current = {} if calibration.assessment is None else calibration.assessment.to_diagnostics()
    assessment, rest = Assessment.from_diagnostics({**current, **stored}, "calibration")
    if rest:
        raise ValueError(f"not keys of an assessment: {', '.join(sorted(rest))}")
    return calibration.replace(assessment=assessment)
