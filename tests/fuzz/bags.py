"""Small ROS bags for the hostile-file tests: valid ones, and ones whose messages lie.

A bag holds ``/tf`` (``base -> flange``, moving), ``/tf_static`` (``flange -> tcp``) and a
``PoseStamped`` marker stream on ``/tracker/marker`` (in ``tracker``), ``count`` messages each at
20 Hz; ``tweak(kind, k, values)`` may change message ``k``'s translation (m), quaternion
(x, y, z, w), stamp (ns) and frame before it is written, so that one message can be made NaN,
1e300, non-unit, out of order or hostile by name.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

EPOCH_NS = 1_700_000_000 * 1_000_000_000
PERIOD_NS = 50_000_000

Tweak = Callable[[str, int, dict], None]


def _unit_xyzw(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    return q if q[3] >= 0 else -q


def write_small_bag(
    path: Path, storage: str = "sqlite3", count: int = 30, seed: int = 0, tweak: Tweak | None = None
) -> Path:
    """Write a small ROS 2 bag (``storage`` ``"sqlite3"`` or ``"mcap"``) into the folder ``path``."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types = store.types
    rng = np.random.default_rng(seed)

    def header(stamp_ns: int, frame: str):
        time = types["builtin_interfaces/msg/Time"](sec=int(stamp_ns // 10**9), nanosec=int(stamp_ns % 10**9))
        return types["std_msgs/msg/Header"](stamp=time, frame_id=frame)

    def tf(values: dict):
        xyz, q = values["xyz"], values["q"]
        transform = types["geometry_msgs/msg/Transform"](
            translation=types["geometry_msgs/msg/Vector3"](x=xyz[0], y=xyz[1], z=xyz[2]),
            rotation=types["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        )
        stamped = types["geometry_msgs/msg/TransformStamped"](
            header=header(values["stamp"], values["parent"]),
            child_frame_id=values["child"],
            transform=transform,
        )
        return types["tf2_msgs/msg/TFMessage"](transforms=[stamped])

    def pose(values: dict):
        xyz, q = values["xyz"], values["q"]
        message = types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](x=xyz[0], y=xyz[1], z=xyz[2]),
            orientation=types["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        )
        return types["geometry_msgs/msg/PoseStamped"](
            header=header(values["stamp"], values["parent"]), pose=message
        )

    messages = []
    static = {"xyz": [0.0, 0.0, 0.1], "q": [0.0, 0.0, 0.0, 1.0], "stamp": EPOCH_NS, "parent": "flange"}
    messages.append(("/tf_static", "tf2_msgs/msg/TFMessage", EPOCH_NS, tf({**static, "child": "tcp"})))
    for k in range(count):
        stamp = EPOCH_NS + k * PERIOD_NS
        robot = {
            "xyz": list(rng.uniform(-0.5, 0.5, 3)),
            "q": list(_unit_xyzw(rng)),
            "stamp": stamp,
            "parent": "base",
            "child": "flange",
        }
        marker = {
            "xyz": list(rng.uniform(-0.3, 0.3, 2)) + [float(rng.uniform(-1.5, -1.0))],
            "q": list(_unit_xyzw(rng)),
            "stamp": stamp + 7_000_000,
            "parent": "tracker",
        }
        if tweak is not None:
            tweak("robot", k, robot)
            tweak("marker", k, marker)
        messages.append(("/tf", "tf2_msgs/msg/TFMessage", stamp, tf(robot)))
        messages.append(("/tracker/marker", "geometry_msgs/msg/PoseStamped", stamp + 7_000_000, pose(marker)))
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        connections = {}
        for topic, msgtype, ns, message in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], int(ns), store.serialize_cdr(message, msgtype))
    return path


def storage_file(folder: Path) -> Path:
    """The one ``.db3`` or ``.mcap`` file of a ROS 2 bag folder."""
    (found,) = [p for p in folder.iterdir() if p.suffix in (".db3", ".mcap")]
    return found
