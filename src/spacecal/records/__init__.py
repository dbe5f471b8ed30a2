"""Typed records: every result that travels between steps, validated on construction."""

from spacecal.records._legacy import *  # noqa: F403
from spacecal.records._legacy import (
    CALIBRATION_SCHEMA_VERSION,
    PAPER_SEGMENTS,
    ROTATION_SEGMENTS,
    TRANSLATION_SEGMENTS,
    CalibrationResult,
    RawRecording,
    Recording,
)
