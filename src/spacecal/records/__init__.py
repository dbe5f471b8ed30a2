"""Typed records: every result that travels between steps, validated on construction.

Each result record has ``to_dict()`` (the file content, with ``schema`` and
``schema_version``) and ``from_dict()`` (which reads every version spacecal has written);
:mod:`spacecal.io` turns them into files.
"""

from spacecal.records.calibration import (
    CALIBRATION_SCHEMA_VERSION,
    CalibrationResult,
    NeedleTip,
    Provenance,
    robot_model_from_dict,
    robot_model_to_dict,
)
from spacecal.records.recording import (
    PAPER_SEGMENTS,
    ROTATION_SEGMENTS,
    TRANSLATION_SEGMENTS,
    RawRecording,
    Recording,
)
from spacecal.records.recording_source import (
    RECORDING_KINDS,
    RecordingSource,
    SourceFile,
    StreamPairing,
)

__all__ = [
    "CALIBRATION_SCHEMA_VERSION",
    "PAPER_SEGMENTS",
    "ROTATION_SEGMENTS",
    "TRANSLATION_SEGMENTS",
    "CalibrationResult",
    "NeedleTip",
    "Provenance",
    "RawRecording",
    "Recording",
    "RECORDING_KINDS",
    "RecordingSource",
    "SourceFile",
    "StreamPairing",
    "robot_model_from_dict",
    "robot_model_to_dict",
]

from spacecal.records.acquisition import AcquisitionProgress
from spacecal.records.guidance import GuidanceResult, StageMeasurement
from spacecal.records.plan import PlanRecord
from spacecal.records.results import (
    CheckResult,
    LandmarkRegistrationResult,
    PhantomResult,
    PivotResult,
    VerificationResult,
)
from spacecal.records.verdict import GRADES, Verdict

__all__ += [
    "AcquisitionProgress",
    "CheckResult",
    "GuidanceResult",
    "LandmarkRegistrationResult",
    "PhantomResult",
    "PivotResult",
    "PlanRecord",
    "StageMeasurement",
    "VerificationResult",
    "GRADES",
    "Verdict",
]
