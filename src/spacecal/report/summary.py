"""What a person reads first: the judgement of a calibration, and the facts behind it.

The HTML report's first screen is built from :func:`assess` (the verdict, coloured, and the
reasons for a red flag) and :func:`provenance_facts` (what was calibrated with what, when,
from which data, by which software). Both read records only; no figure is drawn here.

The judgement of the calibration itself is its verdict (:class:`spacecal.records.Verdict`),
graded once, when it was made, against the thresholds in force then (``calibrate
--thresholds-mm``): the report shows its headline and colour (:attr:`Verdict.headline`,
:attr:`Verdict.level`), the same words the command line prints and the station shows; it
grades nothing again. Evidence the verdict could not see raises a red flag of its own, named
in the headline:

* the calibration does not explain the recording at hand: its residuals are far above those of
  the recording's own closed-form fit (:func:`spacecal.estimators.methods.conventions.calibration_mismatch`;
  no fixed limit, since a distant camera leaves several mm);
* a verification's mean position error exceeds the paper's bound;
* the last check failed.
"""

from __future__ import annotations

import datetime
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from spacecal.estimators.methods.conventions import calibration_mismatch
from spacecal.estimators.methods.samples import sample_residuals
from spacecal.estimators.registry import ESTIMATORS
from spacecal.models.kinematics import forward_kinematics
from spacecal.records import CalibrationResult, CheckResult, Recording, VerificationResult
from spacecal.records.assessment import ExpectedError
from spacecal.records.paper_reference import PAPER_VERIFICATION


@dataclass
class Residuals:
    """Per-sample marker residuals and where they came from.

    Attributes
    ----------
    time_s : numpy.ndarray, shape (N,)
    segment : numpy.ndarray of str, shape (N,)
    position_mm, rotation_deg : numpy.ndarray, shape (N,)
        Distance of the marker origin and rotation angle between the measured and the
        predicted ``tracker_from_marker``.
    source : str
        ``recomputed from the recording`` or ``as stored with the calibration``.
    mismatch : str or None
        Recomputed only: why the calibration does not belong to the recording (it explains it
        far worse than the recording's own closed-form fit), else None.
    """

    time_s: np.ndarray
    segment: np.ndarray
    position_mm: np.ndarray
    rotation_deg: np.ndarray
    source: str
    mismatch: str | None = None

    @property
    def position_rms_mm(self) -> float:
        return float(np.sqrt(np.mean(self.position_mm**2)))

    @property
    def rotation_rms_deg(self) -> float:
        return float(np.sqrt(np.mean(self.rotation_deg**2)))


def residuals_of(calibration: CalibrationResult, recording: Recording | None) -> Residuals | None:
    """The marker residuals of a calibration: recomputed from ``recording`` when given (with
    the robot model the calibration identified, if any), else the per-sample residuals
    stored in its diagnostics; None when neither is available."""
    if recording is not None and recording.visible.any():
        if calibration.robot_model is not None and np.all(np.isfinite(recording.joints_rad)):
            # a kinematic calibration predicts the TCP with the model it identified
            recording = _with_base_from_tcp(
                recording, forward_kinematics(calibration.robot_model, recording.joints_rad)
            )
        found = sample_residuals(recording, calibration.tracker_from_base, calibration.tcp_from_marker)
        rows = found["rows"]
        return Residuals(
            recording.time_s[rows],
            recording.segment[rows],
            np.asarray(found["position_mm"]),
            np.asarray(found["rotation_deg"]),
            "recomputed from the recording",
            calibration_mismatch(recording, calibration.tracker_from_base, calibration.tcp_from_marker),
        )
    kept = None if calibration.assessment is None else calibration.assessment.residuals
    stored = None if kept is None else kept.per_sample
    if stored:
        return Residuals(
            np.array([row.time_s for row in stored]),
            np.array([row.segment for row in stored]),
            np.array([row.position_mm for row in stored]),
            np.array([row.rotation_deg for row in stored]),
            "as stored with the calibration",
        )
    return None


def _with_base_from_tcp(recording: Recording, base_from_tcp_stack: np.ndarray) -> Recording:
    import dataclasses

    return dataclasses.replace(recording, base_from_tcp_stack=base_from_tcp_stack)


@dataclass
class Assessment:
    """The judgement shown first.

    Attributes
    ----------
    level : str
        ``ok`` (green), ``alarm`` (red) or ``unknown`` (grey: no verdict and no red flag).
    headline : str
        The verdict's headline (:attr:`spacecal.records.Verdict.headline`), or ``Do not use:``
        and the evidence the verdict did not see.
    verdict : str or None
        The calibration's own verdict sentence.
    reasons : list of str
        Why the flag is red (empty when it is not).
    numbers : list of (str, str)
        Key figures as (label, value with unit), in reading order.
    """

    level: str
    headline: str
    verdict: str | None
    reasons: list[str] = field(default_factory=list)
    numbers: list[tuple[str, str]] = field(default_factory=list)


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        return None
    return float(value)


def expected_error(calibration: CalibrationResult) -> ExpectedError | None:
    """The calibration's expected error (``position_mm``, ``posture_deg``, ``basis``) when it
    carries one and it holds a position figure; None otherwise."""
    entry = calibration.expected_error
    if entry is None or entry.position_mm is None:
        return None
    return entry


def assess(
    calibration: CalibrationResult,
    residuals: Residuals | None = None,
    verification: VerificationResult | None = None,
    check_history: list[CheckResult] | None = None,
) -> Assessment:
    """Judge a calibration from its verdict, residuals, predicted error, verification and checks."""
    judged = calibration.verdict
    verdict = judged.text if judged is not None else None
    reasons: list[str] = []
    hard: list[tuple[str, str]] = []  # (in the headline, in the reasons): evidence the verdict did not see
    numbers: list[tuple[str, str]] = []

    expected = expected_error(calibration)
    tre = calibration.predicted_tre_mm or {}
    site, cube = _number(tre.get("site")), _number(tre.get("cube_rms"))
    if expected is not None and expected.position_mm is not None:
        position = expected.position_mm
        posture = expected.posture_deg
        text = f"{position:.2f} mm" + (f", {posture:.2f} deg" if posture is not None else "")
        basis = expected.basis
        numbers.append(("expected error at the target", text + (f" ({basis})" if basis else "")))
    if site is not None:
        numbers.append(("predicted error at the site (RMS)", f"{site:.3f} mm"))
    if cube is not None:
        side = _number(tre.get("cube_side_mm"))
        label = f"predicted error over a {side:g} mm cube (RMS)" if side else "predicted error over the cube"
        numbers.append((label, f"{cube:.3f} mm"))
    if site is None and expected is None:
        numbers.append(("predicted error at the site", "not available (no uncertainty with this result)"))

    if residuals is not None:
        rms = residuals.position_rms_mm
        numbers.append(
            (
                "marker residuals (RMS)",
                f"{rms:.3f} mm, {residuals.rotation_rms_deg:.3f} deg ({residuals.source})",
            )
        )
        # no fixed limit on the residuals: a distant camera leaves several mm and is sound;
        # the flag is raised when the recording's own closed-form fit explains it far better
        if residuals.mismatch is not None:
            hard.append(
                (
                    "it does not explain this recording",
                    f"marker residuals are {rms:.2f} mm RMS: {residuals.mismatch}",
                )
            )
    else:
        kept = None if calibration.assessment is None else calibration.assessment.residuals
        stored = None if kept is None else kept.position_rms_mm
        if stored is not None:
            numbers.append(("marker residuals (RMS, as stored)", f"{stored:.3f} mm"))

    if verification is not None:
        stats = verification.statistics()["position_mm"]
        posture_stats = verification.statistics()["posture_deg"]
        bound = PAPER_VERIFICATION["position_mean_bound_mm"]
        where = "simulated" if verification.simulated else "measured"
        numbers.append(
            (
                f"verification, {len(verification.position_error_mm)} targets ({where})",
                f"position mean {stats['mean']:.2f} mm (max {stats['max']:.2f}), "
                f"posture mean {posture_stats['mean']:.2f} deg; paper: mean < {bound:g} mm",
            )
        )
        if stats["mean"] > bound:
            hard.append(
                (
                    "the verification missed",
                    f"verification mean position error {stats['mean']:.2f} mm is above the paper's "
                    f"{bound:g} mm",
                )
            )
    if check_history:
        last = check_history[-1]
        outcome = "PASS" if last.passed else "FAIL"
        numbers.append(
            (
                f"last check ({len(check_history)} in the history)",
                f"{outcome}: worst TCP error {float(np.max(last.tcp_error_mm)):.2f} mm "
                f"(threshold {last.threshold_mm:.2f} mm), {_date(last.checked_utc)}",
            )
        )
        if not last.passed:
            hard.append(("the last check failed", f"the last check ({_date(last.checked_utc)}) failed"))

    # the verdict sentence is shown beside the reasons: they list only what it does not say
    reasons.extend(long for _, long in hard)
    if hard:
        level, headline = "alarm", "Do not use: " + "; ".join(short for short, _ in hard)
    elif judged is not None:
        level, headline = judged.level, judged.headline
    else:
        level, headline = "unknown", "No verdict"
    return Assessment(level, headline, verdict, reasons, numbers)


def _date(iso: str) -> str:
    """``2026-11-22T23:13:08+00:00`` -> ``2026-11-22 23:13 UTC``; other text as it is."""
    if not iso:
        return "unknown"
    try:
        moment = datetime.datetime.fromisoformat(iso.replace("Z", "+00:00"))
    except ValueError:
        return iso
    if moment.tzinfo is not None:
        moment = moment.astimezone(datetime.timezone.utc)
    return moment.strftime("%Y-%m-%d %H:%M UTC")


def _describe_device(entry: Any, keys: tuple[str, ...]) -> str | None:
    if isinstance(entry, str):
        return entry
    if not isinstance(entry, dict):
        return None
    parts = [str(entry[k]) for k in keys if entry.get(k) not in (None, "")]
    return ", ".join(dict.fromkeys(parts)) or None


def _digest(sha256: str | None) -> str:
    return f" (sha256 {sha256[:12]}...)" if sha256 else ""


def provenance_facts(
    calibration: CalibrationResult, recording: Recording | None = None
) -> list[tuple[str, str]]:
    """What was calibrated with what, when, from which data and by which software, as
    (label, text) rows."""
    provenance = calibration.provenance
    metadata = recording.metadata if recording is not None else {}
    devices = provenance.devices or {}
    facts: list[tuple[str, str]] = []
    spec = ESTIMATORS.get(calibration.method)
    facts.append(("method", calibration.method + (f": {spec.summary}" if spec else "")))
    counts = calibration.sample_counts
    used, total = counts.get("used"), counts.get("total")
    if used is not None and total is not None:
        rejected = {
            k.removeprefix("rejected_").replace("_", " "): v
            for k, v in counts.items()
            if k.startswith("rejected_") and v
        }
        detail = ", ".join(f"{v} {k}" for k, v in rejected.items())
        facts.append(("samples used", f"{used} of {total}" + (f" (rejected: {detail})" if detail else "")))
    per_segment = counts.get("per_segment")
    if isinstance(per_segment, dict) and per_segment:
        facts.append(("samples per sweep", ", ".join(f"{k} {v}" for k, v in per_segment.items())))

    robot = _describe_device(
        devices.get("robot"), ("station_name", "model", "name", "url", "serial", "firmware")
    )
    robot = robot or _describe_device(metadata.get("robot"), ("station_name", "model", "name", "url"))
    if calibration.robot_model is not None:
        robot = (
            robot or calibration.robot_model.name
        ) + "; kinematic (DH) parameters identified with this calibration"
    facts.append(("robot", robot or "not recorded"))
    tracker = _describe_device(
        devices.get("tracker"), ("station_name", "name", "model", "url", "serial", "firmware")
    )
    tracker = tracker or _describe_device(metadata.get("tracker"), ("station_name", "name", "model", "url"))
    rate = None
    for entry in (devices.get("tracker"), metadata.get("tracker")):
        if isinstance(entry, dict) and _number(entry.get("rate_hz")):
            rate = float(entry["rate_hz"])
            break
    facts.append(("tracker", (tracker or "not recorded") + (f" at {rate:g} Hz" if rate else "")))
    marker = _describe_device(metadata.get("marker"), ("name",))
    if marker:
        facts.append(("marker", marker))

    if provenance.simulated is True:
        scenario = provenance.scenario or metadata.get("scenario") or {}
        scenario = scenario if isinstance(scenario, dict) else {}
        name, seed = scenario.get("name"), scenario.get("seed")
        facts.append(
            (
                "data",
                "SIMULATED in spacecal's simulator"
                + (
                    f" (scenario {name}" + (f", seed {seed}" if seed is not None else "") + ")"
                    if name
                    else ""
                )
                + ": not a measurement of a real system",
            )
        )
    elif provenance.simulated is False:
        facts.append(("data", "measured on real devices"))
    else:
        facts.append(("data", "origin unknown (imported or older file)"))
    recording_path = provenance.recording
    if recording_path:
        facts.append(("recording", recording_path + _digest(provenance.recording_sha256)))
    if provenance.tracker_stream:
        stream = provenance.tracker_stream + _digest(provenance.tracker_stream_sha256)
        facts.append(("tracker stream", stream))
    if provenance.tool_definition:
        facts.append(
            ("tool definition", provenance.tool_definition + _digest(provenance.tool_definition_sha256))
        )
    integrity = calibration.integrity
    if integrity is not None:
        if integrity.verified:
            state = f"as written (content hash {integrity.content_sha256[:12]}... verified)"
        elif integrity.edited:
            state = "EDITED since it was written (content hash differs): not the calibration as computed"
        else:
            state = f"cannot be verified (a version {calibration.schema_version} file: no content hash)"
        facts.append(("file", state))
    facts.append(("calibrated", _date(provenance.created_utc)))
    facts.append(("software", provenance.software or "unknown"))
    return facts
