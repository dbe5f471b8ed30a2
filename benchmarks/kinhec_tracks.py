"""spacecal on the external KinHEC hand-eye benchmark, beside KinHEC's own solvers.

KinHEC (``pip install kinhec``, MIT) generates robot-world / hand-eye sequences with known
ground truth. This script generates a tier (or reuses a cached copy), converts each sequence
of the tracks noise, robot_error, outliers, temporal and motion to a spacecal recording (see
``kinhec_conversion.py`` beside it for the frames; every conversion is checked first: KinHEC's
noise-free columns must fit its ground truth through the converted chain to 1e-6 mm), writes it
to files and calibrates them through ``spacecal.app.calibrate`` with every method, as the
command line would. A method that raises is recorded as refused, with its one-line message.
KinHEC's reference solvers run on the same sequences under KinHEC's own protocol (keyframes at
least 5 deg or 2 cm apart, at most 200; asynchronous streams paired at the offset estimated
from the streams, and for reference at the true one).

True errors use KinHEC's metric (``kinhec.metrics.calibration_errors``): rotation (deg,
geodesic) and translation (mm) of ``X = tcp_from_marker`` and ``Y = base_from_tracker``
(``inv(tracker_from_base)``). The site error is the calibration's own error at the targets
spacecal's expected error speaks of: the mean distance between where the estimated and the
true ``tracker_from_base`` put the TCP at the frames near the site
(:func:`spacecal.estimators.assessment.held_out_misfit.near_site`); the verification error adds the robot's
own error there (reported against true TCP), as a verification on the robot would see it.

Frames: eye-to-hand the camera is spacecal's tracker and KinHEC's marker its marker;
eye-in-hand the calibration target is the tracker and the camera the marker; KinHEC's flange
is the TCP. KinHEC's trackers report poses only (no fit RMS); joint angles and the robot model
go with the arms spacecal can model: the UR arms and the standard-DH ones (the KUKA LBR iiwa);
``kinematic`` is skipped for the others.

    python benchmarks/kinhec_tracks.py [--tier smoke|small|medium] [--data DIR] [--limit N]
        [--tracks noise robot_error outliers temporal motion] [--methods ml shah ...]
        [--json out.json] [--workers 1]
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import io
import json
import math
import os
import re
import subprocess
import sys
import tempfile
import time
from collections import Counter, defaultdict
from pathlib import Path

# One BLAS thread per process: the solvers' matrices are small, and on a shared machine
# threaded BLAS only contends (measured: spacecal's li 21 s with threads, 2.8 s without);
# ``--workers`` runs sequences in parallel instead.
for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

import kinhec  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from kinhec import motions as kinhec_motions  # noqa: E402
from kinhec import se3 as kinhec_se3  # noqa: E402
from kinhec import solvers as kinhec_solvers  # noqa: E402
from kinhec.benchmark import (  # noqa: E402
    KEYFRAME_MIN_ROT_DEG,
    KEYFRAME_MIN_TRANS_M,
    MAX_KEYFRAMES,
    SOLVERS,
)
from kinhec.io import load_manifest, load_sequence  # noqa: E402
from kinhec.metrics import calibration_errors  # noqa: E402

from spacecal import app  # noqa: E402
from spacecal.core.errors import SpacecalError  # noqa: E402
from spacecal.estimators import ESTIMATORS, Need  # noqa: E402
from spacecal.estimators.assessment.gaussian import probability_within  # noqa: E402
from spacecal.estimators.assessment.held_out_misfit import SITE_RADIUS_MM, SITE_TILT_DEG, near_site  # noqa: E402
from spacecal.io.raw_streams import write_raw_recording  # noqa: E402
from spacecal.io.recording_csv import write_recording  # noqa: E402
from spacecal.records.assessment import ErrorThresholds  # noqa: E402


def _load_conversion():
    """``kinhec_conversion.py`` beside this file, loaded by path (benchmarks is no package)."""
    spec = importlib.util.spec_from_file_location(
        "kinhec_conversion", Path(__file__).resolve().parent / "kinhec_conversion.py"
    )
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


conversion = _load_conversion()

TRACKS = ("noise", "robot_error", "outliers", "temporal", "motion")
TRACK_ALIASES = {"outlier": "outliers", "robot-error": "robot_error"}
#: spacecal's methods, in the order of the tables
SPACECAL_METHODS = tuple(ESTIMATORS)
#: KinHEC's solvers are labelled ``kinhec:<name>`` (two share a name with spacecal's methods)
KINHEC = "kinhec:"
#: KinHEC's reference the ratios compare ``ml`` with
REFERENCE = KINHEC + "shah+lm"
#: The limit an ``unusable`` statement is above: the default ``poor`` limit the runs grade by.
UNUSABLE_ABOVE_MM = ErrorThresholds().poor_mm
#: variants of the reference: every paired frame (no keyframes), the true clock offset
ALL_FRAMES = " (all frames)"
TRUE_OFFSET = " (true offset)"


def default_data_dir(tier: str) -> Path:
    """A cache outside the repository: ``$XDG_CACHE_HOME/spacecal/kinhec/<tier>``."""
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return cache / "spacecal" / "kinhec" / tier


def tier_config(tier: str) -> Path:
    """KinHEC's YAML of a tier, by absolute path (its loader looks in the working folder first)."""
    path = Path(tier)
    if path.suffix in (".yaml", ".yml") and path.is_file():
        return path.resolve()
    return Path(kinhec.__file__).parent / "configs" / f"{tier}.yaml"


def ensure_data(tier: str, data: Path, tracks: list[str], workers: int) -> None:
    """Generate the tier's tracks into ``data`` unless every planned sequence is there."""
    from kinhec.pipeline import generate_dataset
    from kinhec.plans import build_plan, load_tier

    config = tier_config(tier)
    planned = {t: len(c) for t, c in build_plan(load_tier(str(config)), tracks).items()}
    if (data / "sequences.parquet").is_file():
        have = load_manifest(data, tracks)["track"].value_counts().to_dict()
        if all(have.get(t, 0) >= n for t, n in planned.items()):
            print(f"KinHEC data: reusing {data} ({sum(planned.values())} sequences)", file=sys.stderr)
            return
    print(f"KinHEC data: generating tier {tier} tracks {', '.join(tracks)} into {data}", file=sys.stderr)
    started = time.perf_counter()
    with contextlib.redirect_stdout(sys.stderr):
        generate_dataset(
            str(config), data, workers=workers, tracks=tracks, work_dir=data / "work", write_card=False
        )
    print(f"KinHEC data: generated in {time.perf_counter() - started:.0f} s", file=sys.stderr)


def spread_rows(manifest, limit: int | None):
    """The manifest's rows, or ``limit`` of them spread evenly over its order (the factor grid)."""
    if limit is None or len(manifest) <= limit:
        return manifest
    picks = np.unique(np.linspace(0, len(manifest) - 1, limit).round().astype(int))
    return manifest.iloc[picks]


# ---------------------------------------------------------------------------------------------
# one sequence
# ---------------------------------------------------------------------------------------------


def _first_line(exc: BaseException, folder: Path) -> str:
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return text.replace(str(folder) + os.sep, "").replace(str(folder), "")


#: spacecal's grades, best first
GRADES = ("good", "acceptable", "poor", "unusable")


def _verdict(result) -> tuple[str | None, str | None, float | None]:
    """Grade, sentence and graded expected error of a result, whether its verdict is a record
    or (older results) a sentence whose first word is the grade."""
    judged = result.verdict  # an older result's sentence is read into the record too
    if judged is None:
        return None, None, None
    return judged.grade, judged.text, _finite(judged.expected_error_mm)


def _finite(value) -> float | None:
    return float(value) if value is not None and math.isfinite(float(value)) else None


class Truth:
    """What the errors of one sequence are measured against."""

    def __init__(self, seq):
        self.seq = seq
        self.tracker_from_base, self.tcp_from_marker = conversion.truth(seq)
        # the measured robot poses paired with each camera frame (at the true clock offset),
        # the true ones there, and the frames with a measurement
        reported_m, _, valid = seq.paired_measurements()
        ok = valid & np.isfinite(reported_m).all(axis=(1, 2))
        reported = conversion.in_mm(reported_m[ok])
        true = conversion.in_mm(seq.camera.T_base_ee_gt[ok])
        site = near_site(reported, SITE_RADIUS_MM, SITE_TILT_DEG)
        self.reported_tcp_mm = reported[site, :3, 3]
        self.true_tcp_mm = true[site, :3, 3]

    def errors(self, x_m: np.ndarray, y_m: np.ndarray | None) -> dict:
        """KinHEC's errors of ``(X, Y)`` (metres), and the site and verification errors."""
        seq = self.seq
        out = calibration_errors(x_m, seq.X, y_m, seq.Y if y_m is not None else None)
        if y_m is None:
            return out
        tracker_from_base = np.linalg.inv(conversion.in_mm(y_m[None])[0])
        out["tracker_from_base_trans_err_mm"] = conversion.pose_error(
            tracker_from_base, self.tracker_from_base
        )[1]
        out["site_error_mm"] = conversion.site_error_mm(
            tracker_from_base, self.tracker_from_base, self.reported_tcp_mm
        )
        predicted = self.reported_tcp_mm @ tracker_from_base[:3, :3].T + tracker_from_base[:3, 3]
        actual = self.true_tcp_mm @ self.tracker_from_base[:3, :3].T + self.tracker_from_base[:3, 3]
        out["verification_error_mm"] = float(np.mean(np.linalg.norm(predicted - actual, axis=1)))
        return {k: float(v) for k, v in out.items()}


def write_spacecal_input(seq, folder: Path) -> tuple[dict, dict]:
    """The sequence as spacecal files; returns the ``CalibrateSettings`` fields and notes."""
    if seq.synchronous:
        recording = conversion.to_recording(seq)
        path = write_recording(recording, folder / "recording.csv")
        return {"recording": str(path)}, {}
    converted = conversion.to_raw_recording(seq)
    robot, tracker = write_raw_recording(converted.raw, folder / "streams")
    notes = {"true_offset_s": converted.true_offset_s, "reordered_frames": converted.reordered_frames}
    return {"recording": str(robot), "tracker_stream": str(tracker)}, notes


def run_spacecal(seq, truth: Truth, methods: list[str], folder: Path) -> list[dict]:
    rows = []
    inputs, notes = write_spacecal_input(seq, folder)
    modelled = (
        conversion.spacecal_robot_model(seq.manifest["robot"]) is not None
        or conversion.kinematic_model_of(seq.manifest["robot"]) is not None
    )
    for method in methods:
        row: dict = {"source": "spacecal", "method": method}
        if Need.ROBOT_MODEL in ESTIMATORS[method].needs and not modelled:
            row.update(status="skipped", message=f"spacecal has no model of the {seq.manifest['robot']}")
            rows.append(row)
            continue
        settings = app.CalibrateSettings(
            output=str(folder / f"{method}.json"), method=method, force=True, **inputs
        )
        started = time.perf_counter()
        try:
            with contextlib.redirect_stdout(io.StringIO()):
                result = app.calibrate(settings).record
        except SpacecalError as exc:
            row.update(status="refused", message=_first_line(exc, folder))
        except Exception as exc:  # a crash is a finding too; the run goes on
            row.update(status="failed", message=f"{type(exc).__name__}: {_first_line(exc, folder)}")
        else:
            x, y = conversion.kinhec_from_spacecal(result.tracker_from_base, result.tcp_from_marker)
            row.update(truth.errors(x, y))
            d = result.diagnostics
            grade, verdict, graded_mm = _verdict(result)
            expected = d.get("expected_error") or {}
            stated = _finite(expected.get("position_mm")) if "position_mm" in expected else graded_mm
            row.update(
                status="result",
                grade=grade,
                verdict=verdict.splitlines()[0] if verdict else None,
                expected_position_mm=stated,
                expected_refusal=expected.get("refusal"),
            )
            components = expected.get("components") or {}
            # the statement's parts: the noise alone (the fit's inverse Fisher information at
            # the site) and what the marker cannot see (RMS, mm)
            row["noise_only_rms_mm"] = _finite(components.get("noise_tre_rms_mm"))
            row["unseen_rms_mm"] = _finite(components.get("unseen_tip_rms_mm"))
            # the statement with its systematic misfit one standard error either way
            row["expected_range_mm"] = expected.get("position_range_mm")
            if "position_covariance_mm2" in expected:
                # how often an error of the stated covariance is within 1 mm: an honest statement
                # above the unusable limit still meets a small error by chance this often
                row["chance_within_1mm"] = probability_within(expected["position_covariance_mm2"], 1.0)
            source = result.provenance.source
            offset_s = None if source is None else source.time_offset_s
            if offset_s is not None and "true_offset_s" in notes:
                row["time_offset_err_ms"] = 1000.0 * abs(offset_s - notes["true_offset_s"])
        row["runtime_s"] = time.perf_counter() - started
        rows.append(row)
    if notes.get("reordered_frames"):
        for row in rows:
            row["reordered_tracker_frames"] = notes["reordered_frames"]
    return rows


def kinhec_keyframe_data(seq, time_offset: float | None):
    """KinHEC's benchmark protocol (``kinhec.benchmark``): keyframes of the paired streams,
    their absolute poses for AX = YB and consecutive motions for AX = XB."""
    a_abs, b_abs = seq.axyb_poses(time_offset=time_offset)
    if len(a_abs) < 3:
        return None
    index = kinhec_motions.select_keyframes(a_abs, KEYFRAME_MIN_ROT_DEG, KEYFRAME_MIN_TRANS_M, MAX_KEYFRAMES)
    if len(index) < 3:
        index = np.arange(len(a_abs))
    a_abs, b_abs = a_abs[index], b_abs[index]
    pairs = kinhec_motions.motion_pairs(len(index), "consecutive")
    return a_abs, b_abs, kinhec_se3.relative_motions(a_abs, pairs), kinhec_se3.relative_motions(b_abs, pairs)


def solve_kinhec(name: str, data, truth: Truth, seed: int) -> dict:
    """One KinHEC solver on prepared data; a failure is an outcome (as KinHEC counts it)."""
    row: dict = {}
    started = time.perf_counter()
    if data is None:
        row.update(status="refused", message="too few frames")
    else:
        try:
            out = SOLVERS[name](data, np.random.default_rng(seed))
            row.update(truth.errors(out["X"], out.get("Y")))
            finite = math.isfinite(row["X_rot_err_deg"]) and math.isfinite(row["X_trans_err_mm"])
            row["status"] = "result" if finite else "failed"
            if not finite:
                row["message"] = "non-finite estimate"
        except Exception as exc:
            row.update(status="refused", message=f"{type(exc).__name__}: {str(exc).splitlines()[0]}")
    row["runtime_s"] = time.perf_counter() - started
    return row


def kinhec_offset(seq) -> float | None:
    """The clock offset (s) KinHEC's protocol pairs the streams at: estimated from the streams
    by KinHEC's own cross-correlation; None for synchronous streams."""
    if seq.synchronous:
        return None
    offset, _ = kinhec_solvers.estimate_time_offset(
        seq.robot.t, seq.robot.T_base_ee_meas, seq.camera.t, seq.camera.T_cam_target_meas
    )
    return float(offset)


def run_kinhec(seq, truth: Truth, solvers: list[str], seed: int) -> list[dict]:
    """KinHEC's solvers under its protocol; for the reference also on every paired frame (as
    spacecal gets them) and, on asynchronous streams, at the true clock offset."""
    offset = kinhec_offset(seq)
    runs = [(name, "", kinhec_keyframe_data(seq, offset)) for name in solvers]
    reference = REFERENCE[len(KINHEC) :]
    if reference in solvers:
        a_abs, b_abs = seq.axyb_poses(time_offset=offset)
        runs.append((reference, ALL_FRAMES, (a_abs, b_abs, None, None) if len(a_abs) >= 3 else None))
        if offset is not None:
            runs.append((reference, TRUE_OFFSET, kinhec_keyframe_data(seq, seq.time_offset)))
    rows = []
    for name, variant, data in runs:
        row = {"source": "kinhec", "method": KINHEC + name + variant}
        used = seq.time_offset if variant == TRUE_OFFSET else offset
        if used is not None:
            row["time_offset_err_ms"] = 1000.0 * abs(used - seq.time_offset)
        rows.append(dict(row, **solve_kinhec(name, data, truth, seed)))
    return rows


def check_conversion(seq) -> dict:
    """KinHEC's ground truth against the converted data, before any solving."""
    worst_mm, worst_deg = conversion.check_exact(seq)
    out = {"exact_max_mm": worst_mm, "exact_max_deg": worst_deg}
    if seq.synchronous:
        recording = conversion.to_recording(seq)
        distance, angle = conversion.chain_residuals(recording, *conversion.truth(seq))
        clean = ~np.asarray(seq.camera.outlier, dtype=bool)[recording.has_pose]
        if clean.any():
            out["truth_residual_rms_mm"] = float(np.sqrt(np.mean(distance[clean] ** 2)))
            out["truth_residual_rms_deg"] = float(np.sqrt(np.mean(angle[clean] ** 2)))
        expected = conversion.expected_residual_rms(seq)
        if expected is not None and clean.any():
            out["noise_rms_mm"], out["noise_rms_deg"] = expected
            out["residual_over_noise"] = out["truth_residual_rms_mm"] / expected[0]
    return out


def evaluate(root: str, manifest_row: dict, methods: list[str], solvers: list[str], seed: int) -> list[dict]:
    """Every row of one sequence; never raises (a failure becomes a row)."""
    m = manifest_row
    base = {
        k: (m[k].item() if hasattr(m[k], "item") else m[k])
        for k in (
            "sequence_id",
            "track",
            "level",
            "robot",
            "configuration",
            "family",
            "sampling_mode",
            "sync",
            "n_camera_frames",
            "n_visible_frames",
            "n_outlier_frames",
        )
    }
    try:
        seq = load_sequence(Path(root), m["sequence_id"], manifest=pd.DataFrame([m]))
        base["n_measured_frames"] = int(seq.camera.has_measurement.sum())
        base["conversion"] = check_conversion(seq)
        truth = Truth(seq)
    except Exception as exc:
        message = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
        return [dict(base, source="conversion", method="-", status="failed", message=message)]
    rows = []
    with tempfile.TemporaryDirectory(prefix="kinhec-") as folder:
        try:
            rows += run_spacecal(seq, truth, methods, Path(folder))
        except Exception as exc:
            message = f"{type(exc).__name__}: {_first_line(exc, Path(folder))}"
            rows += [
                {"source": "spacecal", "method": k, "status": "failed", "message": message} for k in methods
            ]
    try:
        rows += run_kinhec(seq, truth, solvers, seed)
    except Exception as exc:
        message = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
        rows += [
            {"source": "kinhec", "method": KINHEC + k, "status": "failed", "message": message}
            for k in solvers
        ]
    return [dict(base, **row) for row in rows]


# ---------------------------------------------------------------------------------------------
# tables
# ---------------------------------------------------------------------------------------------


def _values(rows: list[dict], key: str) -> np.ndarray:
    return np.array([r[key] for r in rows if r.get(key) is not None and math.isfinite(r[key])], dtype=float)


def _fmt(value: float | None, digits: int = 2) -> str:
    if value is None or not math.isfinite(value):
        return "–"
    if abs(value) >= 1000:
        return f"{value:.0f}"
    return f"{value:.{digits}f}"


def _median(rows: list[dict], key: str) -> float | None:
    v = _values(rows, key)
    return float(np.median(v)) if len(v) else None


def _mean(rows: list[dict], key: str) -> float | None:
    v = _values(rows, key)
    return float(np.mean(v)) if len(v) else None


def reason_key(message: str) -> str:
    """A refusal message without the file it names and with its numbers replaced, so that like
    reasons group."""
    message = re.sub(r"^[\w.-]+\.csv: ", "", message or "")
    return re.sub(r"\d+(\.\d+)?(e[-+]?\d+)?", "#", message).strip()


def method_order(rows: list[dict]) -> list[str]:
    spacecal = [m for m in SPACECAL_METHODS if any(r["method"] == m for r in rows)]
    spacecal += sorted({r["method"] for r in rows if r["source"] == "spacecal"} - set(spacecal))
    kinhec_methods = {r["method"] for r in rows if r["source"] == "kinhec"}
    order = {KINHEC + name: k for k, name in enumerate(SOLVERS)}

    def rank(method: str) -> tuple[int, str]:
        base = method.split(" (", 1)[0]
        return order.get(base, len(order)), method

    return spacecal + sorted(kinhec_methods, key=rank)


def accuracy_table(rows: list[dict]) -> list[str]:
    lines = [
        "| method | sequences | result | refused | failed | skipped | X rot median (deg) "
        "| X trans median / mean (mm) | Y rot median (deg) | Y trans median / mean (mm) "
        "| site error median / mean (mm) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for method in method_order(rows):
        mine = [r for r in rows if r["method"] == method]
        ok = [r for r in mine if r["status"] == "result"]
        count = Counter(r["status"] for r in mine)
        lines.append(
            f"| {method} | {len(mine)} | {count['result']} | {count['refused']} | "
            f"{count['failed']} | {count['skipped']} | {_fmt(_median(ok, 'X_rot_err_deg'), 3)} | "
            f"{_fmt(_median(ok, 'X_trans_err_mm'))} / {_fmt(_mean(ok, 'X_trans_err_mm'))} | "
            f"{_fmt(_median(ok, 'Y_rot_err_deg'), 3)} | "
            f"{_fmt(_median(ok, 'Y_trans_err_mm'))} / {_fmt(_mean(ok, 'Y_trans_err_mm'))} | "
            f"{_fmt(_median(ok, 'site_error_mm'))} / {_fmt(_mean(ok, 'site_error_mm'))} |"
        )
    return lines


def ratio_lines(rows: list[dict], reference: str) -> list[str]:
    ml = {r["sequence_id"]: r for r in rows if r["method"] == "ml" and r["status"] == "result"}
    ref = {r["sequence_id"]: r for r in rows if r["method"] == reference and r["status"] == "result"}
    if not ml or not ref:
        return [f"spacecal ml / {reference}: no common results."]
    both = sorted(set(ml) & set(ref))
    cases = [(f"the {len(both)} sequences both solved", both, both)]
    if set(ml) != set(ref):
        cases.insert(0, (f"all results ({len(ml)} ml, {len(ref)} {reference})", list(ml), list(ref)))
    out = []
    for label, ids_ml, ids_ref in cases:
        parts = []
        for key, name in (
            ("X_trans_err_mm", "X translation"),
            ("Y_trans_err_mm", "Y translation"),
            ("X_rot_err_deg", "X rotation"),
            ("site_error_mm", "site error"),
        ):
            a = _median([ml[i] for i in ids_ml], key)
            b = _median([ref[i] for i in ids_ref], key)
            parts.append(f"{name} {_fmt(a / b if a is not None and b else None)}×" if ids_ml else "")
        out.append(f"spacecal ml median / {reference} median, {label}: " + ", ".join(parts) + ".")
    return out


def grade_table(rows: list[dict]) -> list[str]:
    lines = [
        "| method | results | good | acceptable | poor | unusable | unusable, site error ≤ 1 mm | "
        "… expected by chance were each statement exact | "
        "… of them, the statement's own range reaching below the unusable limit | "
        "unusable without an expected error | stated expected error median (mm) | "
        "site error / stated: median, max | verification error / stated: median, max |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for method in method_order(rows):
        ok = [
            r for r in rows if r["method"] == method and r["source"] == "spacecal" and r["status"] == "result"
        ]
        if not ok and not any(r["method"] == method and r["source"] == "spacecal" for r in rows):
            continue
        grades = Counter(r.get("grade") for r in ok)
        unusable = [r for r in ok if r.get("grade") == "unusable"]
        close_rows = [r for r in unusable if (r.get("site_error_mm") or math.inf) <= 1.0]
        close = len(close_rows)
        # the range's low end at or below the limit an unusable statement is above
        unpinned = sum(
            1
            for r in close_rows
            if r.get("expected_range_mm") and r["expected_range_mm"][0] <= UNUSABLE_ABOVE_MM
        )
        chance = sum(r.get("chance_within_1mm") or 0.0 for r in unusable)
        without = sum(1 for r in unusable if r.get("expected_position_mm") is None)
        stated = [r for r in ok if r.get("expected_position_mm")]
        site = np.array([r["site_error_mm"] / r["expected_position_mm"] for r in stated])
        verification = np.array([r["verification_error_mm"] / r["expected_position_mm"] for r in stated])
        lines.append(
            f"| {method} | {len(ok)} | {grades['good']} | {grades['acceptable']} | {grades['poor']} | "
            f"{grades['unusable']} | {close} | {chance:.1f} | {unpinned} | {without} | "
            f"{_fmt(_median(stated, 'expected_position_mm'))} | "
            + (f"{_fmt(float(np.median(site)))}, {_fmt(float(np.max(site)))} | " if len(site) else "– | ")
            + (
                f"{_fmt(float(np.median(verification)))}, {_fmt(float(np.max(verification)))} |"
                if len(verification)
                else "– |"
            )
        )
    return lines


def reason_lines(rows: list[dict], heading: str, pick) -> list[str]:
    groups: dict[str, Counter] = defaultdict(Counter)
    for r in rows:
        message = pick(r)
        if message:
            groups[reason_key(message)][r["method"]] += 1
    if not groups:
        return []
    lines = [heading, "", "| count | reason | methods |", "|---|---|---|"]
    for key, methods in sorted(groups.items(), key=lambda kv: -sum(kv[1].values())):
        listed = ", ".join(f"{m} {n}" for m, n in methods.most_common())
        lines.append(f"| {sum(methods.values())} | {key.replace('|', '/')} | {listed} |")
    return lines + [""]


def _refused(r: dict) -> str | None:
    return r.get("message") if r["status"] in ("refused", "failed") and r["source"] == "spacecal" else None


def _soft_refused(r: dict) -> str | None:
    return r.get("expected_refusal") if r["status"] == "result" else None


def conversion_line(rows: list[dict]) -> str:
    seen = {r["sequence_id"]: r.get("conversion") for r in rows if r.get("conversion")}
    if not seen:
        return "Conversion: not checked."
    exact = max(c["exact_max_mm"] for c in seen.values())
    ratios = np.array([c["residual_over_noise"] for c in seen.values() if "residual_over_noise" in c])
    text = (
        f"Conversion check on {len(seen)} sequences: KinHEC's noise-free data fit its ground truth through "
        f"the converted chain to {exact:.1e} mm at most"
    )
    if len(ratios):
        text += (
            f"; the measurements' RMS residual under the ground truth is {np.median(ratios):.2f}× "
            f"(range {ratios.min():.2f}–{ratios.max():.2f}) what the injected noise gives, over "
            f"{len(ratios)} sequences with Gaussian robot and camera noise"
        )
    return text + "."


def temporal_line(rows: list[dict]) -> str | None:
    ml = [r for r in rows if r["method"] == "ml" and r.get("time_offset_err_ms") is not None]
    ref = [r for r in rows if r["method"] == REFERENCE and r.get("time_offset_err_ms") is not None]
    if not ml and not ref:
        return None
    return (
        f"Clock offset error: spacecal (ml, estimated with the calibration) median "
        f"{_fmt(_median(ml, 'time_offset_err_ms'))} ms over {len(ml)}; KinHEC's angular-speed "
        f"cross-correlation median {_fmt(_median(ref, 'time_offset_err_ms'))} ms over {len(ref)}."
    )


def print_tables(rows: list[dict], header: str, compact: bool = False) -> None:
    """Every track's tables; ``compact`` leaves KinHEC's solvers other than the reference out
    of the accuracy table."""
    print(header)
    for track in TRACKS:
        mine = [r for r in rows if r["track"] == track]
        if not mine:
            continue
        sequences = len({r["sequence_id"] for r in mine})
        print(f"\n### Track `{track}` ({sequences} sequences)\n")
        print(conversion_line(mine) + "\n")
        shown = [
            r for r in mine if not compact or r["source"] != "kinhec" or r["method"].startswith(REFERENCE)
        ]
        print("\n".join(accuracy_table(shown)))
        print()
        for reference in (REFERENCE, REFERENCE + ALL_FRAMES):
            for line in ratio_lines(mine, reference):
                print(line)
        line = temporal_line(mine)
        if line:
            print(line)
        print("\nspacecal's verdicts (`result` rows):\n")
        print("\n".join(grade_table(mine)))
        print()
        print("\n".join(reason_lines(mine, "spacecal refusals (the method raised):", _refused)))
        print(
            "\n".join(
                reason_lines(
                    mine,
                    "Graded unusable without an expected error (the expected error's refusal):",
                    _soft_refused,
                )
            )
        )
    everything = reason_lines(rows, "### All tracks: spacecal refusals (the method raised)", _refused)
    everything += reason_lines(
        rows, "### All tracks: graded unusable without an expected error", _soft_refused
    )
    print("\n" + "\n".join(everything))


def spacecal_commit() -> str:
    """The last commit of the spacecal package the run imported (and whether it was modified)."""
    import spacecal

    folder = Path(spacecal.__file__).resolve().parent
    git = ["git", "-C", str(folder)]
    try:
        commit = subprocess.run(
            git + ["log", "-1", "--format=%h", "--", "."], capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            git + ["status", "--porcelain", "--", "."], capture_output=True, text=True, check=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "at an unknown commit"
    return f"src at {commit}" + (" with uncommitted changes" if dirty else "")


def _cpu_s() -> float:
    """CPU seconds of this process and its finished workers."""
    import resource

    own, workers = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + workers.ru_utime + workers.ru_stime


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--tier", default="small", help="smoke | small | medium (or a KinHEC tier YAML)")
    parser.add_argument(
        "--data", type=Path, help="KinHEC data folder (default: a cache outside the repository)"
    )
    parser.add_argument("--tracks", nargs="+", default=list(TRACKS))
    parser.add_argument(
        "--limit", type=int, help="at most N sequences per track, spread over its factor grid"
    )
    parser.add_argument("--methods", nargs="+", default=list(SPACECAL_METHODS), help="spacecal methods")
    parser.add_argument("--kinhec-solvers", nargs="+", default=list(SOLVERS), help="KinHEC's solvers")
    parser.add_argument("--json", type=Path, help="write every row here")
    parser.add_argument("--workers", type=int, default=1, help="processes (generation and evaluation)")
    parser.add_argument("--seed", type=int, default=0, help="seed of KinHEC's RANSAC solver")
    parser.add_argument("--tables-from", type=Path, help="print the tables of an earlier --json run")
    parser.add_argument(
        "--compact", action="store_true", help=f"of KinHEC's solvers, tabulate {REFERENCE} only"
    )
    args = parser.parse_args()
    if args.tables_from:
        document = json.loads(args.tables_from.read_text(encoding="utf-8"))
        print_tables(document["rows"], document["header"], args.compact)
        return
    tracks = [TRACK_ALIASES.get(t, t) for t in args.tracks]
    unknown = sorted(set(tracks) - set(TRACKS)) + sorted(set(args.methods) - set(ESTIMATORS))
    unknown += sorted(set(args.kinhec_solvers) - set(SOLVERS))
    if unknown:
        parser.error(
            f"unknown: {', '.join(unknown)} (tracks {', '.join(TRACKS)}; methods {', '.join(ESTIMATORS)}; "
            f"solvers {', '.join(SOLVERS)})"
        )
    tier_name = Path(args.tier).stem
    data = (args.data or default_data_dir(tier_name)).resolve()
    started = time.perf_counter()
    ensure_data(args.tier, data, tracks, args.workers)
    manifest = load_manifest(data, tracks)
    chosen = [spread_rows(manifest[manifest["track"] == t], args.limit) for t in tracks]
    jobs = [row.to_dict() for part in chosen for _, row in part.iterrows()]
    print(
        f"{len(jobs)} sequences, {len(args.methods)} spacecal methods, "
        f"{len(args.kinhec_solvers)} KinHEC solvers",
        file=sys.stderr,
    )
    rows: list[dict] = []
    evaluated = time.perf_counter()
    cpu_before = _cpu_s()

    def progress(done: int, job: dict, new: list[dict]) -> None:
        elapsed = time.perf_counter() - evaluated
        outcome = Counter(r["status"] for r in new if r["source"] == "spacecal")
        print(
            f"[{done}/{len(jobs)}] {job['sequence_id']} {dict(outcome)} {elapsed:.0f} s",
            file=sys.stderr,
            flush=True,
        )

    if args.workers <= 1:
        for k, job in enumerate(jobs, 1):
            new = evaluate(str(data), job, args.methods, args.kinhec_solvers, args.seed)
            rows += new
            progress(k, job, new)
    else:
        from concurrent.futures import ProcessPoolExecutor, as_completed

        with ProcessPoolExecutor(max_workers=args.workers) as pool:
            futures = {
                pool.submit(evaluate, str(data), job, args.methods, args.kinhec_solvers, args.seed): job
                for job in jobs
            }
            for k, future in enumerate(as_completed(futures), 1):
                job = futures[future]
                try:
                    new = future.result()
                except Exception as exc:  # a worker lost: record it and go on
                    new = [
                        {
                            "sequence_id": job["sequence_id"],
                            "track": job["track"],
                            "source": "conversion",
                            "method": "-",
                            "status": "failed",
                            "message": f"{type(exc).__name__}: {exc}",
                        }
                    ]
                rows += new
                progress(k, job, new)
    rows.sort(key=lambda r: (r["sequence_id"], r["source"], r["method"]))
    wall = time.perf_counter() - started
    evaluation_s, cpu_s = time.perf_counter() - evaluated, _cpu_s() - cpu_before
    header = (
        f"## KinHEC {kinhec.__version__}, tier {tier_name}, {len(jobs)} sequences"
        + (f" (at most {args.limit} per track)" if args.limit else "")
        + f"; spacecal {spacecal_commit()}; evaluated in {evaluation_s / 60:.1f} min "
        f"({cpu_s / 60:.1f} min CPU) on {args.workers} worker(s)"
    )
    print_tables(rows, header, args.compact)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        document = {
            "header": header,
            "kinhec": kinhec.__version__,
            "spacecal": spacecal_commit(),
            "tier": tier_name,
            "data": str(data),
            "arguments": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
            "wall_s": wall,
            "evaluation_wall_s": evaluation_s,
            "evaluation_cpu_s": cpu_s,
            "rows": rows,
        }
        args.json.write_text(json.dumps(document, indent=1, default=float), encoding="utf-8")
        print(f"\nrows written to {args.json}", file=sys.stderr)


if __name__ == "__main__":
    main()
