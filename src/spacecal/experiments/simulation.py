"""Simulated calibration runs: the plan runs on the simulated devices through the same
acquisition loop as on hardware (:func:`spacecal.workflows.acquisition.run_plan`), in
simulated time, and the recording keeps the ground truth beside it for scoring.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from spacecal.core.errors import DegenerateDataError
from spacecal.core.ports import FRAME_OK, RobotState
from spacecal.planning.motion import MotionPlan
from spacecal.records import RawRecording, Recording
from spacecal.sim.devices import SimClock, SimulatedRobot, SimulatedTracker
from spacecal.sim.motion import motion_limits, plan_for_world, recording_metadata
from spacecal.sim.scenario import Scenario
from spacecal.sim.world import World, build_world
from spacecal.workflows.acquisition import AcquisitionResult, AcquisitionSettings, run_plan


@dataclass
class MemorySink:
    """Keeps acquired samples (and, for raw recordings, the robot's state stream) in memory."""

    keep_spheres: bool = False
    rows: list[tuple] = field(default_factory=list)
    robot_states: list[tuple[RobotState, str]] = field(default_factory=list)

    def append(
        self,
        time_s,
        segment,
        joints_rad,
        base_from_tcp,
        tracker_from_marker=None,
        marker_rms_mm=float("nan"),
        spheres_in_tracker=None,
        robot_time_s=float("nan"),
        status=FRAME_OK,
    ) -> None:
        self.rows.append(
            (
                time_s,
                segment,
                joints_rad,
                base_from_tcp,
                tracker_from_marker,
                marker_rms_mm,
                spheres_in_tracker,
                status,
            )
        )

    def add_robot_states(self, states: list[RobotState], segment: str) -> None:
        """Keep the states newer than the last one kept (the loop may hand one tick twice)."""
        for state in states:
            if not self.robot_states or state.time_s > self.robot_states[-1][0].time_s:
                self.robot_states.append((state, segment))

    def recording(self, metadata: dict, sphere_count: int) -> Recording:
        """The paired recording of every sample kept."""
        if not self.rows:
            raise DegenerateDataError("the plan has no sampled moves")
        times, labels, joints, tcp, marker, rms, spheres, status = zip(*self.rows)
        missing = np.full((4, 4), np.nan)
        no_spheres = np.full((sphere_count, 3), np.nan)
        return Recording(
            time_s=np.array(times),
            segment=np.array(labels),
            joints_rad=np.array(joints),
            base_from_tcp_stack=np.array(tcp),
            tracker_from_marker_stack=np.array([missing if m is None else m for m in marker]),
            marker_rms_mm=np.array(rms, dtype=float),
            metadata=metadata,
            spheres_in_tracker=(
                np.array([no_spheres if s is None else s for s in spheres]) if self.keep_spheres else None
            ),
            marker_status=np.array(status),
        )


@dataclass
class Simulation:
    """A simulated calibration run: the world, the plan, the recording and the truth about it.

    Attributes
    ----------
    world : World
    plan : MotionPlan
    recording : Recording
    outlier_kind : numpy.ndarray of str, shape (N,)
        Per recorded frame: ``""`` or the kind of gross error injected (see the scenario).
    true_tracker_from_marker_stack : numpy.ndarray, shape (N, 4, 4)
        Where the marker really was at each recorded frame, mm.
    """

    world: World
    plan: MotionPlan
    recording: Recording
    outlier_kind: np.ndarray
    true_tracker_from_marker_stack: np.ndarray

    def remeasure(self, trial: int) -> tuple[Recording, np.ndarray]:
        """The same motion recorded again with fresh tracker noise (Monte Carlo).

        The arm's path, with the repeatability scatter drawn during the run, is kept; the
        tracker measures it again through its noise model with a noise stream of its own.
        """
        self.world.noise_rng = np.random.default_rng([self.world.scenario.seed, 1, 1000 + trial])
        frames = self.world.track_marker(self.true_tracker_from_marker_stack)
        rec = self.recording
        spheres = None
        if rec.spheres_in_tracker is not None:
            spheres = frames.spheres_in_tracker.copy()
            spheres[~np.isfinite(frames.rms_mm)] = np.nan
        recording = Recording(
            time_s=rec.time_s,
            segment=rec.segment,
            joints_rad=rec.joints_rad,
            base_from_tcp_stack=rec.base_from_tcp_stack,
            tracker_from_marker_stack=frames.tracker_from_marker,
            marker_rms_mm=frames.rms_mm,
            metadata=rec.metadata,
            spheres_in_tracker=spheres,
        )
        return recording, frames.outlier_kind


def simulation_settings(scenario: Scenario) -> AcquisitionSettings:
    """How the simulated run drives its devices: the scenario's speeds; no start guard,
    since simulated frames are never delivered late."""
    limits = motion_limits(scenario)
    return AcquisitionSettings(
        linear_speed_mm_s=limits.linear_speed_mm_s,
        linear_accel_mm_s2=limits.linear_accel_mm_s2,
        move_start_guard_s=0.0,
    )


def _run(world: World, plan: MotionPlan, stream_states: bool) -> tuple[MemorySink, SimulatedTracker]:
    """Run ``plan`` on the world's simulated robot and tracker (simulated time)."""
    s = world.scenario
    robot = SimulatedRobot(
        world, SimClock(), plan.home_joints_rad, limits=motion_limits(s), stream_states=stream_states
    )
    tracker = SimulatedTracker(world, robot)
    sink = MemorySink(keep_spheres=s.record_spheres)
    progress = AcquisitionResult(None, 0, 0, 0, len(plan.moves))  # type: ignore[arg-type]
    run_plan(plan, robot, tracker, sink, simulation_settings(s), progress)
    return sink, tracker


def execute_plan(world: World, plan: MotionPlan) -> tuple[Recording, np.ndarray]:
    """Run a plan on the simulated devices and record it.

    Returns
    -------
    recording : Recording
    outlier_kind : numpy.ndarray of str, shape (N,)
    """
    simulation = _simulation(world, plan)
    return simulation.recording, simulation.outlier_kind


def _simulation(world: World, plan: MotionPlan) -> Simulation:
    sink, tracker = _run(world, plan, stream_states=False)
    recording = sink.recording(
        {**recording_metadata(world), "plan": plan.summary()}, len(world.marker.spheres_in_marker)
    )
    truth = [tracker.truth[t] for t in recording.time_s]
    return Simulation(
        world,
        plan,
        recording,
        np.array([kind for _, kind in truth], dtype=str),
        np.array([pose for pose, _ in truth]),
    )


def simulate(scenario: Scenario, plan: MotionPlan | None = None) -> Simulation:
    """Simulate the scenario's automatic calibration run (``spacecal simulate``).

    Parameters
    ----------
    scenario : Scenario
    plan : MotionPlan, optional
        The motion to run (``spacecal simulate --plan``); default the paper's sweeps from
        the scenario's home.

    Returns
    -------
    Simulation
        ``.recording`` is what ``spacecal calibrate`` reads; ``.world`` holds the truth.
    """
    world = build_world(scenario)
    return _simulation(world, plan or plan_for_world(world))


def simulate_raw(
    scenario: Scenario, clock_offset_s: float = 0.0, plan: MotionPlan | None = None
) -> tuple[RawRecording, World]:
    """The scenario's run (or ``plan``) recorded as two raw streams on offset clocks.

    The robot stream has every controller state during the recorded moves (125 Hz for a
    UR10), stamped on a clock that runs ``clock_offset_s`` ahead of the tracker's; the
    tracker stream has its frames at its rate (20 Hz), stamped on its own clock.
    """
    world = build_world(scenario)
    plan = plan or plan_for_world(world)
    sink, _ = _run(world, plan, stream_states=True)
    if not sink.rows or not sink.robot_states:
        raise DegenerateDataError("the plan has no sampled moves")
    states = [state for state, _ in sink.robot_states]
    frames = sink.recording({}, len(world.marker.spheres_in_marker))
    raw = RawRecording(
        robot_time_s=np.array([state.time_s for state in states]) + clock_offset_s,
        robot_segment=np.array([label for _, label in sink.robot_states]),
        joints_rad=np.array([state.joints_rad for state in states]),
        base_from_tcp_stack=np.array([state.base_from_tcp for state in states]),
        tracker_time_s=frames.time_s,
        # write_raw_recording keeps no status: only plainly seen poses go into the stream
        tracker_from_marker_stack=np.where(
            frames.visible[:, None, None], frames.tracker_from_marker_stack, np.nan
        ),
        marker_rms_mm=frames.marker_rms_mm,
        metadata={**recording_metadata(world), "simulated_clock_offset_s": clock_offset_s},
    )
    return raw, world
