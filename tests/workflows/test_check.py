"""The calibration check passes a calibration that holds and fails one that no longer does."""

import json

import numpy as np
import pytest

from spacecal.cli import main
from spacecal.estimators import calibrate
from spacecal.geometry.transforms import axis_angle_transform, make_transform
from spacecal.io.results_json import write_calibration
from spacecal.records import Provenance
from spacecal.workflows.check import history_path, read_history


@pytest.fixture
def calibration_file(tmp_path, white_simulation):
    from spacecal.io.recording_csv import write_recording

    recording = write_recording(white_simulation.recording, tmp_path / "rec.csv")
    result = calibrate(white_simulation.recording, "ml")
    result = result.replace(
        provenance=Provenance(
            recording=str(recording), simulated=True, scenario=white_simulation.world.scenario.to_dict()
        )
    )
    return write_calibration(result, tmp_path / "cal.json")


def tamper(path, key, change):
    data = json.loads(path.read_text())
    data[key] = (
        (change @ np.array(data[key])).tolist()
        if key == "tracker_from_base"
        else (np.array(data[key]) @ change).tolist()
    )
    out = path.with_name(f"tampered_{key}.json")
    out.write_text(json.dumps(data))
    return out


def test_good_calibration_passes_and_is_logged(calibration_file, capsys):
    assert main(["check", str(calibration_file)]) == 0
    assert "PASS" in capsys.readouterr().out
    history, _ = read_history(calibration_file)
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


def test_a_missed_frame_on_a_long_running_tracker_is_not_an_error(white_simulation):
    # Real trackers number frames from power-up; one missed frame must not end the check.
    from dataclasses import replace as replace_frame

    from spacecal.core.errors import DegenerateDataError
    from spacecal.core.ports import FRAME_MISSING
    from spacecal.planning.check_poses import check_joints
    from spacecal.sim.devices import SimClock, SimulatedRobot, SimulatedTracker
    from spacecal.workflows.check import check_with_robot

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
    calibration = calibrate(white_simulation.recording, "ml", uncertainty=False)
    robot = SimulatedRobot(world, SimClock())
    result = check_with_robot(
        calibration,
        robot,
        LongRunning(world, robot, hidden_frames=1),
        check_joints(world.nominal_model, world.home_joints_rad, 2),
    )
    assert result.passed
    robot = SimulatedRobot(world, SimClock())
    with pytest.raises(DegenerateDataError, match="not visible"):
        check_with_robot(
            calibration,
            robot,
            LongRunning(world, robot, hidden_frames=10**6),
            check_joints(world.nominal_model, world.home_joints_rad, 2),
        )
