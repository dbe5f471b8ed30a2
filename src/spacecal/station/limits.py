"""The station's bounds: nothing a page, a script or a slow connection does grows without end.

* :class:`RateLimit`: how many of a thing (new calibrations) may be made in a window of time.
* :class:`HeaderDeadlineProtocol`: uvicorn's HTTP/1.1 protocol with a deadline on reading a
  request's headers. uvicorn closes an idle keep-alive connection after a few seconds, but a
  connection that sends part of a request and then nothing (a slow or half-open client) it keeps
  for as long as the client likes; hundreds of them fill the server.
* :data:`MAX_CONNECTIONS`: the connections served at once; beyond them uvicorn answers 503.

The confirmation tickets (:class:`spacecal.station.motions.Tickets`) and the live views'
sockets (closed at their run's end) are bounded where they live.
"""

from __future__ import annotations

import asyncio
import collections
import secrets
import threading
import time
from typing import Any

from uvicorn.protocols.http.h11_impl import H11Protocol

#: How long a client may take to send a request's headers, s (a browser sends them at once).
HEADER_READ_TIMEOUT_S = 10.0
#: Connections (pages, live views, idle keep-alives) the station serves at once.
MAX_CONNECTIONS = 200
#: Notes kept for pages (:class:`Notes`).
MAX_NOTES = 256


class RateLimit:
    """At most ``count`` events in any ``window_s`` seconds.

    Parameters
    ----------
    count : int
    window_s : float
    """

    def __init__(self, count: int, window_s: float):
        self.count = count
        self.window_s = window_s
        self._times: collections.deque[float] = collections.deque()
        self._lock = threading.Lock()

    def allow(self) -> bool:
        """True (and the event counted) when one more event fits in the window."""
        now = time.monotonic()
        with self._lock:
            while self._times and now - self._times[0] > self.window_s:
                self._times.popleft()
            if len(self._times) >= self.count:
                return False
            self._times.append(now)
            return True

    def wait_s(self) -> float:
        """How long until one more event fits, s."""
        with self._lock:
            if len(self._times) < self.count:
                return 0.0
            return max(0.0, self.window_s - (time.monotonic() - self._times[0]))


class HeaderDeadlineProtocol(H11Protocol):
    """uvicorn's h11 protocol, closing a connection whose next request's headers have not all
    arrived within :data:`HEADER_READ_TIMEOUT_S` of the connection or of the last response.

    The deadline is armed whenever the connection waits for a request and disarmed when one
    begins (and when the connection becomes a websocket, which then has its own pings).
    """

    header_timeout_s = HEADER_READ_TIMEOUT_S

    def __init__(self, *args: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self._header_deadline: asyncio.TimerHandle | None = None
        self._waiting_since_cycle: Any = None

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._arm_header_deadline()

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm_header_deadline()
        super().connection_lost(exc)

    def on_response_complete(self) -> None:
        super().on_response_complete()
        if not self.transport.is_closing() and (self.cycle is None or self.cycle.response_complete):
            self._arm_header_deadline()

    def handle_websocket_upgrade(self, event: Any) -> None:
        self._disarm_header_deadline()
        super().handle_websocket_upgrade(event)

    def data_received(self, data: bytes) -> None:
        super().data_received(data)
        if self.cycle is not None and self.cycle is not self._waiting_since_cycle:
            self._disarm_header_deadline()  # a request began: its headers are in

    def _arm_header_deadline(self) -> None:
        self._disarm_header_deadline()
        self._waiting_since_cycle = self.cycle
        self._header_deadline = self.loop.call_later(self.header_timeout_s, self._header_deadline_passed)

    def _disarm_header_deadline(self) -> None:
        if self._header_deadline is not None:
            self._header_deadline.cancel()
            self._header_deadline = None

    def _header_deadline_passed(self) -> None:
        self._header_deadline = None
        waiting = self.cycle is self._waiting_since_cycle and (
            self.cycle is None or self.cycle.response_complete
        )
        if waiting and not self.transport.is_closing():
            self.transport.close()


class Notes:
    """The one-line notes (mostly errors) a step leaves for the page it returns to, kept by the
    station and named in the address by a random key: a page shows only text the station
    itself wrote. A note may also be a form as it was submitted, with its fields' messages
    (:class:`~spacecal.station.device_forms.DeviceForm`). The newest :data:`MAX_NOTES` are
    kept."""

    def __init__(self, keep: int | None = None):
        self.keep = keep or MAX_NOTES
        self._notes: collections.OrderedDict[str, object] = collections.OrderedDict()
        self._lock = threading.Lock()

    def add(self, text: object) -> str:
        """Keep ``text`` (a line, or a form); the key that names it."""
        key = secrets.token_urlsafe(9)
        with self._lock:
            self._notes[key] = text
            while len(self._notes) > self.keep:
                self._notes.popitem(last=False)
        return key

    def get(self, key: str | None) -> object | None:
        """The note ``key`` names, or None."""
        if not key:
            return None
        with self._lock:
            return self._notes.get(key)
