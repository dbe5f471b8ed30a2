"""Plan files run on any devices, and every acquisition keeps both raw streams."""

import json

import numpy as np
import pytest

from spacecal import app
from spacecal.core.errors import InvalidInputError
from spacecal.estimators import calibrate
from spacecal.experiments.truth import calibration_error
from spacecal.io.raw_streams import read_raw_recording
from spacecal.io.recording_csv import read_recording
from spacecal.records import PlanRecord
from spacecal.sim.motion import plan_for_world
from spacecal.sim.scenario import load_scenario
from spacecal.sim.world import build_world


@pytest.fixture(scope="module")
def plan_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("plan") / "plan.json"
    planned = app.plan(app.PlanSettings(budget_s=15.0, scenario="paper-white", output=str(path)))
    record, [written] = planned.record, planned.files_written
    assert written == path and record.runnable
    return path


def test_the_plan_file_holds_every_move_and_reads_back(plan_file):
    data = json.loads(plan_file.read_text())
    assert data["schema_version"] == 2 and data["kind"] == "site-optimal"
    record = PlanRecord.from_dict(data)
    assert len(record.moves) == len(data["moves"]) > 3
    assert sum(m.duration_s for m in record.moves) == pytest.approx(record.motion_time_s)
    holds = [m for m in record.moves if np.allclose(m.start, m.end)]
    assert holds and all(m.label == "station" for m in holds)
    assert json.dumps(PlanRecord.from_dict(record.to_dict()).to_dict()) == json.dumps(record.to_dict())


def test_a_version_1_plan_is_read_but_not_run(plan_file, tmp_path):
    old = {
        "schema": "spacecal.plan",
        "schema_version": 1,
        "budget_s": 30.0,
        "motion_time_s": 29.0,
        "predicted_error_mm": 0.3,
        "paper_sweep": {},
        "home_joints_rad": [0.0] * 6,
        "station_joints_rad": [[0.0] * 6],
        "moves": [{"label": "transit", "duration_s": 1.0}],
    }
    path = tmp_path / "old.json"
    path.write_text(json.dumps(old))
    assert not PlanRecord.from_dict(old).runnable
    with pytest.raises(InvalidInputError, match="older spacecal"):
        app.simulate(app.SimulateSettings(str(tmp_path / "r.csv"), scenario="paper-white", plan=str(path)))


def test_simulate_and_acquire_run_the_same_plan(plan_file, tmp_path):
    app.simulate(app.SimulateSettings(str(tmp_path / "sim.csv"), "paper-white", plan=str(plan_file)))
    acquired = app.acquire(
        app.AcquireSettings(str(tmp_path / "acq.csv"), scenario="paper-white", plan=str(plan_file))
    ).record
    record = PlanRecord.from_dict(json.loads(plan_file.read_text()))
    assert acquired.result is not None and acquired.result.complete
    assert acquired.moves == len(record.moves)
    assert acquired.motion_time_s == pytest.approx(record.motion_time_s)
    sim, acq = read_recording(tmp_path / "sim.csv"), read_recording(tmp_path / "acq.csv")
    assert set(sim.segment) == set(acq.segment) == {"transit", "station"}
    assert abs(len(sim) - len(acq)) <= 0.05 * len(sim)
    # the acquisition's metadata names the plan it ran
    meta = json.loads((tmp_path / "acq.meta.json").read_text())
    assert meta["plan"]["file"] == str(plan_file.resolve())


def test_a_plan_for_another_set_up_or_another_home_is_refused(plan_file, tmp_path):
    data = json.loads(plan_file.read_text())
    data["home_joints_rad"][0] += 0.1
    moved = tmp_path / "moved.json"
    moved.write_text(json.dumps(data))
    with pytest.raises(InvalidInputError, match="another set-up"):
        app.simulate(app.SimulateSettings(str(tmp_path / "r.csv"), "paper-white", plan=str(moved)))
    with pytest.raises(InvalidInputError, match="from the plan's home"):
        app.acquire(app.AcquireSettings(str(tmp_path / "a.csv"), scenario="paper-white", plan=str(moved)))
    data = json.loads(plan_file.read_text())
    data["flange_from_tcp"][2][3] += 5.0
    other_tool = tmp_path / "tool.json"
    other_tool.write_text(json.dumps(data))
    with pytest.raises(InvalidInputError, match="another tool"):
        app.acquire(
            app.AcquireSettings(str(tmp_path / "a.csv"), scenario="paper-white", plan=str(other_tool))
        )
    assert not (tmp_path / "a.csv").exists() and not (tmp_path / "a.robot.csv").exists()


def test_the_paper_sweeps_as_a_plan_file_and_a_site(tmp_path):
    site = (-550.0, -150.0, 320.0)
    planned = app.plan(
        app.PlanSettings(
            scenario="paper-white", paper_sweeps=True, site_mm=site, output=str(tmp_path / "s.json")
        )
    )
    record, [path] = planned.record, planned.files_written
    assert record.kind == "paper-sweeps" and record.site_in_base is not None
    assert np.allclose(record.site_in_base, site)
    assert {m.label for m in record.moves} >= {"rot_x", "rot_y", "rot_z", "lin_x", "lin_y", "lin_z"}
    out = app.simulate(app.SimulateSettings(str(tmp_path / "r.csv"), "paper-white", plan=str(path))).record
    assert out.samples > 300
    with pytest.raises(InvalidInputError, match="--site"):
        app.PlanSettings(site_mm=(float("nan"), 0.0, 0.0))


def test_acquire_writes_both_raw_streams_and_pairs_them(tmp_path):
    out = app.acquire(app.AcquireSettings(str(tmp_path / "rec.csv"), scenario="paper-white")).record
    result = out.result
    assert result is not None and result.raw_paths is not None and result.pairing is not None
    raw = read_raw_recording(*result.raw_paths)
    recording = read_recording(tmp_path / "rec.csv")
    # every controller tick (125 Hz) of the recorded moves, each frame once
    assert np.median(np.diff(raw.robot_time_s)) == pytest.approx(1 / 125, rel=1e-3)
    assert len(raw.tracker_time_s) == result.samples_written
    # a frame at the very edge of a move's robot stream may fall outside it at the estimated offset
    assert result.samples_written - len(recording) <= 6
    assert raw.spheres_in_tracker is not None and raw.arrival_robot_time_s is not None
    # simulated devices share one clock: the estimated offset is (close to) zero
    assert result.pairing.offset_origin == "estimated" and abs(result.pairing.offset_s) < 2e-3
    assert json.loads((tmp_path / "rec.meta.json").read_text())["pairing"]["estimated"] is True
    world = build_world(load_scenario("paper-white"))
    error = calibration_error(calibrate(recording, "ml", uncertainty=False), world)
    assert error["tre_rms_mm"] < 0.1


def test_streams_on_clocks_from_unrelated_epochs_are_linked_by_arrival(tmp_path):
    """A tracker counting from its own power-up (1000 s behind the robot's clock): the arrival
    times link the clocks and the offset estimate resolves the rest."""
    from spacecal.estimators.time_offset import pair_at_estimated_offset

    app.acquire(app.AcquireSettings(str(tmp_path / "rec.csv"), scenario="paper-white"))
    raw = read_raw_recording(tmp_path / "rec.robot.csv", tmp_path / "rec.tracker.csv")
    import dataclasses

    shifted = dataclasses.replace(raw, tracker_time_s=raw.tracker_time_s - 1000.0)
    recording, pairing = pair_at_estimated_offset(shifted)
    assert pairing.estimated and pairing.offset_s == pytest.approx(1000.0, abs=2e-3)
    assert len(raw.tracker_time_s) - len(recording) <= 6


def test_an_existing_raw_stream_is_never_overwritten(tmp_path):
    (tmp_path / "rec.tracker.csv").write_text("keep me\n")
    with pytest.raises(InvalidInputError, match="exists"):
        app.acquire(app.AcquireSettings(str(tmp_path / "rec.csv"), scenario="paper-white"))
    assert (tmp_path / "rec.tracker.csv").read_text() == "keep me\n"


def test_stop_and_go_averages_the_frames_of_each_station(tmp_path):
    out = app.acquire(
        app.AcquireSettings(str(tmp_path / "sg.csv"), scenario="paper-white", stop_and_go=5)
    ).record
    assert out.result is not None and out.result.complete
    recording = read_recording(tmp_path / "sg.csv")
    meta = json.loads((tmp_path / "sg.meta.json").read_text())
    assert meta["sampling"] == {"mode": "stop-and-go", "frames_per_station": 5, "frame_period_s": 0.05}
    # six stations along each recorded move of the sweeps, one averaged sample each
    world = build_world(load_scenario("paper-white"))
    recorded = [m for m in plan_for_world(world).moves if m.sample_period_s > 0]
    assert len(recording) == meta["stations_averaged"] == 6 * len(recorded)
    assert out.result.samples_written >= 5 * len(recording)
    error = calibration_error(calibrate(recording, "ml", uncertainty=False), world)
    assert error["tre_rms_mm"] < 0.15
    with pytest.raises(InvalidInputError, match="--stop-and-go"):
        app.AcquireSettings("x.csv", stop_and_go=2)


def test_a_plan_for_a_needle_path_plans_for_the_needle_at_its_target(tmp_path):
    # a target about 110 mm below the TCP at home, approached from above at a slant
    entry, target = np.array([-560.0, -150.0, 300.0]), np.array([-575.0, -165.0, 230.0])
    record = app.plan(
        app.PlanSettings(budget_s=12.0, scenario="paper-white", needle_path_mm=(*entry, *target))
    ).record
    assert record.site_base_from_tcp is not None and np.allclose(record.site_in_base, target)
    direction = (target - entry) / np.linalg.norm(target - entry)
    assert np.allclose(record.site_base_from_tcp[:3, 2], direction)  # the needle along the path
    stations = [m.end[:3, 3] for m in record.moves if m.label == "station"]
    # the stations are drawn around the target: nearer to it than a plan for home is
    for_home = app.plan(app.PlanSettings(budget_s=12.0, scenario="paper-white")).record
    home_stations = [m.end[:3, 3] for m in for_home.moves if m.label == "station"]
    assert np.linalg.norm(np.mean(stations, axis=0) - target) < np.linalg.norm(
        np.mean(home_stations, axis=0) - target
    )
    with pytest.raises(InvalidInputError, match="not both"):
        app.PlanSettings(site_mm=(0.0, 0.0, 0.0), needle_path_mm=(*entry, *target))
