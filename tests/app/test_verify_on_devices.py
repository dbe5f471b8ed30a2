"""``spacecal verify`` on the devices (paper §5.2) through the motion session: on the simulated
robot and tracker, where the truth is known, the reported errors are compared with the true
reached poses; bad input is one line and nothing moves."""

import json

import numpy as np
import pytest

from spacecal import app
from spacecal.cli.main import main
from spacecal.core.errors import UnreachableError
from spacecal.io.results_json import read_calibration
from spacecal.records import VerificationResult


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    folder = tmp_path_factory.mktemp("verify")
    recording = folder / "rec.csv"
    app.simulate(app.SimulateSettings(output=str(recording)))
    path = folder / "cal.json"
    app.calibrate(app.CalibrateSettings(str(recording), output=str(path), method="ml"))
    return path


@pytest.fixture
def robots(monkeypatch):
    """Every simulated world and robot the sessions open, kept for the truth."""
    import spacecal.app.motion_session as session

    opened = []
    original = session.simulated_devices

    def keep(scenario, start_s=0.0, speed=None):
        world, robot, tracker = original(scenario, start_s, speed)
        opened.append((world, robot))
        return world, robot, tracker

    monkeypatch.setattr(session, "simulated_devices", keep)
    return opened


def test_fifteen_needle_poses_reported_as_the_truth_within_the_stated_error(calibration, tmp_path, robots):
    out = tmp_path / "ver.json"
    result = app.verify(
        app.VerifySettings(str(calibration), devices=app.DeviceSettings("sim", "sim"), output=str(out))
    ).record.result
    assert result is not None and len(result.position_error_mm) == 15
    assert result.simulated and "calibrated marker" in result.measured_by
    assert VerificationResult.from_dict(json.loads(out.read_text())).measured_by == result.measured_by
    ((world, robot),) = robots
    cal = read_calibration(calibration)
    # the truth of each reached pose: where the true arm put its TCP (the needle) at the joints it
    # came to rest at, seen from the true tracker
    truth = np.array(
        [
            world.tracker_from_base @ world.true_base_from_tcp(q, jitter=False).reshape(4, 4)
            for q in result.joints_rad
        ]
    )
    true_errors = np.linalg.norm(truth[:, :3, 3] - result.desired_tracker_from_needle[:, :3, 3], axis=1)
    reported_off = np.linalg.norm(truth[:, :3, 3] - result.reached_tracker_from_needle[:, :3, 3], axis=1)
    stated = cal.assessment.position_mm
    print(
        f"stated {stated:.3f} mm; reported mean {result.position_error_mm.mean():.3f}, true mean "
        f"{true_errors.mean():.3f}; reported pose off the truth RMS {np.sqrt(np.mean(reported_off**2)):.3f}, "
        f"max {reported_off.max():.3f} mm"
    )
    # the reported reached pose lies off the true one by the calibration's own error at the tip
    # (the marker carries tcp_from_marker): its RMS over the poses within the stated error
    assert np.sqrt(np.mean(reported_off**2)) <= stated
    # and the reported errors differ from the true ones by no more than that
    assert np.all(np.abs(result.position_error_mm - true_errors) <= reported_off + 1e-9)


def test_a_dry_run_plans_the_poses_and_moves_nothing(calibration, robots, capsys):
    code = main(["verify", str(calibration), "--robot", "sim", "--tracker", "sim", "--dry-run"])
    out = capsys.readouterr().out
    assert code == 0 and "15 needle poses planned" in out and "nothing moved" in out
    ((_, robot),) = robots
    assert robot.commands == []


def test_a_needle_pose_out_of_reach_is_refused_before_anything_moves(calibration, tmp_path, robots, capsys):
    cal = read_calibration(calibration)
    far = cal.tracker_from_base @ np.array([[1, 0, 0, 5000.0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    targets = tmp_path / "far.json"
    targets.write_text(json.dumps({"tracker_from_needle": [far.tolist()]}))
    with pytest.raises(UnreachableError, match="needle pose 1"):
        app.verify(
            app.VerifySettings(
                str(calibration), devices=app.DeviceSettings("sim", "sim"), targets=str(targets)
            )
        )
    code = main(["verify", str(calibration), "--robot", "sim", "--tracker", "sim", "--targets", str(targets)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and "needle pose 1" in err[0] and "nothing moved" in err[0]
    assert all(robot.commands == [] for _, robot in robots)


@pytest.mark.parametrize(
    "content, words",
    [
        ({"tracker_from_needle": []}, "list of 1..100"),
        ({"tracker_from_needle": [[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]]]}, "tracker_from_needle[0]"),
        (
            {"tracker_from_needle": [[[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]]},
            "tracker_from_needle[0]",
        ),
    ],
)
def test_bad_needle_pose_files_are_one_line(calibration, tmp_path, capsys, robots, content, words):
    targets = tmp_path / "poses.json"
    targets.write_text(json.dumps(content))
    code = main(["verify", str(calibration), "--robot", "sim", "--tracker", "sim", "--targets", str(targets)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and words in err[0], err
    assert robots == []  # refused before any device was opened
