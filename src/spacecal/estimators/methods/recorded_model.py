"""The robot model a recording's poses come from: the controller's own, or the nominal one it names."""

from __future__ import annotations

import numpy as np

from spacecal.models.kinematics import RobotModel, fit_reported_kinematics
from spacecal.models.robot_kinds import is_robot_kind, robot_kind
from spacecal.records import Recording, robot_model_from_dict


def nominal_robot_model(recording: Recording) -> RobotModel | None:
    """The robot model the recording's poses come from, or None: the controller's own model
    where the metadata carries it (``robot.kinematic_model``, e.g. a factory-calibrated arm),
    else the nominal model named there (with its TCP)."""
    robot = recording.metadata.get("robot", {})
    recorded = recorded_robot_model(recording)
    if recorded is not None:
        return recorded
    name = robot.get("model") if isinstance(robot, dict) else None
    if not is_robot_kind(name):
        return None
    return robot_kind(name).model(np.asarray(robot.get("flange_from_tcp", np.eye(4)), dtype=float))


#: Pairs of joints and reported poses used to identify a controller's model (evenly spread).
IDENTIFY_PAIRS = 80


def recorded_robot_model(recording: Recording) -> RobotModel | None:
    """The kinematic model the robot itself computed its poses with: from the metadata
    (``robot.kinematic_model``), or, where the acquisition could not read it from the
    controller (``robot.identify_kinematics_from_poses``), identified from the recording's
    pairs of joints and reported TCP poses. None when neither applies."""
    robot = recording.metadata.get("robot", {})
    if not isinstance(robot, dict):
        return None
    name = robot.get("model")
    base = robot_kind(name).model() if is_robot_kind(name) else None
    data = robot.get("kinematic_model")
    if isinstance(data, dict):
        return robot_model_from_dict(data, "recording metadata robot.kinematic_model", base)
    if robot.get("identify_kinematics_from_poses") is True and base is not None:
        rows = np.flatnonzero(np.all(np.isfinite(recording.joints_rad), axis=1))
        if len(rows) < 6:
            return None
        rows = rows[np.unique(np.linspace(0, len(rows) - 1, IDENTIFY_PAIRS).astype(int))]
        start = base.with_tcp(np.asarray(robot.get("flange_from_tcp", np.eye(4)), dtype=float))
        model, _ = fit_reported_kinematics(
            start, recording.joints_rad[rows], recording.base_from_tcp_stack[rows]
        )
        return model
    return None
