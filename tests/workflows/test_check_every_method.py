"""``spacecal check`` on the simulated devices, for every registry method: it expects at each pose
the misfit the calibration left there, so an untouched set-up passes while a tracker moved by
2 mm and a marker turned on the tool by 1 degree fail; with the controller reporting through its
factory calibration (paper-realistic), through the catalogue model (1-2 mm of kinematic error at
the flange), and with a pose-only tracker (no fit RMS: the estimators do not know its noise)."""

import contextlib

import numpy as np
import pytest

from spacecal import app
from spacecal.estimators import ESTIMATORS, calibrate
from spacecal.experiments.simulation import simulate
from spacecal.geometry.transforms import axis_angle_transform, make_transform
from spacecal.io.recording_csv import write_recording
from spacecal.io.results_json import write_calibration
from spacecal.records import Provenance, RecordingSource
from spacecal.sim.scenario import PRESETS

CASES = ("paper-realistic", "paper-realistic-nominal", "pose-only")


@pytest.fixture(scope="module")
def recordings(realistic_simulation, tmp_path_factory):
    """Per case: the recording on disk and the scenario of its devices."""
    folder = tmp_path_factory.mktemp("every-method")
    nominal = simulate(PRESETS["paper-realistic-nominal"])
    cases = {
        "paper-realistic": (realistic_simulation.recording, realistic_simulation.world.scenario),
        "paper-realistic-nominal": (nominal.recording, nominal.world.scenario),
        "pose-only": (realistic_simulation.recording.as_pose_only(), realistic_simulation.world.scenario),
    }
    return {
        case: (recording, write_recording(recording, folder / f"{case}.csv"), scenario)
        for case, (recording, scenario) in cases.items()
    }


def calibration_file(recordings, case, method):
    recording, path, scenario = recordings[case]
    result = calibrate(recording, method).replace(
        provenance=Provenance(
            source=RecordingSource.paired_csv(str(path)), simulated=True, scenario=scenario.to_dict()
        )
    )
    return write_calibration(result, path.with_name(f"{case}-{method}.json"))


@contextlib.contextmanager
def set_up(monkeypatch, move_mm=0.0, turn_deg=0.0, seed=5):
    """The simulated devices of the check, with the tracker moved along its x axis by ``move_mm``
    or the marker turned on the tool by ``turn_deg`` about its x axis (as the protocol fakes do),
    and noise drawn afresh (not the draws the recording began with)."""
    from spacecal.app import motion_session as acquisition

    opened = acquisition.simulated_devices

    def changed(scenario, start_s=0.0, speed=None):
        world, robot, tracker = opened(scenario, start_s, speed)
        world.noise_rng = np.random.default_rng([seed, 11])
        world.tracker_from_base = make_transform(np.eye(3), [move_mm, 0.0, 0.0]) @ world.tracker_from_base
        world.tcp_from_marker = world.tcp_from_marker @ axis_angle_transform([1, 0, 0], np.radians(turn_deg))
        return world, robot, tracker

    with monkeypatch.context() as patch:
        patch.setattr(acquisition, "simulated_devices", changed)
        yield


@pytest.mark.parametrize("method", sorted(ESTIMATORS))
@pytest.mark.parametrize("case", CASES)
def test_a_sound_set_up_passes_and_a_moved_tracker_or_a_bumped_marker_fails(
    recordings, monkeypatch, case, method
):
    path = str(calibration_file(recordings, case, method))
    with set_up(monkeypatch):
        sound = app.check(app.CheckSettings(path)).record
    result = sound.result
    assert result is not None and result.expected_misfit_mm is not None
    assert "departures from the misfit the calibration left" in sound.threshold_basis
    assert result.passed, (result.tcp_error_mm, result.tolerance_mm, result.rotation_error_deg)
    with set_up(monkeypatch, move_mm=2.0):
        moved = app.check(app.CheckSettings(path, poses=2)).record.result
    with set_up(monkeypatch, turn_deg=1.0):
        bumped = app.check(app.CheckSettings(path, poses=2)).record.result
    assert moved is not None and not moved.passed and np.all(moved.tcp_error_mm > moved.tolerance_mm)
    assert (
        bumped is not None and not bumped.passed and np.all(bumped.rotation_error_deg > bumped.tolerance_deg)
    )
