"""The simulated devices' clocks: simulated time, and wall-clock time sped up or not."""

from __future__ import annotations

import time

import pytest

from spacecal.sim.devices import RealClock, SimClock


def test_simulated_time_only_moves_forward():
    clock = SimClock(5.0)
    clock.advance_to(7.0)
    clock.advance_to(6.0)
    assert clock.now_s == 7.0


@pytest.mark.parametrize("speed", [1.0, 4.0])
def test_a_real_clock_waits_its_simulated_time_divided_by_its_speed(speed):
    clock = RealClock(start_s=100.0, speed=speed)
    assert 100.0 <= clock.now_s < 100.1 * speed
    started = time.monotonic()
    clock.advance_to(100.0 + 0.4 * speed)
    waited = time.monotonic() - started
    assert waited >= 0.39  # sleep never returns early; the clock may have run before the call
    assert clock.now_s >= 100.0 + 0.4 * speed


def test_a_clock_that_does_not_run_is_refused():
    with pytest.raises(ValueError, match="positive"):
        RealClock(speed=0.0)


class _LateClock(RealClock):
    """A real-time clock on a busy machine: every wait ends 20 ms late."""

    def advance_to(self, time_s: float) -> None:
        super().advance_to(time_s)
        time.sleep(0.020)


def test_a_late_frame_shows_the_marker_where_it_was_at_its_time_stamp():
    import numpy as np

    from spacecal.sim.devices import SimulatedRobot, SimulatedTracker
    from spacecal.sim.scenario import load_scenario
    from spacecal.sim.world import build_world

    world = build_world(load_scenario("paper-white"))
    robot = SimulatedRobot(world, _LateClock())
    tracker = SimulatedTracker(world, robot)
    start = robot.state().base_from_tcp
    target = start.copy()
    target[:3, 3] += [80.0, 0.0, 0.0]
    robot.move_linear(target, 100.0, 500.0, asynchronous=True)
    lateness = []
    for _ in range(8):
        frame = tracker.next_frame(1.0)
        truth, _ = tracker.truth[frame.time_s]
        joints = robot._joints_at(robot._motion, np.array([frame.time_s]))[-1]
        expected = world.tracker_from_base @ world.true_base_from_tcp(joints)[0] @ world.tcp_from_marker
        # the marker moves at up to 100 mm/s: 20 ms late would put it 2 mm off its time stamp
        assert np.linalg.norm(truth[:3, 3] - expected[:3, 3]) < 0.05
        lateness.append(frame.time_s - frame.frame_number * tracker.period_s)
    assert min(lateness) >= 0.019  # the frames were late, and stamped when they were taken
