"""The paper's verification experiment on the simulated system (``spacecal verify``)."""

from __future__ import annotations

import numpy as np

from spacecal.core.ports import Robot, RobotState
from spacecal.estimators.methods.kinematic import joint_compliance_of
from spacecal.geometry.transforms import axis_angle_transform, make_transform
from spacecal.models.compliance import JointCompliance, encoder_joints_for
from spacecal.models.kinematics import RobotModel, forward_kinematics
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


class DeflectionCompensatedRobot:
    """A robot commanded in its joints' true angles: a joint move goes to the encoder angles
    at which gravity deflects the shoulder and elbow onto the commanded ones.

    Inverse kinematics on a calibration's identified model gives the true joint angles that
    put the TCP on a target; a compliant arm commanded to them as encoder angles sags off it.
    This wrapper applies the compliance the calibration identified
    (:func:`~spacecal.models.compliance.encoder_joints_for`). Linear moves, which the
    controller plans with its own model, and the state it reports pass through unchanged.

    Parameters
    ----------
    robot : Robot
        The arm as its controller drives it (encoder angles).
    model : RobotModel
        The identified model the torques are computed with.
    compliance : JointCompliance
        The identified compliance.
    """

    def __init__(self, robot: Robot, model: RobotModel, compliance: JointCompliance):
        self.robot, self.model, self.compliance = robot, model, compliance

    def state(self) -> RobotState:
        """The controller's state (encoder angles)."""
        return self.robot.state()

    def move_joints(self, joints_rad: np.ndarray, speed_rad_s: float, accel_rad_s2: float) -> None:
        """Move until the joints' true angles (6,), rad, are ``joints_rad``."""
        encoder = encoder_joints_for(self.model, self.compliance, joints_rad)[0]
        self.robot.move_joints(encoder, speed_rad_s, accel_rad_s2)

    def move_linear(
        self, base_from_tcp: np.ndarray, speed_mm_s: float, accel_mm_s2: float, asynchronous: bool = False
    ) -> None:
        """The controller's straight-line move (its own model), unchanged."""
        self.robot.move_linear(base_from_tcp, speed_mm_s, accel_mm_s2, asynchronous)

    def stop(self) -> None:
        """Stop the arm."""
        self.robot.stop()


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
    # and the joints it solves for are the compliant arm's true angles when the calibration
    # identified its compliance: the robot is commanded the encoder angles that sag onto them
    compliance = joint_compliance_of(calibration)
    commanded: Robot = robot if compliance is None else DeflectionCompensatedRobot(robot, model, compliance)
    if tcp_from_needle is None:
        tcp_from_needle = calibration.tcp_from_needle
    return run_verification(
        calibration, commanded, laser, model, targets, world.home_joints_rad, tcp_from_needle=tcp_from_needle
    )
