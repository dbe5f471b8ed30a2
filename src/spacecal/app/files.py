"""App functions around files: ``register-landmarks``, ``report``, ``export``, ``import-plus``."""

from __future__ import annotations

import contextlib
import ipaddress
import os
import re
import shutil
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spacecal.app._common import check_belongs, guard_outputs, open_calibration, refuse_overwriting_inputs
from spacecal.app.result import NOTE_CHARS, CommandResult, note_lines, paths
from spacecal.core.errors import InvalidInputError
from spacecal.core.text import quoted, sanitize_for_terminal
from spacecal.io.atomic import atomic_path
from spacecal.io.check_history import history_path, read_history
from spacecal.io.plus_config import (
    read_plus_landmarks,
    read_plus_transform,
    write_plus_coordinate_definitions,
)
from spacecal.io.plus_import import recording_from_plus_sequence
from spacecal.io.plus_sequence import read_plus_sequence
from spacecal.io.recordings import metadata_path, open_calibrated_recording, write_recording
from spacecal.io.results_json import read_json_object, write_json
from spacecal.io.slicer import write_slicer_transform
from spacecal.records import CalibrationResult, LandmarkRegistrationResult, Recording, VerificationResult
from spacecal.registration.landmarks import LandmarkDetectionSettings
from spacecal.report.html import Report, write_figures, write_report
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
    force: bool = False


def register_landmarks(settings: RegisterLandmarksSettings) -> CommandResult[LandmarkRegistrationResult]:
    """Detect the landmark touches and register.

    Returns
    -------
    CommandResult of LandmarkRegistrationResult
        The registration; the registration JSON written, if asked.
    """
    refuse_overwriting_inputs(
        settings.output, settings.sequence, settings.config, force=settings.force, any_file=True
    )
    sequence = read_plus_sequence(settings.sequence)
    _, landmarks = read_plus_landmarks(settings.config)
    stylus_from_tip = read_plus_transform(settings.config, "StylusTip", "Stylus")
    detection = None
    if settings.plus_compatible:
        times = sequence.timestamps_s
        spacing = float(
            min(np.linalg.norm(a - b) for i, a in enumerate(landmarks) for b in landmarks[i + 1 :])
        )
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
    return registration_result(result, float(sequence.timestamps_s[0]), paths(path))


def registration_result(
    result: LandmarkRegistrationResult, start_s: float, files: tuple[Path, ...] = ()
) -> CommandResult[LandmarkRegistrationResult]:
    """The result of ``register-landmarks`` from its registration, the time its sequence starts
    (s; the touches are shown from there) and the file written."""
    lines = [
        *(f"wrote {path}" for path in files),
        f"registered {len(result.residuals_mm)} landmarks (detected at "
        + ", ".join(f"{t - start_s:.1f}" for t in result.detected_at_s)
        + " s)",
        "reference_from_phantom:",
        *("  " + "  ".join(f"{v:11.6f}" for v in row) for row in result.reference_from_phantom),
        f"landmark error: mean {result.fre_mean_mm:.3f} mm (PLUS's 'Error'), RMS {result.fre_rms_mm:.3f} mm; "
        "per landmark " + ", ".join(f"{v:.2f}" for v in result.residuals_mm),
    ]
    return CommandResult(result, files, lines=tuple(lines))


@dataclass(frozen=True)
class ReportSettings:
    """``spacecal report``: a self-contained HTML report (works offline) and PNG figures."""

    calibration: str
    output: str
    recording: str | None = None
    verification: str | None = None
    png_dir: str | None = None
    force: bool = False
    accept_edited: bool = False


def report(settings: ReportSettings) -> CommandResult[tuple[str, ...]]:
    """Write the report of a calibration (with its recording, verification and check history).

    Returns
    -------
    CommandResult of tuple of str
        The titles of the report's plots; the HTML file written first, then any PNG figures.
    """
    refuse_overwriting_inputs(
        settings.output,
        settings.calibration,
        settings.recording,
        settings.verification,
        history_path(settings.calibration),
        force=settings.force,
    )
    calibration, notes = open_calibration(settings.calibration, "report", settings.accept_edited)
    opened = open_calibrated_recording(calibration, settings.recording, bool(settings.accept_edited))
    recording = None
    if opened is not None:
        recording = opened.recording
        if opened.tracker_stream is not None:
            notes.append(f"recording: {opened.how}")
        check_belongs(recording, calibration.tracker_from_base, calibration.tcp_from_marker, str(opened.path))
    else:
        notes.append("no recording found (pass --recording): sweeps and residuals are not shown")
    verification = None
    if settings.verification:
        verification = _read_verification(settings.verification)
    history, unreadable, others = read_history(settings.calibration, calibration.content_sha256)
    if unreadable:
        notes.append(f"{unreadable} unreadable line(s) in the check history were skipped")
    if others:
        notes.append(
            f"{others} check(s) in {history_path(settings.calibration)} are of another calibration (one "
            "this file replaced, or logged before checks recorded the calibration's hash): not shown"
        )
    report_data = Report(calibration, recording, verification, history)
    with atomic_path(settings.output) as temporary, _staged_folder(settings.png_dir) as png_dir:
        _, titles = write_report(report_data, temporary)
        staged = write_figures(report_data, png_dir) if png_dir else []
    figures = [Path(settings.png_dir) / Path(f).name for f in staged] if settings.png_dir else []
    lines = [f"wrote {settings.output} ({len(titles)} plots: {', '.join(titles)})"]
    if figures:
        lines.append(f"wrote {len(figures)} PNG figures: {', '.join(str(p) for p in figures)}")
    return CommandResult(
        tuple(titles), (Path(settings.output), *figures), tuple(notes), (*lines, *note_lines(notes))
    )


#: What other spacecal files are, for the one line that refuses them as a verification.
_OTHER_RESULTS = {
    "spacecal.phantom": "a phantom experiment result (spacecal phantom -o)",
    "spacecal.calibration": "a calibration",
    "spacecal.check": "a check result",
    "spacecal.landmark_registration": "a landmark registration",
    "spacecal.acquisition_progress": "an acquisition progress file",
}


def _read_verification(path: str) -> VerificationResult:
    """The verification file, or one line saying what the file is instead."""
    data = read_json_object(path, "verification")
    schema = data.get("schema")
    legacy = schema is None and "points" in data  # early files had no schema name
    if schema != VerificationResult.SCHEMA and not legacy:
        what = _OTHER_RESULTS.get(str(schema), f"a {schema!r} file" if schema else "not a spacecal result")
        raise InvalidInputError(
            f"{path}: --verification takes the file of 'spacecal verify -o'; this is {what}"
        )
    return VerificationResult.from_dict(data, what=path)


@contextlib.contextmanager
def _staged_folder(folder: str | None) -> Iterator[str | None]:
    """A temporary folder beside ``folder`` whose files are moved into it (each by a rename)
    when the block completes, so figures are never left half-written."""
    if folder is None:
        yield None
        return
    target = Path(folder)
    target.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(dir=target, prefix=".staging."))
    try:
        yield str(staging)
        for item in staging.iterdir():
            os.replace(item, target / item.name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


#: A host name (RFC 1123): dot-separated labels of ASCII letters, digits and inner hyphens.
_HOST_NAME = re.compile(r"(?!-)[A-Za-z0-9-]{1,63}(?<!-)(?:\.(?!-)[A-Za-z0-9-]{1,63}(?<!-))*\.?", re.ASCII)
_PORT = re.compile(r"[0-9]{1,5}", re.ASCII)


def igtl_host_port(text: str) -> tuple[str, int | None]:
    """The host and port of ``--igtl HOST[:PORT]``: a host name, an IPv4 address or an IPv6
    address in brackets (``[::1]:18944``); the port None when not given.

    Checked here as a whole, not through a URL parser: that one raises on an unclosed
    bracket, and reads ``ho/st``, ``user@host`` or ``host?x`` as the host ``ho`` or ``host``,
    which would connect somewhere not named.

    Raises
    ------
    InvalidInputError
        Anything else, named.
    """
    where = f"--igtl {quoted(text)}"
    host, port = text, None
    if text.startswith("["):
        closing = text.find("]")
        if closing < 0:
            raise InvalidInputError(f"{where}: an IPv6 address opened with '[' is not closed with ']'")
        host, rest = text[1:closing], text[closing + 1 :]
        try:
            host = str(ipaddress.IPv6Address(host))
        except ValueError:
            raise InvalidInputError(f"{where}: {quoted(host)} in brackets is not an IPv6 address") from None
        if rest:
            if not rest.startswith(":"):
                raise InvalidInputError(f"{where}: expected ':PORT' after the IPv6 address in brackets")
            port = rest[1:]
    elif text.count(":") > 1:
        raise InvalidInputError(f"{where}: write an IPv6 address in brackets, e.g. [::1]:18944")
    else:
        host, colon, after = text.partition(":")
        port = after if colon else None
        if not (_HOST_NAME.fullmatch(host) and len(host) <= 253):
            raise InvalidInputError(f"{where}: {quoted(host)} is not a host name or IPv4 address (HOST:PORT)")
    if port is None:
        return host, None
    if not _PORT.fullmatch(port) or not 1 <= int(port) <= 65535:
        raise InvalidInputError(f"{where}: the port must be a number from 1 to 65535, not {quoted(port)}")
    return host, int(port)


@dataclass(frozen=True)
class ExportSettings:
    """``spacecal export``: a calibration for 3D Slicer, PLUS, or over OpenIGTLink."""

    calibration: str
    slicer: str | None = None
    plus: str | None = None
    igtl: str | None = None
    force: bool = False
    accept_edited: bool = False


def export(settings: ExportSettings) -> CommandResult[CalibrationResult]:
    """Export the calibration to every target named.

    Returns
    -------
    CommandResult of CalibrationResult
        The calibration exported and the files written; its lines say one export each, after a
        ``note: ...`` line for a calibration that cannot be verified or was accepted edited.
    """
    if not (settings.slicer or settings.plus or settings.igtl):
        raise InvalidInputError(
            "say where to export: --slicer FILE.tfm, --plus FILE.xml, --igtl HOST:PORT, --easy-handeye2, "
            "--ros2-launch, --urdf, --static-tf or --ur-calibration"
        )
    guard_outputs([settings.slicer, settings.plus], [settings.calibration], settings.force)
    calibration, notes = open_calibration(settings.calibration, "export", settings.accept_edited)
    error = None if calibration.expected_error is None else calibration.expected_error.position_mm
    done = [f"note: {note}" for note in notes]
    files = []
    if settings.slicer:
        path = write_slicer_transform(calibration.tracker_from_base, settings.slicer)
        files.append(path)
        done.append(f"wrote {path} (loads in 3D Slicer as BaseToTracker; its matrix is tracker_from_base)")
    if settings.plus:
        path = write_plus_coordinate_definitions(
            settings.plus,
            [
                (calibration.tracker_from_base, "Base", "Tracker", error),
                (calibration.tcp_from_marker, "Marker", "TCP", None),
            ],
        )
        files.append(path)
        done.append(f"wrote {path} (PLUS CoordinateDefinitions: BaseToTracker, MarkerToTCP)")
    if settings.igtl:
        from spacecal.adapters.igtl import IGTL_DEFAULT_PORT, publish_transform

        host, port = igtl_host_port(settings.igtl)
        port = IGTL_DEFAULT_PORT if port is None else port
        publish_transform(host, port, "BaseToTracker", calibration.tracker_from_base)
        done.append(f"sent BaseToTracker to igtl://{f'[{host}]' if ':' in host else host}:{port}")
    return CommandResult(
        calibration,
        tuple(Path(f) for f in files),
        tuple(notes),
        tuple(sanitize_for_terminal(line, NOTE_CHARS) for line in done),  # names from the calibration
        provenance=calibration.provenance,
    )


@dataclass(frozen=True)
class ImportPlusSettings:
    """``spacecal import-plus``: a PLUS sequence file as a recording CSV."""

    sequence: str
    output: str
    marker: str = "MarkerToTracker"
    tcp: str = "TCPToBase"
    segment: str = "static"
    force: bool = False


def import_plus(settings: ImportPlusSettings) -> CommandResult[Recording]:
    """Convert the sequence.

    Returns
    -------
    CommandResult of Recording
        The recording; its CSV and metadata written.
    """
    guard_outputs([settings.output, metadata_path(settings.output)], [settings.sequence], settings.force)
    recording = recording_from_plus_sequence(
        settings.sequence, settings.marker, settings.tcp, settings.segment
    )
    path = write_recording(recording, settings.output)
    line = f"wrote {path}: {len(recording)} frames, {int(recording.visible.sum())} with the marker seen"
    return CommandResult(recording, (path, metadata_path(path)), lines=(line,))
