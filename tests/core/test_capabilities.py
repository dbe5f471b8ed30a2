"""Optional robot capabilities are Protocols (core/ports.py) a workflow checks with isinstance:
what each device has, and a robot with none of them."""

import numpy as np

from spacecal.core.ports import (
    Closable,
    ControlledRobot,
    ModelledRobot,
    Robot,
    RobotState,
    StreamingRobot,
)
from spacecal.sim.devices import SimulatedRobot, SimulatedTracker
from spacecal.sim.scenario import load_scenario
from spacecal.sim.world import build_world


class BareRobot:
    """A Robot and nothing more."""

    def state(self) -> RobotState:
        return RobotState(0.0, np.zeros(6), np.eye(4))

    def move_joints(self, joints_rad, speed_rad_s, accel_rad_s2) -> None:
        pass

    def move_linear(self, base_from_tcp, speed_mm_s, accel_mm_s2, asynchronous=False) -> None:
        pass

    def stop(self) -> None:
        pass


def test_a_bare_robot_has_no_optional_capability():
    robot = BareRobot()
    assert isinstance(robot, Robot)
    for capability in (StreamingRobot, ModelledRobot, ControlledRobot, Closable):
        assert not isinstance(robot, capability), capability.__name__


def test_the_simulated_arm_streams_its_states_and_has_nothing_to_connect_or_close():
    world = build_world(load_scenario("paper-white"))
    robot = SimulatedRobot(world, stream_states=True)
    assert isinstance(robot, Robot) and isinstance(robot, StreamingRobot)
    assert not isinstance(robot, (ModelledRobot, ControlledRobot, Closable))
    assert not isinstance(SimulatedTracker(world, robot), Closable)


def test_the_ur_adapter_declares_every_capability_it_has():
    ur = __import__("pytest").importorskip("spacecal.adapters.ur")
    for capability in (StreamingRobot, ControlledRobot, Closable):
        members = [name for name in vars(capability) if not name.startswith("_")]
        assert all(callable(getattr(ur.URRobot, name, None)) for name in members), capability.__name__
    assert callable(ur.URRobot.controller_model)


def test_no_layer_that_drives_devices_probes_them_by_attribute():
    """What a device can do is a Protocol checked with isinstance; hasattr, or getattr on
    anything but the object's own fields, would bring back probing by name (a device with a
    same-named attribute of another meaning would pass)."""
    import ast
    from pathlib import Path

    import spacecal

    root = Path(spacecal.__file__).parent
    found = []
    for folder in ("app", "workflows", "station"):
        for path in sorted((root / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)):
                    continue
                own = bool(node.args) and isinstance(node.args[0], ast.Name) and node.args[0].id == "self"
                if node.func.id == "hasattr" or (node.func.id == "getattr" and not own):
                    found.append(f"{path.relative_to(root)}:{node.lineno} {node.func.id}")
    assert found == []
