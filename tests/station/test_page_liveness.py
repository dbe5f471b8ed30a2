"""A page that stops answering the station's pings (a frozen browser, an unplugged station
computer: the connection stays open, nothing answers) counts as lost, and the run it watched
stops, as a closed tab's does."""

from __future__ import annotations

import base64
import os
import socket
import time
from urllib.parse import urlsplit

import pytest

from spacecal import app

#: The pings of this test's station, s: short, so the test takes seconds, not the 25 s the
#: station allows a real page (``spacecal.station.server.PAGE_PING_INTERVAL_S`` and ``_TIMEOUT_S``).
PINGS = {"ping_interval_s": 0.5, "ping_timeout_s": 1.0}
#: The run stops within this of the page falling silent, s: the pings' 1.5 s and room for a busy
#: machine, and well short of uvicorn's default pings (20 s, then 20 s to answer).
LOST_WITHIN_S = 15.0
#: A child process imports spacecal and starts the simulated devices within this, s (2 busy cores).
STARTS_WITHIN_S = 120.0


def silent_page(url: str, path: str) -> socket.socket:
    """Opens the live view's websocket by hand and then never reads from it: the pings go
    unanswered, as from a frozen page, while the connection stays open. It names the station's
    origin, as the station's own page does (a socket of any other origin is refused)."""
    address = urlsplit(url)
    connection = socket.create_connection((address.hostname, address.port), timeout=10)
    key = base64.b64encode(os.urandom(16)).decode()
    connection.sendall(
        (
            f"GET {path} HTTP/1.1\r\nHost: {address.netloc}\r\nOrigin: {url}\r\nUpgrade: websocket\r\n"
            f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n"
        ).encode()
    )
    answer = b""
    while b"\r\n\r\n" not in answer:
        answer += connection.recv(1)
    assert answer.startswith(b"HTTP/1.1 101"), answer
    return connection


def wait_until(condition, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError("timed out")
        time.sleep(0.05)


@pytest.mark.parametrize("served", [PINGS], indirect=True)
def test_a_page_that_stops_answering_stops_the_run_it_watched(served, tmp_path):
    settings = app.AcquireSettings(
        str(tmp_path / "rec.csv"),
        devices=app.DeviceSettings("sim", "sim"),
        confirm_robot_motion=True,
        simulated_speed=1.0,
    )
    run = served.station.runs.start(1, "bay 1", settings)
    run.page_connected()  # a page that answers, until the robot moves
    wait_until(lambda: run.samples > 0 or not run.active, STARTS_WITHIN_S)
    assert run.active, run.message
    page = silent_page(served.url, f"/runs/{run.id}/ws")
    silent_since = time.monotonic()
    try:
        wait_until(lambda: run.watchers == 2, 10.0)
        run.page_disconnected()  # the answering page closes: only the silent one watches now
        assert run.active, run.message
        run.thread.join(timeout=STARTS_WITHIN_S)
        assert run.state == "stopped", run.message
        assert "the station's page was closed or lost its connection" in run.message
        assert run.watchers == 0
        assert run.stop_requested_at is not None and run.stop_requested_at - silent_since < LOST_WITHIN_S
    finally:
        page.close()
