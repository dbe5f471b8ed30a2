"""The command line: the whole chain, exit codes, and one readable line for every bad input."""

import json
import re
import subprocess
import sys

import numpy as np
import pytest

from spacecal.cli import main

from .io.test_recording_csv import BAD_INPUTS, mutate


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_simulate_calibrate_verify_chain(tmp_path, capsys):
    recording = tmp_path / "rec.csv"
    code, out, _ = run(capsys, "simulate", "--scenario", "paper-white", "-o", str(recording))
    assert code == 0 and "planned motion time" in out
    assert (tmp_path / "rec.meta.json").is_file()
    calibration = tmp_path / "cal.json"
    code, out, _ = run(capsys, "calibrate", str(recording), "--method", "paper", "-o", str(calibration))
    assert code == 0 and "sphere: radius" in out
    data = json.loads(calibration.read_text())
    assert data["method"] == "paper" and len(data["tracker_from_base"]) == 4
    code, out, _ = run(
        capsys,
        "verify",
        str(calibration),
        "-o",
        str(tmp_path / "ver.json"),
        "--figure",
        str(tmp_path / "fig7.png"),
    )
    assert code == 0 and "position error" in out
    verification = json.loads((tmp_path / "ver.json").read_text())
    assert len(verification["points"]) == 15
    # white noise, exact kinematics: the needle lands within a few tenths of a millimetre
    assert verification["statistics"]["position_mm"]["max"] < 0.3
    assert (tmp_path / "fig7.png").stat().st_size > 10_000


def test_demo_prints_the_summary_and_writes_outputs(tmp_path, capsys):
    code, out, _ = run(capsys, "demo", "--out", str(tmp_path))
    assert code == 0
    for needle in (
        "planned motion time",
        "paper estimator: TRE",
        "ML estimator",
        "verification position error",
        "0.87 / <1.05",
    ):
        assert needle in out
    for name in ("recording.csv", "calibration.json", "verification.json", "verification_errors.png"):
        assert (tmp_path / name).is_file()


@pytest.mark.parametrize("case", sorted(BAD_INPUTS))
def test_bad_recordings_give_one_line_and_exit_1(case, recording_file, tmp_path, capsys):
    edit, message = BAD_INPUTS[case]
    bad = mutate(recording_file, tmp_path, edit)
    code, out, err = run(capsys, "calibrate", str(bad), "-o", str(tmp_path / "cal.json"))
    assert code == 1
    assert len(err.strip().splitlines()) == 1 and err.startswith("spacecal: error:")
    assert "Traceback" not in err
    assert not (tmp_path / "cal.json").exists()


def test_missing_segment_and_unknown_method(recording_file, tmp_path, capsys):
    text = recording_file.read_text().replace(",lin_z,", ",static,")
    bad = tmp_path / "no_lin_z.csv"
    bad.write_text(text)
    code, _, err = run(capsys, "calibrate", str(bad), "-o", str(tmp_path / "c.json"))
    assert code == 1 and "'lin_z' is missing" in err
    code, _, err = run(
        capsys, "calibrate", str(recording_file), "--method", "nope", "-o", str(tmp_path / "c.json")
    )
    assert code == 1 and "valid methods:" in err and "paper" in err and "robust" in err


def test_bad_scenarios(tmp_path, capsys):
    scenario = tmp_path / "s.json"
    scenario.write_text(json.dumps({"white_noise_rms": 0.1}))
    code, _, err = run(capsys, "simulate", "--scenario", str(scenario), "-o", str(tmp_path / "r.csv"))
    assert code == 1 and "unknown scenario key(s) white_noise_rms" in err
    code, _, err = run(capsys, "simulate", "--scenario", "no-such", "-o", str(tmp_path / "r.csv"))
    assert code == 1 and "neither a file nor a preset" in err


def test_verify_needs_a_scenario_for_foreign_calibrations(tmp_path, capsys, white_simulation):
    from spacecal.estimators import calibrate
    from spacecal.io.results_json import write_calibration

    path = write_calibration(calibrate(white_simulation.recording), tmp_path / "cal.json")
    code, _, err = run(capsys, "verify", str(path))
    assert code == 1 and "pass --scenario" in err


def test_console_script_exit_codes(tmp_path):
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    result = subprocess.run(
        [sys.executable, "-m", "spacecal", "calibrate", str(empty), "-o", "x.json"],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 1 and result.stderr.strip().endswith("the recording is empty")
    assert "Traceback" not in result.stderr
    usage = subprocess.run([sys.executable, "-m", "spacecal", "calibrate"], capture_output=True, text=True)
    assert usage.returncode == 2
    # one line, naming what is missing and where the usage is (not argparse's usage block)
    assert usage.stderr.strip().splitlines() == [
        "spacecal calibrate: error: the following arguments are required: recording, -o/--output "
        "(see spacecal calibrate --help)"
    ]


def test_ml_writes_covariance_and_predicted_tre(recording_file, tmp_path, capsys):
    out = tmp_path / "ml.json"
    code, text, _ = run(
        capsys, "calibrate", str(recording_file), "--method", "ml", "-o", str(out), "--target=-573,-164,338"
    )
    assert code == 0 and "predicted TRE" in text and "verdict: good" in text
    data = json.loads(out.read_text())
    assert len(data["covariance"]["matrix"]) == 12 and data["predicted_tre_mm"]["site"] > 0
    assert data["predicted_tre_mm"]["targets"][0]["target_in_base_mm"] == [-573.0, -164.0, 338.0]
    code, text, _ = run(
        capsys, "bound", str(recording_file), "--calibration", str(out), "--sigma-mm", "0.144"
    )
    assert code == 0 and "Cramer-Rao lower bound" in text


@pytest.mark.parametrize("method", ["shah", "li", "dornaika", "tsai", "park", "daniilidis", "robust"])
def test_every_method_runs_from_the_cli(method, recording_file, tmp_path, capsys):
    code, text, err = run(
        capsys, "calibrate", str(recording_file), "--method", method, "-o", str(tmp_path / "c.json")
    )
    assert code == 0, err
    assert json.loads((tmp_path / "c.json").read_text())["method"] == method


def test_bad_options_give_one_line(recording_file, tmp_path, capsys):
    code, _, err = run(
        capsys,
        "calibrate",
        str(recording_file),
        "--method",
        "ml",
        "--target",
        "1,2",
        "-o",
        str(tmp_path / "c.json"),
    )
    assert code == 1 and "--target takes x,y,z" in err
    code, _, err = run(
        capsys,
        "calibrate",
        str(recording_file),
        "--method",
        "ml",
        "--sigma-mm",
        "-1",
        "-o",
        str(tmp_path / "c.json"),
    )
    assert code == 1 and "--sigma-mm must be a positive" in err
    code, _, err = run(capsys, "pivot", str(tmp_path))
    assert code == 1 and "no .txt pose files" in err


def test_pivot_command_on_the_real_recording(capsys, tmp_path):
    from .conftest import shared_realdata

    folder = shared_realdata("pivot_sksurgery_ndi")
    code, text, _ = run(
        capsys,
        "pivot",
        str(folder / "PivotCalibration"),
        "--subset",
        str(folder / "subset57_sksurgerycalibration.txt"),
        "-o",
        str(tmp_path / "p.json"),
    )
    assert code == 0 and "-14.473, 394.634, -7.407" in text and "1.761 mm per axis" in text


def test_acquire_dry_run_and_run(tmp_path, capsys):
    out = tmp_path / "acq.csv"
    code, text, _ = run(capsys, "acquire", "-o", str(out), "--dry-run", "--scenario", "paper-white")
    assert code == 0 and "nothing moved" in text and not out.exists()
    code, text, _ = run(capsys, "acquire", "-o", str(out), "--scenario", "paper-white")
    planned = int(re.search(r"plan: (\d+) moves", text).group(1))  # 19: the 180-degree sweep passes home
    assert code == 0 and f"{planned}/{planned} moves" in text
    code, _, err = run(capsys, "acquire", "-o", str(out), "--scenario", "paper-white")
    assert code == 1 and "exists" in err
    code, _, err = run(
        capsys, "acquire", "-o", str(tmp_path / "b.csv"), "--workspace-box=-600,0,-600,400,0,800"
    )
    assert code == 1 and "workspace box" in err and not (tmp_path / "b.csv").exists()


def test_export_to_slicer_and_plus(recording_file, tmp_path, capsys):
    from spacecal.io.plus_config import read_plus_transform
    from spacecal.io.slicer import read_slicer_transform

    calibration = tmp_path / "cal.json"
    assert run(capsys, "calibrate", str(recording_file), "-o", str(calibration))[0] == 0
    code, out, _ = run(
        capsys,
        "export",
        str(calibration),
        "--slicer",
        str(tmp_path / "t.tfm"),
        "--plus",
        str(tmp_path / "t.xml"),
    )
    assert code == 0
    expected = np.array(json.loads(calibration.read_text())["tracker_from_base"])
    assert np.allclose(read_slicer_transform(tmp_path / "t.tfm"), expected, atol=1e-9)
    assert np.allclose(read_plus_transform(tmp_path / "t.xml", "Base", "Tracker"), expected, atol=1e-6)
    code, _, err = run(capsys, "export", str(calibration))
    assert code == 1 and "say where to export" in err


def test_register_landmarks_command_on_the_real_plus_recording(capsys, tmp_path):
    from .conftest import shared_realdata

    folder = shared_realdata("plus_phantom_landmarks")
    code, out, _ = run(
        capsys,
        "register-landmarks",
        str(folder / "EightLandmarkPointsTrackedForPhantomRegistration.igs.mha"),
        "--config",
        str(folder / "PlusDeviceSet_fCal_Sim_RecordPhantomLandmarks.xml"),
        "--plus-compatible",
        "-o",
        str(tmp_path / "reg.json"),
    )
    assert code == 0 and "mean 0.207 mm (PLUS's 'Error')" in out
    assert json.loads((tmp_path / "reg.json").read_text())["fre_mean_mm"] == pytest.approx(0.207, abs=0.001)


def test_phantom_command(tmp_path, capsys):
    code, out, _ = run(
        capsys,
        "phantom",
        "--scenario",
        "paper-white",
        "--cases",
        "3",
        "-o",
        str(tmp_path / "p.json"),
        "--figure",
        str(tmp_path / "fig9.png"),
    )
    assert code == 0 and "entry (mm)" in out and "paper minimum" in out
    assert len(json.loads((tmp_path / "p.json").read_text())["cases"]) == 3
    assert (tmp_path / "fig9.png").stat().st_size > 10_000


def test_report_command(recording_file, tmp_path, capsys):
    calibration = tmp_path / "cal.json"
    assert run(capsys, "calibrate", str(recording_file), "--method", "ml", "-o", str(calibration))[0] == 0
    code, out, _ = run(
        capsys, "report", str(calibration), "-o", str(tmp_path / "r.html"), "--png-dir", str(tmp_path)
    )
    assert code == 0 and "Sweeps and fits" in out and "Uncertainty" in out
    assert (tmp_path / "r.html").stat().st_size > 3_000_000 and (tmp_path / "residuals.png").is_file()


def test_raw_streams_from_the_cli(tmp_path, capsys):
    code, out, _ = run(
        capsys,
        "simulate",
        "--scenario",
        "paper-white",
        "--raw",
        "--clock-offset-ms",
        "30",
        "-o",
        str(tmp_path / "rec"),
    )
    assert code == 0 and "rec.robot.csv" in out
    code, out, _ = run(
        capsys,
        "calibrate",
        str(tmp_path / "rec.robot.csv"),
        "--tracker-stream",
        str(tmp_path / "rec.tracker.csv"),
        "--method",
        "ml",
        "-o",
        str(tmp_path / "cal.json"),
    )
    estimated = float(re.search(r"clock offset estimated: robot clock ([-0-9.]+) ms", out).group(1))
    assert code == 0 and abs(estimated - 30.0) < 0.1
    code, _, err = run(
        capsys,
        "calibrate",
        str(tmp_path / "rec.robot.csv"),
        "--tracker-stream",
        str(tmp_path / "rec.tracker.csv"),
        "--time-offset-ms",
        "soon",
        "-o",
        str(tmp_path / "c.json"),
    )
    assert code == 1 and "--time-offset-ms takes a number" in err


def test_plan_command(tmp_path, capsys):
    code, out, _ = run(capsys, "plan", "--budget", "20s", "-o", str(tmp_path / "plan.json"))
    assert code == 0 and "paper's sweeps" in out
    data = json.loads((tmp_path / "plan.json").read_text())
    assert data["motion_time_s"] <= 20.0 and len(data["station_joints_rad"]) >= 3
    code, _, err = run(capsys, "plan", "--budget=-5s")
    assert code == 1 and "must be positive" in err


def test_a_replaced_calibration_shows_none_of_the_old_ones_checks(recording_file, tmp_path, capsys):
    from spacecal.io.check_history import read_history

    calibration = tmp_path / "cal.json"
    assert run(capsys, "calibrate", str(recording_file), "-o", str(calibration))[0] == 0
    code, out, _ = run(capsys, "check", str(calibration), "--recording", str(recording_file))
    assert code == 0 and "PASS" in out
    assert len(read_history(calibration).checks) == 1
    code, _, err = run(capsys, "calibrate", str(recording_file), "--method", "ml", "-o", str(calibration))
    assert code == 1 and err == (
        f"spacecal: error: {calibration}: an existing calibration; choose another file or pass --force "
        "to replace it\n"
    )
    code, _, _ = run(
        capsys, "calibrate", str(recording_file), "--method", "ml", "-o", str(calibration), "--force"
    )
    assert code == 0
    history = read_history(calibration)
    assert history.checks == [] and history.other_calibrations == 1 and history.unreadable == 0
    code, out, _ = run(capsys, "report", str(calibration), "-o", str(tmp_path / "r.html"))
    assert code == 0 and "Check history" not in out.splitlines()[0]
    assert "note: 1 check(s) in" in out and "are of another calibration" in out
    # the next check is this calibration's first
    assert run(capsys, "check", str(calibration), "--recording", str(recording_file))[0] == 0
    assert len(read_history(calibration).checks) == 1
    code, out, _ = run(capsys, "report", str(calibration), "-o", str(tmp_path / "r.html"))
    assert code == 0 and "Check history" in out.splitlines()[0]


def test_an_edited_calibration_is_one_line_unless_accepted(recording_file, tmp_path, capsys):
    calibration = tmp_path / "cal.json"
    assert run(capsys, "calibrate", str(recording_file), "-o", str(calibration))[0] == 0
    data = json.loads(calibration.read_text())
    data["tracker_from_base"][0][3] += 2.0  # 2 mm
    calibration.write_text(json.dumps(data, indent=2))
    line = (
        f"spacecal: error: {calibration} has been edited since it was written (content hash differs); "
        "pass --accept-edited to use it anyway\n"
    )
    for argv in (
        ["check", str(calibration), "--recording", str(recording_file)],
        ["export", str(calibration), "--slicer", str(tmp_path / "t.tfm")],
        ["export", str(calibration), "--urdf", str(tmp_path / "t.urdf"), "--plus", str(tmp_path / "t.xml")],
        ["report", str(calibration), "-o", str(tmp_path / "r.html")],
    ):
        code, out, err = run(capsys, *argv)
        assert (code, out, err) == (1, "", line), argv
    assert not list(tmp_path.glob("t.*")) and not (tmp_path / "r.html").exists()
    code, out, err = run(
        capsys,
        "export",
        str(calibration),
        "--slicer",
        str(tmp_path / "t.tfm"),
        "--urdf",
        str(tmp_path / "t.urdf"),
        "--accept-edited",
    )
    assert code == 0 and out.count("has been edited since it was written") == 1
    assert out.startswith(f"note: {calibration} has been edited") and "wrote" in out
    code, out, err = run(
        capsys, "check", str(calibration), "--recording", str(recording_file), "--accept-edited"
    )
    assert "note: " in out and "used as --accept-edited asks" in out
    code, _, err = run(
        capsys, "bound", str(recording_file), "--calibration", str(calibration), "--sigma-mm", "0.1"
    )
    assert code == 1 and "bound does not use an edited calibration" in err and len(err.splitlines()) == 1


def test_future_versions_of_result_files_are_refused_in_one_line(recording_file, tmp_path, capsys):
    calibration = tmp_path / "cal.json"
    assert run(capsys, "calibrate", str(recording_file), "-o", str(calibration))[0] == 0
    verification = tmp_path / "ver.json"
    verification.write_text(
        json.dumps({"schema": "spacecal.verification", "schema_version": 5, "points": []})
    )
    code, _, err = run(
        capsys,
        "report",
        str(calibration),
        "--verification",
        str(verification),
        "-o",
        str(tmp_path / "r.html"),
    )
    assert code == 1 and err == (
        f"spacecal: error: {verification}: schema_version 5 is newer than this spacecal reads (1, 2, 3, 4): "
        "written by a newer spacecal, update it to read this file\n"
    )
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps({"schema": "spacecal.plan", "schema_version": 7}))
    for argv in (
        ["simulate", "--plan", str(plan), "-o", str(tmp_path / "s.csv")],
        ["acquire", "--plan", str(plan), "-o", str(tmp_path / "a.csv")],
    ):
        code, _, err = run(capsys, *argv)
        assert code == 1 and len(err.splitlines()) == 1, err
        assert "schema_version 7 is newer than this spacecal reads (1, 2)" in err
    data = json.loads(calibration.read_text())
    data["schema_version"] = 5
    calibration.write_text(json.dumps(data))
    code, _, err = run(
        capsys, "check", str(calibration), "--recording", str(recording_file), "--accept-edited"
    )
    assert code == 1 and err == (
        f"spacecal: error: {calibration}: schema_version 5 is newer than this spacecal reads "
        "(1, 2, 3, 4): written by a newer spacecal, update it to read this file\n"
    )


def test_kinematic_calibrate_prints_the_residuals_the_report_shows(tmp_path, capsys, realistic_simulation):
    from spacecal.io.recording_csv import write_recording
    from spacecal.io.results_json import read_calibration
    from spacecal.report.summary import residuals_of

    recording = write_recording(realistic_simulation.recording, tmp_path / "rec.csv")
    code, out, err = run(
        capsys, "calibrate", str(recording), "--method", "kinematic", "-o", str(tmp_path / "k.json")
    )
    assert code == 0, err
    line = next(line for line in out.splitlines() if "marker residuals" in line)
    found = re.fullmatch(
        r"marker residuals \(RMS, identified robot kinematics\): "
        r"position ([0-9.]+) mm, rotation ([0-9.]+) deg",
        line,
    )
    assert found, line
    # the report recomputes them from the recording with the identified model: the same figures
    shown = residuals_of(read_calibration(tmp_path / "k.json"), realistic_simulation.recording)
    assert shown is not None and shown.source == "recomputed from the recording"
    assert found.group(1) == f"{shown.position_rms_mm:.3f}"
    assert found.group(2) == f"{shown.rotation_rms_deg:.3f}"
    # an estimator that keeps the recorded TCP poses says so
    code, out, _ = run(capsys, "calibrate", str(recording), "--method", "ml", "-o", str(tmp_path / "m.json"))
    assert code == 0 and "marker residuals (RMS, recorded TCP poses): position " in out


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (["acquire", "-o", "rec.csv", "--dry-run", "--speed-mm-s", "1_00"], "invalid decimal value: '1_00'"),
        (["simulate", "-o", "rec.csv", "--seed", "1_0"], "invalid integer value: '1_0'"),
        (["simulate", "-o", "rec.csv", "--seed", "١٢"], "invalid integer value: '١٢'"),
        (["acquire", "-o", "rec.csv", "--live-view", "8_080"], "invalid port_number value: '8_080'"),
    ],
)
def test_option_values_with_digit_groups_are_usage_errors(tmp_path, capsys, monkeypatch, argv, said):
    """Option values are numbers as the file readers take them (``core.strict_numbers``):
    ``1_00`` and other scripts' digits, which ``float()`` and ``int()`` take, are refused in one
    line before anything runs."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as usage:
        main(argv)
    err = capsys.readouterr().err
    assert usage.value.code == 2 and said in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "rec.csv").exists()


@pytest.mark.parametrize(
    ("option", "value", "said"),
    [
        ("--tool-offset-mm", "1_0,0,0", "--tool-offset-mm takes x,y,z in mm, got '1_0,0,0'"),
        ("--time-offset-ms", "1_0", "--time-offset-ms takes a number or 'estimate', got '1_0'"),
    ],
)
def test_listed_option_values_with_digit_groups_are_one_line(
    tmp_path, capsys, monkeypatch, option, value, said
):
    monkeypatch.chdir(tmp_path)
    command = "acquire" if option == "--tool-offset-mm" else "calibrate"
    argv = (
        ["acquire", "-o", "rec.csv", "--dry-run"]
        if command == "acquire"
        else ["calibrate", "rec.csv", "-o", "c.json"]
    )
    code, out, err = run(capsys, *argv, option, value)
    assert code == 1 and said in err and len(err.strip().splitlines()) == 1, err


def test_plain_option_values_still_parse():
    from spacecal.cli.main import build_parser

    parsed = build_parser().parse_args(
        ["acquire", "-o", "rec.csv", "--speed-mm-s", "1.5e2", "--live-view", "8080"]
    )
    assert parsed.speed_mm_s == 150.0 and parsed.live_view == 8080
