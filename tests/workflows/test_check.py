"""The calibration check passes a calibration that holds and fails one that no longer does."""

import json

import numpy as np
import pytest

from spacecal.cli import main
from spacecal.estimators import calibrate
from spacecal.geometry.transforms import axis_angle_transform, make_transform
from spacecal.io.check_history import history_path, read_history
from spacecal.io.results_json import read_calibration, write_calibration
from spacecal.records import Provenance, RecordingSource
from spacecal.testing.calibrations import with_stored


@pytest.fixture
def calibration_file(tmp_path, white_simulation):
    from spacecal.io.recording_csv import write_recording

    recording = write_recording(white_simulation.recording, tmp_path / "rec.csv")
    result = calibrate(white_simulation.recording, "ml")
    result = result.replace(
        provenance=Provenance(
            source=RecordingSource.paired_csv(str(recording)),
            simulated=True,
            scenario=white_simulation.world.scenario.to_dict(),
        )
    )
    return write_calibration(result, tmp_path / "cal.json")


def tamper(path, key, change):
    """A calibration, written by spacecal (its hash holds), that no longer matches the world."""
    calibration = read_calibration(path)
    matrix = getattr(calibration, key)
    moved = change @ matrix if key == "tracker_from_base" else matrix @ change
    return write_calibration(calibration.replace(**{key: moved}), path.with_name(f"tampered_{key}.json"))


def test_good_calibration_passes_and_is_logged(calibration_file, capsys):
    assert main(["check", str(calibration_file)]) == 0
    assert "PASS" in capsys.readouterr().out
    history = read_history(calibration_file).checks
    assert len(history) == 1 and history[0].passed and len(history[0].labels) == 3
    assert history[0].simulated is True
    assert history_path(calibration_file).name == "cal.checks.jsonl"


@pytest.mark.parametrize(
    "fault,key,change",
    [
        ("marker bumped by 1 deg", "tcp_from_marker", axis_angle_transform([0, 1, 0], np.radians(1.0))),
        ("tracker moved by 2 mm", "tracker_from_base", make_transform(np.eye(3), [2.0, 0.0, 0.0])),
    ],
)
def test_a_calibration_that_no_longer_holds_fails(calibration_file, capsys, fault, key, change):
    assert main(["check", str(tamper(calibration_file, key, change)), "--poses", "2"]) == 1
    captured = capsys.readouterr()
    assert "FAIL" in captured.out and "no longer holds" in captured.err


def test_check_against_a_recording(calibration_file, tmp_path, capsys):
    assert main(["check", str(calibration_file), "--recording", str(tmp_path / "rec.csv")]) == 0
    out = capsys.readouterr().out
    assert "rot_x" in out and "PASS" in out


def _check_run(world, calibration, tracker_factory, poses=2, robot_options=None):
    from spacecal.experiments.simulation import simulation_settings
    from spacecal.planning.check_poses import check_plan
    from spacecal.planning.motion import MotionLimits
    from spacecal.sim.devices import SimClock, SimulatedRobot
    from spacecal.workflows.check import check_thresholds, check_with_robot

    robot = SimulatedRobot(world, SimClock(), **(robot_options or {}))
    plan = check_plan(
        world.nominal_model, world.home_joints_rad, poses, MotionLimits(), 1 / world.scenario.tracker_rate_hz
    )
    threshold_mm, threshold_deg, _ = check_thresholds(calibration, 10)
    result = check_with_robot(
        calibration,
        robot,
        tracker_factory(world, robot),
        plan,
        threshold_mm,
        threshold_deg,
        simulation_settings(world.scenario),
    )
    return result, robot


def test_a_missed_frame_on_a_long_running_tracker_is_not_an_error(white_simulation):
    # Real trackers number frames from power-up; one missed frame must not end the check.
    from dataclasses import replace as replace_frame

    from spacecal.core.errors import DegenerateDataError
    from spacecal.core.ports import FRAME_MISSING
    from spacecal.sim.devices import SimulatedTracker

    class LongRunning(SimulatedTracker):
        def __init__(self, *args, hidden_frames):
            super().__init__(*args)
            self.hidden_frames = hidden_frames

        def next_frame(self, timeout_s):
            frame = replace_frame(super().next_frame(timeout_s), frame_number=1_000_000 + self._delivered)
            if self._delivered <= self.hidden_frames:
                return replace_frame(frame, status=FRAME_MISSING, tracker_from_marker=None)
            return frame

    world = white_simulation.world
    calibration = calibrate(white_simulation.recording, "ml")
    result, _ = _check_run(world, calibration, lambda w, r: LongRunning(w, r, hidden_frames=1))
    assert result.passed and result.labels == ["check-1", "check-2"]
    with pytest.raises(DegenerateDataError, match="the marker was seen in 0 frames"):
        _check_run(world, calibration, lambda w, r: LongRunning(w, r, hidden_frames=10**6))


def test_a_safety_stop_during_the_check_stops_the_robot_and_logs_nothing(white_simulation):
    from spacecal.core.errors import DeviceError
    from spacecal.sim.devices import SimulatedTracker

    calibration = calibrate(white_simulation.recording, "ml")
    with pytest.raises(DeviceError, match="check stopped: robot protective stop"):
        _check_run(
            white_simulation.world, calibration, SimulatedTracker, robot_options={"protective_stop_at_s": 1.0}
        )


def test_thresholds_follow_the_calibration_and_the_frames_averaged(white_simulation):
    from spacecal.workflows.check import CHECK_FLOOR_MM, FALLBACK_THRESHOLD_MM, check_thresholds

    calibration = calibrate(white_simulation.recording, "ml")
    one_frame, _, _ = check_thresholds(calibration, 1)
    ten_frames, _, basis = check_thresholds(calibration, 10)
    assert one_frame > ten_frames >= CHECK_FLOOR_MM and "10 frame(s)" in basis
    bare = calibration.replace(diagnostics={}, assessment=None)
    assert check_thresholds(bare, 10)[0] == FALLBACK_THRESHOLD_MM


def _expectations(poses):
    rng = np.random.default_rng(4)
    return dict(
        misfit_mm=rng.normal(size=(poses, 3)),
        expected_misfit_mm=rng.normal(size=(poses, 3)),
        tolerance_mm=np.full(poses, 0.4),
        misfit_deg=rng.normal(scale=0.1, size=(poses, 3)),
        expected_misfit_deg=rng.normal(scale=0.1, size=(poses, 3)),
        tolerance_deg=np.full(poses, 0.15),
    )


def test_a_check_with_expected_misfits_round_trips_and_passes_on_its_tolerances():
    from spacecal.records import CheckResult

    values = _expectations(2)
    # the first pose departs beyond its tolerance, though under the larger common threshold
    result = CheckResult(
        np.array([0.5, 0.1]),
        np.array([0.05, 0.05]),
        0.6,
        0.15,
        ["a", "b"],
        basis="from the recording",
        **{**values, "tolerance_mm": np.array([0.4, 0.6])},
    )
    assert not result.passed
    again = CheckResult.from_dict(json.loads(json.dumps(result.to_dict())))
    assert again.to_dict() == result.to_dict() and not again.passed and again.basis == "from the recording"
    assert result.to_dict()["schema_version"] == 3
    assert result.to_dict()["poses"][0]["expected_misfit_mm"] == values["expected_misfit_mm"][0].tolist()


def test_expected_misfits_come_whole():
    from spacecal.core.errors import InvalidInputError
    from spacecal.records import CheckResult

    values = _expectations(2)
    with pytest.raises(InvalidInputError, match="or none of them"):
        CheckResult(np.zeros(2), np.zeros(2), 1.0, 1.0, misfit_mm=values["misfit_mm"])
    with pytest.raises(InvalidInputError, match="shape"):
        CheckResult(np.zeros(3), np.zeros(3), 1.0, 1.0, **values)


def test_histories_of_every_schema_version_still_read(tmp_path):
    calibration = tmp_path / "cal.json"
    old = [
        # version 1: no schema fields, no "simulated"
        {"threshold_mm": 1.0, "threshold_deg": 1.0, "checked_utc": "2024-01-01T00:00:00+00:00",
         "poses": [{"label": "pose 1", "tcp_error_mm": 0.4, "rotation_error_deg": 0.1}]},
        # version 2
        {"schema": "spacecal.check", "schema_version": 2, "simulated": True, "devices": {"robot": "sim"},
         "threshold_mm": 1.0, "threshold_deg": 1.0, "checked_utc": "2025-01-01T00:00:00+00:00",
         "poses": [{"label": "check-1", "tcp_error_mm": 1.4, "rotation_error_deg": 0.1}]},
    ]  # fmt: skip
    # each line bound to the calibration it checked (its content hash)
    bound = [{**line, "calibration_sha256": "a" * 64} for line in old]
    history_path(calibration).write_text("".join(json.dumps(line) + "\n" for line in bound))
    from spacecal.io.check_history import append_history
    from spacecal.records import CheckResult

    append_history(
        calibration,
        CheckResult(np.array([0.1]), np.array([0.02]), 0.4, 0.15, ["check-1"], **_expectations(1)),
        "a" * 64,
    )
    history, unreadable, _ = read_history(calibration, "a" * 64)
    assert unreadable == 0
    assert [h.passed for h in history] == [True, False, True]
    assert [h.has_expectations for h in history] == [False, False, True]
    assert history[1].simulated is True and history[0].simulated is None


def test_the_tolerance_factor_is_the_chi_quantile_of_the_stated_false_alarm_rate():
    from scipy.stats import chi2

    from spacecal.workflows.check import FALSE_ALARM_RATE, tolerance_factor

    for poses in (2, 3):
        k = tolerance_factor(poses)
        # two tests per pose (position, rotation), each at its share of the rate
        assert 1.0 - (1.0 - chi2.sf(k**2, 3)) ** (2 * poses) == pytest.approx(FALSE_ALARM_RATE)
    assert tolerance_factor(3) == pytest.approx(3.90, abs=0.01)


def _field_around_home(world, misfit, noise_mm=0.0, seed=3):
    """A misfit field over poses around the world's home (random tilts up to 40 deg, positions in
    a 300 mm cube), its misfits from ``misfit(poses) -> (N, 6)`` plus white noise."""
    from spacecal.geometry.transforms import axis_angle_transform
    from spacecal.models.kinematics import forward_kinematics
    from spacecal.workflows.check import MisfitField

    rng = np.random.default_rng(seed)
    home = forward_kinematics(world.nominal_model, world.home_joints_rad)
    axes = rng.normal(size=(1500, 3))
    poses = np.array(
        [
            make_transform(
                home[:3, :3] @ axis_angle_transform(axis, np.radians(rng.uniform(0, 40)))[:3, :3],
                home[:3, 3] + rng.uniform(-150, 150, 3),
            )
            for axis in axes
        ]
    )
    values = misfit(poses) + rng.normal(scale=noise_mm, size=(len(poses), 6)) * [1, 1, 1, 0.1, 0.1, 0.1]
    return MisfitField(poses, values[:, :3], values[:, 3:]), home


def _transform_error_misfit(poses):
    """What errors of the two transforms put in the misfit: the TCP position and the tool's
    rotation matrix, linearly."""
    rotation_error = np.array([[0.0, -2e-4, 1e-4], [2e-4, 0.0, -3e-4], [-1e-4, 3e-4, 0.0]])
    offset_in_tool = np.array([0.3, -0.2, 0.5])
    position = poses[:, :3, 3] @ rotation_error.T + poses[:, :3, :3] @ offset_in_tool + [0.1, 0.2, -0.3]
    turn = poses[:, :3, :3] @ np.array([0.02, -0.01, 0.03]) + [0.01, 0.0, -0.01]
    return np.column_stack([position, turn])


def test_a_misfit_the_transforms_put_is_predicted_between_the_recorded_poses(white_simulation):
    from spacecal.geometry.transforms import axis_angle_transform
    from spacecal.workflows.check import expected_misfit

    field, home = _field_around_home(white_simulation.world, _transform_error_misfit)
    pose = home @ make_transform(axis_angle_transform([1, 2, 0], np.radians(12))[:3, :3], [30, -20, 10])
    expected = expected_misfit(field, pose)
    truth = _transform_error_misfit(pose[None])[0]
    # exact but for the small ridge on combinations the poses do not span
    np.testing.assert_allclose(expected.misfit_mm, truth[:3], atol=1e-4)
    np.testing.assert_allclose(expected.misfit_deg, truth[3:], atol=1e-5)
    assert expected.frame_sd_mm < 1e-4 and expected.frames >= 20


def test_the_prediction_and_a_frame_s_scatter_follow_the_noise(white_simulation):
    from spacecal.workflows.check import expected_misfit

    noise = 0.2
    errors, spreads = [], []
    for seed in range(20):
        field, home = _field_around_home(white_simulation.world, _transform_error_misfit, noise, seed)
        expected = expected_misfit(field, home)
        errors.append(
            (expected.misfit_mm - _transform_error_misfit(home[None])[0, :3]) / expected.prediction_sd_mm
        )
        spreads.append(expected.frame_sd_mm)
    # a frame's scatter is the noise's (the worst axis of an estimate: a little above it)
    assert noise < np.median(spreads) < 1.2 * noise
    # the prediction's error over its standard deviation: at most about one per axis
    assert np.sqrt(np.mean(np.square(errors))) < 1.2


def test_a_pose_far_from_the_recorded_motion_is_not_predicted(white_simulation):
    from spacecal.core.errors import DegenerateDataError
    from spacecal.workflows.check import expected_misfit

    field, home = _field_around_home(white_simulation.world, _transform_error_misfit)
    with pytest.raises(DegenerateDataError, match="recorded frames within 100 mm of a check pose"):
        expected_misfit(field, home @ make_transform(np.eye(3), [400.0, 0.0, 0.0]))


def test_only_the_recording_a_calibration_was_made_from_gives_its_misfits(white_simulation):
    import dataclasses

    from spacecal.core.errors import DegenerateDataError
    from spacecal.workflows.check import misfit_field

    recording = white_simulation.recording
    calibration = calibrate(recording, "ml")
    field = misfit_field(calibration, recording)
    assert len(field) == int(recording.visible.sum())
    with pytest.raises(DegenerateDataError, match="no per-sample residuals"):
        misfit_field(calibration.replace(diagnostics={}, assessment=None), recording)
    # the same recording acquired again after the tracker was pushed
    moved = make_transform(np.eye(3), [0.5, 0.0, 0.0]) @ recording.tracker_from_marker_stack
    again = dataclasses.replace(recording, tracker_from_marker_stack=moved)
    with pytest.raises(DegenerateDataError, match="changed since calibrating"):
        misfit_field(calibration, again)
    # a marker turned in the calibration file: positions unchanged, rotations not
    turned = calibration.replace(
        tcp_from_marker=calibration.tcp_from_marker @ axis_angle_transform([0, 0, 1], 0.01)
    )
    with pytest.raises(DegenerateDataError, match="changed since calibrating"):
        misfit_field(turned, recording)


def test_without_its_recording_the_check_falls_back_and_says_why(calibration_file, tmp_path, capsys):
    (tmp_path / "rec.csv").unlink()
    assert main(["check", str(calibration_file), "--poses", "2"]) == 0
    out = capsys.readouterr().out
    assert "sigma of the calibration's expected error" in out and "rec.csv is not there" in out
    history = read_history(calibration_file).checks
    assert np.all(history[-1].expected_misfit_mm == 0.0) and "is not there" in history[-1].basis


def test_a_calibration_from_raw_streams_has_its_misfits_expected(tmp_path, capsys):
    from spacecal import app

    app.simulate(app.SimulateSettings(str(tmp_path / "rec"), "paper-white", raw=True, clock_offset_ms=30.0))
    app.calibrate(
        app.CalibrateSettings(
            str(tmp_path / "rec.robot.csv"),
            str(tmp_path / "cal.json"),
            "ml",
            tracker_stream=str(tmp_path / "rec.tracker.csv"),
        )
    )
    checked = app.check(app.CheckSettings(str(tmp_path / "cal.json"), poses=2)).record
    assert checked.result is not None and checked.result.passed
    assert "departures from the misfit the calibration left" in checked.threshold_basis


def test_a_kinematic_calibration_s_misfits_are_at_its_identified_poses_and_older_files_still_read(
    white_simulation,
):
    from spacecal.estimators.methods.samples import residual_table, sample_residuals
    from spacecal.workflows.check import misfit_field, robot_pose

    recording = white_simulation.recording
    calibration = calibrate(recording, "kinematic")
    assert calibration.robot_model is not None
    field = misfit_field(calibration, recording)
    first = int(np.flatnonzero(recording.visible)[0])
    identified = robot_pose(calibration, recording.base_from_tcp_stack[first], recording.joints_rad[first])
    np.testing.assert_allclose(field.base_from_tcp_stack[0], identified)
    # files written before kinematic stated its residuals at the identified poses
    older = sample_residuals(recording, calibration.tracker_from_base, calibration.tcp_from_marker)
    older_file = with_stored(calibration, per_sample_residuals=residual_table(recording, older))
    assert len(misfit_field(older_file, recording)) == len(field)
