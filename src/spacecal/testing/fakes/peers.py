"""Hostile peers for the deadline tests: a TCP server on a loopback address that hands each
client connection to one behaviour on its own thread.

Behaviours, each given the connection, the :class:`Peer` and the bytes an honest device would
send now (or ``b""``):

* :func:`silent`: keeps the connection open, reads, never sends;
* :func:`drip`: sends those bytes (then more of the same) one byte at a time, for ever;
* :func:`announce`: sends a header announcing a huge body, then nothing more;
* :func:`hang_up`: sends the first half of those bytes and closes the connection.

``Peer.ended`` is set when the client's side of a connection ends (closed or shut down), so a
test can check that a call given up also gave up its connection.
"""

from __future__ import annotations

import itertools
import select
import socket
import threading
import time
from collections.abc import Callable

from spacecal.testing.fakes.net import accept_connections, listen

#: Time between two bytes of a drip, s: a reply of a few dozen bytes takes many seconds.
DRIP_INTERVAL_S = 0.2


class Peer:
    """A TCP server on ``host:port`` (port 0: any free one) running ``serve(connection, peer)`` for
    each client connection on its own thread; a context manager that stops it and closes every
    connection."""

    def __init__(self, serve: Callable[[socket.socket, Peer], None], host: str = "127.0.0.1", port: int = 0):
        self.server = listen(host, port)
        self.host, self.port = self.server.getsockname()[:2]
        self.stop = threading.Event()
        self.ended = threading.Event()
        self.accepted = 0
        self._connections: list[socket.socket] = []
        self._serve = serve
        self._thread = threading.Thread(target=self._accept, daemon=True)
        self._thread.start()

    def _accept(self) -> None:
        for connection in accept_connections(self.server, self.stop):
            self.accepted += 1
            self._connections.append(connection)
            threading.Thread(target=self._run, args=(connection,), daemon=True).start()

    def _run(self, connection: socket.socket) -> None:
        try:
            self._serve(connection, self)
        except OSError:
            self.ended.set()

    def client_gone(self, connection: socket.socket) -> bool:
        """Whether the client closed or shut down its side (checked without blocking)."""
        try:
            readable, _, _ = select.select([connection], [], [], 0)
            if readable and not connection.recv(4096, socket.MSG_PEEK):
                self.ended.set()
                return True
        except OSError:
            self.ended.set()
            return True
        return False

    def __enter__(self) -> Peer:
        return self

    def __exit__(self, *_) -> None:
        self.stop.set()
        for connection in self._connections:
            try:
                connection.close()
            except OSError:
                pass
        self._thread.join(timeout=2.0)


def silent(connection: socket.socket, peer: Peer, honest: bytes = b"") -> None:
    """Read everything, send nothing, until the client goes or the test ends."""
    connection.settimeout(0.1)
    while not peer.stop.is_set():
        try:
            if not connection.recv(4096):
                peer.ended.set()
                return
        except TimeoutError:
            continue


def drip(connection: socket.socket, peer: Peer, honest: bytes = b"") -> None:
    """Send ``honest`` (then the same again) one byte every :data:`DRIP_INTERVAL_S`."""
    for byte in itertools.cycle(honest or b"x"):
        if peer.stop.is_set() or peer.client_gone(connection):
            return
        connection.sendall(bytes([byte]))
        time.sleep(DRIP_INTERVAL_S)


def announce(header: bytes) -> Callable[[socket.socket, Peer, bytes], None]:
    """A behaviour that sends ``header`` (a header announcing a huge body), then nothing."""

    def behave(connection: socket.socket, peer: Peer, honest: bytes = b"") -> None:
        connection.sendall(header)
        silent(connection, peer)

    return behave


def hang_up(connection: socket.socket, peer: Peer, honest: bytes = b"") -> None:
    """Send the first half of ``honest`` and close the connection."""
    connection.sendall(honest[: max(len(honest) // 2, 1)])
    connection.close()
