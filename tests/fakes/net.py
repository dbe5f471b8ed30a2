"""Socket helpers shared by the fakes."""

from __future__ import annotations

import socket
import threading


def accept_connections(host: str, port: int, stop: threading.Event):
    """Yield each client connection to ``host:port`` until ``stop`` is set (polling every 0.2 s)."""
    server = socket.create_server((host, port))
    server.settimeout(0.2)
    try:
        while not stop.is_set():
            try:
                connection, _ = server.accept()
            except socket.timeout:
                continue
            yield connection
    finally:
        server.close()
