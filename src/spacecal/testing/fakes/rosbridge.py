"""A fake rosbridge v2 server (WebSocket, JSON) in front of a simulated arm's joint controller.

Written from the rosbridge v2 protocol specification (RobotWebTools/rosbridge_suite,
``ROSBRIDGE_PROTOCOL.md``) and what rosbridge_library's action capability sends, not from a
client's habits:

* ``subscribe`` / ``unsubscribe`` (by ``id``, or every subscription of the topic) and
  ``publish`` (server to client: ``{"op": "publish", "topic", "msg"}``): ``/joint_states``
  (``sensor_msgs/msg/JointState``) at :data:`PUBLISH_HZ`, stamped with the arm's clock;
* ``send_action_goal`` (``action``, ``action_type``, ``args``, ``feedback``, ``id``) for one
  ``control_msgs/action/FollowJointTrajectory`` server; ``action_feedback`` (``id``,
  ``action``, ``values``) while it runs when ``feedback`` was asked for; ``action_result``
  (``id``, ``action``, ``values``, ``status`` as ``action_msgs/msg/GoalStatus``, ``result``):
  SUCCEEDED 4 with ``result`` true at the end, CANCELED 5 when cancelled or preempted, and
  a goal the server rejects (joint names it does not drive, no points) as rosbridge reports a
  failed goal: ``status`` UNKNOWN 0, ``result`` false, ``values`` the reason in words;
* ``cancel_action_goal`` (``id`` of the goal, ``action``): an ``id`` that matches no goal in
  progress is ignored, as the specification says it must match one.

The joint controller behaves as ros2_control's ``joint_trajectory_controller`` in the ways a
client sees: a trajectory is followed from where the arm is (linear interpolation between
points, each joint at most :attr:`FakeArm.max_speed_rad_s`); a new goal preempts the one in
progress; on a cancel it holds the current position. ``cancel="ignore"`` is a server that
rejects cancels (another vendor's action server, or an older one): the arm goes on.
``mode="nonsense"`` is a WebSocket server that is no rosbridge: it answers every message with
text that is not a rosbridge message. What rosbridge does when its client vanishes is kept too:
the goal of a client that went away runs to its end (rosbridge does not cancel it).

Run on its own (the tests kill the process to cut the link)::

    python -m spacecal.testing.fakes.rosbridge --host 127.0.0.1 --port 0 \
        --joints shoulder_pan_joint,... [--start 0,-1.57,...] [--cancel hold|ignore] \
        [--mode rosbridge|nonsense] [--speed-deg-s 60]

``--goals-block`` is rosbridge launched with ``send_action_goals_in_new_thread:=false``: a
goal holds its connection's message queue until it ends, so a cancel is read only then.
``--tf-model UR10`` also publishes ``/tf`` (``tf2_msgs/msg/TFMessage``, metres and a
quaternion): ``base_link`` to ``tool0`` by that model's kinematics of the joints, its tool frame
shifted by ``--tf-offset-mm`` (a driver whose URDF is not the model spacecal was given).

It prints ``READY {"host", "port", "control_port"}``; the control port takes one line,
``state``, and answers JSON of the arm (``joints``, ``moving``, ``goals``, ``cancels``).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import socket
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from spacecal.geometry.transforms import make_transform, matrix_to_quaternion_wxyz
from spacecal.io.ros_common import UR_JOINT_NAMES
from spacecal.testing.fakes.net import accept_connections, listen

#: /joint_states rate, Hz (a joint_state_broadcaster's usual 100 Hz).
PUBLISH_HZ = 100.0
#: The controller's own loop, Hz.
CONTROL_HZ = 500.0
#: Feedback rate of the action server, Hz (joint_trajectory_controller's action_monitor_rate).
FEEDBACK_HZ = 20.0
FEEDBACK_S = 1.0 / FEEDBACK_HZ
#: The arm counts as at a trajectory's last point within this (rad) per joint.
GOAL_TOLERANCE_RAD = 1e-3
ACTION_TYPE = "control_msgs/action/FollowJointTrajectory"
JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
TF_TOPIC, TF_TYPE = "/tf", "tf2_msgs/msg/TFMessage"
#: action_msgs/msg/GoalStatus
STATUS_UNKNOWN, STATUS_EXECUTING, STATUS_SUCCEEDED, STATUS_CANCELED = 0, 2, 4, 5


@dataclass
class _Goal:
    id: str
    connection: object
    feedback: bool
    times_s: np.ndarray  # (P,) from the goal's start
    positions: np.ndarray  # (P, N) in the arm's joint order
    started_s: float
    start_joints: np.ndarray
    last_feedback_s: float = 0.0


@dataclass
class FakeArm:
    """The simulated arm's joints under a trajectory controller (rad, s)."""

    names: tuple[str, ...]
    joints: np.ndarray
    max_speed_rad_s: float = np.radians(60.0)
    goal: _Goal | None = None
    cancels: int = 0
    goals: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)

    clock0: float = field(default_factory=time.monotonic)

    def now_s(self) -> float:
        """The arm's clock (the stamps of its joint states), s."""
        return time.monotonic() - self.clock0

    def start(self, goal: _Goal) -> None:
        """Follow ``goal`` from where the arm is (preempting any other)."""
        self.goal = goal

    def hold(self) -> None:
        """Hold the current position (a cancelled goal)."""
        self.goal = None

    def sample(self) -> tuple[float, np.ndarray]:
        """(stamp s, joints rad) as the joint-state broadcaster publishes them."""
        return self.now_s(), self.joints.copy()

    def desired(self, now_s: float) -> np.ndarray:
        goal = self.goal
        assert goal is not None
        times = np.concatenate([[0.0], goal.times_s])
        points = np.vstack([goal.start_joints, goal.positions])
        since = now_s - goal.started_s
        return np.array([np.interp(since, times, points[:, k]) for k in range(len(self.names))])

    def step(self, now_s: float, dt_s: float) -> None:
        if self.goal is None:
            return
        change = self.desired(now_s) - self.joints
        self.joints = self.joints + np.clip(change, -self.max_speed_rad_s * dt_s, self.max_speed_rad_s * dt_s)

    def reached(self, now_s: float) -> bool:
        goal = self.goal
        return (
            goal is not None
            and now_s - goal.started_s >= goal.times_s[-1]
            and bool(np.all(np.abs(self.joints - goal.positions[-1]) < GOAL_TOLERANCE_RAD))
        )


class WorldArm:
    """The fake world's robot (:class:`spacecal.sim.devices.SimulatedRobot`) behind the
    trajectory controller, so the world's tracker sees the arm rosbridge moves: a goal is
    followed point by point (linearly between them), a cancel stops the arm; joint states are
    the robot's controller ticks."""

    def __init__(self, fake_world, names: tuple[str, ...]):
        self.fake, self.names = fake_world, names
        self.goal: _Goal | None = None
        self.cancels = self.goals = 0
        self.lock = threading.Lock()

    @property
    def robot(self):
        return self.fake.robot  # the UR configuration may replace the world's robot

    def now_s(self) -> float:
        return float(self.fake.clock.now_s)

    def start(self, goal: _Goal) -> None:
        self.goal = goal
        self.robot.start_trajectory(goal.times_s, goal.positions)

    def hold(self) -> None:
        self.goal = None
        self.robot.stop()

    def step(self, now_s: float, dt_s: float) -> None:
        pass  # the simulated robot moves on the world's clock by itself

    def reached(self, now_s: float) -> bool:
        return self.goal is not None and not self.robot.state().moving

    def sample(self) -> tuple[float, np.ndarray]:
        state = self.robot.tick_state()
        return float(state.time_s), np.asarray(state.joints_rad, dtype=float)


def start_world_rosbridge(fake_world, host: str, names: tuple[str, ...] = UR_JOINT_NAMES) -> int:
    """A fake rosbridge on ``host`` (a free port) driving the world's robot; its port."""
    bridge = FakeRosbridge(WorldArm(fake_world, names))
    ready, bound = threading.Event(), list[int]()
    threading.Thread(target=bridge.serve, args=(host, 0, ready, bound), daemon=True).start()
    if not ready.wait(10):
        raise RuntimeError("the fake rosbridge did not start")
    return bound[0]


def _duration_s(value) -> float:
    """builtin_interfaces/Duration ``{"sec", "nanosec"}`` in s."""
    return float(value.get("sec", 0)) + float(value.get("nanosec", 0)) * 1e-9


class FakeRosbridge:
    """The server: one asyncio loop on its own thread, one arm."""

    def __init__(
        self,
        arm: FakeArm | WorldArm,
        action: str = "/joint_trajectory_controller/follow_joint_trajectory",
        topic: str = "/joint_states",
        cancel: str = "hold",
        mode: str = "rosbridge",
        tf: tuple[str, str, Callable[[np.ndarray], np.ndarray]] | None = None,
        goals_block: bool = False,
    ):
        self.arm, self.action, self.topic = arm, action, topic
        self.cancel_mode, self.mode = cancel, mode
        #: (parent frame, child frame, parent_from_child (4, 4) mm of the joints) for /tf
        self.tf = tf
        #: rosbridge with ``send_action_goals_in_new_thread`` false: a goal holds the
        #: connection's message queue until it ends (a cancel is read only afterwards)
        self.goals_block = goals_block
        self._subscriptions: dict[object, dict[str, str | None]] = {}
        self._loop = asyncio.new_event_loop()

    def now_s(self) -> float:
        return self.arm.now_s()

    # -- wire ---------------------------------------------------------------------------
    async def _send(self, connection, message: dict) -> None:
        with contextlib.suppress(Exception):  # a client gone in the meantime
            await connection.send(json.dumps(message))

    async def _serve_client(self, connection) -> None:
        self._subscriptions[connection] = {}
        try:
            async for text in connection:
                if self.mode == "nonsense":
                    await connection.send("HELLO " + str(text)[:20][::-1])
                    continue
                while self.goals_block and self.arm.goal is not None:
                    await asyncio.sleep(0.005)
                try:
                    message = json.loads(text)
                    op = message["op"]
                except (ValueError, KeyError, TypeError):
                    await self._status(connection, "error", "not a rosbridge message")
                    continue
                await self._handle(connection, op, message)
        except Exception:  # the connection dropped
            pass
        finally:
            self._subscriptions.pop(connection, None)

    async def _status(self, connection, level: str, text: str, id_=None) -> None:
        message = {"op": "status", "level": level, "msg": text}
        if id_ is not None:
            message["id"] = id_
        await self._send(connection, message)

    async def _handle(self, connection, op: str, message: dict) -> None:
        subscriptions = self._subscriptions.setdefault(connection, {})
        if op == "subscribe":
            topic, kind = message.get("topic"), message.get("type")
            if topic == TF_TOPIC and self.tf is not None:
                if kind not in (None, TF_TYPE, "tf2_msgs/TFMessage"):
                    await self._status(connection, "error", f"{topic} is a {TF_TYPE}, not {kind}")
                else:
                    subscriptions[str(message.get("id", topic))] = topic
            elif topic != self.topic:
                await self._status(
                    connection, "warning", f"topic {topic} does not exist yet", message.get("id")
                )
            elif kind not in (None, JOINT_STATE_TYPE, "sensor_msgs/JointState"):
                await self._status(connection, "error", f"{topic} is a {JOINT_STATE_TYPE}, not {kind}")
            else:
                subscriptions[str(message.get("id", topic))] = topic
        elif op == "unsubscribe":
            if "id" in message:
                subscriptions.pop(str(message["id"]), None)
            else:
                for key in [k for k, v in subscriptions.items() if v == message.get("topic")]:
                    del subscriptions[key]
        elif op == "send_action_goal":
            await self._goal(connection, message)
        elif op == "cancel_action_goal":
            with self.arm.lock:
                goal = self.arm.goal
                if goal is None or goal.id != message.get("id") or message.get("action") != self.action:
                    return  # no goal in progress by that id: nothing to cancel
                self.arm.cancels += 1
                if self.cancel_mode != "hold":
                    return  # the server rejects the cancel: the trajectory goes on
                self.arm.hold()
            await self._result(goal, STATUS_CANCELED, 0, "cancelled")
        elif op in ("advertise", "unadvertise", "publish", "call_service"):
            await self._status(connection, "error", f"{op} is not offered by this server")
        else:
            await self._status(connection, "error", f"unknown op {op!r}")

    async def _result(self, goal: _Goal, status: int, code: int, text: str, result: bool = True) -> None:
        await self._send(
            goal.connection,
            {
                "op": "action_result",
                "id": goal.id,
                "action": self.action,
                "values": {"error_code": code, "error_string": text},
                "status": status,
                "result": result,
            },
        )

    async def _goal(self, connection, message: dict) -> None:
        goal_id = str(message.get("id", ""))

        async def refuse(reason: str) -> None:
            await self._send(
                connection,
                {
                    "op": "action_result",
                    "id": goal_id,
                    "action": message.get("action"),
                    "values": reason,
                    "status": STATUS_UNKNOWN,
                    "result": False,
                },
            )

        if message.get("action") != self.action:
            return  # no such action server: rosbridge's client waits for it (no answer)
        if message.get("action_type") != ACTION_TYPE:
            await refuse(f"the action type of {self.action} is {ACTION_TYPE}")
            return
        args = message.get("args") or {}
        try:
            trajectory = args["trajectory"]
            names = list(trajectory["joint_names"])
            points = trajectory["points"]
            order = [names.index(name) for name in self.arm.names]
            if len(names) != len(self.arm.names) or not points:
                raise ValueError
            times = np.array([_duration_s(p["time_from_start"]) for p in points])
            positions = np.array([[float(p["positions"][k]) for k in order] for p in points])
            if np.any(np.diff(times) <= 0) or not np.all(np.isfinite(positions)):
                raise ValueError
        except (KeyError, ValueError, TypeError, IndexError):
            await refuse("Action goal was rejected")
            return
        now = self.now_s()
        with self.arm.lock:
            previous = self.arm.goal
            self.arm.start(
                _Goal(
                    goal_id,
                    connection,
                    bool(message.get("feedback")),
                    times,
                    positions,
                    now,
                    self.arm.sample()[1],
                )
            )
            self.arm.goals += 1
        if previous is not None:
            await self._result(
                previous, STATUS_CANCELED, 0, "Current goal cancelled due to new incoming action."
            )

    # -- the arm's loop --------------------------------------------------------------------
    async def _run_arm(self) -> None:
        period, last_publish = 1.0 / CONTROL_HZ, -1.0
        last = self.now_s()
        while True:
            await asyncio.sleep(period)
            now = self.now_s()
            finished: _Goal | None = None
            feedback: tuple[_Goal, list[float]] | None = None
            with self.arm.lock:
                self.arm.step(now, now - last)
                goal = self.arm.goal
                if goal is not None and self.arm.reached(now):
                    finished = goal
                    self.arm.hold()
                publish = now - last_publish >= 1.0 / PUBLISH_HZ
                goal = self.arm.goal
                report = goal is not None and goal.feedback and now - goal.last_feedback_s >= FEEDBACK_S
                if publish or report:  # the world's arm computes a state per look
                    stamp, joints = self.arm.sample()
                if report and goal is not None:
                    goal.last_feedback_s, feedback = now, (goal, joints.tolist())
            last = now
            if finished is not None:
                await self._result(finished, STATUS_SUCCEEDED, 0, "")
            if feedback is not None:
                await self._send(
                    feedback[0].connection,
                    {
                        "op": "action_feedback",
                        "id": feedback[0].id,
                        "action": self.action,
                        "values": {"joint_names": list(self.arm.names), "actual": {"positions": feedback[1]}},
                    },
                )
            if publish:
                last_publish = now
                await self._publish(stamp, joints.tolist())

    async def _publish(self, stamp: float, joints: list[float]) -> None:
        sec = int(np.floor(stamp))
        header_stamp = {"sec": sec, "nanosec": int((stamp - sec) * 1e9)}
        msg = {
            "header": {"stamp": header_stamp, "frame_id": ""},
            "name": list(self.arm.names),
            "position": joints,
            "velocity": [0.0] * len(joints),
            "effort": [0.0] * len(joints),
        }
        tf = None
        if self.tf is not None:
            parent, child, pose_of = self.tf
            pose = pose_of(np.asarray(joints))
            w, x, y, z = matrix_to_quaternion_wxyz(pose[:3, :3])
            t = pose[:3, 3] / 1000.0  # ROS: metres
            tf = {
                "transforms": [
                    {
                        "header": {"stamp": header_stamp, "frame_id": parent},
                        "child_frame_id": child,
                        "transform": {
                            "translation": {"x": t[0], "y": t[1], "z": t[2]},
                            "rotation": {"x": x, "y": y, "z": z, "w": w},
                        },
                    }
                ]
            }
        for connection, subscriptions in list(self._subscriptions.items()):
            if self.mode != "rosbridge":
                continue
            if self.topic in subscriptions.values():
                await self._send(connection, {"op": "publish", "topic": self.topic, "msg": msg})
            if tf is not None and TF_TOPIC in subscriptions.values():
                await self._send(connection, {"op": "publish", "topic": TF_TOPIC, "msg": tf})

    def serve(self, host: str, port: int, ready: threading.Event, bound: list) -> None:
        from websockets.asyncio.server import serve

        async def main() -> None:
            async with serve(self._serve_client, host, port, max_size=2**20) as server:
                bound.append(server.sockets[0].getsockname()[1])
                ready.set()
                await self._run_arm()

        self._loop.run_until_complete(main())

    def state(self) -> dict:
        with self.arm.lock:
            return {
                "joints": self.arm.sample()[1].tolist(),
                "moving": self.arm.goal is not None,
                "goals": self.arm.goals,
                "cancels": self.arm.cancels,
                "time_s": self.now_s(),
            }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=0)
    parser.add_argument("--joints", required=True, help="joint names, comma-separated, in the arm's order")
    parser.add_argument("--start", help="start joint angles, rad, comma-separated (default: zeros)")
    parser.add_argument("--speed-deg-s", type=float, default=60.0)
    parser.add_argument("--cancel", choices=["hold", "ignore"], default="hold")
    parser.add_argument("--mode", choices=["rosbridge", "nonsense"], default="rosbridge")
    parser.add_argument(
        "--goals-block",
        action="store_true",
        help="as rosbridge with send_action_goals_in_new_thread:=false: a goal holds the message queue",
    )
    parser.add_argument("--action", default="/joint_trajectory_controller/follow_joint_trajectory")
    parser.add_argument(
        "--tf-model", help="publish /tf base_link -> tool0 by this UR model's kinematics (e.g. UR10)"
    )
    parser.add_argument(
        "--tf-offset-mm", type=float, default=0.0, help="... with the tool frame off by this along its x (mm)"
    )
    args = parser.parse_args()
    names = tuple(args.joints.split(","))
    start = np.zeros(len(names)) if not args.start else np.array([float(v) for v in args.start.split(",")])
    arm = FakeArm(names, start, np.radians(args.speed_deg_s))
    tf = None
    if args.tf_model:
        from spacecal.models.kinematics import forward_kinematics
        from spacecal.models.robot_kinds import robot_kind

        model = robot_kind(args.tf_model).model()
        offset = make_transform(np.eye(3), [args.tf_offset_mm, 0.0, 0.0])
        tf = ("base_link", "tool0", lambda q: forward_kinematics(model, q) @ offset)
    bridge = FakeRosbridge(
        arm, action=args.action, cancel=args.cancel, mode=args.mode, tf=tf, goals_block=args.goals_block
    )
    ready, bound = threading.Event(), list[int]()
    threading.Thread(target=bridge.serve, args=(args.host, args.port, ready, bound), daemon=True).start()
    if not ready.wait(10):
        sys.exit("the fake rosbridge did not start")
    stop = threading.Event()
    control = listen(args.host, 0)

    def serve_control() -> None:
        for connection in accept_connections(control, stop):
            with connection, connection.makefile("rw") as stream:
                for line in stream:
                    reply = json.dumps(bridge.state()) if line.strip() == "state" else "ERROR"
                    stream.write(reply + "\n")
                    stream.flush()

    threading.Thread(target=serve_control, daemon=True).start()
    info = {"host": args.host, "port": bound[0], "control_port": control.getsockname()[1]}
    print("READY " + json.dumps(info), flush=True)
    with contextlib.suppress(KeyboardInterrupt):
        sys.stdin.read()  # dies with its parent
    stop.set()


def arm_state(host: str, control_port: int) -> dict:
    """The fake arm's state from its control port (the tests' independent look at the arm)."""
    with socket.create_connection((host, control_port), timeout=5) as sock:
        stream = sock.makefile("rw")
        stream.write("state\n")
        stream.flush()
        return json.loads(stream.readline())


if __name__ == "__main__":
    main()
