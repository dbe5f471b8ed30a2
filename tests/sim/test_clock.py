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
