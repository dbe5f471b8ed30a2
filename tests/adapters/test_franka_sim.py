"""The ``franka://`` adapter through real pylibfranka against the Franka protocol simulator
(``franka-sim``, see :mod:`tests.adapters.franka_sim`): state, joint and straight-line moves,
a stop mid-move, a robot that vanishes mid-move, and a reflex refused before any motion.

The simulator's position servo tracks a finished minimum-jerk path to about 1e-4 rad (measured);
the bounds below are the adapter's own arrival tolerance and the CLI's stop times."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

pytest.importorskip("pylibfranka")

from spacecal.adapters import DeviceOptions, franka, open_device
from spacecal.adapters.franka import ARRIVAL_RAD, SETTLE_S, WALL_DEADLINE_FACTOR, FrankaRobot
from spacecal.adapters.franka_motion import path_duration
from spacecal.core.errors import DeviceError, InvalidInputError
from spacecal.core.ports import (
    SAFETY_NORMAL,
    Closable,
    ControlledRobot,
    Identified,
    ModelledRobot,
    Preflight,
    Robot,
    plausible_tracked_pose,
)
from spacecal.geometry.rotations import rotation_angle
from spacecal.geometry.transforms import rotvec_to_matrix

from .franka_sim import HOST, FrankaSim, _answers
from .ur_runs import SPACECAL, run

#: Real client libraries against a protocol simulator, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime

#: From the stop to the arm standing still, s of the robot's clock (the UR stop tests' STILL_WITHIN_S).
STILL_WITHIN_S = 1.0
#: Still: no joint moved more than this over :data:`STILL_WINDOW_S`, rad (the servo settles
#: to well below 1e-4 rad), but joint 7, which creeps while the simulator holds the pose (low
#: gain and friction on the last wrist joint: up to 2.4e-4 rad per 0.1 s measured, after any
#: motion or none) and so only has to be within :data:`JOINT7_CREEP_RAD`.
STILL_RAD, STILL_WINDOW_S, JOINT7_CREEP_RAD = 1e-4, 0.1, 5e-4
#: From killing the simulator to the one-line error, s: libfranka's UDP receive times out
#: after 1 s; the rest is margin for a loaded 2-core machine.
LOST_WITHIN_S = 3.0
#: Joint speed and acceleration of the test moves, rad/s and rad/s^2.
SPEED, ACCEL = 1.0, 2.0


@pytest.fixture
def sim(tmp_path):
    made = []

    def start(*options: str) -> FrankaSim:
        made.append(FrankaSim(tmp_path, *options))
        return made[-1]

    yield start
    for process in made:
        process.stop()


def open_robot(control: bool = True) -> FrankaRobot:
    return open_device(f"franka://{HOST}", "robot", DeviceOptions(control=control))


def unmoved(before: np.ndarray, after: np.ndarray) -> bool:
    """Joints 1-6 within :data:`STILL_RAD`, joint 7 within its creep over a few seconds."""
    moved = np.abs(np.asarray(after) - np.asarray(before))
    return bool(moved[:6].max() < STILL_RAD and moved[6] < 10 * JOINT7_CREEP_RAD)


def robot_time(robot: FrankaRobot) -> float:
    return robot.state().time_s


def still_since(robot: FrankaRobot, since_s: float, within_s: float) -> float:
    """Seconds of the robot's clock after ``since_s`` (its time at the stop) at which the
    joints stood still for :data:`STILL_WINDOW_S`; fails when not within ``within_s``. The
    robot's clock, not the wall's: on a loaded computer the simulator runs slower than real
    time, and its arm takes as much longer to stop (a real robot's clock is real time)."""
    window: list[tuple[float, np.ndarray]] = []
    wall_deadline = time.monotonic() + WALL_DEADLINE_FACTOR * (within_s + STILL_WINDOW_S) + 5.0
    while time.monotonic() < wall_deadline:
        state = robot.state()
        now = state.time_s
        if now - since_s > within_s + STILL_WINDOW_S:
            break
        window.append((now, state.joints_rad))
        window = [(t, q) for t, q in window if now - t <= STILL_WINDOW_S]
        if now - window[0][0] >= 0.9 * STILL_WINDOW_S:
            spread = np.ptp(np.array([q for _, q in window]), axis=0)
            if spread[:6].max() < STILL_RAD and spread[6] < JOINT7_CREEP_RAD:
                return window[0][0] - since_s
        time.sleep(0.005)
    raise AssertionError(f"the arm was not still within {within_s} s of the stop")


def wait_until(condition, timeout_s: float = 20.0) -> None:
    """Poll ``condition()`` until it holds (a motion under way), at most ``timeout_s`` of wall time."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "the motion did not get under way"
        time.sleep(0.005)


def test_state_identity_and_checks(sim):
    sim()
    robot = open_robot(control=False)
    try:
        for port in (Robot, ModelledRobot, ControlledRobot, Closable, Preflight, Identified):
            assert isinstance(robot, port)
        first, second = robot.state(), robot.state()
        assert first.joints_rad.shape == (7,) and first.safety == SAFETY_NORMAL and not first.moving
        assert second.time_s > first.time_s  # the robot's own 1 kHz clock
        assert plausible_tracked_pose(first.base_from_tcp)
        # mm, not metres: an FR3 end effector is 0.1 to 1 m from its base
        assert 100.0 < np.linalg.norm(first.base_from_tcp[:3, 3]) < 1000.0
        identity = robot.identity()
        assert identity.firmware == "FCI server version 10" and identity.serial is None
        findings = {f.subject: f for f in robot.preflight()}
        assert findings["robot mode"].level == "ok" and findings["robot state"].level == "ok"
        assert findings["end effector"].text.startswith("set in Desk (F_T_EE): X 0.0 Y 0.0 Z 0.0 mm")
        with pytest.raises(DeviceError, match="read-only"):
            robot.move_joints(first.joints_rad, SPEED, ACCEL)
    finally:
        robot.close()


def test_a_robot_kind_of_another_vendor_is_refused(sim):
    sim()
    refused = "^--robot-model UR10e is a Universal Robots arm; a Franka robot is one of FR3, Panda$"
    with pytest.raises(InvalidInputError, match=refused):
        open_device(f"franka://{HOST}", "robot", DeviceOptions(robot_model="UR10e"))
    robot = open_robot(control=False)  # the refused one was closed: the robot takes a client again
    robot.close()


def test_joint_move_reaches_its_target_in_its_time(sim):
    sim()
    robot = open_robot()
    try:
        start = robot.state().joints_rad
        target = start + np.array([0.4, -0.2, 0.0, 0.3, 0.0, 0.2, -0.3])
        began = robot_time(robot)
        robot.move_joints(target, SPEED, ACCEL)
        took = robot_time(robot) - began  # the robot's clock (see still_since)
        planned = path_duration(0.4, SPEED, ACCEL)
        assert planned - 0.05 < took < planned + SETTLE_S + 0.5
        reached = robot.state()
        assert np.max(np.abs(reached.joints_rad - target)) < ARRIVAL_RAD
        assert np.max(np.abs(reached.joints_rad - target)[:6]) < 1e-3  # joint 7 creeps (ARRIVAL_RAD)
        assert not reached.moving and reached.safety == SAFETY_NORMAL
        off = np.abs(reached.joints_rad - target)
        print(f"{off.max():.2e} rad from the target (joint {off.argmax() + 1}), {took:.2f} s")
    finally:
        robot.close()


def test_straight_line_move_keeps_to_its_line(sim):
    sim()
    robot = open_robot()
    try:
        here = robot.state().base_from_tcp
        target = here.copy()
        target[:3, 3] += [60.0, -40.0, 50.0]
        target[:3, :3] = here[:3, :3] @ rotvec_to_matrix([0.0, 0.0, 0.3])  # about the tool axis
        robot.move_linear(target, 100.0, 400.0, asynchronous=True)
        off_line, states = [], 0
        direction = (target[:3, 3] - here[:3, 3]) / np.linalg.norm(target[:3, 3] - here[:3, 3])
        while True:
            state = robot.state()
            states += 1
            offset = state.base_from_tcp[:3, 3] - here[:3, 3]
            off_line.append(np.linalg.norm(offset - direction * (offset @ direction)))
            if not state.moving:
                break
            time.sleep(0.01)
        time.sleep(0.3)  # the servo settles
        assert states > 10
        assert max(off_line) < 2.0  # mm, a position servo tracking a straight path
        arrived = robot.state().base_from_tcp
        arrived_mm = np.linalg.norm(arrived[:3, 3] - target[:3, 3])
        assert arrived_mm < 1.0
        assert rotation_angle(arrived[:3, :3].T @ target[:3, :3]) < np.radians(0.1)
        print(f"{max(off_line):.3f} mm off the line, {arrived_mm:.3f} mm from the target")
    finally:
        robot.close()


def test_a_stop_mid_move_stills_the_arm_for_good(sim):
    sim()
    robot = open_robot()
    try:
        start = robot.state().joints_rad
        target = start + np.array([1.0, 0, 0, 0, 0, 0, 0])
        stopped_at: list[float] = []

        def stop_soon():
            wait_until(lambda: robot.state().joints_rad[0] - start[0] > 0.1)
            stopped_at.append(robot_time(robot))
            robot.stop()

        stopper = threading.Thread(target=stop_soon)
        stopper.start()
        robot.move_joints(target, SPEED, ACCEL)  # returns once stopped, short of its target
        stopper.join()
        still_after = still_since(robot, stopped_at[0], STILL_WITHIN_S)
        here = robot.state().joints_rad
        assert 0.1 < here[0] - start[0] < 0.9  # it moved, and stopped short
        time.sleep(1.0)
        assert unmoved(here, robot.state().joints_rad)  # never moves again
        with pytest.raises(DeviceError, match="was stopped"):
            robot.move_joints(target, SPEED, ACCEL)
        print(f"still {still_after:.3f} s after the stop")
    finally:
        robot.close()


def test_a_stop_ends_an_asynchronous_straight_line_move(sim):
    sim()
    robot = open_robot()
    try:
        here = robot.state().base_from_tcp
        target = here.copy()
        target[:3, 3] += [0.0, 150.0, 0.0]
        robot.move_linear(target, 100.0, 400.0, asynchronous=True)
        wait_until(lambda: robot.state().base_from_tcp[1, 3] - here[1, 3] > 20.0)
        assert robot.state().moving
        stopped_at = robot_time(robot)
        robot.stop()
        after_s = still_since(robot, stopped_at, STILL_WITHIN_S)
        print(f"straight-line move still {after_s:.3f} s after the stop")
        reached = robot.state()
        assert not reached.moving
        travelled = np.linalg.norm(reached.base_from_tcp[:3, 3] - here[:3, 3])
        assert 20.0 < travelled < 140.0  # it moved, and stopped short
    finally:
        robot.close()


def test_a_move_past_its_deadline_is_stopped_in_one_line(sim, monkeypatch):
    sim()
    robot = open_robot()
    try:
        # a deadline a second short of the path's end: the same path as a stalled motion
        monkeypatch.setattr(franka, "MOTION_MARGIN_S", -1.0)
        target = robot.state().joints_rad + np.array([0.8, 0, 0, 0, 0, 0, 0])
        with pytest.raises(DeviceError, match=r"^the Franka robot did not finish the joint move within "):
            robot.move_joints(target, SPEED, ACCEL)
        gave_up_at = robot_time(robot)
        print(f"given up, still {still_since(robot, gave_up_at, STILL_WITHIN_S):.3f} s later")
        assert np.max(np.abs(robot.state().joints_rad - target)) > 0.05  # stopped short
        with pytest.raises(DeviceError, match="was stopped"):
            robot.move_joints(target, SPEED, ACCEL)
    finally:
        robot.close()


def test_a_robot_that_vanishes_mid_move_is_one_line_within_a_deadline(sim):
    process = sim()
    robot = open_robot()
    try:
        target = robot.state().joints_rad + np.array([1.0, 0, 0, 0, 0, 0, 0])
        killed_at: list[float] = []

        start = robot.state().joints_rad

        def kill_soon():
            wait_until(lambda: robot.state().joints_rad[0] - start[0] > 0.1)
            killed_at.append(time.monotonic())
            process.kill()

        killer = threading.Thread(target=kill_soon)
        killer.start()
        with pytest.raises(DeviceError) as raised:
            robot.move_joints(target, SPEED, ACCEL)
        ended_after = time.monotonic() - killed_at[0]
        killer.join()
        line = str(raised.value)
        assert "\n" not in line and f"lost the connection to the Franka robot on {HOST}" in line
        assert ended_after < LOST_WITHIN_S
        print(f"lost {ended_after:.3f} s after the kill")
        began = time.monotonic()
        with pytest.raises(DeviceError, match="lost the connection"):
            robot.state()
        assert time.monotonic() - began < 0.1  # known lost: not waited for again
    finally:
        began = time.monotonic()
        robot.close()
        assert time.monotonic() - began < LOST_WITHIN_S


def test_a_robot_that_vanishes_at_rest_is_one_line_within_a_deadline(sim):
    process = sim()
    robot = open_robot(control=False)
    try:
        robot.state()
        process.kill()
        began = time.monotonic()
        with pytest.raises(DeviceError, match=f"lost the connection to the Franka robot on {HOST}"):
            for _ in range(10_000):  # a packet or two may still be on its way
                robot.state()
        assert time.monotonic() - began < LOST_WITHIN_S
    finally:
        robot.close()


def test_a_reflex_is_refused_before_any_motion(sim):
    sim("--enforce-motion-limits")
    robot = open_robot()
    try:
        start = robot.state().joints_rad
        target = start + np.array([1.0, 0, 0, 0, 0, 0, 0])
        # far beyond an FR3's jerk limit: the robot aborts the motion with a reflex
        with pytest.raises(DeviceError, match="reflex"):
            robot.move_joints(target, 20.0, 500.0)
        latched = robot.state()
        assert latched.safety == "stopped_by_a_reflex"
        with pytest.raises(DeviceError) as refused:
            robot.move_joints(target, SPEED, ACCEL)
        line = str(refused.value)
        assert line.startswith("the robot is not ready (robot mode): the arm stopped in a reflex (")
        assert line.endswith("; nothing moved") and "\n" not in line
        time.sleep(0.3)
        assert unmoved(latched.joints_rad, robot.state().joints_rad)
        problems = [f for f in robot.preflight() if f.level == "problem"]
        assert [f.subject for f in problems] == ["robot mode"]
    finally:
        robot.close()


def test_nothing_listening_is_one_line():
    # no simulator: libfranka's port is closed on this machine
    if _answers():
        pytest.skip("something listens on port 1337 here")
    began = time.monotonic()
    with pytest.raises(DeviceError, match=f"no Franka robot answers on {HOST}:1337"):
        open_robot()
    assert time.monotonic() - began < 4.0


def test_doctor_names_a_robot_that_does_not_answer():
    if _answers():
        pytest.skip("something listens on port 1337 here")
    result = run([*SPACECAL, "doctor", "--robot", f"franka://{HOST}"], timeout_s=60)
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert f"robot: connection: PROBLEM: no Franka robot answers on {HOST}:1337" in result.stdout


#: franka-sim reports ``O_T_EE`` at the origin of link 7 (its MuJoCo body), where the FCI
#: reports the flange (link 7 moved 107 mm along its z axis, the FR3's d_F) composed with
#: ``F_T_EE``: the simulator's end effector is 107 mm short of the flange.
SIM_LINK7_FROM_FLANGE_MM = 107.0


def test_the_nominal_fr3_model_is_the_simulators_arm(sim):
    pytest.importorskip("spacecal.models.robot_kinds")
    from spacecal.models.kinematics import forward_kinematics

    sim()
    robot = open_robot()
    try:
        model, source = robot.controller_model()
        assert model.name == "FR3" and "nominal FR3" in source
        flange_from_sim_ee = np.eye(4)
        flange_from_sim_ee[2, 3] = -SIM_LINK7_FROM_FLANGE_MM
        rng = np.random.default_rng(7)
        start = robot.state().joints_rad
        errors, turns = [], []
        for _ in range(3):
            target = start + rng.uniform(-0.4, 0.4, 7)
            robot.move_joints(target, SPEED, ACCEL)
            state = robot.state()
            predicted = forward_kinematics(model, state.joints_rad) @ flange_from_sim_ee
            errors.append(np.linalg.norm(predicted[:3, 3] - state.base_from_tcp[:3, 3]))
            turns.append(rotation_angle(predicted[:3, :3].T @ state.base_from_tcp[:3, :3]))
        print(f"nominal FR3 vs the simulator: {max(errors):.2e} mm, {max(turns):.2e} rad")
        # measured 6e-5 mm (the wire's single precision) and 8e-5 rad (the MuJoCo model's
        # rounded link orientations)
        assert max(errors) < 0.01 and max(turns) < 2e-4, (errors, turns)
    finally:
        robot.close()


def test_a_target_beyond_the_joint_limits_is_refused_before_any_motion(sim):
    pytest.importorskip("spacecal.models.robot_kinds")
    sim()
    robot = open_robot()
    try:
        start = robot.state().joints_rad
        target = start.copy()
        target[3] = robot.nominal.joint_upper_rad[3] + 0.01
        refused = r"^joint 4 target .* outside the FR3's limits .*nothing moved$"
        with pytest.raises(InvalidInputError, match=refused):
            robot.move_joints(target, SPEED, ACCEL)
        time.sleep(0.2)
        assert unmoved(start, robot.state().joints_rad)
    finally:
        robot.close()


def test_doctor_checks_the_simulated_robot_and_moves_nothing(sim):
    pytest.importorskip("spacecal.models.robot_kinds")
    sim()
    before = open_robot(control=False)
    try:
        joints = before.state().joints_rad
    finally:
        before.close()
    result = run([*SPACECAL, "doctor", "--robot", f"franka://{HOST}"], timeout_s=60)
    assert "Traceback" not in result.stderr
    lines = result.stdout.splitlines()
    for expected in (
        "robot: controller version: ok: FCI server version 10, libfranka ",
        "robot: robot mode: ok: Idle (ready for commands)",
        "robot: robot state: ok: streaming at 1 kHz",
        "robot: end effector: ok: set in Desk (F_T_EE): X 0.0 Y 0.0 Z 0.0 mm",
        # the simulator's end effector is link 7's origin (SIM_LINK7_FROM_FLANGE_MM): doctor
        # names the mismatch, and a run would refuse to start on it
        "robot: kinematics: warning: the nominal FR3 model puts the end effector 107.00 mm from",
        "robot: kinematics: PROBLEM: the nominal FR3 kinematics",
    ):
        assert any(line.startswith(expected) for line in lines), (expected, result.stdout)
    assert result.returncode == 1
    after = open_robot(control=False)
    try:
        assert unmoved(joints, after.state().joints_rad)
    finally:
        after.close()
