"""Universal Robots arms over RTDE through ``ur-rtde`` (extra ``ur``, pinned to 1.6.5).

* State: ``RTDEReceiveInterface`` with a short explicit recipe (the default one is about
  1.2 kB per packet, and the controller drops clients that do not drain it). The pose comes
  in metres with a rotation vector and is converted to mm here, at the boundary.
* Motion: ``RTDEControlInterface`` (it uploads its URScript and talks to it through
  registers): ``moveJ``, ``moveL`` (optionally asynchronous), ``stopL``.
* Faults: protective and emergency stops from ``safety_status_bits``; a lost connection
  (``isConnected()`` turns false, but the getters keep returning the last values forever) and
  a controller timestamp that stops advancing are device errors.
* The client constructor returns normally after about 2.5 s with ``isConnected() == False``
  when nothing answers, and ``disconnect()`` sleeps 500 ms per interface.
"""

from __future__ import annotations

import time

import numpy as np

from spacecal.adapters import require
from spacecal.core.errors import DeviceError
from spacecal.core.ports import SAFETY_EMERGENCY_STOP, SAFETY_NORMAL, SAFETY_PROTECTIVE_STOP, RobotState
from spacecal.core.units import metres_to_mm, mm_to_metres
from spacecal.geometry.rotations import rotation_angle
from spacecal.geometry.transforms import make_transform, matrix_to_rotvec, rotvec_to_matrix

RECEIVE_VARIABLES = ["timestamp", "actual_q", "actual_qd", "actual_TCP_pose", "safety_status_bits"]
PROTECTIVE_STOP_BITS = 1 << 2
EMERGENCY_STOP_BITS = (1 << 5) | (1 << 6) | (1 << 7)
#: A move counts as finished within these of its target, with the joints at rest.
ARRIVAL_MM, ARRIVAL_RAD, REST_RAD_S = 0.05, 1e-4, 1e-3


def pose_to_ur(base_from_tcp) -> list[float]:
    """Our 4x4 pose (mm) -> UR ``[x, y, z, rx, ry, rz]`` (m, rotation vector)."""
    pose = np.asarray(base_from_tcp, dtype=float)
    return [*mm_to_metres(pose[:3, 3]).tolist(), *matrix_to_rotvec(pose[:3, :3]).tolist()]


def pose_from_ur(ur_pose) -> np.ndarray:
    """UR ``[x, y, z, rx, ry, rz]`` (m, rotation vector) -> our 4x4 pose (mm)."""
    values = np.asarray(ur_pose, dtype=float)
    return make_transform(rotvec_to_matrix(values[3:6]), metres_to_mm(values[:3]))


class URRobot:
    """A UR arm behind the Robot protocol.

    Parameters
    ----------
    host : str
    control : bool
        Connect the control interface too (not needed to read states, e.g. in a dry run).
    stale_after_s : float
        A controller timestamp that does not advance for this long (wall time) is stale.
    """

    def __init__(self, host: str, control: bool = True, stale_after_s: float = 0.5):
        rtde_receive = require("rtde_receive", "ur")
        self.host = host
        self.stale_after_s = stale_after_s
        self._receive = rtde_receive.RTDEReceiveInterface(host, -1.0, RECEIVE_VARIABLES)
        if not self._receive.isConnected():
            raise DeviceError(f"no UR controller answers RTDE on {host}:30004")
        self._control = None
        if control:
            rtde_control = require("rtde_control", "ur")
            self._control = rtde_control.RTDEControlInterface(host)
            if not self._control.isConnected():
                raise DeviceError(f"the UR control interface on {host} did not connect")
        self._target: np.ndarray | None = None
        self._last_timestamp: float | None = None
        self._last_change = time.monotonic()

    def state(self) -> RobotState:
        if not self._receive.isConnected():
            raise DeviceError(f"lost the RTDE connection to {self.host}")
        timestamp = float(self._receive.getTimestamp())
        now = time.monotonic()
        if timestamp != self._last_timestamp:
            self._last_timestamp, self._last_change = timestamp, now
        elif now - self._last_change > self.stale_after_s:
            raise DeviceError(
                f"UR state is stale: its timestamp has not advanced for {now - self._last_change:.1f} s"
            )
        bits = int(self._receive.getSafetyStatusBits())
        safety = (
            SAFETY_EMERGENCY_STOP
            if bits & EMERGENCY_STOP_BITS
            else SAFETY_PROTECTIVE_STOP
            if bits & PROTECTIVE_STOP_BITS
            else SAFETY_NORMAL
        )
        pose = pose_from_ur(self._receive.getActualTCPPose())
        speeds = np.asarray(self._receive.getActualQd(), dtype=float)
        moving = False
        if self._target is not None:
            arrived = (
                np.linalg.norm(pose[:3, 3] - self._target[:3, 3]) < ARRIVAL_MM
                and rotation_angle(pose[:3, :3] @ self._target[:3, :3].T) < ARRIVAL_RAD
                and np.max(np.abs(speeds)) < REST_RAD_S
            )
            moving = not arrived and safety == SAFETY_NORMAL
            if not moving:
                self._target = None
        return RobotState(
            timestamp, np.asarray(self._receive.getActualQ(), dtype=float), pose, safety, moving
        )

    def _require_control(self):
        if self._control is None:
            raise DeviceError("this UR connection was opened read-only")
        if not self._control.isConnected():
            raise DeviceError(f"lost the UR control connection to {self.host}")
        return self._control

    def move_joints(self, joints_rad, speed_rad_s: float, accel_rad_s2: float) -> None:
        if not self._require_control().moveJ([float(v) for v in joints_rad], speed_rad_s, accel_rad_s2):
            raise DeviceError("the UR controller refused or aborted moveJ")

    def move_linear(
        self, base_from_tcp, speed_mm_s: float, accel_mm_s2: float, asynchronous: bool = False
    ) -> None:
        control = self._require_control()
        target = np.asarray(base_from_tcp, dtype=float)
        if not control.moveL(
            pose_to_ur(target),
            float(mm_to_metres(speed_mm_s)),
            float(mm_to_metres(accel_mm_s2)),
            asynchronous,
        ):
            raise DeviceError("the UR controller refused or aborted moveL")
        self._target = target if asynchronous else None

    def stop(self) -> None:
        self._target = None
        if self._control is not None and self._control.isConnected():
            self._control.stopL(1.0)

    def close(self) -> None:
        if self._control is not None:
            self._control.stopScript()
            self._control.disconnect()
        self._receive.disconnect()
