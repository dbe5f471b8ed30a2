"""What leaves ``estimators/`` is typed: no module outside it reads a calibration's diagnostics by
key, a built calibration and its assessment cannot be changed, and old files fill the typed
fields."""

import ast
import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

import spacecal
from spacecal.estimators import calibrate
from spacecal.records import CalibrationResult
from spacecal.records.assessment import Assessment, ErrorThresholds, ExpectedError

PACKAGE = Path(spacecal.__file__).parent


def _named_diagnostics(node: ast.AST) -> bool:
    """``diagnostics`` or ``<anything>.diagnostics``."""
    return (isinstance(node, ast.Name) and node.id == "diagnostics") or (
        isinstance(node, ast.Attribute) and node.attr == "diagnostics"
    )


def _key(node: ast.AST) -> str:
    return node.value if isinstance(node, ast.Constant) and isinstance(node.value, str) else "?"


def keyed_reads(tree: ast.AST) -> list[tuple[int, str]]:
    """Every ``diagnostics[...]`` and ``diagnostics.get(...)`` in a module: (line, key)."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Subscript) and _named_diagnostics(node.value):
            found.append((node.lineno, _key(node.slice)))
        elif (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr in ("get", "pop", "setdefault")
            and _named_diagnostics(node.func.value)
        ):
            found.append((node.lineno, _key(node.args[0]) if node.args else "?"))
    return found


def test_the_scan_finds_what_it_looks_for():
    code = "x = c.diagnostics['a']\ny = diagnostics.get('b')\nz = stored.get('c')\nc.diagnostics['d'] = 1\n"
    assert keyed_reads(ast.parse(code)) == [(1, "a"), (2, "b"), (4, "d")]


def test_no_module_outside_the_estimators_reads_diagnostics_by_key():
    offending = []
    for path in sorted(PACKAGE.rglob("*.py")):
        relative = path.relative_to(PACKAGE).as_posix()
        if relative.startswith("estimators/"):
            continue
        for line, key in keyed_reads(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            offending.append(f"{relative}:{line} diagnostics[{key!r}]")
    assert not offending, "read the calibration's typed fields instead: " + ", ".join(offending)


@pytest.fixture(scope="module")
def assessed(white_simulation):
    return calibrate(white_simulation.recording, "ml")


def test_a_built_calibration_and_its_assessment_cannot_be_changed(assessed):
    assessment = assessed.assessment
    assert assessment is not None and assessment.expected_error is not None
    with pytest.raises(dataclasses.FrozenInstanceError):
        assessed.assessment = None
    with pytest.raises(dataclasses.FrozenInstanceError):
        assessment.verdict = None
    with pytest.raises(dataclasses.FrozenInstanceError):
        assessment.expected_error.position_mm = 0.0
    with pytest.raises(TypeError):
        assessment.expected_error.components["noise_tre_rms_mm"] = 0.0
    with pytest.raises(ValueError):
        assessment.expected_error.position_covariance_mm2[0, 0] = 0.0
    rows = assessment.residuals.per_sample
    assert isinstance(rows, tuple) and len(rows) == int(np.sum(assessed.sample_counts["used"]))
    with pytest.raises(dataclasses.FrozenInstanceError):
        rows[0].position_mm = 0.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        assessed.noise.sigma_per_axis_mm = 1.0


def test_the_paper_method_s_fits_are_read_only(realistic_simulation):
    fits = calibrate(realistic_simulation.recording, "paper", uncertainty=False).sweep_fits
    assert fits is not None and fits.sphere is not None and set(fits.lines) == {"lin_x", "lin_y", "lin_z"}
    with pytest.raises(TypeError):
        fits.lines["lin_x"] = fits.lines["lin_y"]
    with pytest.raises(ValueError):
        fits.sphere.centre_in_tracker_mm[0] = 0.0


def test_the_verdict_is_graded_once_against_the_thresholds_in_force(white_simulation, assessed):
    strict = ErrorThresholds(0.001, 0.002, 0.003)
    graded = calibrate(white_simulation.recording, "ml", error_thresholds=strict)
    assert graded.assessment.thresholds == strict and assessed.assessment.thresholds == ErrorThresholds()
    assert graded.verdict.grade == "unusable" and assessed.verdict.grade != "unusable"
    # the numbers it was graded by are the same: only the grade moved
    assert graded.expected_error.position_mm == assessed.expected_error.position_mm


def test_the_file_keeps_the_old_keys_and_reads_back_the_same(assessed):
    content = assessed.to_dict()
    stored = content["diagnostics"]
    for key in ("expected_error", "verdict", "residual_position_rms_mm", "per_sample_residuals", "noise"):
        assert key in stored
    again = CalibrationResult.from_dict(json.loads(json.dumps(content)))
    assert again.assessment == assessed.assessment
    assert again.to_dict()["diagnostics"] == stored
    assert again.content_sha256 == assessed.content_sha256


def test_an_old_file_with_only_diagnostics_fills_the_typed_fields():
    """A version-2 file: no hash, the assessment and the paper's fits as diagnostics keys, the
    verdict an older file's sentence."""
    content = {
        "schema": "spacecal.calibration",
        "schema_version": 2,
        "method": "paper",
        "tracker_from_base": np.eye(4).tolist(),
        "tcp_from_marker": np.eye(4).tolist(),
        "sample_counts": {"total": 3, "used": 3, "rejected": 0},
        "provenance": {},
        "diagnostics": {
            "expected_error": {"position_mm": 0.7, "posture_deg": 0.1, "basis": "held-out blocks"},
            "verdict": "acceptable: an older file's sentence",
            "residual_position_rms_mm": 0.2,
            "residual_rotation_rms_deg": 0.05,
            "sphere": {
                "centre_in_tracker_mm": [1.0, 2.0, 3.0],
                "radius_mm": 150.0,
                "rms_mm": 0.1,
                "samples": 90,
            },
            "lines": {
                "lin_x": {
                    "straightness_rms_mm": 0.05,
                    "length_mm": 100.0,
                    "direction_in_tracker": [1.0, 0.0, 0.0],
                    "samples": 30,
                }
            },
            "noise": {
                "sigma_per_axis_mm": 0.08,
                "source": "the tracker's RMS",
                "observations": "raw spheres",
            },
            "rotation_span_deg": {"rot_x": 40.0},
        },
    }
    read = CalibrationResult.from_dict(content)
    assert read.expected_error == ExpectedError(0.7, 0.1, basis="held-out blocks")
    assert read.verdict.grade == "acceptable"
    assert read.assessment.residuals.position_rms_mm == 0.2 and read.assessment.residuals.per_sample is None
    assert read.assessment.thresholds == ErrorThresholds()
    assert read.sweep_fits.sphere.radius_mm == 150.0 and read.sweep_fits.lines["lin_x"].length_mm == 100.0
    assert read.noise.sigma_per_axis_mm == 0.08
    # what is the method's own stays a diagnostic
    assert read.diagnostics == {"rotation_span_deg": {"rot_x": 40.0}}


def test_the_typed_fields_are_not_also_diagnostics(assessed):
    with pytest.raises(spacecal.core.errors.InvalidInputError, match="typed fields"):
        assessed.replace(diagnostics={**assessed.diagnostics, "expected_error": {"position_mm": 0.1}})
    assert isinstance(assessed.assessment, Assessment)
