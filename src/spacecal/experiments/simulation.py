"""Run the paper's calibration motion in the simulated world and record what the devices report."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spacecal.core.errors import DegenerateDataError, InvalidInputError
from spacecal.models.kinematics import forward_kinematics
from spacecal.planning.motion import MotionLimits, track_path
from spacecal.planning.paper_sweeps import MotionPlan, PaperSweepSettings, plan_paper_sweeps
from spacecal.planning.stations import StationSettings, plan_stations
from spacecal.planning.visibility import VisibilityModel
from spacecal.records import Recording
from spacecal.sim.scenario import Scenario
from spacecal.sim.world import World, build_world


@dataclass
class Simulation:
    """A simulated calibration run: the world, the plan, the recording and the truth about it.

    Attributes
    ----------
    outlier_kind : numpy.ndarray of str, shape (N,)
        Per recorded frame: ``""`` or the kind of gross error injected (see the scenario).
    """

    world: World
    plan: MotionPlan
    recording: Recording
    outlier_kind: np.ndarray
    trajectory: Trajectory

    def remeasure(self, trial: int) -> tuple[Recording, np.ndarray]:
        """The same motion in the same world, recorded again with fresh noise (Monte Carlo)."""
        self.world.noise_rng = np.random.default_rng([self.world.scenario.seed, 1, 1000 + trial])
        recording, outlier_kind = measure_trajectory(self.world, self.trajectory)
        recording.metadata["plan"] = self.plan.summary()
        return recording, outlier_kind


def sweep_settings(scenario: Scenario) -> PaperSweepSettings:
    """The paper sweep settings a scenario asks for."""
    return PaperSweepSettings(
        rotation_each_way_deg=scenario.rotation_deg,
        translation_stroke_mm=scenario.translation_mm,
        rotation_sample_period_s=scenario.rotation_sample_period_s,
        translation_sample_period_s=scenario.translation_sample_period_s,
        limits=MotionLimits(
            linear_speed_mm_s=scenario.linear_speed_mm_s,
            angular_speed_rad_s=np.radians(scenario.angular_speed_deg_s),
        ),
    )


def plan_for_world(world: World) -> MotionPlan:
    """Plan the scenario's motion in a world, predicting visibility from its layout."""
    s = world.scenario
    visibility = VisibilityModel(world.tracker, world.marker, world.tracker_from_base, world.tcp_from_marker)
    if s.motion == "paper":
        return plan_paper_sweeps(world.nominal_model, world.home_joints_rad, sweep_settings(s), visibility)
    if s.motion == "stations":
        settings = StationSettings(
            count=s.stations,
            frames_per_station=s.frames_per_station,
            cube_mm=s.station_cube_mm,
            tilt_deg=s.station_tilt_deg,
            frame_period_s=1.0 / s.tracker_rate_hz,
            limits=sweep_settings(s).limits,
        )
        return plan_stations(
            world.nominal_model,
            world.home_joints_rad,
            settings,
            visibility,
            np.random.default_rng([s.seed, 3]),
        )
    raise InvalidInputError(f"unknown motion {s.motion!r}; valid: paper, stations")


def recording_metadata(world: World) -> dict:
    """Metadata written next to a recording (the estimator does not need it)."""
    s = world.scenario
    return {
        "robot": {
            "model": world.nominal_model.name,
            "flange_from_tcp": world.nominal_model.flange_from_tcp.tolist(),
            "controller_hz": world.nominal_model.controller_hz,
        },
        "tracker": {"name": world.tracker.name, "rate_hz": world.tracker.rate_hz},
        "marker": world.marker.to_dict(),
        "units": {"length": "mm", "angle": "rad", "time": "s"},
        "source": "spacecal simulator",
        "scenario": s.to_dict(),
    }


@dataclass
class Trajectory:
    """The sampled motion of a plan: what the robot does, before anything is measured.

    Attributes
    ----------
    time_s : numpy.ndarray, shape (N,)
    segment : numpy.ndarray of str, shape (N,)
    joints_rad : numpy.ndarray, shape (N, 6)
    """

    time_s: np.ndarray
    segment: np.ndarray
    joints_rad: np.ndarray


def sample_plan(world: World, plan: MotionPlan) -> Trajectory:
    """Joint angles at every tracker sample of a plan.

    The controller follows each Cartesian move with its nominal model (continuous IK).
    """
    times, labels, joints = [], [], []
    clock = 0.0
    q = plan.home_joints_rad
    for move in plan.moves:
        if move.sample_period_s > 0:
            t_local = np.arange(0.0, move.duration_s, move.sample_period_s)
            q_move = track_path(world.nominal_model, move.poses_at(t_local), q)
            times.append(clock + t_local)
            labels.extend([move.label] * len(t_local))
            joints.append(q_move)
            q = q_move[-1]
        q = track_path(world.nominal_model, move.end[None], q)[0]
        clock += move.duration_s
    if not joints:
        raise DegenerateDataError("the plan has no sampled moves")
    return Trajectory(np.concatenate(times), np.array(labels), np.concatenate(joints))


def measure_trajectory(world: World, trajectory: Trajectory) -> tuple[Recording, np.ndarray]:
    """Record a trajectory: the arm moves by its true kinematics with repeatability scatter,
    the tracker sees the true marker pose through its noise model, and robot states are
    paired with tracker frames at the frame times. Draws from ``world.noise_rng``.

    Returns
    -------
    recording : Recording
    outlier_kind : numpy.ndarray of str, shape (N,)
    """
    reported = forward_kinematics(world.nominal_model, trajectory.joints_rad)
    true_tcp = world.true_base_from_tcp(trajectory.joints_rad)
    frames = world.track_marker(world.tracker_from_base @ true_tcp @ world.tcp_from_marker)
    spheres = None
    if world.scenario.record_spheres:
        spheres = frames.spheres_in_tracker.copy()
        spheres[~np.isfinite(frames.rms_mm)] = np.nan
    recording = Recording(
        time_s=trajectory.time_s,
        segment=trajectory.segment,
        joints_rad=trajectory.joints_rad,
        base_from_tcp_stack=reported,
        tracker_from_marker_stack=frames.tracker_from_marker,
        marker_rms_mm=frames.rms_mm,
        metadata=recording_metadata(world),
        spheres_in_tracker=spheres,
    )
    return recording, frames.outlier_kind


def execute_plan(world: World, plan: MotionPlan) -> tuple[Recording, np.ndarray]:
    """Move the simulated robot through a plan and record it (see :func:`measure_trajectory`)."""
    return measure_trajectory(world, sample_plan(world, plan))


def simulate(scenario: Scenario) -> Simulation:
    """Simulate the paper's automatic calibration run (``spacecal simulate``).

    Parameters
    ----------
    scenario : Scenario

    Returns
    -------
    Simulation
        ``.recording`` is what ``spacecal calibrate`` reads; ``.world`` holds the truth.
    """
    world = build_world(scenario)
    plan = plan_for_world(world)
    trajectory = sample_plan(world, plan)
    recording, outlier_kind = measure_trajectory(world, trajectory)
    recording.metadata["plan"] = plan.summary()
    return Simulation(world, plan, recording, outlier_kind, trajectory)


def simulate_raw(scenario: Scenario, clock_offset_s: float = 0.0):
    """The paper's sweeps recorded as two raw streams on offset clocks.

    The robot stream has the controller's states at its rate (125 Hz for a UR10), stamped on
    a clock that runs ``clock_offset_s`` ahead of the tracker's; the tracker stream has its
    frames at its rate (20 Hz), stamped on its own clock.

    Returns
    -------
    RawRecording, World
    """
    from spacecal.records import RawRecording

    world = build_world(scenario)
    plan = plan_for_world(world)
    robot_times, robot_labels, robot_joints = [], [], []
    tracker_times, tracker_joints = [], []
    clock, q = 0.0, plan.home_joints_rad
    tick = 1.0 / world.nominal_model.controller_hz
    frame = 1.0 / world.tracker.rate_hz
    for move in plan.moves:
        if move.sample_period_s > 0:
            # both devices sample on their own grids of the common (true) time
            t_robot = np.arange(np.ceil(clock / tick) * tick, clock + move.duration_s, tick) - clock
            t_frames = np.arange(np.ceil(clock / frame) * frame, clock + move.duration_s, frame) - clock
            q_robot = track_path(world.nominal_model, move.poses_at(t_robot), q)
            q_frames = track_path(world.nominal_model, move.poses_at(t_frames), q)
            robot_times.append(clock + t_robot)
            robot_labels.extend([move.label] * len(t_robot))
            robot_joints.append(q_robot)
            tracker_times.append(clock + t_frames)
            tracker_joints.append(q_frames)
            q = q_robot[-1]
        q = track_path(world.nominal_model, move.end[None], q)[0]
        clock += move.duration_s
    robot_joints = np.concatenate(robot_joints)
    tracker_joints = np.concatenate(tracker_joints)
    true_tcp = world.true_base_from_tcp(tracker_joints)
    frames = world.track_marker(world.tracker_from_base @ true_tcp @ world.tcp_from_marker)
    raw = RawRecording(
        robot_time_s=np.concatenate(robot_times) + clock_offset_s,
        robot_segment=np.array(robot_labels),
        joints_rad=robot_joints,
        base_from_tcp_stack=forward_kinematics(world.nominal_model, robot_joints),
        tracker_time_s=np.concatenate(tracker_times),
        tracker_from_marker_stack=frames.tracker_from_marker,
        marker_rms_mm=frames.rms_mm,
        metadata={**recording_metadata(world), "simulated_clock_offset_s": clock_offset_s},
    )
    return raw, world
