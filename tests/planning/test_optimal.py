"""The site-error planner: it respects its budget, more time buys less predicted error, and a
30 s plan with identification beats the paper's one-minute sweep with the paper's estimator."""

import numpy as np
import pytest

from spacecal.estimators import calibrate
from spacecal.experiments.simulation import execute_plan, plan_for_world
from spacecal.experiments.verification import verify_in_simulation
from spacecal.planning.optimal import PlannerSettings, paper_sweep_site_error, plan_for_site
from spacecal.planning.visibility import VisibilityModel
from spacecal.sim.scenario import PRESETS
from spacecal.sim.world import build_world


@pytest.fixture(scope="module")
def setting():
    world = build_world(PRESETS["paper-realistic"])
    visibility = VisibilityModel(world.tracker, world.marker, world.tracker_from_base, world.tcp_from_marker)
    return world, visibility


def test_budget_is_respected_and_buys_accuracy(setting):
    world, visibility = setting
    short = plan_for_site(
        world.nominal_model,
        world.home_joints_rad,
        visibility,
        np.random.default_rng(0),
        PlannerSettings(budget_s=12.0),
    )
    long = plan_for_site(
        world.nominal_model,
        world.home_joints_rad,
        visibility,
        np.random.default_rng(0),
        PlannerSettings(budget_s=30.0),
    )
    assert short.motion_time_s <= 12.0 and long.motion_time_s <= 30.0
    assert long.predicted_error_mm < short.predicted_error_mm
    assert len(long.station_joints_rad) > len(short.station_joints_rad)
    paper = paper_sweep_site_error(world.nominal_model, plan_for_world(world), visibility)
    assert long.predicted_error_mm < 1.2 * paper  # half the time, about the paper sweep's predicted error


def test_a_30_s_plan_beats_the_paper_sweep_on_verification(setting):
    world, visibility = setting
    scenario = world.scenario
    planned = plan_for_site(world.nominal_model, world.home_joints_rad, visibility, np.random.default_rng(0))
    recording, _ = execute_plan(build_world(scenario), planned.plan)
    ours = verify_in_simulation(calibrate(recording, "kinematic", uncertainty=False), scenario).statistics()
    paper_recording, _ = execute_plan(build_world(scenario), plan_for_world(world))
    paper = verify_in_simulation(
        calibrate(paper_recording, "paper", uncertainty=False), scenario
    ).statistics()
    assert planned.motion_time_s <= 30.0
    assert ours["position_mm"]["mean"] < 0.8 * paper["position_mm"]["mean"]
