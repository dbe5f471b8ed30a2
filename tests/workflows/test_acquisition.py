"""Acquisition on simulated devices: the complete run, every fault, resume, and refusals."""

import dataclasses
import json

import numpy as np
import pytest

from spacecal.core.errors import DeviceError, InvalidInputError
from spacecal.core.ports import Robot, Tracker
from spacecal.estimators import calibrate
from spacecal.experiments.truth import calibration_error
from spacecal.io.acquisition_progress import progress_path
from spacecal.io.raw_streams import read_raw_recording
from spacecal.io.recording_csv import read_recording
from spacecal.sim.devices import SimClock, SimulatedRobot, SimulatedTracker
from spacecal.sim.motion import plan_for_world, recording_metadata
from spacecal.sim.scenario import PRESETS
from spacecal.sim.world import build_world
from spacecal.workflows.acquisition import AcquisitionStopped, SampleGrid, acquire


def setup(**robot_options):
    world = build_world(PRESETS["paper-white"])
    robot = SimulatedRobot(world, SimClock(), **robot_options)
    return world, plan_for_world(world), robot


def test_simulated_devices_implement_the_interfaces():
    world, _, robot = setup()
    assert isinstance(robot, Robot) and isinstance(SimulatedTracker(world, robot), Tracker)


def test_complete_run_records_the_paper_sweeps_and_calibrates(tmp_path):
    world, plan, robot = setup()
    path = tmp_path / "rec.csv"
    seen = []
    result = acquire(
        plan,
        robot,
        SimulatedTracker(world, robot),
        path,
        recording_metadata(world),
        on_sample=lambda n, v, i, label: seen.append(label),
    )
    assert result.complete and result.samples_written == len(seen)
    recording = read_recording(path)
    assert set(recording.segment) == {"rot_x", "rot_y", "rot_z", "lin_x", "lin_y", "lin_z"}
    assert abs(robot.clock.now_s - plan.motion_time_s) < 1.0  # the run took the planned time
    # rotation sweeps sampled every 100 ms, translations every 50 ms (paper §4)
    rot = np.diff(recording.time_s[recording.segment == "rot_y"])
    lin = np.diff(recording.time_s[recording.segment == "lin_y"])
    assert np.median(rot) == pytest.approx(0.1) and np.median(lin) == pytest.approx(0.05)
    assert calibration_error(calibrate(recording, "paper", uncertainty=False), world)["tre_rms_mm"] < 0.1
    assert json.loads(progress_path(path).read_text())["moves_completed"] == len(plan.moves)


class Jittering(SimulatedTracker):
    """A tracker that stamps each frame when it takes it, 0-5 ms after its nominal instant,
    as a streamed OpenIGTLink sender does."""

    def __init__(self, world, robot):
        super().__init__(world, robot)
        self.rng = np.random.default_rng(1)

    def next_frame(self, timeout_s):
        frame = super().next_frame(timeout_s)
        return dataclasses.replace(frame, time_s=frame.time_s + self.rng.uniform(0.0, 0.005))


def test_jittering_timestamps_keep_every_sample_period(tmp_path):
    counts = {}
    for name, tracker in (("regular", SimulatedTracker), ("jittering", Jittering)):
        world, plan, robot = setup()
        path = tmp_path / f"{name}.csv"
        acquire(plan, robot, tracker(world, robot), path, recording_metadata(world))
        recording = read_recording(path)
        labels, counts[name] = np.unique(recording.segment, return_counts=True)
        for label, period in (("rot_y", 0.1), ("lin_y", 0.05)):
            gaps = np.diff(recording.time_s[recording.segment == label])
            assert np.median(gaps) == pytest.approx(period, abs=0.005)
    # a stamp a little less than a period after the last recorded one still counts for its
    # period: a translation sweep at the tracker's rate keeps every frame
    assert np.all(np.abs(counts["jittering"] - counts["regular"]) <= 1), counts


def test_sample_grid_records_one_frame_per_period():
    rng = np.random.default_rng(2)
    frames = np.arange(400) * 0.05 + rng.uniform(0.0, 0.01, 400)  # 20 Hz, stamped up to 10 ms late
    for period, expected in ((0.05, 400), (0.1, 200), (0.07, 286)):
        grid = SampleGrid(period)
        taken = frames[[grid.take(t) for t in frames]]
        assert abs(len(taken) - expected) <= 1 and np.diff(taken).min() > 0.6 * min(period, 0.05)
    assert not any(SampleGrid(0.0).take(t) for t in frames)  # a transit records nothing


class Interrupting(SimulatedTracker):
    """A tracker during which the user presses Ctrl-C after some frames."""

    def __init__(self, *args, after: int):
        super().__init__(*args)
        self.after = after

    def next_frame(self, timeout_s):
        if self._delivered >= self.after:
            raise KeyboardInterrupt
        return super().next_frame(timeout_s)


class FrozenRobot(SimulatedRobot):
    """A controller whose state stream stops updating (stale timestamps) after a while."""

    def state(self):
        state = super().state()
        if self.clock.now_s > 15.0:
            from dataclasses import replace

            return replace(state, time_s=15.0)
        return state


FAULTS = {
    "protective stop": (
        lambda w, r: (r, SimulatedTracker(w, r)),
        {"protective_stop_at_s": 20.0},
        "robot protective stop",
    ),
    "tracker unplugged": (
        lambda w, r: (r, SimulatedTracker(w, r, unplug_after_frames=150)),
        {},
        "tracker lost",
    ),
    "Ctrl-C": (lambda w, r: (r, Interrupting(w, r, after=120)), {}, "interrupted by the user"),
}


@pytest.mark.parametrize("fault", sorted(FAULTS))
def test_faults_stop_the_robot_keep_the_data_and_resume(fault, tmp_path):
    make, robot_options, message = FAULTS[fault]
    world, plan, robot = setup(**robot_options)
    robot, tracker = make(world, robot)
    path = tmp_path / "rec.csv"
    with pytest.raises(AcquisitionStopped, match=message) as stopped:
        acquire(plan, robot, tracker, path, recording_metadata(world))
    assert robot.commands[-1] == "stop"
    kept = read_recording(path)
    written = stopped.value.result.samples_written
    # every frame is in the raw tracker stream; pairing may drop a frame at either end of the
    # robot's stream (this simulated robot keeps no stream: its states come at the frames)
    assert len(read_raw_recording(*stopped.value.result.raw_paths).tracker_time_s) == written > 50
    assert written - 2 <= len(kept) <= written
    assert "resume with --resume" in str(stopped.value)
    progress = json.loads(progress_path(path).read_text())
    assert (
        0 < progress["moves_completed"] < len(plan.moves)
        and message.split()[0] in progress["stopped_because"]
    )
    # clear the fault and resume: the plan completes and earlier samples are still there
    robot.protective_stop_at_s, robot._safety = None, "normal"
    result = acquire(
        plan, robot, SimulatedTracker(world, robot), path, recording_metadata(world), resume=True
    )
    assert result.complete
    resumed = read_recording(path)
    assert len(resumed) > len(kept) and np.isin(kept.time_s, resumed.time_s).all()
    assert set(resumed.segment) == {"rot_x", "rot_y", "rot_z", "lin_x", "lin_y", "lin_z"}


def test_stale_robot_stream_is_a_fault(tmp_path):
    world = build_world(PRESETS["paper-white"])
    robot = FrozenRobot(world, SimClock())
    with pytest.raises(AcquisitionStopped, match="robot data stale"):
        acquire(
            plan_for_world(world),
            robot,
            SimulatedTracker(world, robot),
            tmp_path / "r.csv",
            recording_metadata(world),
        )
    assert robot.commands[-1] == "stop" and len(read_recording(tmp_path / "r.csv")) > 50


def test_refusals(tmp_path):
    world, plan, robot = setup()
    path = tmp_path / "rec.csv"
    path.write_text("precious data\n")
    with pytest.raises(InvalidInputError, match="exists"):
        acquire(plan, robot, SimulatedTracker(world, robot), path, {})
    assert path.read_text() == "precious data\n"
    with pytest.raises(InvalidInputError, match="nothing to resume"):
        acquire(plan, robot, SimulatedTracker(world, robot), tmp_path / "other.csv", {}, resume=True)


def test_resume_refuses_another_plan(tmp_path):
    world, plan, robot = setup(protective_stop_at_s=5.0)
    path = tmp_path / "rec.csv"
    with pytest.raises(AcquisitionStopped):
        acquire(plan, robot, SimulatedTracker(world, robot), path, recording_metadata(world))
    plan.moves = plan.moves[:-1]
    with pytest.raises(InvalidInputError, match="different plan"):
        acquire(plan, robot, SimulatedTracker(world, robot), path, recording_metadata(world), resume=True)


def test_a_stopped_robot_refuses_new_motion():
    world, _, robot = setup(protective_stop_at_s=0.0)
    with pytest.raises(DeviceError, match="protective stop"):
        robot.move_joints(world.home_joints_rad, 1.0, 1.0)


def test_a_loop_held_up_past_a_deadline_does_not_fail_a_move_that_finished(tmp_path):
    """The loop is held up once, mid-move, for longer than the move's deadline (a slow disk's
    fsync, a busy computer): the robot has meanwhile arrived, so the move is done and the run
    goes on. Only a robot still moving past the deadline fails it (the test below)."""
    world, plan, robot = setup()
    first = plan.moves[0]
    held_up_s = 1.5 * first.duration_s + 2.0 + 1.0  # past the deadline, with a second to spare

    class HeldUpOnce(SimulatedTracker):
        frames = 0

        def next_frame(self, timeout_s):
            self.frames += 1
            if self.frames == 3:  # a few frames into the first move
                robot.clock.advance_to(robot.clock.now_s + held_up_s)
            return super().next_frame(timeout_s)

    path = tmp_path / "rec.csv"
    result = acquire(plan, robot, HeldUpOnce(world, robot), path, recording_metadata(world))
    assert result.moves_completed == len(plan.moves)


def test_a_move_that_never_finishes_ends_the_run_at_its_deadline(tmp_path):
    """A controller that keeps reporting "moving" (the run that stood still for five minutes)
    ends the run with the move named, the robot stopped and the samples kept."""
    world, plan, robot = setup()

    class NeverArrives(SimulatedRobot):
        def state(self):
            return dataclasses.replace(super().state(), moving=True)

    stuck = NeverArrives(world, robot.clock)
    path = tmp_path / "rec.csv"
    started = stuck.clock.now_s
    with pytest.raises(
        AcquisitionStopped, match=r"move 1/\d+ \(\w+\) did not finish within its deadline"
    ) as stop:
        acquire(plan, stuck, SimulatedTracker(world, stuck), path, recording_metadata(world))
    first = plan.moves[0]
    assert stuck.clock.now_s - started <= 1.5 * first.duration_s + 2.0 + 0.2  # one frame past the deadline
    assert stuck.commands[-1] == "stop" and stop.value.result.moves_completed == 0
    assert progress_path(path).is_file()
