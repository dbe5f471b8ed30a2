"""The paper's verification experiment on the simulated system (``spacecal verify``)."""

from __future__ import annotations

import numpy as np

from spacecal.geometry.transforms import axis_angle_transform, make_transform
from spacecal.models.kinematics import forward_kinematics
from spacecal.records import CalibrationResult
from spacecal.sim.devices import SimulatedLaserTracker, SimulatedRobot
from spacecal.sim.scenario import Scenario
from spacecal.sim.world import World, build_world
from spacecal.workflows.verification import VerificationResult, run_verification


def verification_targets(world: World, count: int, rng: np.random.Generator) -> np.ndarray:
    """Needle target poses (count, 4, 4) in the tracker frame around the surgical site.

    Positions are uniform in a cube of side ``target_cube_mm`` centred on the site;
    orientations tilt the home needle orientation by up to ``target_tilt_deg`` about a
    random horizontal-ish axis.
    """
    s = world.scenario
    home = forward_kinematics(world.nominal_model, world.home_joints_rad)
    targets = []
    for _ in range(count):
        offset = rng.uniform(-0.5, 0.5, 3) * s.target_cube_mm
        axis = rng.normal(size=3)
        tilt = np.radians(rng.uniform(0, s.target_tilt_deg))
        orientation = home[:3, :3] @ axis_angle_transform(axis, tilt)[:3, :3]
        base_from_needle = make_transform(orientation, world.site_in_base + offset)
        targets.append(world.tracker_from_base @ base_from_needle)
    return np.array(targets)


def verify_in_simulation(
    calibration: CalibrationResult,
    scenario: Scenario,
    count: int | None = None,
    seed: int = 0,
    tcp_from_needle=None,
) -> VerificationResult:
    """Run the verification experiment (paper §5.2) in the world of ``scenario``.

    Parameters
    ----------
    calibration : CalibrationResult
        The calibration to test (its ``tracker_from_base``).
    scenario : Scenario
        Must be the scenario the calibration's recording was simulated from.
    count : int, optional
        Number of needle poses; the scenario's ``verification_targets`` (15) if omitted.
    seed : int
        Seeds the target poses.
    tcp_from_needle : array_like, shape (4, 4), optional
        Where IK puts the needle tip in the TCP frame; when omitted, the calibration's measured
        tip (:attr:`CalibrationResult.tcp_from_needle`) if it has one, else the controller's
        TCP. The reference always measures the true tip.
    """
    world = build_world(scenario)
    count = scenario.verification_targets if count is None else count
    targets = verification_targets(world, count, np.random.default_rng([scenario.seed, 2, seed]))
    robot = SimulatedRobot(world)
    laser = SimulatedLaserTracker(world, robot)
    # IK with the identified kinematic model when the calibration carries one, else with the
    # controller's own (nominal or factory-calibrated), as spacecal does on real hardware
    model = calibration.robot_model_for_ik(world.controller_model)
    if tcp_from_needle is None:
        tcp_from_needle = calibration.tcp_from_needle
    return run_verification(
        calibration, robot, laser, model, targets, world.home_joints_rad, tcp_from_needle=tcp_from_needle
    )
