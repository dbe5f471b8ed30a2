"""App functions that estimate: ``calibrate``, ``bound``, ``pivot``."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from spacecal.app._common import (
    check_belongs,
    check_consistent,
    open_calibration,
    provenance_of,
    refuse_overwriting_inputs,
)
from spacecal.app.record import open_record, record_calibration
from spacecal.app.result import CommandResult, Quality, note_lines, paths
from spacecal.core.errors import DegenerateDataError, InvalidInputError
from spacecal.core.text import sanitize_for_terminal
from spacecal.estimators import calibrate as estimate
from spacecal.estimators.methods.likelihood import residual_noise_level, tre_lower_bound
from spacecal.estimators.methods.observations import (
    build_observations,
    marker_geometry_of,
    sphere_noise_from_marker_rms,
)
from spacecal.io.digest import file_sha256
from spacecal.io.pose_files import read_matrix_folder
from spacecal.io.recordings import metadata_path, open_calibrated_recording, open_path
from spacecal.io.results_json import read_json_object, write_calibration, write_json
from spacecal.records import CalibrationResult, NeedleTip, PivotResult, Recording
from spacecal.records.assessment import ErrorThresholds
from spacecal.registration.pivot import pivot_calibration

Point = tuple[float, float, float]


def check_points(points: Sequence[Sequence[float]], option: str) -> np.ndarray | None:
    """Targets (M, 3) in mm, finite; None when there are none."""
    if not points:
        return None
    array = np.asarray(points, dtype=float)
    if array.ndim != 2 or array.shape[1] != 3 or not np.all(np.isfinite(array)):
        raise InvalidInputError(f"{option} takes finite x,y,z in mm")
    if np.any(np.abs(array) > 1e5):
        raise InvalidInputError(
            f"{option}: a point {float(np.max(np.abs(array))):.3g} mm away is not a target"
        )
    return array


def check_positive(value: float | None, option: str, unit: str, low: float = 1e-6, high: float = 1e6) -> None:
    """Refuse a value that is not a finite number in ``low..high`` (``option`` names it)."""
    if value is not None and not (math.isfinite(value) and low <= value <= high):
        raise InvalidInputError(
            f"{option} must be a positive number of {unit} in {low:g}..{high:g}, got {value}"
        )


@dataclass(frozen=True)
class CalibrateSettings:
    """``spacecal calibrate``: estimate ``tracker_from_base`` and ``tcp_from_marker``.

    Attributes
    ----------
    recording : str
        Recording CSV, or with ``tracker_stream`` the raw robot stream.
    output : str
        Calibration JSON to write.
    method : str
        Estimator name (see :data:`spacecal.estimators.ESTIMATORS`).
    tracker_stream : str or None
        The raw tracker stream: the two streams are paired first.
    time_offset_ms : float or None
        With ``tracker_stream``: robot clock minus tracker clock, ms, any finite size (the
        clocks may count from unrelated epochs); None = estimate it.
    targets_in_base : sequence of (x, y, z)
        Points in the base frame (mm) to predict the TRE at.
    sigma_mm : float or None
        Per-axis sphere noise, mm; default: estimated from the tracker's RMS.
    error_thresholds : ErrorThresholds or None
        Limits of the verdict's grades; default 0.5 / 1 / 2 mm.
    include_doubtful_frames : bool
        Also use poses the tracker reported with a status other than ``ok`` (e.g. partially
        out of volume); by default they are left out.
    tracker_kind : str
        What the tracker measures (:data:`TRACKER_KINDS`): ``auto`` (spheres when the recording
        has the tracker's fit RMS or sphere positions, else poses), ``spheres`` (an optical
        tracker of passive or active spheres reporting its fit RMS: refused without it) or
        ``pose`` (a tracker or camera that reports poses only: any fit RMS is ignored and the
        anisotropic noise is learnt from the residuals).
    record : str or None
        Also write the calibration to this record (an SQLite file or a database URL), opened
        before anything is computed.
    tip : str or None
        A pivot result (``spacecal pivot -o``) of the needle on this marker: the calibration
        carries the tip, IK aims it instead of the controller's TCP (:attr:`CalibrationResult.
        tcp_from_needle`), and the expected error is stated there.
    """

    recording: str
    output: str
    method: str = "paper"
    tracker_stream: str | None = None
    time_offset_ms: float | None = None
    targets_in_base: tuple[Point, ...] = ()
    sigma_mm: float | None = None
    error_thresholds: ErrorThresholds | None = None
    force: bool = False
    include_doubtful_frames: bool = False
    tracker_kind: str = "auto"
    record: str | None = None
    tip: str | None = None


#: Choices of ``CalibrateSettings.tracker_kind`` (``--tracker-kind``).
TRACKER_KINDS = ("auto", "spheres", "pose")


def as_tracker_kind(recording: Recording, kind: str) -> Recording:
    """The recording as a tracker of ``kind`` measures it (see :class:`CalibrateSettings`)."""
    if kind not in TRACKER_KINDS:
        raise InvalidInputError(f"--tracker-kind takes one of {', '.join(TRACKER_KINDS)}, got {kind!r}")
    if kind == "pose":
        return recording.as_pose_only()
    if kind == "spheres" and np.isfinite(recording.marker_rms_mm[recording.visible]).sum() < 3:
        raise InvalidInputError(
            "--tracker-kind spheres: the recording has no fit RMS of the tracker (a pose-only tracker?); "
            "use --tracker-kind pose"
        )
    return recording


def calibrate(settings: CalibrateSettings) -> CommandResult[CalibrationResult]:
    """Read a recording (or two raw streams), calibrate it, and write the result.

    Returns
    -------
    CommandResult of CalibrationResult
        The calibration, the file written, its provenance and its verdict as the quality (an
        unusable calibration is written, and does not pass).
    """
    ledger = open_record(settings.record) if settings.record else None
    try:
        out = _calibrate(settings)
        if ledger is not None:
            record_calibration(ledger, out, source="cli")
    finally:
        if ledger is not None:
            ledger.close()
    return out


def _calibrate(settings: CalibrateSettings) -> CommandResult[CalibrationResult]:
    refuse_overwriting_inputs(
        settings.output,
        settings.recording,
        metadata_path(settings.recording),
        settings.tracker_stream,
        settings.tip,
        force=settings.force,
        any_file=True,
    )
    check_positive(settings.sigma_mm, "--sigma-mm", "millimetres", 1e-4, 10.0)
    tip = read_needle_tip(settings.tip) if settings.tip else None
    targets = check_points(settings.targets_in_base, "--target")
    offset_s = None
    if settings.time_offset_ms is not None:
        if not math.isfinite(settings.time_offset_ms):
            raise InvalidInputError(
                "--time-offset-ms takes a finite number of milliseconds (robot clock minus "
                "tracker clock), or 'estimate'"
            )
        offset_s = settings.time_offset_ms / 1000.0
    try:
        opened = open_path(
            settings.recording, settings.tracker_stream or None, offset_s, offset_option="--time-offset-ms"
        )
    except DegenerateDataError as exc:  # only raw streams' pairing is degenerate
        raise DegenerateDataError(
            f"{exc}; pass --time-offset-ms (robot clock minus tracker clock, ms)"
        ) from None
    note = opened.pairing_note
    recording = opened.recording
    recording = as_tracker_kind(recording, settings.tracker_kind)
    doubtful = int(recording.doubtful.sum())
    doubtful_note = None
    if doubtful:
        statuses = ", ".join(sorted(set(np.asarray(recording.marker_status)[recording.doubtful].tolist())))
        if settings.include_doubtful_frames:
            recording = recording.trusting_doubtful_frames()
            doubtful_note = f"{doubtful} doubtful frame(s) ({statuses}) used as asked"
        else:
            doubtful_note = (
                f"{doubtful} doubtful frame(s) ({statuses}) left out; --include-doubtful-frames uses them"
            )
    options: dict[str, Any] = {}
    if targets is not None:
        options["targets_in_base"] = targets
    if settings.sigma_mm is not None:
        options["sigma_mm"] = settings.sigma_mm
    if settings.error_thresholds is not None:
        options["error_thresholds"] = settings.error_thresholds
    if tip is not None:
        options["needle_tip"] = tip
    # a recording that another reading of its conventions explains far better is refused
    # before any estimate; the rest is judged by its expected error, however large its residuals
    check_consistent(recording, str(settings.recording))
    result = estimate(recording, settings.method, **options)
    provenance = provenance_of(recording, opened.source, settings.recording, settings.tracker_kind)
    notes = []
    if provenance.tool_definition is not None and provenance.tool_definition_sha256 is None:
        notes.append(
            f"the recording names the tool definition {provenance.tool_definition}, which is not there: "
            "the calibration records its path but not its sha256"
        )
    result = result.replace(provenance=provenance)
    path = write_calibration(result, settings.output)
    return calibrate_result(result, path, tuple(n for n in (note, doubtful_note) if n), tuple(notes))


def read_needle_tip(path: str) -> NeedleTip:
    """The needle tip of a pivot result file (``spacecal pivot -o``), with its error
    covariance and the file's name and sha256.

    Raises
    ------
    InvalidInputError
        For a file that is not a pivot result.
    """
    pivot = PivotResult.from_dict(read_json_object(path, "pivot result"), f"{path}")
    return NeedleTip.from_pivot(pivot, str(path), file_sha256(path))


def calibrate_result(
    result: CalibrationResult, path: Path, clock_notes: tuple[str, ...] = (), notes: tuple[str, ...] = ()
) -> CommandResult[CalibrationResult]:
    """The result of ``calibrate`` from the calibration written to ``path``, the notes on its
    clocks and doubtful frames (printed as they are) and other notes."""
    counts = result.sample_counts
    lines = [*clock_notes, *note_lines(notes)]
    lines.append(f"wrote {path} (method {result.method}; {counts['used']} of {counts['total']} samples used)")
    fits = result.sweep_fits
    if fits is not None and fits.sphere is not None:
        straight = ", ".join(
            f"{sanitize_for_terminal(k, 60)} {v.straightness_rms_mm:.3f} mm" for k, v in fits.lines.items()
        )  # segment labels come from the recording file
        lines.append(
            f"sphere: radius {fits.sphere.radius_mm:.2f} mm, fit RMS {fits.sphere.rms_mm:.3f} mm; "
            f"line straightness RMS: {straight}"
        )
    assessment = result.assessment
    residuals = None if assessment is None else assessment.residuals
    if residuals is not None and residuals.position_rms_mm is not None:
        # a kinematic calibration places the TCP with the kinematics it identified, as the
        # report does; the line says which, so the two are read as the same quantity
        tcp = "identified robot kinematics" if result.robot_model is not None else "recorded TCP poses"
        lines.append(
            f"marker residuals (RMS, {tcp}): position {residuals.position_rms_mm:.3f} mm, "
            f"rotation {residuals.rotation_rms_deg:.3f} deg"
        )
    if result.predicted_tre_mm:
        tre = result.predicted_tre_mm
        lines.append(
            f"predicted TRE: {tre['site']:.3f} mm at the site, {tre['cube_rms']:.3f} mm RMS over a "
            f"{tre['cube_side_mm']:.0f} mm cube around it"
        )
        lines += [f"  at {t['target_in_base_mm']}: {t['tre_mm']:.3f} mm" for t in tre.get("targets", [])]
    if counts.get("rejected_outlier"):
        lines.append(f"outliers: {counts['rejected_outlier']} frames flagged (listed in the result file)")
    tip = result.tcp_from_needle
    if result.needle_tip is not None and tip is not None:
        lines.append(
            "needle tip (pivot, "
            f"{result.needle_tip.sd_mm:.3f} mm per axis): IK aims it at "
            + ", ".join(f"{v:.2f}" for v in tip[:3, 3])
            + " mm in the TCP frame"
        )
    expected = result.expected_error
    if expected is not None and expected.position_mm is not None:
        lines.append(
            f"expected error at a target near the site: {expected.position_mm:.2f} mm, "
            f"{expected.posture_deg:.2f} deg"
        )
    quality = None
    judged = result.verdict
    if judged is not None:
        lines.append(f"verdict: {judged.text}")
        quality = Quality(
            judged.usable,
            judged.text,
            f"calibration unusable (written to {path}): {'; '.join(judged.reasons)}",
        )
    return CommandResult(result, (path,), (*clock_notes, *notes), tuple(lines), quality, result.provenance)


@dataclass(frozen=True)
class BoundSettings:
    """``spacecal bound``: the Cramér–Rao lower bound on TRE for a recording.

    ``accept_edited``: use the calibration's own recording although it changed since the
    calibration was made from it (an edited calibration is refused all the same).
    """

    recording: str
    calibration: str
    sigma_mm: float | None = None
    targets_in_base: tuple[Point, ...] = ()
    accept_edited: bool = False


def recorded_noise(recording: Recording, calibration: CalibrationResult) -> tuple[float, str]:
    """The per-axis sphere noise (mm) a recording says it has, and where it came from: the
    tracker's fit RMS in it; else the noise the calibration was computed with (``calibrate
    --sigma-mm``); else the noise its residuals on the recording show (chi-square over the
    degrees of freedom, as the likelihood learns it for a pose-only tracker), which includes
    whatever systematic error the calibration leaves."""
    rms = recording.marker_rms_mm[recording.visible]
    if np.isfinite(rms).sum() >= 3:
        sigma = sphere_noise_from_marker_rms(rms, len(marker_geometry_of(recording)))
        return float(sigma), "from the tracker's fit RMS in the recording"
    stored = None if calibration.noise is None else calibration.noise.sigma_per_axis_mm
    if isinstance(stored, (int, float)) and not isinstance(stored, bool) and 0.0 < stored < math.inf:
        return float(stored), "the noise the calibration was computed with"
    obs = build_observations(recording)
    learnt = residual_noise_level(obs, calibration.tracker_from_base, calibration.tcp_from_marker)
    if not (math.isfinite(learnt) and learnt > 0.0):
        raise InvalidInputError(
            "the recording shows no noise to bound with (no tracker fit RMS, residuals of zero): "
            "pass --sigma-mm, the tracker's per-axis sphere noise in mm"
        )
    return float(learnt), (
        "learnt from the calibration's residuals on the recording, which has no tracker fit RMS; "
        "systematic error counts as noise here, so the bound is on the high side"
    )


def _point(values: Sequence[float]) -> Point:
    x, y, z = (float(v) for v in values)
    return (x, y, z)


@dataclass(frozen=True)
class TargetBound:
    """The bound at one target: ``target_in_base_mm`` (3,) and ``tre_mm``."""

    target_in_base_mm: Point
    tre_mm: float


@dataclass(frozen=True)
class BoundResult:
    """What ``spacecal bound`` found: the Cramér–Rao lower bound on TRE for a recording.

    Attributes
    ----------
    site_mm : float
        The bound at the site (the centroid of the marker positions, base frame), mm.
    site_in_base_mm : tuple of float
        That site (3,), base frame, mm.
    cube_rms_mm : float
        RMS of the bound over a ``cube_side_mm`` cube around the site, mm.
    cube_side_mm : float
        The cube's side, mm.
    targets : tuple of TargetBound
        The bound at each ``--target``.
    sigma_mm : float
        The per-axis sphere noise the bound was computed for, mm.
    sigma_source : str
        Where ``sigma_mm`` came from (given, the tracker's fit RMS, the calibration, or learnt).
    """

    site_mm: float
    site_in_base_mm: Point
    cube_rms_mm: float
    cube_side_mm: float
    targets: tuple[TargetBound, ...]
    sigma_mm: float
    sigma_source: str

    @classmethod
    def from_summary(cls, summary: dict[str, Any], sigma_mm: float, sigma_source: str) -> BoundResult:
        """From :func:`~spacecal.estimators.methods.likelihood.tre_summary`'s dict."""
        return cls(
            site_mm=float(summary["site"]),
            site_in_base_mm=_point(summary["site_in_base_mm"]),
            cube_rms_mm=float(summary["cube_rms"]),
            cube_side_mm=float(summary["cube_side_mm"]),
            targets=tuple(
                TargetBound(_point(t["target_in_base_mm"]), float(t["tre_mm"]))
                for t in summary.get("targets", [])
            ),
            sigma_mm=float(sigma_mm),
            sigma_source=sigma_source,
        )


def bound(settings: BoundSettings) -> CommandResult[BoundResult]:
    """The Cramér–Rao lower bound on TRE for a recording.

    Returns
    -------
    CommandResult of BoundResult
        The bound at the site, over the cube and at the targets (mm), with the per-axis sphere
        noise it was computed for (as given, else from the recording) and where that came from.
        Its notes say e.g. that the calibration, of an older version, cannot be verified.
    """
    check_positive(settings.sigma_mm, "--sigma-mm", "millimetres", 1e-4, 10.0)
    calibration, notes = open_calibration(settings.calibration, "bound")
    opened = open_calibrated_recording(calibration, settings.recording, settings.accept_edited)
    if opened is None:
        raise InvalidInputError(f"{settings.recording}: no such recording")
    recording = opened.recording
    check_belongs(
        recording, calibration.tracker_from_base, calibration.tcp_from_marker, str(settings.recording)
    )
    sigma_mm, source = settings.sigma_mm, "given with --sigma-mm"
    if sigma_mm is None:
        sigma_mm, source = recorded_noise(recording, calibration)
    found = tre_lower_bound(
        recording,
        calibration.tracker_from_base,
        calibration.tcp_from_marker,
        sigma_mm,
        check_points(settings.targets_in_base, "--target"),
    )
    result = BoundResult.from_summary(found, float(sigma_mm), source)
    lines = [
        *note_lines(notes),
        f"Cramer-Rao lower bound on TRE for {settings.recording} with {result.sigma_mm:.3g} mm per-axis "
        f"sphere noise ({source}):",
        f"  {result.site_mm:.4f} mm at the site, {result.cube_rms_mm:.4f} mm RMS over a "
        f"{result.cube_side_mm:.0f} mm cube around it",
        *(f"  at {list(t.target_in_base_mm)}: {t.tre_mm:.4f} mm" for t in result.targets),
    ]
    return CommandResult(result, notes=tuple(notes), lines=tuple(lines))


@dataclass(frozen=True)
class PivotSettings:
    """``spacecal pivot``: pivot calibration of a pointer or needle tip.

    Attributes
    ----------
    poses : str
        Folder of 4x4 ``.txt`` pose files, or a recording CSV.
    method : str
        ``aos`` (algebraic one-step) or ``sphere``.
    subset : str or None
        File listing the pose file names to use.
    output : str or None
        Pivot result JSON.
    """

    poses: str
    method: str = "aos"
    subset: str | None = None
    output: str | None = None
    force: bool = False


def pivot(settings: PivotSettings) -> CommandResult[PivotResult]:
    """Pivot calibration.

    Returns
    -------
    CommandResult of PivotResult
        The tip and pivot point; the result JSON written, if asked.
    """
    source = Path(settings.poses)
    refuse_overwriting_inputs(
        settings.output, settings.poses, settings.subset, force=settings.force, any_file=True
    )
    if settings.output and source.is_dir() and Path(settings.output).resolve().parent == source.resolve():
        if Path(settings.output).suffix == ".txt" and not settings.force:
            raise InvalidInputError(
                f"{settings.output}: would overwrite a pose file; choose another file or pass --force"
            )
    if source.is_dir():
        names = None
        if settings.subset:
            subset = Path(settings.subset)
            if not subset.is_file():
                raise InvalidInputError(f"{subset}: no such subset file")
            try:
                names = subset.read_text(encoding="utf-8").split()
            except UnicodeDecodeError:
                raise InvalidInputError(f"{subset}: not UTF-8 text (one pose file name per line)") from None
        poses = read_matrix_folder(source, names)
    else:
        poses = open_path(source).recording.tracker_from_marker_stack
    result = pivot_calibration(poses, settings.method)
    path = write_json(result.to_dict(), settings.output) if settings.output else None
    return pivot_result(result, paths(path))


def pivot_result(result: PivotResult, files: tuple[Path, ...] = ()) -> CommandResult[PivotResult]:
    """The result of ``pivot`` from its pivot calibration and the file written."""
    summary = result.to_dict()
    lines = [
        *(f"wrote {path}" for path in files),
        f"pivot calibration ({result.method}, {summary['frames']} frames)",
        "  tip in marker   (mm): " + ", ".join(f"{v:.3f}" for v in result.tip_in_marker),
        "  pivot in tracker (mm): " + ", ".join(f"{v:.3f}" for v in result.pivot_in_tracker),
        f"  residual: RMS {result.rms_mm:.3f} mm (3-D), {result.rms_per_axis_mm:.3f} mm per axis "
        f"(scikit-surgerycalibration's figure), mean {summary['residual_mean_mm']:.3f}, "
        f"max {summary['residual_max_mm']:.3f} mm",
    ]
    return CommandResult(result, files, lines=tuple(lines))
