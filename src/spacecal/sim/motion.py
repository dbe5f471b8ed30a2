"""The motion a scenario asks for, and the metadata its simulated recordings carry."""

from __future__ import annotations

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.planning.motion import MotionLimits, MotionPlan
from spacecal.planning.paper_sweeps import PaperSweepSettings, plan_paper_sweeps
from spacecal.planning.stations import StationSettings, plan_stations
from spacecal.planning.visibility import VisibilityModel
from spacecal.records.calibration import robot_model_to_dict
from spacecal.sim.scenario import Scenario
from spacecal.sim.world import World


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
    """Plan the scenario's motion in a world, predicting visibility from its layout.

    The plan is made with the controller's model, as on real hardware spacecal plans with the
    model the controller publishes (the nominal one where it publishes none)."""
    s = world.scenario
    visibility = VisibilityModel(world.tracker, world.marker, world.tracker_from_base, world.tcp_from_marker)
    if s.motion == "paper":
        return plan_paper_sweeps(world.controller_model, world.home_joints_rad, sweep_settings(s), visibility)
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
            world.controller_model,
            world.home_joints_rad,
            settings,
            visibility,
            np.random.default_rng([s.seed, 3]),
        )
    raise InvalidInputError(f"unknown motion {s.motion!r}; valid: paper, stations")


def recording_metadata(world: World) -> dict:
    """Metadata written next to a recording.

    As the UR adapter records a controller that publishes its factory calibration, a
    calibrated simulated controller's model rides in ``robot.kinematic_model`` (what
    :func:`spacecal.estimators.methods.recorded_model.recorded_robot_model` reads); a nominal one is
    named only (``robot.model``)."""
    s = world.scenario
    calibrated = s.controller_kinematics == "calibrated"
    return {
        "robot": {
            "model": world.controller_model.name,
            "flange_from_tcp": world.controller_model.flange_from_tcp.tolist(),
            "controller_hz": world.controller_model.controller_hz,
            **({"kinematic_model": robot_model_to_dict(world.controller_model)} if calibrated else {}),
            "kinematics_source": (
                "the simulated controller's factory calibration"
                if calibrated
                else f"the nominal {world.nominal_model.name} model"
            ),
        },
        "tracker": {"name": world.tracker.name, "rate_hz": world.tracker.rate_hz},
        "marker": world.marker.to_dict(),
        "units": {"length": "mm", "angle": "rad", "time": "s"},
        "source": "spacecal simulator",
        "simulated": True,
        "scenario": s.to_dict(),
    }


def motion_limits(scenario: Scenario) -> MotionLimits:
    """The TCP limits the simulated robot moves with in a scenario."""
    return sweep_settings(scenario).limits
