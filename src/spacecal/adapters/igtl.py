"""OpenIGTLink (PLUS Server, 3D Slicer) through ``pyigtl`` (extra ``igtl``).

PLUS names transforms ``<From>To<To>``: ``MarkerToTracker`` maps marker coordinates into
the tracker frame, i.e. our ``tracker_from_marker``; ``BaseToTracker`` is our
``tracker_from_base``. Header-version-2 messages may carry ``TransformStatus`` metadata
(``OK``/``INVALID``), which we map to the frame status. pyigtl keeps only the newest message
per device name, so frames are read by timestamp, never counted.
"""

from __future__ import annotations

import time

import numpy as np

from spacecal.adapters import require
from spacecal.core.errors import DeviceError, InvalidInputError
from spacecal.core.ports import FRAME_MISSING, FRAME_OK, TrackerFrame
from spacecal.geometry.transforms import is_rigid_transform

#: Time the connection stays open after publishing, so the server reads the message.
PUBLISH_LINGER_S = 0.3

#: Time given to a server's backlog of old messages on connect before frames are read.
BACKLOG_DRAIN_S = 0.3


class IGTLTracker:
    """A tracker read from an OpenIGTLink TRANSFORM stream (Tracker protocol).

    Parameters
    ----------
    host, port : str, int
    device_name : str
        The stream to follow (PLUS naming), default ``MarkerToTracker``.
    connect_timeout_s : float
        How long to wait for the first message before giving up.
    """

    def __init__(
        self,
        host: str,
        port: int = 18944,
        device_name: str = "MarkerToTracker",
        connect_timeout_s: float = 5.0,
    ):
        pyigtl = require("pyigtl", "igtl")
        self.device_name = device_name
        self._client = pyigtl.OpenIGTLinkClient(host=host, port=port)
        self._last_timestamp = -np.inf
        self._frame_number = 0
        first = self._client.wait_for_message(device_name, timeout=connect_timeout_s)
        if first is None:
            self.close()
            raise DeviceError(
                f"no {device_name} message from igtl://{host}:{port} within {connect_timeout_s:.0f} s"
            )
        # A server may flush a backlog of old messages on connect: let it pass, keep the newest.
        time.sleep(BACKLOG_DRAIN_S)
        self._pending = self._client.wait_for_message(device_name, timeout=0.0) or first

    def next_frame(self, timeout_s: float) -> TrackerFrame:
        deadline = time.monotonic() + timeout_s
        repeated = False
        while True:
            message = self._pending or self._client.wait_for_message(
                self.device_name, timeout=max(deadline - time.monotonic(), 0.0)
            )
            self._pending = None
            if message is None:
                if repeated:
                    raise DeviceError(
                        f"{self.device_name} timestamps stopped advancing for {timeout_s:.1f} s: stale stream"
                    )
                raise DeviceError(
                    f"no {self.device_name} message for {timeout_s:.1f} s: stream stalled or lost"
                )
            if message.timestamp > self._last_timestamp:
                break
            repeated = True
        self._last_timestamp = message.timestamp
        self._frame_number += 1
        status = (getattr(message, "metadata", None) or {}).get("TransformStatus", "OK").upper()
        matrix = np.asarray(message.matrix, dtype=float)
        ok = status == "OK" and is_rigid_transform(matrix, atol=1e-4)
        return TrackerFrame(
            time_s=float(message.timestamp),
            frame_number=self._frame_number,
            status=FRAME_OK if ok else FRAME_MISSING,
            tracker_from_marker=matrix if ok else None,
        )

    def close(self) -> None:
        self._client.stop()


def publish_transform(host: str, port: int, name: str, a_from_b, timestamp: float | None = None) -> None:
    """Send one TRANSFORM (e.g. the calibration as ``BaseToTracker``) to an OpenIGTLink server.

    Parameters
    ----------
    name : str
        PLUS-style ``<From>To<To>`` name; ``BaseToTracker`` carries ``tracker_from_base``.
    a_from_b : array_like, shape (4, 4), mm
    """
    pyigtl = require("pyigtl", "igtl")
    matrix = np.asarray(a_from_b, dtype=float)
    if matrix.shape != (4, 4) or not is_rigid_transform(matrix):
        raise InvalidInputError(f"{name}: not a 4x4 rigid transform")
    client = pyigtl.OpenIGTLinkClient(host=host, port=port)
    try:
        deadline = time.monotonic() + 5.0
        while not client.is_connected():
            if time.monotonic() > deadline:
                raise DeviceError(f"could not connect to igtl://{host}:{port}")
            time.sleep(0.05)
        message = pyigtl.TransformMessage(
            matrix, timestamp=time.time() if timestamp is None else timestamp, device_name=name
        )
        if not client.send_message(message, wait=True):
            raise DeviceError(f"could not send {name} to igtl://{host}:{port}")
        # Servers stream to every client: closing at once, with their messages unread, resets the
        # connection and can drop ours before the server has read it.
        time.sleep(PUBLISH_LINGER_S)
    finally:
        client.stop()
