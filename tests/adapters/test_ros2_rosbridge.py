"""The ros2:// adapter (real roslibpy) against the fake rosbridge v2 server in its own process:
joint states by name, joint moves reached, STOP stilling the arm (by the cancel on a
joint_trajectory_controller, by a hold goal on a server that rejects cancels), a killed
server and servers that are no rosbridge ending in one line within bounded time."""

import http.server
import json
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

pytest.importorskip("roslibpy")
pytest.importorskip("websockets")

from spacecal.adapters import ROBOT, DeviceOptions, device_address, open_device
from spacecal.adapters.ros2 import CANCEL_STILL_S, HOLD_STILL_S, UR_JOINT_NAMES, model_of
from spacecal.core.errors import DeviceError, InvalidInputError
from spacecal.testing.fakes.rosbridge import arm_state

#: Real client library against a protocol fake, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime

#: From STOP to the arm standing still, s: the UR stop tests' bound (test_ur_stops.STILL_WITHIN_S).
STILL_WITHIN_S = 1.0
#: From the server's death to the one line, s: the stale bound (0.5 s) and the poll.
LOST_WITHIN_S = 2.0
START = [0.0, -1.2, 1.4, -1.8, -1.57, 0.0]
ACTION = "/joint_trajectory_controller/follow_joint_trajectory"


class Bridge:
    def __init__(self, *options: str, joints=UR_JOINT_NAMES, start=START):
        self.process = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "spacecal.testing.fakes.rosbridge",
                "--joints",
                ",".join(joints),
                "--start",
                ",".join(str(v) for v in start),
                *options,
            ],
            stdout=subprocess.PIPE,
            stdin=subprocess.PIPE,
            text=True,
        )
        line = self.process.stdout.readline()
        assert line.startswith("READY "), line
        self.info = json.loads(line[6:])

    def url(self, query="model=UR10") -> str:
        return f"ros2://{self.info['host']}:{self.info['port']}?{query}"

    def arm(self) -> dict:
        return arm_state(self.info["host"], self.info["control_port"])

    def kill(self) -> None:
        self.process.kill()
        self.process.wait(5)


@pytest.fixture
def bridges():
    started = []

    def start(*options, **kw) -> Bridge:
        bridge = Bridge(*options, **kw)
        started.append(bridge)
        return bridge

    yield start
    for bridge in started:
        if bridge.process.poll() is None:
            bridge.kill()


def open_robot(url: str, control: bool = True):
    return open_device(url, ROBOT, DeviceOptions(control=control))


def still_after(bridge: Bridge, since: float, within_s: float) -> float:
    """Seconds from ``since`` until the fake arm's joints stopped changing (two looks 0.1 s
    apart within 1e-6 rad); fails past ``within_s``."""
    previous = np.array(bridge.arm()["joints"])
    while True:
        time.sleep(0.05)
        now = np.array(bridge.arm()["joints"])
        if np.max(np.abs(now - previous)) < 1e-6:
            return time.monotonic() - since
        assert time.monotonic() - since < within_s + 0.5, "the arm did not stand still"
        previous = now


def test_the_url_takes_the_default_port_and_its_query():
    address = device_address("ros2://Robot?model=UR10&joints=a,b,c,d,e,f", ROBOT)
    assert address.port == 9090 and "joints=a,b,c,d,e,f" in address.query
    with pytest.raises(InvalidInputError, match="not speed"):
        open_robot("ros2://127.0.0.1:1?model=UR10&speed=3")
    with pytest.raises(InvalidInputError, match="model=KIND"):
        open_robot("ros2://127.0.0.1:1")
    with pytest.raises(InvalidInputError, match="has 6"):
        open_robot("ros2://127.0.0.1:1?model=UR10&joints=a,b")
    # the TCP on the flange, as a pendant shows it (a trajectory controller knows none)
    model = model_of({"model": "UR10", "tcp": "0,0,200,0,0,1.5707963267948966"}, None)
    assert np.allclose(model.flange_from_tcp[:3, 3], [0, 0, 200])
    assert np.allclose(model.flange_from_tcp[:3, :2], [[0, -1], [1, 0], [0, 0]], atol=1e-12)
    with pytest.raises(InvalidInputError, match="tcp= takes"):
        open_robot("ros2://127.0.0.1:1?model=UR10&tcp=0,0,nan,0,0,0")


def test_state_reads_the_joints_by_name_in_the_models_order(bridges):
    # the broadcaster publishes in its own order (here reversed); the model's order is the URL's
    bridge = bridges(joints=tuple(reversed(UR_JOINT_NAMES)), start=list(reversed(START)))
    robot = open_robot(bridge.url())
    try:
        state = robot.state()
        assert np.allclose(state.joints_rad, START, atol=1e-9)
        assert not state.moving
        from spacecal.models.kinematics import forward_kinematics
        from spacecal.models.robot_kinds import robot_kind

        assert np.allclose(state.base_from_tcp, forward_kinematics(robot_kind("UR10").model(), START))
        # a stream at the broadcaster's rate, stamped by its clock
        time.sleep(0.3)
        states = robot.drain_states()
        assert len(states) > 15 and np.all(np.diff([s.time_s for s in states]) > 0)
    finally:
        robot.close()


def test_joint_names_that_do_not_match_are_one_line(bridges):
    bridge = bridges(joints=("j1", "j2", "j3", "j4", "j5", "j6"))
    with pytest.raises(DeviceError) as caught:
        open_robot(bridge.url())
    line = str(caught.value)
    assert "\n" not in line and "j1" in line and "shoulder_pan_joint" in line and "joints=" in line
    robot = open_robot(bridge.url("model=UR10&joints=j1,j2,j3,j4,j5,j6"))
    robot.close()


def test_a_joint_move_is_reached(bridges):
    bridge = bridges()
    robot = open_robot(bridge.url())
    try:
        target = np.array(START) + np.radians([10, -5, 8, 4, -6, 12])
        started = time.monotonic()
        robot.move_joints(target, 0.5, 1.0)
        took = time.monotonic() - started
        arm = bridge.arm()
        assert np.max(np.abs(np.array(arm["joints"]) - target)) < 2e-3
        assert np.max(np.abs(robot.state().joints_rad - target)) < 2e-3
        assert not arm["moving"] and arm["goals"] == 1
        # 12 degrees at 0.5 rad/s, 1 rad/s^2: 0.92 s planned
        assert 0.8 < took < 2.5
    finally:
        robot.close()


def test_a_read_only_robot_does_not_move(bridges):
    bridge = bridges()
    robot = open_robot(bridge.url(), control=False)
    try:
        with pytest.raises(DeviceError, match="read-only"):
            robot.move_joints(START, 0.5, 1.0)
        assert bridge.arm()["goals"] == 0
    finally:
        robot.close()


def _stop_mid_move(bridge: Bridge):
    robot = open_robot(bridge.url())
    target = np.array(START) + np.radians([40, 0, 0, 0, 0, 0])
    errors = []

    def move():
        try:
            robot.move_joints(target, 0.6, 2.0)
        except DeviceError as exc:
            errors.append(str(exc))

    mover = threading.Thread(target=move)
    mover.start()
    time.sleep(0.5)
    assert bridge.arm()["moving"]
    stopped_at = time.monotonic()
    robot.stop()
    stop_took = time.monotonic() - stopped_at
    mover.join(5)
    still = still_after(bridge, stopped_at, STILL_WITHIN_S)
    reached = np.array(bridge.arm()["joints"])
    return robot, target, stop_took, still, reached, errors


@pytest.mark.parametrize(("cancel", "stilled_by"), [("hold", "cancel"), ("ignore", "hold")])
def test_stop_mid_move_stills_the_arm(bridges, cancel, stilled_by):
    bridge = bridges("--cancel", cancel)
    robot, target, stop_took, still, reached, errors = _stop_mid_move(bridge)
    try:
        assert robot.stopped_by == stilled_by
        assert still < STILL_WITHIN_S and stop_took < STILL_WITHIN_S
        assert np.max(np.abs(reached - target)) > np.radians(10)  # stopped short of the target
        assert bridge.arm()["cancels"] == 1
        assert errors and "stopped (CANCELED)" in errors[0]
        # nothing moves it again: not by itself, not by a further command
        time.sleep(0.5)
        assert np.allclose(bridge.arm()["joints"], reached, atol=1e-6)
        with pytest.raises(DeviceError, match="stopped"):
            robot.move_joints(target, 0.5, 1.0)
    finally:
        robot.close()


def test_a_killed_server_ends_a_move_in_one_line_in_bounded_time(bridges):
    bridge = bridges()
    robot = open_robot(bridge.url())
    try:
        errors = []

        def move():
            try:
                robot.move_joints(np.array(START) + np.radians([40, 0, 0, 0, 0, 0]), 0.4, 1.0)
            except DeviceError as exc:
                errors.append((time.monotonic(), str(exc)))

        mover = threading.Thread(target=move)
        mover.start()
        time.sleep(0.4)
        killed_at = time.monotonic()
        bridge.kill()
        mover.join(LOST_WITHIN_S + 1)
        assert not mover.is_alive()
        ended_at, line = errors[0]
        assert ended_at - killed_at < LOST_WITHIN_S
        assert "\n" not in line and ("lost" in line or "no joint state" in line)
        with pytest.raises(DeviceError):
            robot.state()
    finally:
        started = time.monotonic()
        robot.close()
        assert time.monotonic() - started < 2.0


def test_a_killed_server_makes_the_state_an_error(bridges):
    bridge = bridges()
    robot = open_robot(bridge.url())
    try:
        robot.state()
        bridge.kill()
        deadline = time.monotonic() + LOST_WITHIN_S
        while True:
            try:
                robot.state()
            except DeviceError as exc:
                assert "\n" not in str(exc)
                break
            assert time.monotonic() < deadline
            time.sleep(0.05)
    finally:
        robot.close()


class _Page(http.server.BaseHTTPRequestHandler):
    def do_GET(self):
        self.send_response(404)
        self.end_headers()

    def log_message(self, *_):
        pass


def test_a_plain_http_server_is_not_a_rosbridge(bridges):
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Page)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        started = time.monotonic()
        with pytest.raises(DeviceError, match="is not a rosbridge server") as caught:
            open_robot(f"ros2://127.0.0.1:{server.server_address[1]}?model=UR10")
        assert "\n" not in str(caught.value) and time.monotonic() - started < 4.0
    finally:
        server.shutdown()


def test_a_websocket_that_answers_nonsense_is_not_a_rosbridge(bridges):
    bridge = bridges("--mode", "nonsense")
    started = time.monotonic()
    with pytest.raises(DeviceError, match="is not a rosbridge server") as caught:
        open_robot(bridge.url())
    assert "\n" not in str(caught.value) and time.monotonic() - started < 4.0


def test_nothing_listening_is_one_line():
    with pytest.raises(DeviceError, match="no rosbridge"):
        open_robot("ros2://127.0.0.1:9?model=UR10")


def test_a_wrong_action_name_is_one_line_and_nothing_moves(bridges):
    bridge = bridges()
    robot = open_robot(bridge.url(f"model=UR10&action={ACTION}_x"))
    try:
        started = time.monotonic()
        with pytest.raises(DeviceError, match="did not take"):
            robot.move_joints(np.array(START) + 0.1, 0.5, 1.0)
        assert time.monotonic() - started < 3.0
        assert bridge.arm()["goals"] == 0
    finally:
        robot.close()


def test_trajectory_times_never_step_back():
    # a time a hair below a whole second once became sec 2, nanosec 0 (rounded up to 1e9 and
    # wrapped): a trajectory going back in time, which the controller rejects
    from spacecal.adapters.ros2 import _duration

    assert _duration(2.9999999999) == {"sec": 3, "nanosec": 0}
    assert _duration(0.05) == {"sec": 0, "nanosec": 50_000_000}
    times = np.linspace(0.05, 7.0, 140)
    stamps = [_duration(t)["sec"] + _duration(t)["nanosec"] * 1e-9 for t in times]
    assert np.all(np.diff(stamps) > 0)


def test_an_asynchronous_move_that_is_not_taken_shows_in_the_state(bridges):
    # the acquisition commands linear moves asynchronously and reads state() until the arm is
    # no longer moving: a goal nobody took must be an error there, never an arrival
    bridge = bridges()
    robot = open_robot(bridge.url(f"model=UR10&action={ACTION}_x"))
    try:
        pose = robot.state().base_from_tcp.copy()
        pose[2, 3] += 20.0
        robot.move_linear(pose, 50.0, 200.0, asynchronous=True)
        assert robot.state().moving
        started = time.monotonic()
        with pytest.raises(DeviceError, match="did not take the linear move"):
            while robot.state().moving:
                assert time.monotonic() - started < 3.0
                time.sleep(0.05)
        assert bridge.arm()["goals"] == 0
    finally:
        robot.close()


def test_an_asynchronous_linear_move_arrives(bridges):
    bridge = bridges()
    robot = open_robot(bridge.url())
    try:
        start = robot.state().base_from_tcp.copy()
        pose = start.copy()
        pose[0, 3] += 30.0
        robot.move_linear(pose, 50.0, 200.0, asynchronous=True)
        along = []
        while robot.state().moving:
            along.append(robot.state().base_from_tcp[:3, 3])
            time.sleep(0.02)
        reached = robot.state().base_from_tcp
        assert np.linalg.norm(reached[:3, 3] - pose[:3, 3]) < 0.5
        # along the straight line: y and z stay, to the fake's linear interpolation between points
        path = np.array(along)
        assert np.max(np.abs(path[:, 1:] - start[1:3, 3])) < 0.5
    finally:
        robot.close()


def test_a_port_that_never_answers_the_upgrade_is_one_line_within_the_deadline():
    import socket

    server = socket.create_server(("127.0.0.1", 0))
    try:
        started = time.monotonic()
        with pytest.raises(DeviceError, match="did not answer a WebSocket upgrade within 3 s"):
            open_robot(f"ros2://127.0.0.1:{server.getsockname()[1]}?model=UR10")
        assert 2.9 < time.monotonic() - started < 4.0
    finally:
        server.close()


def test_the_read_only_check_measures_the_joint_state_rate(bridges):
    bridge = bridges()
    robot = open_robot(bridge.url(), control=False)
    try:
        findings = {f.subject: f for f in robot.preflight()}
        assert findings["joint states"].level == "ok"
        # the fake's broadcaster publishes at 100 Hz; a loaded machine delays its loop
        rate = float(findings["joint states"].text.split(" at ")[1].split(" Hz")[0])
        assert 40 <= rate <= 110
        assert bridge.arm()["goals"] == 0  # read-only: nothing was sent to the action server
    finally:
        robot.close()


@pytest.mark.parametrize("offset_mm", [0.0, 3.0])
def test_the_read_only_check_compares_the_model_with_tf(bridges, offset_mm):
    # the driver publishes base_link -> tool0 by its own description; a 3 mm difference (a
    # calibrated URDF, another tool frame) is named, an agreeing one passes
    bridge = bridges("--tf-model", "UR10", "--tf-offset-mm", str(offset_mm))
    robot = open_robot(bridge.url("model=UR10&tf=base_link,tool0"), control=False)
    try:
        finding = {f.subject: f for f in robot.preflight()}["tf"]
        apart = float(finding.text.split("puts the TCP ")[1].split(" mm")[0])
        assert apart == pytest.approx(offset_mm, abs=0.01)
        assert finding.level == ("ok" if offset_mm == 0 else "warning")
    finally:
        robot.close()
    with pytest.raises(InvalidInputError, match="tf= takes two"):
        open_robot(bridge.url("model=UR10&tf=base_link"))


def test_a_rosbridge_whose_goals_block_its_queue_cannot_be_stopped_and_the_stop_says_so(bridges):
    # rosbridge with send_action_goals_in_new_thread:=false reads the cancel, and the hold
    # goal, only once the goal is over: the stop gives up within its deadlines and says nothing
    # stilled the arm (docs/ros2.md: launch rosbridge with the option true)
    bridge = bridges("--goals-block")
    robot = open_robot(bridge.url())
    try:
        target = np.array(START) + np.radians([60, 0, 0, 0, 0, 0])  # 2.4 s at 0.5 rad/s
        errors = []

        def move():
            try:
                robot.move_joints(target, 0.5, 2.0)
            except DeviceError as exc:
                errors.append(str(exc))

        mover = threading.Thread(target=move)
        mover.start()
        time.sleep(0.4)
        started = time.monotonic()
        robot.stop()
        assert time.monotonic() - started < CANCEL_STILL_S + HOLD_STILL_S + 0.3
        assert robot.stopped_by is None and bridge.arm()["moving"]
        mover.join(5)
        assert errors and "was stopped" in errors[0]
    finally:
        robot.close()


def test_the_model_comes_from_the_robot_kind_table(bridges):
    from spacecal.models.kinematics import forward_kinematics
    from spacecal.models.robot_kinds import robot_kind

    bridge = bridges()
    robot = open_robot(bridge.url("model=UR5e"))
    try:
        model, _ = robot.controller_model()
        assert model.name == "UR5e"
        assert np.allclose(robot.state().base_from_tcp, forward_kinematics(robot_kind("UR5e").model(), START))
    finally:
        robot.close()
    with pytest.raises(InvalidInputError, match="unknown robot kind"):
        open_robot(bridge.url("model=UR99"))
    # a 7-joint arm is refused in one line until the robot interface carries 7-joint states
    with pytest.raises(InvalidInputError, match="has 7 joints"):
        open_robot(bridge.url("model=LBR+iiwa+14+R820&joints=a,b,c,d,e,f,g"))


def test_the_model_comes_from_a_urdf_with_its_joint_names(bridges):
    pytest.importorskip("yourdfpy")
    from pathlib import Path

    from spacecal.models.kinematics import forward_kinematics
    from spacecal.models.urdf import robot_model_from_urdf

    urdf = Path(__file__).parents[1] / "models" / "data" / "urdf" / "ur10_robot.urdf"
    bridge = bridges()
    robot = open_robot(bridge.url(f"urdf={urdf}&base=base_link&tool=tool0"))
    try:
        # the joints are the URDF chain's, by name (here ur_robot_driver's)
        assert robot.joint_names == UR_JOINT_NAMES
        expected = forward_kinematics(robot_model_from_urdf(urdf, "base_link", "tool0"), START)
        assert np.allclose(robot.state().base_from_tcp, expected)
    finally:
        robot.close()
    with pytest.raises(InvalidInputError, match="base=LINK&tool=LINK"):
        open_robot(bridge.url(f"urdf={urdf}&base=base_link"))
