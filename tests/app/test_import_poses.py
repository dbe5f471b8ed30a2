"""``spacecal import-poses``: a simulated run exported as two TUM trajectories on clocks apart,
imported and calibrated, gives the calibration of the same data given as raw CSV streams; an
eye-in-hand camera's hand-eye transform is recovered; every bad input is one line and exit 1."""

import dataclasses
import json
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from spacecal import app
from spacecal.cli import main
from spacecal.core.errors import InvalidInputError
from spacecal.estimators import calibrate
from spacecal.estimators.time_offset import pair_streams
from spacecal.experiments.simulation import simulate_raw
from spacecal.geometry.transforms import invert_transform, make_transform
from spacecal.io.raw_streams import read_raw_recording, write_raw_recording
from spacecal.io.results_json import read_calibration
from spacecal.io.tum import write_tum
from spacecal.records import RawRecording
from spacecal.sim.scenario import PRESETS

CLOCK_OFFSET_S = 0.08  # robot clock ahead of the tracker's: within the estimator's +-0.2 s search
#: Shorter sweeps than the paper's keep the simulation quick; the comparison needs no more.
SCENARIO = dataclasses.replace(PRESETS["paper-white"], rotation_deg=30.0, translation_mm=150.0)


@pytest.fixture(scope="module")
def pose_only():
    """A simulated run as a TUM pair can carry it: the tracker's seen poses only, no fit RMS,
    no joints; with the raw CSV streams of exactly those numbers."""
    raw, world = simulate_raw(SCENARIO, clock_offset_s=CLOCK_OFFSET_S)
    seen = np.isfinite(raw.tracker_from_marker_stack[:, 0, 0])
    data = RawRecording(
        robot_time_s=raw.robot_time_s,
        robot_segment=np.full(len(raw.robot_time_s), "tum"),
        joints_rad=np.full_like(raw.joints_rad, np.nan),
        base_from_tcp_stack=raw.base_from_tcp_stack,
        tracker_time_s=raw.tracker_time_s[seen],
        tracker_from_marker_stack=raw.tracker_from_marker_stack[seen],
        marker_rms_mm=np.full(int(seen.sum()), np.nan),
        metadata={"units": {"length": "mm", "angle": "rad", "time": "s"}},
    )
    return data, world


def _run(*args):
    return main([str(a) for a in args])


def _calibrate(tmp_path, stem, name, *extra):
    assert (
        _run(
            "calibrate",
            tmp_path / f"{stem}.robot.csv",
            "--tracker-stream",
            tmp_path / f"{stem}.tracker.csv",
            "--method",
            "ml",
            "-o",
            tmp_path / name,
            *extra,
        )
        == 0
    )
    return read_calibration(tmp_path / name)


def _difference(a, b):
    """Largest difference of the two calibrations: translations (mm), rotation entries."""
    return max(
        float(np.max(np.abs(a.tracker_from_base - b.tracker_from_base))),
        float(np.max(np.abs(a.tcp_from_marker - b.tcp_from_marker))),
    )


def _export(tmp_path, data, robot_shift_s=0.0, units="m"):
    """The run as two TUM files (in ``units``); the robot's clock moved on by ``robot_shift_s``."""
    robot = write_tum(
        tmp_path / "robot.tum",
        data.robot_time_s + robot_shift_s,
        data.base_from_tcp_stack,
        units,
        comments=("robot: base_from_tcp",),
    )
    tracker = write_tum(
        tmp_path / "tracker.tum",
        data.tracker_time_s,
        data.tracker_from_marker_stack,
        units,
        ("tracker_from_marker",),
    )
    return robot, tracker


def test_a_tum_pair_calibrates_as_the_same_csv_streams(tmp_path, pose_only, capsys):
    data, _ = pose_only
    write_raw_recording(data, tmp_path / "csv")
    from_csv = _calibrate(tmp_path, "csv", "csv.json")
    robot, tracker = _export(tmp_path, data)
    assert _run("import-poses", "--robot", robot, "--tracker", tracker, "-o", tmp_path / "tum") == 0
    out = capsys.readouterr().out
    assert f"({len(data.robot_time_s)} robot poses)" in out and "--tracker-stream" in out
    meta = json.loads((tmp_path / "tum.meta.json").read_text())
    assert meta["source"] == "TUM import" and meta["tum"]["tracker_file"] == str(tracker)
    from_tum = _calibrate(tmp_path, "tum", "tum.json")
    # the same numbers (metres and x,y,z,w quaternions in between): the same calibration
    difference = _difference(from_tum, from_csv)
    with capsys.disabled():
        print(f"TUM vs CSV, offset estimated: largest difference {difference:.3g}")
    assert difference < 1e-6
    offsets = [c.provenance.source.time_offset_s for c in (from_csv, from_tum)]
    assert abs(offsets[0] - CLOCK_OFFSET_S) < 2e-3 and abs(offsets[1] - offsets[0]) < 1e-9
    # an existing import is not replaced without --force
    assert _run("import-poses", "--robot", robot, "--tracker", tracker, "-o", tmp_path / "tum") == 1
    assert "--force" in capsys.readouterr().err
    assert (
        _run("import-poses", "--robot", robot, "--tracker", tracker, "-o", tmp_path / "tum", "--force") == 0
    )


def test_clocks_seconds_or_minutes_apart_with_the_offset_given(tmp_path, pose_only, capsys):
    data, _ = pose_only
    write_raw_recording(data, tmp_path / "csv")
    offset_ms = CLOCK_OFFSET_S * 1000
    from_csv = _calibrate(tmp_path, "csv", "csv.json", "--time-offset-ms", offset_ms)
    # 5 s apart, in mm: through the command line with the offset given
    robot, tracker = _export(tmp_path, data, robot_shift_s=5.0, units="mm")
    assert (
        _run("import-poses", "--robot", robot, "--tracker", tracker, "--units", "mm", "-o", tmp_path / "a")
        == 0
    )
    from_tum = _calibrate(tmp_path, "a", "a.json", "--time-offset-ms", 5000.0 + offset_ms)
    difference = _difference(from_tum, from_csv)
    with capsys.disabled():
        print(f"TUM (5 s apart, mm) vs CSV, offset given: largest difference {difference:.3g}")
    assert difference < 1e-6
    # five minutes apart: the streams do not overlap, the import says so; paired at the offset
    # (calibrate's --time-offset-ms takes +-10 s for now) the calibration is the same
    robot, tracker = _export(tmp_path, data, robot_shift_s=300.0)
    capsys.readouterr()
    out = app.import_poses(app.ImportPosesSettings(str(robot), str(tracker), str(tmp_path / "b")))
    assert len(out.notes) == 1 and "do not overlap" in out.notes[0] and "--time-offset-ms" in out.notes[0]
    raw = read_raw_recording(*out.files_written[:2])
    far = calibrate(pair_streams(raw, 300.0 + CLOCK_OFFSET_S), "ml")
    near = calibrate(pair_streams(data, CLOCK_OFFSET_S), "ml")
    difference = _difference(far, near)
    with capsys.disabled():
        print(f"TUM (300 s apart) vs the same streams, offset given: largest difference {difference:.3g}")
    assert difference < 1e-6


#: Eye-in-hand truth: the target 900 mm in front of the base, the camera 80 mm off the TCP.
BASE_FROM_TARGET = make_transform(
    Rotation.from_euler("xyz", [180, 0, 90], degrees=True).as_matrix(), [900.0, 50, 0]
)
TCP_FROM_CAMERA = make_transform(
    Rotation.from_euler("xyz", [5, -10, 30], degrees=True).as_matrix(), [80.0, 0, 40]
)
ROBOT_RATE_HZ = 128.0  # binary fractions of a second: frame times fall exactly on robot states


def _eye_in_hand_run(tmp_path):
    """A camera on the tool filming a fixed target while the tool turns and moves (noise-free).
    The camera's clock runs 2 s behind the robot's; every 4th robot state has a frame."""
    time_s = np.arange(1024) / ROBOT_RATE_HZ
    phase = 2 * np.pi * time_s / time_s[-1]
    rotvec = np.radians(35.0) * np.stack([np.sin(phase), np.sin(2 * phase), 0.6 * np.cos(3 * phase)], axis=1)
    start = Rotation.from_euler("xyz", [0, 90, 0], degrees=True)  # the camera looks along +x
    rotations = (start * Rotation.from_rotvec(rotvec)).as_matrix()
    positions = np.stack([150 * np.sin(phase), 200 * np.sin(2 * phase), 400 + 100 * np.cos(phase)], axis=1)
    base_from_tcp = make_transform(rotations, positions)
    target_from_camera = invert_transform(BASE_FROM_TARGET) @ base_from_tcp[::4] @ TCP_FROM_CAMERA
    robot = write_tum(tmp_path / "arm.tum", time_s + 100.0, base_from_tcp)
    camera = write_tum(tmp_path / "camera.tum", time_s[::4] + 98.0, target_from_camera)
    return robot, camera, target_from_camera


def test_eye_in_hand_recovers_the_hand_eye_transform(tmp_path, capsys):
    robot, camera, target_from_camera = _eye_in_hand_run(tmp_path)
    args = ["import-poses", "--robot", robot, "--tracker", camera, "--eye-in-hand", "-o", tmp_path / "eye"]
    assert _run(*args) == 0
    assert "eye-in-hand" in capsys.readouterr().out
    result = _calibrate(tmp_path, "eye", "eye.json", "--time-offset-ms", 2000)
    # tracker = the fixed target, marker = the camera: tcp_from_marker is the hand-eye transform
    errors = (
        np.max(np.abs(result.tcp_from_marker - TCP_FROM_CAMERA)),
        np.max(np.abs(result.tracker_from_base - invert_transform(BASE_FROM_TARGET))),
    )
    with capsys.disabled():
        print(f"eye-in-hand, no noise: tcp_from_camera off {errors[0]:.3g}, target_from_base {errors[1]:.3g}")
    assert max(errors) < 1e-6
    meta = json.loads((tmp_path / "eye.meta.json").read_text())
    assert meta["tum"]["eye_in_hand"] is True and meta["frames"]["marker"].startswith("camera")
    # the target's pose in the camera (solvePnP's camera_from_target) is not a camera trajectory:
    # calibrate names the reading that explains it, in one line
    inverted = write_tum(
        tmp_path / "pnp.tum", np.arange(256) / 32.0 + 98.0, invert_transform(target_from_camera)
    )
    assert (
        _run("import-poses", "--robot", robot, "--tracker", inverted, "--eye-in-hand", "-o", tmp_path / "pnp")
        == 0
    )
    capsys.readouterr()
    code = _run(
        "calibrate",
        tmp_path / "pnp.robot.csv",
        "--tracker-stream",
        tmp_path / "pnp.tracker.csv",
        "--time-offset-ms",
        2000,
        "--method",
        "ml",
        "-o",
        tmp_path / "pnp.json",
    )
    err = capsys.readouterr().err
    assert code == 1 and len(err.strip().splitlines()) == 1, err
    # inverting either stack explains it exactly (the hand-eye duality): one of them is named
    assert "poses are inverted" in err and "far better if" in err, err


def test_eye_in_hand_with_camera_noise_is_within_the_fits_covariance(tmp_path, capsys):
    """Noise on the camera's poses, in the camera's frame (0.2 mm, 0.05 deg per axis): the
    error of both transforms is within the fit's own covariance (99.99 % of chi-square(12))."""
    robot, _, target_from_camera = _eye_in_hand_run(tmp_path)
    rng = np.random.default_rng(0)
    count = len(target_from_camera)
    noise = make_transform(
        Rotation.from_rotvec(rng.normal(scale=np.radians(0.05), size=(count, 3))).as_matrix(),
        rng.normal(scale=0.2, size=(count, 3)),
    )
    camera = write_tum(tmp_path / "noisy.tum", np.arange(count) / 32.0 + 98.0, target_from_camera @ noise)
    out = app.import_poses(
        app.ImportPosesSettings(str(robot), str(camera), str(tmp_path / "eye"), eye_in_hand=True)
    )
    result = calibrate(pair_streams(read_raw_recording(*out.files_written[:2]), 2.0), "ml")
    target_from_base = invert_transform(BASE_FROM_TARGET)
    # the perturbation parameters of spacecal.models.kinematics.apply_pose_step
    error = np.concatenate(
        [
            result.tracker_from_base[:3, 3] - target_from_base[:3, 3],
            Rotation.from_matrix(result.tracker_from_base[:3, :3] @ target_from_base[:3, :3].T).as_rotvec(),
            result.tcp_from_marker[:3, 3] - TCP_FROM_CAMERA[:3, 3],
            Rotation.from_matrix(TCP_FROM_CAMERA[:3, :3].T @ result.tcp_from_marker[:3, :3]).as_rotvec(),
        ]
    )
    chi_square = float(error @ np.linalg.solve(np.asarray(result.covariance["matrix"]), error))
    with capsys.disabled():
        print(
            f"eye-in-hand, noisy: tcp_from_camera off {np.linalg.norm(error[6:9]):.3f} mm, "
            f"{np.degrees(np.linalg.norm(error[9:])):.4f} deg; chi-square {chi_square:.1f} (12 dof)"
        )
    assert chi_square < chi2.ppf(0.9999, 12)


GOOD_LINE = "{t} 0.5 0.1 0.3 0 0 0 1"


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("2.5 1_000 0.1 0.3 0 0 0 1", "line 4: tx '1_000' is not a plain number"),
        ("2.5 0.5 NaN 0.3 0 0 0 1", "line 4: ty 'NaN' is not a finite number"),
        ("2.5 0.5 0.1 Inf 0 0 0 1", "line 4: tz 'Inf' is not a finite number"),
        ("2.5 0.5 0.1 5e6 0 0 0 1", "line 4: translation 5e\\+06 m is beyond"),
        ("2.5 0.5 0.1 0.3 0 0 0 2", "line 4: quaternion qx qy qz qw has norm 2"),
        ("0.5 0.5 0.1 0.3 0 0 0 1", "line 4: timestamp 0.5 is before"),
        ("2.0 0.5 0.1 0.3 0 0 0 1", "line 4: timestamp 2.0 repeats"),
        ("2.5 0.5 0.1 0.3 0 0 1", "line 4: 7 columns"),
        ("2.5 0.5 0.1 0.3 0 0 0 1 0", "line 4: 9 columns"),
    ],
)
def test_each_malformed_file_is_one_line_and_exit_1(tmp_path, capsys, line, message):
    good = "\n".join(GOOD_LINE.format(t=t) for t in range(10, 30)) + "\n"
    robot = tmp_path / "robot.tum"
    robot.write_text(good)
    tracker = tmp_path / "tracker.tum"
    tracker.write_text(
        "# tracker_from_marker\n1.0 0.5 0.1 0.3 0 0 0 1\n2.0 0.5 0.1 0.3 0 0 0 1\n" + line + "\n"
    )
    assert _run("import-poses", "--robot", robot, "--tracker", tracker, "-o", tmp_path / "out") == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and str(tracker) in err and "Traceback" not in err
    assert err.startswith("spacecal: error: ") and re.search(message, err), err
    assert not (tmp_path / "out.robot.csv").exists()


def test_bad_pairs_and_options(tmp_path, capsys):
    lines = "\n".join(GOOD_LINE.format(t=t) for t in range(10, 30)) + "\n"
    robot = tmp_path / "robot.tum"
    robot.write_text(lines)
    few = tmp_path / "few.tum"
    few.write_text("\n".join(lines.splitlines()[:5]) + "\n")
    cases = [
        (["--robot", robot, "--tracker", few], "few.tum: 5 poses; at least 10"),
        (["--robot", robot, "--tracker", robot], "given as both the robot and the tracker"),
        (["--robot", tmp_path / "nope.tum", "--tracker", robot], "no such robot TUM trajectory file"),
        (["--robot", robot, "--tracker", robot.with_name("x.tum"), "--units", "mm"], "no such tracker TUM"),
    ]
    for args, message in cases:
        assert _run("import-poses", *args, "-o", tmp_path / "out") == 1
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1, err
    # metres read as mm
    assert (
        _run("import-poses", "--robot", robot, "--tracker", robot, "--units", "mm", "-o", tmp_path / "o") == 1
    )
    capsys.readouterr()
    copy = tmp_path / "tracker.tum"
    copy.write_text(lines)
    assert (
        _run("import-poses", "--robot", robot, "--tracker", copy, "--units", "mm", "-o", tmp_path / "o") == 1
    )
    assert "look like metres read as mm" in capsys.readouterr().err
    # an unknown unit is a usage error (2); the settings refuse it too
    with pytest.raises(SystemExit) as info:
        _run("import-poses", "--robot", robot, "--tracker", copy, "--units", "cm", "-o", tmp_path / "o")
    assert info.value.code == 2
    with pytest.raises(InvalidInputError, match="--units must be one of m, mm"):
        app.ImportPosesSettings(str(robot), str(copy), "o", units="cm")
