"""The fuzz harness's hang detector (``spacecal.testing.fuzz.time_limit``): a case that computes
for ever is stopped by its CPU time, one that is blocked by the wall clock, and a sound case
that waits longer than its CPU limit on a busy machine is not a hang."""

from __future__ import annotations

import time

import pytest

from spacecal.testing.fuzz import WALL_LIMIT_FACTOR, Hang, time_limit

LIMIT_S = 1.0


def test_a_case_that_computes_for_ever_is_a_hang_by_its_cpu_time():
    started = time.process_time()
    with pytest.raises(Hang), time_limit(LIMIT_S):
        while time.process_time() - started < 60.0:
            pass
    assert time.process_time() - started < 10.0


def test_waiting_longer_than_the_cpu_limit_is_not_a_hang():
    with time_limit(LIMIT_S):
        time.sleep(1.5 * LIMIT_S)


def test_a_blocked_case_is_a_hang_by_the_wall_clock():
    started = time.monotonic()
    with pytest.raises(Hang), time_limit(LIMIT_S):
        time.sleep(60.0)
    assert WALL_LIMIT_FACTOR * LIMIT_S <= time.monotonic() - started + 0.05
