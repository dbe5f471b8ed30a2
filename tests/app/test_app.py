"""Every command's app function called directly, as a notebook would: typed settings in,
typed records out, files that read back to the same records."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from spacecal import app
from spacecal.core.errors import InvalidInputError
from spacecal.io.results_json import read_calibration, read_json_object
from spacecal.records import (
    CalibrationResult,
    CheckResult,
    LandmarkRegistrationResult,
    PhantomResult,
    PlanRecord,
    VerificationResult,
)

from ..conftest import shared_realdata


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    folder = tmp_path_factory.mktemp("app")
    out = app.simulate(app.SimulateSettings(str(folder / "rec.csv"), scenario="paper-white", seed=4))
    return folder, out


def test_simulate_returns_what_it_wrote(simulated):
    folder, result = simulated
    out, paths = result.record, result.files_written
    assert out.simulated and out.seed == 4 and out.scenario == "paper-white"
    assert paths[0] == folder / "rec.csv" and paths[1].name == "rec.meta.json"
    assert 0 < out.visible <= out.samples == sum(1 for _ in open(paths[0])) - 1


def test_calibrate_bound_verify_check_report_export(simulated):
    folder, _ = simulated
    calibrated = app.calibrate(
        app.CalibrateSettings(
            str(folder / "rec.csv"),
            str(folder / "cal.json"),
            "ml",
            targets_in_base=((-573.0, -164.0, 338.0),),
        )
    )
    assert isinstance(calibrated.record, CalibrationResult)
    provenance = calibrated.record.provenance
    assert calibrated.provenance == provenance
    assert provenance.simulated is True and provenance.scenario["seed"] == 4
    assert provenance.recording == str((folder / "rec.csv").resolve())
    [path] = calibrated.files_written
    again = read_calibration(path)
    assert np.array_equal(again.tracker_from_base, calibrated.record.tracker_from_base)
    assert again.provenance == provenance

    bound = app.bound(app.BoundSettings(str(folder / "rec.csv"), str(path), 0.144)).record
    assert 0 < bound.site_mm <= calibrated.record.predicted_tre_mm["site"] * 1.5
    assert bound.sigma_mm == 0.144 and bound.sigma_source == "given with --sigma-mm"

    verified = app.verify(app.VerifySettings(str(path), points=5, output=str(folder / "ver.json")))
    assert isinstance(verified.record, VerificationResult) and verified.record.simulated
    assert (
        "from the calibration's provenance" in verified.lines[1] and verified.record.scenario == "paper-white"
    )
    read_back = VerificationResult.from_dict(read_json_object(folder / "ver.json", "verification"))
    assert np.allclose(read_back.position_error_mm, verified.record.position_error_mm)

    checked = app.check(app.CheckSettings(str(path), poses=2)).record
    assert isinstance(checked.result, CheckResult) and checked.result.passed and checked.result.simulated
    recorded = app.check(app.CheckSettings(str(path), recording=str(folder / "rec.csv"))).record
    assert recorded.result.simulated is None

    report = app.report(app.ReportSettings(str(path), str(folder / "r.html")))
    assert "Check history" in report.record and report.files_written[0].stat().st_size > 1_000_000

    lines = app.export(app.ExportSettings(str(path), slicer=str(folder / "t.tfm"))).lines
    assert len(lines) == 1 and (folder / "t.tfm").is_file()


def test_an_output_never_overwrites_an_input(simulated):
    folder, _ = simulated
    before = (folder / "rec.csv").read_bytes()
    with pytest.raises(InvalidInputError, match="overwrite an input"):
        app.calibrate(app.CalibrateSettings(str(folder / "rec.csv"), str(folder / "rec.csv")))
    with pytest.raises(InvalidInputError, match="overwrite an input"):
        app.calibrate(app.CalibrateSettings(str(folder / "rec.csv"), str(folder / "rec.meta.json")))
    assert (folder / "rec.csv").read_bytes() == before


def test_acquire_on_the_simulated_devices(tmp_path):
    dry = app.acquire(
        app.AcquireSettings(str(tmp_path / "a.csv"), scenario="paper-white", dry_run=True)
    ).record
    assert dry.dry_run and dry.simulated and dry.moves > 0 and not (tmp_path / "a.csv").exists()
    run = app.acquire(app.AcquireSettings(str(tmp_path / "a.csv"), scenario="paper-white")).record
    assert run.result is not None and run.result.complete and run.result.samples_written > 100
    with pytest.raises(InvalidInputError, match="workspace-box"):
        app.AcquireSettings(str(tmp_path / "b.csv"), workspace_box=(1.0, 0.0, 0.0, 1.0, 0.0, 1.0))


def test_plan_phantom_scenario(tmp_path):
    planned = app.plan(app.PlanSettings(budget_s=15.0, output=str(tmp_path / "plan.json")))
    record, [path] = planned.record, planned.files_written
    assert isinstance(record, PlanRecord) and record.motion_time_s <= 15.0
    assert PlanRecord.from_dict(json.loads(path.read_text())).motion_time_s == record.motion_time_s
    result = app.phantom(app.PhantomCommandSettings(scenario="paper-white", method="ml", cases=2)).record
    assert isinstance(result, PhantomResult) and len(result.entry_error_mm) == 2
    assert PhantomResult.from_dict(result.to_dict()).method == "ml"
    scenario = app.scenario("paper-white").record
    assert scenario["name"] == "paper-white" and dataclasses.is_dataclass(app.PlanSettings)


def test_pivot_and_landmarks_on_real_recordings(tmp_path):
    pivot_folder = shared_realdata("pivot_sksurgery_ndi")
    pivoted = app.pivot(
        app.PivotSettings(
            str(pivot_folder / "PivotCalibration"),
            subset=str(pivot_folder / "subset57_sksurgerycalibration.txt"),
            output=str(tmp_path / "p.json"),
        )
    )
    result, [path] = pivoted.record, pivoted.files_written
    assert np.allclose(result.tip_in_marker, [-14.473, 394.634, -7.407], atol=1e-3) and path.is_file()
    folder = shared_realdata("plus_phantom_landmarks")
    registered = app.register_landmarks(
        app.RegisterLandmarksSettings(
            str(folder / "EightLandmarkPointsTrackedForPhantomRegistration.igs.mha"),
            str(folder / "PlusDeviceSet_fCal_Sim_RecordPhantomLandmarks.xml"),
            plus_compatible=True,
            output=str(tmp_path / "reg.json"),
        )
    )
    registration, [written] = registered.record, registered.files_written
    assert isinstance(registration, LandmarkRegistrationResult)
    assert registration.fre_mean_mm == pytest.approx(0.207, abs=0.001)
    assert np.allclose(
        LandmarkRegistrationResult.from_dict(json.loads(written.read_text())).reference_from_phantom,
        registration.reference_from_phantom,
    )


def test_demo_returns_its_parts(tmp_path):
    out = app.demo(app.DemoSettings(scenario="paper-white", out=str(tmp_path)))
    assert {p.name for p in out.files_written} == {
        "recording.csv",
        "calibration.json",
        "verification.json",
        "verification_errors.png",
    }
    calibration = read_calibration(tmp_path / "calibration.json")
    assert calibration.provenance.simulated and calibration.provenance.scenario["name"] == "paper-white"


def test_pivot_files_of_both_versions_read_back(tmp_path):
    from spacecal.records import PivotResult

    folder = shared_realdata("pivot_sksurgery_ndi")
    pivoted = app.pivot(app.PivotSettings(str(folder / "PivotCalibration"), output=str(tmp_path / "p.json")))
    result, [path] = pivoted.record, pivoted.files_written
    again = PivotResult.from_dict(json.loads(path.read_text()))
    assert np.array_equal(again.residuals_mm, result.residuals_mm) and again.rms_mm == result.rms_mm
    version_1 = {k: v for k, v in result.to_dict().items() if k not in ("residuals_mm", "units")}
    version_1["schema_version"] = 1
    old = PivotResult.from_dict(version_1)
    assert old.rms_mm == pytest.approx(result.rms_mm) and old.frames == len(result.residuals_mm)


def test_calibrate_with_a_pivot_measured_tip(simulated, tmp_path):
    """``--tip pivot.json``: the calibration carries the tip and the pivot file's sha256, says
    where IK aims, and refuses a file that is not a pivot result in one line."""
    from spacecal.io.digest import file_sha256
    from spacecal.sim.pivot import simulate_pivot
    from spacecal.sim.scenario import load_scenario
    from spacecal.sim.world import build_world

    folder, _ = simulated
    world = build_world(dataclasses.replace(load_scenario("paper-white"), seed=4))
    pivot = tmp_path / "pivot.json"
    pivot.write_text(json.dumps(simulate_pivot(world).to_dict()))
    out = app.calibrate(
        app.CalibrateSettings(str(folder / "rec.csv"), str(tmp_path / "cal.json"), "ml", tip=str(pivot))
    )
    tip = out.record.needle_tip
    assert tip is not None and tip.source_sha256 == file_sha256(pivot) and tip.frames > 100
    assert any(line.startswith("needle tip (pivot") for line in out.lines)
    assert read_calibration(tmp_path / "cal.json").needle_tip is not None
    with pytest.raises(InvalidInputError, match="pivot"):
        app.calibrate(
            app.CalibrateSettings(
                str(folder / "rec.csv"), str(tmp_path / "again.json"), "ml", tip=str(tmp_path / "cal.json")
            )
        )
