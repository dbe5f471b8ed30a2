"""A ROS 2 arm through rosbridge with ``roslibpy`` (extra ``ros2``): ``ros2://HOST[:PORT]``.

* State: ``sensor_msgs/msg/JointState`` on ``/joint_states`` (``topic=``), the joints taken
  by name in the model's order (``joints=`` lists the names, in the model's order; a UR model
  defaults to ur_robot_driver's names). A message without every one of those names is not
  the arm's (a gripper's); the first message must name them all, or the URL is refused in one
  line naming both lists. The TCP pose is the model's forward kinematics of the joints: a
  trajectory controller publishes no TCP pose of its own.
* Motion: one ``control_msgs/action/FollowJointTrajectory`` goal per move, to
  ``/joint_trajectory_controller/follow_joint_trajectory`` (``action=``): a joint move is a
  trapezoid on its largest joint distance, a linear move the joints along the straight TCP
  path, both sampled every :data:`POINT_PERIOD_S` with positions and velocities.
* STOP: ``cancel_action_goal`` first. ros2_control's joint_trajectory_controller holds the
  current position when its goal is cancelled, so on it the cancel alone stills the arm. When
  the arm is not still within :data:`CANCEL_STILL_S` of the cancel (an action server that
  rejects cancels, a rosbridge whose goals block its message queue), a hold goal follows: one
  trajectory point at the current joints, which preempts the running goal on every
  FollowJointTrajectory server. Which of the two stilled it is kept in
  :attr:`Ros2Robot.stopped_by`.
* Deadlines: connecting (a probe of the server with spacecal's own socket, then roslibpy's
  connection), every move (its duration and a margin), the goal's first sign of life, the
  stop. A connection that drops, or joint states that stop coming for :data:`STALE_AFTER_S`,
  ends a move at once with one line; roslibpy's reconnecting is switched off then, so nothing
  sent before the loss is ever sent again after it.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import parse_qsl

import numpy as np

from spacecal.adapters import DeviceAddress, DeviceOptions, require
from spacecal.adapters.rosbridge_probe import probe_rosbridge
from spacecal.core.errors import DeviceError, InvalidInputError
from spacecal.core.ports import (
    FINDING_OK,
    FINDING_PROBLEM,
    FINDING_WARNING,
    DeviceFinding,
    DeviceIdentity,
    RobotState,
)
from spacecal.core.text import sanitize_for_terminal
from spacecal.core.units import metres_to_mm
from spacecal.geometry.rotations import rotation_angle
from spacecal.geometry.transforms import make_transform, quaternion_wxyz_to_matrix, rotvec_to_matrix
from spacecal.io.ros_common import UR_JOINT_NAMES
from spacecal.models.kinematics import RobotModel, forward_kinematics
from spacecal.models.robot_kinds import robot_kind, ur_kind_names
from spacecal.planning.motion import (
    MotionLimits,
    time_move,
    track_path,
    trapezoid_duration,
    trapezoid_progress,
)

DEFAULT_ACTION = "/joint_trajectory_controller/follow_joint_trajectory"
DEFAULT_TOPIC = "/joint_states"
ACTION_TYPE = "control_msgs/action/FollowJointTrajectory"
JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
#: Joints of a RobotState (spacecal.core.ports): the arms spacecal can run.
ROBOT_STATE_JOINTS = 6
#: The query fields a ros2:// URL takes.
QUERY_FIELDS = ("joints", "model", "urdf", "base", "tool", "tcp", "action", "topic", "tf")
TF_TOPICS, TF_TYPE = ("/tf", "/tf_static"), "tf2_msgs/msg/TFMessage"
#: The model and /tf agree when the tool frame is within these of each other (mm, rad): a URDF
#: with a UR's calibrated kinematics differs from the nominal model by 1-2 mm at the flange.
TF_AGREE_MM, TF_AGREE_RAD = 1.0, 1e-3
#: How long the read-only check waits for the /tf chain, s.
TF_WAIT_S = 1.0
#: Deadline of the first look (WebSocket upgrade and a first joint state), s.
PROBE_DEADLINE_S = 3.0
#: Deadline of roslibpy's connection and of its first joint state, s.
CONNECT_DEADLINE_S = 3.0
#: Deadline of closing the connection (the WebSocket closing handshake), s.
CLOSE_DEADLINE_S = 1.0
#: Joint states older than this (wall time, s) are stale: the arm's broadcaster publishes at
#: 100-500 Hz, and a loaded computer has been seen to go 0.1 s without a message.
STALE_AFTER_S = 0.5
#: A goal that neither reports feedback, nor ends, nor moves the arm within this is taken as
#: not taken (rejected, or no action server of that name), s.
GOAL_TAKEN_WITHIN_S = 1.5
#: Time a move may take beyond its planned duration, as a fraction of it and a fixed margin.
MOVE_MARGIN_FRACTION, MOVE_MARGIN_S = 0.5, 2.0
#: Trajectory points are this far apart in time, s.
POINT_PERIOD_S = 0.05
#: After the cancel, the arm must be still within this or a hold goal follows, s.
CANCEL_STILL_S = 0.3
#: After a hold goal, the arm must be still within this, s.
HOLD_STILL_S = 0.7
#: "Still": no joint moved more than this (rad) over :data:`STILL_WINDOW_S`.
STILL_RAD, STILL_WINDOW_S = 2e-4, 0.06
#: The hold goal's one point is due this long after it is sent, s (ros2_control rejects a point
#: at zero time when the arm moves).
HOLD_AFTER_S = 0.05
#: A move ends within these of its target: the controller's own goal tolerance decides success,
#: this checks that the joint states agree (rad).
ARRIVAL_RAD = 2e-3
#: goal states (action_msgs/msg/GoalStatus)
STATUS_NAMES = {
    0: "UNKNOWN",
    1: "ACCEPTED",
    2: "EXECUTING",
    3: "CANCELING",
    4: "SUCCEEDED",
    5: "CANCELED",
    6: "ABORTED",
}
STATUS_SUCCEEDED = 4
#: The read-only check counts joint states over this, s; fewer than MIN_STATE_HZ is a problem.
PREFLIGHT_WINDOW_S, MIN_STATE_HZ = 0.5, 20.0
#: States kept between two drains (a minute at 500 Hz).
STREAM_CAPACITY = 30_000


#: Whether Twisted's logging was begun by this module (once per process).
_LOGGING_BEGUN = False


def _quiet_client_logs() -> None:
    """Keep roslibpy's and Twisted's own log records (tracebacks of a send racing a closing
    connection, a message roslibpy could not parse) off the terminal: what they mean for a run
    reaches the user as this adapter's one-line errors."""
    for name in ("roslibpy", "twisted"):
        logger = logging.getLogger(name)
        logger.addHandler(logging.NullHandler())
        logger.propagate = False
    # Twisted prints what it logs before its logging begins to stderr; send it to the logger
    from twisted.logger import STDLibLogObserver, globalLogBeginner

    global _LOGGING_BEGUN
    if not _LOGGING_BEGUN:
        _LOGGING_BEGUN = True
        with contextlib.suppress(Exception):
            observer: Any = STDLibLogObserver(name="twisted")
            globalLogBeginner.beginLoggingTo([observer], redirectStandardIO=False)


def _stop_reconnecting(ros) -> None:
    """Switch off roslibpy's reconnecting (Twisted's ``ReconnectingClientFactory.stopTrying``),
    on the reactor's thread, where the factory's state lives; from any thread."""
    with contextlib.suppress(Exception):
        from twisted.internet import reactor

        factory = ros.factory
        factory.continueTrying = False  # read by the factory before it schedules a retry
        reactor.callFromThread(factory.stopTrying)


def parse_query(query: str) -> dict[str, str]:
    """The fields of a ros2:// URL's query; one line for a field it does not take."""
    fields = dict(parse_qsl(query, keep_blank_values=True))
    unknown = sorted(set(fields) - set(QUERY_FIELDS))
    if unknown:
        raise InvalidInputError(
            f"ros2:// takes the query fields {', '.join(QUERY_FIELDS)}; not {', '.join(unknown)}"
        )
    return fields


def model_of(fields: dict[str, str], robot_model: str | None) -> RobotModel:
    """The arm's model: the robot kind of ``model=`` (else ``--robot-model``), or the chain
    ``base=`` to ``tool=`` of the URDF ``urdf=PATH`` (its name ``model=`` if given); with the
    URL's ``tcp=``.

    Raises
    ------
    InvalidInputError
        No model named; an unknown kind; a URDF without both links, or one
        :func:`spacecal.models.urdf.robot_model_from_urdf` refuses; an arm of other than
        :data:`ROBOT_STATE_JOINTS` joints.
    """
    name = fields.get("model") or robot_model
    if "urdf" in fields:
        base, tool = fields.get("base"), fields.get("tool")
        if not base or not tool:
            raise InvalidInputError("urdf= needs the chain's links too: urdf=PATH&base=LINK&tool=LINK")
        from spacecal.models.urdf import robot_model_from_urdf

        model = robot_model_from_urdf(fields["urdf"], base, tool, name=name or None)
    elif name:
        model = robot_kind(name).model()
    else:
        raise InvalidInputError(
            "a ros2:// robot needs its model: add model=KIND (e.g. ros2://HOST?model=UR10) or "
            "urdf=PATH&base=LINK&tool=LINK to the URL"
        )
    if model.n_joints != ROBOT_STATE_JOINTS:
        raise InvalidInputError(
            f"the {model.name} has {model.n_joints} joints: spacecal's robot interface carries "
            f"{ROBOT_STATE_JOINTS}-joint states (RobotState), so it cannot run this arm yet"
        )
    return with_url_tcp(model, fields)


def urdf_joint_names(source: str, base: str, tool: str) -> tuple[str, ...]:
    """The names of the moving joints from ``base`` to ``tool`` of a URDF file, in chain order
    (the order of :func:`spacecal.models.urdf.robot_model_from_urdf`'s joints)."""
    import xml.etree.ElementTree as ElementTree

    try:
        root = ElementTree.parse(source).getroot()
    except (OSError, ElementTree.ParseError) as exc:
        raise InvalidInputError(f"urdf= {source!r} could not be read ({exc})") from None
    up: dict[str, tuple[str, str, str]] = {}
    for joint in root.iter("joint"):
        parent, child = joint.find("parent"), joint.find("child")
        if parent is not None and child is not None:
            up[str(child.get("link"))] = (
                str(parent.get("link")),
                str(joint.get("name")),
                str(joint.get("type")),
            )
    names: list[str] = []
    link = tool
    while link != base and link in up and len(names) < 256:
        link, joint_name, kind = up[link]
        if kind in ("revolute", "continuous"):
            names.append(str(joint_name))
    return tuple(reversed(names))


def with_url_tcp(model: RobotModel, fields: dict[str, str]) -> RobotModel:
    """``model`` with the TCP of ``tcp=X,Y,Z,RX,RY,RZ`` (mm, rotation vector in rad, in the
    flange frame); a trajectory controller knows no TCP, so without it the TCP is the model's."""
    if "tcp" not in fields:
        return model
    try:
        values = np.array([float(v) for v in fields["tcp"].split(",")])
    except ValueError:
        values = np.array([])
    if values.shape != (6,) or not np.all(np.isfinite(values)) or np.any(np.abs(values[:3]) > 2000):
        raise InvalidInputError(
            "tcp= takes X,Y,Z,RX,RY,RZ: mm within +-2000 and a rotation vector in rad (the TCP on the flange)"
        )
    return model.with_tcp(make_transform(rotvec_to_matrix(values[3:]), values[:3]))


def joint_names_of(fields: dict[str, str], model: RobotModel) -> tuple[str, ...]:
    """The joint names in the model's order: ``joints=`` of the URL, or a UR's driver names."""
    if "joints" in fields:
        names = tuple(n.strip() for n in fields["joints"].split(","))
    elif "urdf" in fields:
        names = urdf_joint_names(fields["urdf"], fields.get("base", ""), fields.get("tool", ""))
    elif model.name in ur_kind_names():
        names = UR_JOINT_NAMES
    else:
        raise InvalidInputError(f"name the {model.name}'s joints in the URL: joints=NAME1,NAME2,...")
    if len(names) != model.n_joints or len(set(names)) != len(names) or not all(names):
        raise InvalidInputError(
            f"joints= names {len(names)} joint(s); the {model.name} has {model.n_joints}, each named once"
        )
    return names


def _duration(seconds: float) -> dict[str, int]:
    """builtin_interfaces/Duration of ``seconds`` (to the nanosecond, never rounded up to a
    nanosecond field of 1e9)."""
    sec, nanosec = divmod(int(round(seconds * 1e9)), 1_000_000_000)
    return {"sec": sec, "nanosec": nanosec}


def joint_trajectory(
    names: tuple[str, ...], times_s: np.ndarray, positions: np.ndarray, velocities: np.ndarray | None = None
) -> dict:
    """A trajectory_msgs/JointTrajectory of points at ``times_s`` (P,) from its start, ``positions``
    (P, N) rad and ``velocities`` (P, N) rad/s."""
    points = []
    for k, t in enumerate(times_s):
        point = {"positions": [float(v) for v in positions[k]], "time_from_start": _duration(float(t))}
        if velocities is not None:
            point["velocities"] = [float(v) for v in velocities[k]]
        points.append(point)
    return {"joint_names": list(names), "points": points}


def joint_move_points(start, target, speed_rad_s: float, accel_rad_s2: float):
    """Times (P,), positions (P, N) and velocities (P, N) of a rest-to-rest trapezoid on the
    largest joint distance, every :data:`POINT_PERIOD_S` (the first point after the start)."""
    start, target = np.asarray(start, dtype=float), np.asarray(target, dtype=float)
    duration, accel_time = trapezoid_duration(
        float(np.max(np.abs(target - start))), speed_rad_s, accel_rad_s2
    )
    duration = max(duration, POINT_PERIOD_S)
    steps = max(1, int(np.ceil(duration / POINT_PERIOD_S)))
    times = np.linspace(duration / steps, duration, steps)
    s = trapezoid_progress(times, duration, accel_time)
    ds = np.gradient(
        trapezoid_progress(np.concatenate([[0.0], times]), duration, accel_time),
        np.concatenate([[0.0], times]),
    )[1:]
    ds[-1] = 0.0
    return times, start + s[:, None] * (target - start), ds[:, None] * (target - start)


@dataclass
class _Goal:
    """One trajectory goal as sent: what it is (in messages), where it ends (rad), the joints
    when it was sent, when (monotonic s), its deadline, and what came back."""

    what: str
    target: np.ndarray
    start: np.ndarray
    sent: float
    deadline: float = float("inf")
    id: str | None = None
    done: threading.Event = field(default_factory=threading.Event)
    fed: threading.Event = field(default_factory=threading.Event)
    outcome: Any = None
    failed: bool = False
    #: its end was judged (state() and the waiting move judge it once)
    checked: bool = False
    #: the stop cancelled or preempted it
    stopped: bool = False
    #: when it was reported done while the joint states were not yet at its end
    ended: float | None = None


def _status(outcome: Any) -> int | None:
    """The GoalStatus number of a roslibpy result (its enum, or the number rosbridge sent)."""
    status = (outcome or {}).get("status")
    return getattr(status, "value", status)


def _status_name(status: int | None) -> str:
    return "without a status" if status is None else STATUS_NAMES.get(status, str(status))


class Ros2Robot:
    """A ROS 2 arm behind the Robot protocol, through rosbridge.

    Parameters
    ----------
    host : str
    port : int
    model : RobotModel
        The arm's model; its TCP pose is computed with it.
    joint_names : tuple of str
        The names of the model's joints, in its order, as ``/joint_states`` names them.
    action, topic : str
        The FollowJointTrajectory action and the JointState topic.
    control : bool
        Allow motion now (else only after :meth:`connect_control`).
    limits : MotionLimits, optional
        The limits linear moves are timed with (their linear ones set per move).
    """

    def __init__(
        self,
        host: str,
        port: int,
        model: RobotModel,
        joint_names: tuple[str, ...],
        action: str = DEFAULT_ACTION,
        topic: str = DEFAULT_TOPIC,
        control: bool = False,
        limits: MotionLimits | None = None,
        tf_frames: tuple[str, str] | None = None,
    ):
        self.host, self.port, self.action, self.topic = host, port, action, topic
        #: (base frame, tool frame) of /tf to check the model against, or None
        self.tf_frames = tf_frames
        #: child frame -> (parent frame, parent_from_child (4, 4) mm), from /tf and /tf_static
        self._tf: dict[str, tuple[str, np.ndarray]] = {}
        self.nominal, self.kinematics = model, None
        self.joint_names = joint_names
        self.limits = limits or MotionLimits()
        self.name = f"rosbridge at ws://{host}:{port}"
        #: what stilled the arm at the last stop: "cancel", "hold", "arrived" (the move ended at
        #: its target before either took effect), or None (nothing did, or nothing had to)
        self.stopped_by: str | None = None
        self._control = control
        self._stopped = False
        self._lost: str | None = None
        self._lock = threading.Lock()
        self._latest: tuple[float, np.ndarray, float] | None = None  # (stamp s, joints, arrival)
        self._history: collections.deque = collections.deque(maxlen=64)  # (arrival, joints)
        self._stream: collections.deque[RobotState] = collections.deque(maxlen=STREAM_CAPACITY)
        self._skipped = self._received = 0
        self._goal: _Goal | None = None
        first = probe_rosbridge(host, port, topic, JOINT_STATE_TYPE, PROBE_DEADLINE_S)
        self._order = self._joint_order(first)
        roslibpy = require("roslibpy", "ros2")
        _quiet_client_logs()
        self._roslibpy = roslibpy
        self._ros = roslibpy.Ros(host, port)
        try:
            try:
                self._ros.run(timeout=CONNECT_DEADLINE_S)
            except Exception:  # roslibpy.core.RosTimeoutError
                raise DeviceError(
                    f"{self.name} did not accept roslibpy's connection within {CONNECT_DEADLINE_S:g} s"
                ) from None
            self._ros.on("close", self._connection_lost)
            self._topic = roslibpy.Topic(self._ros, topic, JOINT_STATE_TYPE, queue_length=1)
            self._topic.subscribe(self._joint_state)
            self._action = roslibpy.ActionClient(self._ros, action, ACTION_TYPE)
            self._tf_topics = []
            if tf_frames is not None:
                for name in TF_TOPICS:
                    tf_topic = roslibpy.Topic(self._ros, name, TF_TYPE)
                    tf_topic.subscribe(self._transforms)
                    self._tf_topics.append(tf_topic)
            deadline = time.monotonic() + CONNECT_DEADLINE_S
            while self._latest is None:
                if time.monotonic() > deadline:
                    raise DeviceError(f"{self.name} sent no joint state within {CONNECT_DEADLINE_S:g} s")
                time.sleep(0.01)
        except BaseException:
            self.close()
            raise

    # -- joint states ----------------------------------------------------------------------
    def _joint_order(self, message: dict) -> list[int]:
        names = [str(n) for n in message.get("name", [])]
        missing = [n for n in self.joint_names if n not in names]
        if missing:
            shown = sanitize_for_terminal(", ".join(names) or "none", 300)  # the driver's names
            raise DeviceError(
                f"{self.topic} names the joints {shown}, not "
                f"{', '.join(missing)} of the {self.nominal.name}: give joints=NAME1,... in the model's order"
            )
        return [names.index(n) for n in self.joint_names]

    def _joint_state(self, message: dict) -> None:
        """roslibpy's callback (its reactor thread): keep the newest state of the arm's joints."""
        arrival = time.monotonic()
        try:
            names = list(message["name"])
            positions = message["position"]
            joints = np.array([float(positions[names.index(n)]) for n in self.joint_names])
            stamp = message["header"]["stamp"]
            time_s = float(stamp["sec"]) + float(stamp["nanosec"]) * 1e-9
        except (KeyError, ValueError, TypeError, IndexError):
            self._skipped += 1  # another publisher's joints (a gripper), or not a JointState
            return
        if not np.all(np.isfinite(joints)):
            self._skipped += 1
            return
        with self._lock:
            self._received += 1
            self._latest = (time_s, joints, arrival)
            self._history.append((arrival, joints))
        with contextlib.suppress(DeviceError):
            self._stream.append(RobotState(time_s, joints, forward_kinematics(self.nominal, joints)))

    def _transforms(self, message: dict) -> None:
        """roslibpy's callback for /tf and /tf_static: keep each frame's newest transform."""
        for item in message.get("transforms", []) if isinstance(message, dict) else []:
            try:
                t, r = item["transform"]["translation"], item["transform"]["rotation"]
                rotation = quaternion_wxyz_to_matrix([r["w"], r["x"], r["y"], r["z"]])
                pose = make_transform(rotation, metres_to_mm(np.array([t["x"], t["y"], t["z"]], dtype=float)))
                parent, child = (
                    str(item["header"]["frame_id"]).lstrip("/"),
                    str(item["child_frame_id"]).lstrip("/"),
                )
            except (KeyError, TypeError, ValueError):
                continue
            if np.all(np.isfinite(pose)):
                self._tf[child] = (parent, pose)

    def tf_pose(self) -> np.ndarray | None:
        """``base_from_tool`` (4, 4), mm, of the ``tf=BASE,TOOL`` frames from /tf, or None when
        the chain between them is not (yet) known."""
        if self.tf_frames is None:
            return None
        base, frame = self.tf_frames
        pose = np.eye(4)
        for _ in range(64):  # a tf tree is a few dozen frames deep at most
            if frame == base:
                return pose
            if frame not in self._tf:
                return None
            parent, parent_from_frame = self._tf[frame]
            pose, frame = parent_from_frame @ pose, parent
        return None

    def _connection_lost(self, *_) -> None:
        """roslibpy's ``close`` event: the link is gone; never reconnect (a reconnected
        roslibpy sends what was queued while it was down)."""
        self._lost = self._lost or f"lost the connection to {self.name}"
        _stop_reconnecting(self._ros)

    def _fresh(self) -> tuple[float, np.ndarray]:
        """(stamp, joints) of the newest joint state, or a DeviceError when it is stale or lost."""
        if self._lost is not None:
            raise DeviceError(self._lost)
        with self._lock:
            latest = self._latest
        if latest is None:
            raise DeviceError(f"{self.name} sent no joint state")
        age = time.monotonic() - latest[2]
        if age > STALE_AFTER_S:
            self._lost = f"no joint state from {self.name} for {age:.1f} s: the connection is lost"
            self._connection_lost()
            raise DeviceError(self._lost)
        return latest[0], latest[1]

    def _still(self) -> bool:
        """No joint moved more than :data:`STILL_RAD` over the last :data:`STILL_WINDOW_S`."""
        with self._lock:
            history = list(self._history)
        if not history:
            return False
        newest = history[-1][0]
        if time.monotonic() - newest > STALE_AFTER_S:
            return False
        window = [q for t, q in history if t >= newest - STILL_WINDOW_S]
        older = [q for t, q in history if t < newest - STILL_WINDOW_S]
        if not older:
            return False
        reference = older[-1]
        return all(float(np.max(np.abs(q - reference))) < STILL_RAD for q in window)

    # -- Robot protocol ----------------------------------------------------------------------
    def state(self) -> RobotState:
        time_s, joints = self._fresh()
        goal = self._goal
        moving = goal is not None and self._check_goal(goal, joints)
        return RobotState(time_s, joints, forward_kinematics(self.nominal, joints), moving=moving)

    def drain_states(self) -> list[RobotState]:
        """Every joint state since the last call, oldest first."""
        states = []
        while self._stream:
            states.append(self._stream.popleft())
        return states

    def connect_control(self) -> None:
        """Allow motion (nothing is sent to the arm)."""
        self._control = True

    def _send(self, what: str, times, positions, velocities=None) -> _Goal:
        """Send one trajectory goal (``what`` names it in messages); the goal's record (its id,
        events, outcome, deadline)."""
        if self._lost is not None:
            raise DeviceError(self._lost)
        if not self._ros.is_connected:
            raise DeviceError(f"lost the connection to {self.name}")
        goal = _Goal(what, np.asarray(positions[-1], dtype=float), self._fresh()[1], time.monotonic())
        goal.deadline = goal.sent + float(times[-1]) * (1 + MOVE_MARGIN_FRACTION) + MOVE_MARGIN_S

        def finished(result) -> None:
            goal.outcome = result
            goal.done.set()

        def failed(result) -> None:
            goal.outcome, goal.failed = result, True
            goal.done.set()

        message = self._roslibpy.Goal(
            {"trajectory": joint_trajectory(self.joint_names, times, positions, velocities)}
        )
        goal.id = self._action.send_goal(message, finished, lambda _: goal.fed.set(), failed)
        self._goal = goal
        return goal

    def _require_motion(self) -> None:
        if not self._control:
            raise DeviceError(f"the robot at {self.name} was opened read-only")
        if self._stopped:
            raise DeviceError(f"the robot at {self.name} was stopped: it takes no further motion")

    def _check_goal(self, goal: _Goal, joints: np.ndarray) -> bool:
        """Whether ``goal`` is still running; a DeviceError (the arm stopped first) when it was
        not taken within :data:`GOAL_TAKEN_WITHIN_S`, overran its deadline, or ended other than
        SUCCEEDED, or its end is not where the joint states are."""
        what, now = goal.what, time.monotonic()
        if goal.checked:
            return False
        if goal.stopped:  # the stop's: cancelled, or preempted by the hold goal
            return not goal.done.is_set()
        if not goal.done.is_set():
            taken = goal.fed.is_set() or float(np.max(np.abs(joints - goal.start))) > STILL_RAD
            if not taken and now - goal.sent > GOAL_TAKEN_WITHIN_S:
                goal.checked = True
                self.stop()
                raise DeviceError(
                    f"{self.action} did not take the {what} within {GOAL_TAKEN_WITHIN_S:g} s "
                    f"(no such action server on {self.name}, or it rejected the goal)"
                )
            if now > goal.deadline:
                goal.checked = True
                self.stop()
                raise DeviceError(f"the {what} did not end within {goal.deadline - goal.sent:.1f} s; stopped")
            return True
        outcome = goal.outcome or {}
        status = _status(outcome)
        values = outcome.get("values")
        code = values.get("error_code", 0) if isinstance(values, dict) else None
        if goal.failed or status != STATUS_SUCCEEDED or code != 0:
            goal.checked = True
            text = values.get("error_string", "") if isinstance(values, dict) else values
            text = sanitize_for_terminal(text, 120) if text else ""  # the controller's words
            raise DeviceError(
                f"{self.action} ended the {what} {_status_name(status)}"
                + (f" (error code {sanitize_for_terminal(code, 20)})" if code else "")
                + (f": {text}" if text else "")
            )
        # the controller's goal tolerance decides success; its joint states must agree
        if float(np.max(np.abs(joints - goal.target))) > ARRIVAL_RAD:
            goal.ended = now if goal.ended is None else goal.ended
            if now - goal.ended > STALE_AFTER_S:
                goal.checked = True
                raise DeviceError(
                    f"{self.action} reported the {what} done, but the joints are not at its end"
                )
            return True
        goal.checked = True
        return False

    def _wait(self, goal: _Goal) -> None:
        """Wait for a goal to end (:meth:`_check_goal`); a lost link ends the wait at once."""
        while True:
            try:
                _, joints = self._fresh()
            except DeviceError:
                self._give_up()
                raise
            if goal.stopped:
                goal.done.wait(CANCEL_STILL_S + HOLD_STILL_S)
                status = _status(goal.outcome)
                ended = "no result from the controller" if status is None else _status_name(status)
                raise DeviceError(f"the {goal.what} was stopped ({ended})")
            if not self._check_goal(goal, joints):
                return
            goal.done.wait(0.02)

    def move_joints(self, joints_rad, speed_rad_s: float, accel_rad_s2: float) -> None:
        self._require_motion()
        target = np.asarray(joints_rad, dtype=float)
        if target.shape != (len(self.joint_names),) or not np.all(np.isfinite(target)):
            raise InvalidInputError(
                f"a joint move of the {self.nominal.name} takes {len(self.joint_names)} angles"
            )
        _, here = self._fresh()
        times, positions, velocities = joint_move_points(here, target, speed_rad_s, accel_rad_s2)
        self._wait(self._send("joint move", times, positions, velocities))

    def move_linear(
        self, base_from_tcp, speed_mm_s: float, accel_mm_s2: float, asynchronous: bool = False
    ) -> None:
        self._require_motion()
        _, here = self._fresh()
        limits = MotionLimits(
            linear_speed_mm_s=speed_mm_s,
            linear_accel_mm_s2=accel_mm_s2,
            angular_speed_rad_s=self.limits.angular_speed_rad_s,
            angular_accel_rad_s2=self.limits.angular_accel_rad_s2,
            joint_speed_rad_s=self.limits.joint_speed_rad_s,
        )
        start = forward_kinematics(self.nominal, here)
        move, _ = time_move(
            self.nominal, "move", start, np.asarray(base_from_tcp, dtype=float), here, limits, 0.0
        )
        duration = max(float(move.duration_s), POINT_PERIOD_S)
        steps = max(1, int(np.ceil(duration / POINT_PERIOD_S)))
        times = np.linspace(duration / steps, duration, steps)
        positions = track_path(self.nominal, move.poses_at(np.minimum(times, move.duration_s)), here)
        goal = self._send("linear move", times, positions)
        if not asynchronous:
            self._wait(goal)

    def stop(self) -> None:
        """Cancel the goal; when the arm is not still soon after, hold it where it is (see the
        module's notes); no further motion is taken after it."""
        self._stopped = True
        goal = self._goal
        if goal is None or self._lost is not None or not self._ros.is_connected:
            return
        goal.stopped = True
        if goal.done.is_set() and self._still():
            return
        with contextlib.suppress(Exception):
            self._action.cancel_goal(goal.id)
        if self._settles(CANCEL_STILL_S):
            self.stopped_by = self._stilled_by(goal, "cancel")
            return
        try:
            _, here = self._fresh()
            hold = self._send("hold", np.array([HOLD_AFTER_S]), here[None], np.zeros((1, len(here))))
            hold.checked = True  # the stop's own: what it did is stopped_by
        except DeviceError:
            return  # the link is gone: nothing more can be sent
        self.stopped_by = self._stilled_by(goal, "hold") if self._settles(HOLD_STILL_S) else None

    @staticmethod
    def _stilled_by(goal: _Goal, how: str) -> str:
        """``how``, unless the goal ran to its end meanwhile (SUCCEEDED): then ``arrived``."""
        return "arrived" if goal.done.is_set() and _status(goal.outcome) == STATUS_SUCCEEDED else how

    def _settles(self, within_s: float) -> bool:
        deadline = time.monotonic() + within_s
        while time.monotonic() < deadline:
            if self._still():
                return True
            time.sleep(0.01)
        return False

    def _give_up(self) -> None:
        """The link is lost in the middle of a move: stop trying; nothing queued is sent later."""
        self._stopped = True
        self._connection_lost()

    # -- read-only -----------------------------------------------------------------------
    def controller_model(self) -> tuple[RobotModel, str]:
        return self.nominal, f"the nominal {self.nominal.name} model named for {self.name}"

    def identity(self) -> DeviceIdentity:
        return DeviceIdentity(model=self.nominal.name)

    def preflight(self) -> list[DeviceFinding]:
        """Read-only: how often joint states come (over :data:`PREFLIGHT_WINDOW_S`), whether
        their stamps advance, and what moves the arm. Nothing is sent to the action server."""
        findings = []
        first_stamp, _ = self._fresh()
        before = self._received
        time.sleep(PREFLIGHT_WINDOW_S)
        stamp, _ = self._fresh()
        rate = (self._received - before) / PREFLIGHT_WINDOW_S
        joints = ", ".join(self.joint_names)
        if rate < MIN_STATE_HZ or stamp <= first_stamp:
            findings.append(
                DeviceFinding(
                    FINDING_PROBLEM,
                    "joint states",
                    f"{self.topic} came at {rate:.0f} Hz with stamps that "
                    f"{'advance' if stamp > first_stamp else 'stand still'}: a run needs at least "
                    f"{MIN_STATE_HZ:g} Hz of fresh states (the joint_state_broadcaster's publish_rate)",
                )
            )
        else:
            text = f"{self.topic} at {rate:.0f} Hz ({joints})"
            findings.append(DeviceFinding(FINDING_OK, "joint states", text))
        if self._skipped:
            findings.append(
                DeviceFinding(
                    FINDING_WARNING,
                    "joint states",
                    f"{self._skipped} message(s) on {self.topic} lacked the arm's joints and were skipped",
                )
            )
        findings.append(
            DeviceFinding(
                FINDING_OK,
                "motion",
                f"through {self.action} (not checked read-only: a goal not taken within "
                f"{GOAL_TAKEN_WITHIN_S:g} s ends the run)",
            )
        )
        findings.append(DeviceFinding(FINDING_OK, "kinematics", f"the nominal {self.nominal.name} model"))
        if self.tf_frames is not None:
            findings.append(self._tf_finding())
        return findings

    def _tf_finding(self) -> DeviceFinding:
        """How far the model's TCP is from the ``tf=BASE,TOOL`` chain's tool frame, at rest."""
        base, tool = self.tf_frames or ("", "")
        deadline = time.monotonic() + TF_WAIT_S
        while (pose := self.tf_pose()) is None and time.monotonic() < deadline:
            time.sleep(0.02)
        if pose is None:
            return DeviceFinding(
                FINDING_WARNING,
                "tf",
                f"no /tf chain from {base} to {tool} within {TF_WAIT_S:g} s: not compared",
            )
        model_pose = forward_kinematics(self.nominal, self._fresh()[1])
        apart_mm = float(np.linalg.norm(model_pose[:3, 3] - pose[:3, 3]))
        apart_rad = float(rotation_angle(model_pose[:3, :3].T @ pose[:3, :3]))
        text = (
            f"the {self.nominal.name} model puts the TCP {apart_mm:.2f} mm and "
            f"{np.degrees(apart_rad):.3f} deg from {tool} in {base} on /tf"
        )
        if apart_mm <= TF_AGREE_MM and apart_rad <= TF_AGREE_RAD:
            return DeviceFinding(FINDING_OK, "tf", text)
        return DeviceFinding(
            FINDING_WARNING,
            "tf",
            text + ": the driver's description (perhaps its calibrated kinematics) is not the model, or "
            "tcp= is not the tool frame; spacecal computes with the model",
        )

    def close(self) -> None:
        """Close the connection, within :data:`CLOSE_DEADLINE_S`; never raises.

        Nothing more is sent but the WebSocket's close (rosbridge ends a closed client's
        subscriptions itself): a send queued behind the close would reach a closed protocol."""
        ros = getattr(self, "_ros", None)
        if ros is None:
            return
        closed = threading.Event()
        _stop_reconnecting(ros)
        with contextlib.suppress(Exception):
            ros.factory.remove_all_listeners("ready")  # nothing queued is sent on a later connection
            ros.on("close", lambda *_: closed.set())
        with contextlib.suppress(Exception):
            if ros.is_connected and self._lost is None:
                ros.close(timeout=CLOSE_DEADLINE_S)
                closed.wait(CLOSE_DEADLINE_S)
        self._lost = self._lost or f"the connection to {self.name} was closed"


def open_device(address: DeviceAddress, options: DeviceOptions) -> Ros2Robot:
    """The ``ros2://`` row of the URL table (:data:`spacecal.adapters.DEVICE_SCHEMES`)."""
    fields = parse_query(address.query)
    model = model_of(fields, options.robot_model)
    return Ros2Robot(
        address.host,
        int(address.port or 9090),
        model,
        joint_names_of(fields, model),
        action=fields.get("action") or DEFAULT_ACTION,
        topic=fields.get("topic") or DEFAULT_TOPIC,
        control=options.control,
        limits=options.limits,
        tf_frames=tf_frames_of(fields),
    )


def tf_frames_of(fields: dict[str, str]) -> tuple[str, str] | None:
    """``tf=BASE,TOOL``: the /tf frames the model's base and TCP are checked against."""
    if "tf" not in fields:
        return None
    frames = tuple(f.strip().lstrip("/") for f in fields["tf"].split(","))
    if len(frames) != 2 or not all(frames) or frames[0] == frames[1]:
        raise InvalidInputError("tf= takes two /tf frames: BASE,TOOL (e.g. tf=base_link,tool0)")
    return frames[0], frames[1]
