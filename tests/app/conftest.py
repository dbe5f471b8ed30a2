"""Fixtures of the app tests: the simulated devices the motion sessions open, kept for the truth."""

import pytest


def keep_simulated_devices(monkeypatch, kept=lambda world, robot: (world, robot)):
    """A list that fills with ``kept(world, robot)`` of every simulated world and robot the
    motion sessions open from now on (their truth), in order."""
    import spacecal.app.motion_session as session

    opened = []
    original = session.simulated_devices

    def keep(scenario, start_s=0.0, speed=None):
        world, robot, tracker = original(scenario, start_s, speed)
        opened.append(kept(world, robot))
        return world, robot, tracker

    monkeypatch.setattr(session, "simulated_devices", keep)
    return opened


@pytest.fixture
def robots(monkeypatch):
    """Every simulated world and robot the sessions open, kept for the truth."""
    return keep_simulated_devices(monkeypatch)
