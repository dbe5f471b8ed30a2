"""Socket helpers shared by the fakes."""

from __future__ import annotations

import socket
import threading


def listen(host: str, port: int) -> socket.socket:
    """A listening socket, bound now (so a busy port fails before the world reports READY)."""
    server = socket.create_server((host, port))
    server.settimeout(0.2)
    return server


def accept_connections(server: socket.socket, stop: threading.Event):
    """Yield each client connection of a listening socket until ``stop`` is set."""
    try:
        while not stop.is_set():
            try:
                connection, _ = server.accept()
            except TimeoutError:
                continue
            yield connection
    finally:
        server.close()
