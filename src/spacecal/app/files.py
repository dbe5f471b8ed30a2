"""App functions around files: ``register-landmarks``, ``report``, ``export``, ``import-plus``."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spacecal.app._common import refuse_overwriting_inputs
from spacecal.core.errors import InvalidInputError
from spacecal.estimators.landmarks import LandmarkDetectionSettings
from spacecal.io.plus_config import (
    read_plus_landmarks,
    read_plus_transform,
    write_plus_coordinate_definitions,
)
from spacecal.io.plus_import import recording_from_plus_sequence
from spacecal.io.plus_sequence import read_plus_sequence
from spacecal.io.recording_csv import metadata_path, read_recording, write_recording
from spacecal.io.results_json import read_calibration, read_json_object, write_json
from spacecal.io.slicer import write_slicer_transform
from spacecal.records import LandmarkRegistrationResult, VerificationResult
from spacecal.report.html import Report, write_report
from spacecal.workflows.check import read_history
from spacecal.workflows.landmark_registration import register_landmarks_from_stylus


@dataclass(frozen=True)
class RegisterLandmarksSettings:
    """``spacecal register-landmarks``: a phantom registered to its reference marker from a
    tracked-stylus PLUS recording.

    Attributes
    ----------
    sequence : str
        PLUS sequence file with ``<reference>ToTracker`` and ``<stylus>ToTracker``.
    config : str
        PLUS device set with the ``StylusTip`` to ``Stylus`` transform and the landmarks.
    reference, stylus : str
        Tool names.
    plus_compatible : bool
        Average the landmark frames exactly as PLUS does.
    output : str or None
        Registration JSON to write.
    """

    sequence: str
    config: str
    reference: str = "Reference"
    stylus: str = "Stylus"
    plus_compatible: bool = False
    output: str | None = None


def register_landmarks(
    settings: RegisterLandmarksSettings,
) -> tuple[LandmarkRegistrationResult, np.ndarray, Path | None]:
    """Detect the landmark touches and register; returns the result, the sequence's
    timestamps (s) and the file written."""
    refuse_overwriting_inputs(settings.output, settings.sequence, settings.config)
    sequence = read_plus_sequence(settings.sequence)
    _, landmarks = read_plus_landmarks(settings.config)
    stylus_from_tip = read_plus_transform(settings.config, "StylusTip", "Stylus")
    detection = None
    if settings.plus_compatible:
        times = sequence.timestamps_s
        spacing = min(np.linalg.norm(a - b) for i, a in enumerate(landmarks) for b in landmarks[i + 1 :])
        detection = LandmarkDetectionSettings(
            acquisition_rate_hz=1.0 / (times[1] - times[0]),
            min_landmark_spacing_mm=spacing,
            plus_compatible=True,
        )
    result = register_landmarks_from_stylus(
        sequence.timestamps_s,
        sequence.transform(f"{settings.reference}ToTracker"),
        sequence.transform(f"{settings.stylus}ToTracker"),
        stylus_from_tip,
        landmarks,
        detection,
    )
    path = write_json(result.to_dict(), settings.output) if settings.output else None
    return result, sequence.timestamps_s, path


@dataclass(frozen=True)
class ReportSettings:
    """``spacecal report``: a self-contained HTML report (works offline) and PNG figures."""

    calibration: str
    output: str
    recording: str | None = None
    verification: str | None = None
    png_dir: str | None = None


@dataclass(frozen=True)
class ReportOutput:
    path: Path
    titles: list[str]
    notes: list[str] = field(default_factory=list)


def report(settings: ReportSettings) -> ReportOutput:
    """Write the report of a calibration (with its recording, verification and check history)."""
    refuse_overwriting_inputs(
        settings.output, settings.calibration, settings.recording, settings.verification
    )
    calibration = read_calibration(settings.calibration)
    notes = []
    recording_path = settings.recording or calibration.provenance.recording
    recording = None
    if recording_path and Path(recording_path).is_file():
        recording = read_recording(recording_path)
    else:
        notes.append("no recording found (pass --recording): sweeps and residuals are not shown")
    verification = None
    if settings.verification:
        verification = VerificationResult.from_dict(
            read_json_object(settings.verification, "verification"), what=settings.verification
        )
    history, unreadable = read_history(settings.calibration)
    if unreadable:
        notes.append(f"{unreadable} unreadable line(s) in the check history were skipped")
    path, titles = write_report(
        Report(calibration, recording, verification, history), settings.output, settings.png_dir
    )
    return ReportOutput(path, titles, notes)


@dataclass(frozen=True)
class ExportSettings:
    """``spacecal export``: a calibration for 3D Slicer, PLUS, or over OpenIGTLink."""

    calibration: str
    slicer: str | None = None
    plus: str | None = None
    igtl: str | None = None


def export(settings: ExportSettings) -> list[str]:
    """Export the calibration to every target named; returns one line per export done."""
    if not (settings.slicer or settings.plus or settings.igtl):
        raise InvalidInputError(
            "say where to export: --slicer FILE.tfm, --plus FILE.xml, --igtl HOST:PORT, --easy-handeye2, "
            "--ros2-launch, --urdf, --static-tf or --ur-calibration"
        )
    refuse_overwriting_inputs(settings.slicer, settings.calibration)
    refuse_overwriting_inputs(settings.plus, settings.calibration)
    calibration = read_calibration(settings.calibration)
    error = calibration.diagnostics.get("expected_error", {}).get("position_mm")
    done = []
    if settings.slicer:
        path = write_slicer_transform(calibration.tracker_from_base, settings.slicer)
        done.append(f"wrote {path} (loads in 3D Slicer as BaseToTracker; its matrix is tracker_from_base)")
    if settings.plus:
        path = write_plus_coordinate_definitions(
            settings.plus,
            [
                (calibration.tracker_from_base, "Base", "Tracker", error),
                (calibration.tcp_from_marker, "Marker", "TCP", None),
            ],
        )
        done.append(f"wrote {path} (PLUS CoordinateDefinitions: BaseToTracker, MarkerToTCP)")
    if settings.igtl:
        from spacecal.adapters import parse_device_url
        from spacecal.adapters.igtl import publish_transform

        _, host, port = parse_device_url("igtl://" + settings.igtl, ("igtl",))
        publish_transform(host, port or 18944, "BaseToTracker", calibration.tracker_from_base)
        done.append(f"sent BaseToTracker to igtl://{host}:{port or 18944}")
    return done


@dataclass(frozen=True)
class ImportPlusSettings:
    """``spacecal import-plus``: a PLUS sequence file as a recording CSV."""

    sequence: str
    output: str
    marker: str = "MarkerToTracker"
    tcp: str = "TCPToBase"
    segment: str = "static"


def import_plus(settings: ImportPlusSettings) -> tuple[Path, int, int]:
    """Convert the sequence; returns the recording written, its frames and visible frames."""
    refuse_overwriting_inputs(settings.output, settings.sequence)
    refuse_overwriting_inputs(metadata_path(settings.output), settings.sequence)
    recording = recording_from_plus_sequence(
        settings.sequence, settings.marker, settings.tcp, settings.segment
    )
    path = write_recording(recording, settings.output)
    return path, len(recording), int(recording.visible.sum())
