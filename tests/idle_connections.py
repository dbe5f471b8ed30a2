"""Connections that send part of a request and then nothing, for the servers' bound tests (the
station and the live view): how many of them the server has closed."""

from __future__ import annotations

import socket


def closed_by_the_server(connections: list[socket.socket], wait_s: float = 5.0) -> int:
    """How many of ``connections`` the server closed (end of stream or a reset), each read for
    at most ``wait_s``."""
    closed = 0
    for connection in connections:
        connection.settimeout(wait_s)
        try:
            closed += connection.recv(1) == b""
        except OSError:
            closed += 1
    return closed
