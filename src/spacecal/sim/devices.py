"""Simulated devices behind the interfaces of :mod:`spacecal.devices`."""

from __future__ import annotations

import numpy as np

from ..models.kinematics import forward_kinematics
from .world import World


class SimulatedRobot:
    """The world's robot: moves by its true kinematics, reports by its nominal model.

    Each move lands with fresh repeatability scatter. ``time_s`` advances by a joint-space
    move duration and is quantised to controller ticks, as a real controller's state is.
    """

    def __init__(self, world: World, joints_rad=None):
        self.world = world
        self._joints = np.array(world.home_joints_rad if joints_rad is None else joints_rad, dtype=float)
        self._true_base_from_tcp = world.true_base_from_tcp(self._joints)[0]
        self.time_s = 0.0

    def joint_positions(self) -> np.ndarray:
        return self._joints.copy()

    def reported_base_from_tcp(self) -> np.ndarray:
        return forward_kinematics(self.world.nominal_model, self._joints)

    def true_base_from_tcp(self) -> np.ndarray:
        """Ground truth, for simulated instruments only."""
        return self._true_base_from_tcp.copy()

    def move_joints(self, joints_rad, speed_rad_s: float, accel_rad_s2: float) -> None:
        target = np.asarray(joints_rad, dtype=float)
        distance = float(np.max(np.abs(target - self._joints)))
        duration = distance / speed_rad_s + speed_rad_s / accel_rad_s2 if distance > 0 else 0.0
        tick = 1.0 / self.world.nominal_model.controller_hz
        self.time_s = np.ceil((self.time_s + duration) / tick) * tick
        self._joints = target
        self._true_base_from_tcp = self.world.true_base_from_tcp(target)[0]


class SimulatedLaserTracker:
    """The paper's laser tracker: measures the needle pose exactly, in the tracker frame."""

    def __init__(self, world: World, robot: SimulatedRobot, tcp_from_needle=None):
        self.world = world
        self.robot = robot
        self.tcp_from_needle = np.eye(4) if tcp_from_needle is None else np.asarray(tcp_from_needle)

    def measure_tracker_from_needle(self) -> np.ndarray:
        return self.world.tracker_from_base @ self.robot.true_base_from_tcp() @ self.tcp_from_needle
