"""The simulated robot following a joint trajectory (what a trajectory controller's goal is):
through its points at their times, linearly between them, from where the arm was."""

import numpy as np

from spacecal.sim.devices import SimClock, SimulatedRobot
from spacecal.sim.scenario import load_scenario
from spacecal.sim.world import build_world


def test_a_trajectory_passes_its_points_at_their_times_and_ends_at_the_last():
    world = build_world(load_scenario("paper-white"))
    clock = SimClock()
    robot = SimulatedRobot(world, clock)
    start = robot.state().joints_rad
    points = start + np.array([[0.1, 0, 0, 0, 0, 0], [0.1, -0.2, 0, 0, 0, 0.3]])
    duration = robot.start_trajectory([1.0, 3.0], points)
    assert duration == 3.0 and robot.state().moving
    clock.advance_to(0.5)
    assert np.allclose(robot.state().joints_rad, start + [0.05, 0, 0, 0, 0, 0])
    clock.advance_to(1.0)
    assert np.allclose(robot.state().joints_rad, points[0])
    clock.advance_to(2.0)
    assert np.allclose(robot.state().joints_rad, (points[0] + points[1]) / 2)
    clock.advance_to(3.5)
    state = robot.state()
    assert not state.moving and np.allclose(state.joints_rad, points[1])


def test_a_stop_holds_a_trajectory_where_it_is():
    world = build_world(load_scenario("paper-white"))
    clock = SimClock()
    robot = SimulatedRobot(world, clock)
    start = robot.state().joints_rad
    robot.start_trajectory([2.0], (start + 0.2)[None])
    clock.advance_to(1.0)
    robot.stop()
    clock.advance_to(3.0)
    assert np.allclose(robot.state().joints_rad, start + 0.1)
