"""Fixtures of the station's tests: a record on SQLite and on PostgreSQL, a station served on
loopback in a thread, and headless Chromium (Debian's package) driven by Playwright.

In CI (CI=true) a missing piece (the station extra, Chromium, the PostgreSQL URL) fails the
tests instead of skipping them.
"""

from __future__ import annotations

import os
import shutil
import socket
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import pytest

IN_CI = os.environ.get("CI") == "true"
#: The PostgreSQL server of the record's tests (.ci/run starts one and sets it).
POSTGRES_ENV = "SPACECAL_TEST_POSTGRES_URL"
#: Every browser action's bound, ms: a hang detector, not a promise. A page's request waits
#: for the station's server, which writes the record to the disk, and this machine's disk
#: stalls for a minute at times (64 s measured with nothing but a loaded test run on it, inside
#: a 60-s wait for the findings). What the station promises in time (a STOP stills the arm, a
#: run ends) is asserted apart, with the stalls left out (:func:`tests.station.test_browser.
#: wait_for_run_end`, the stop tests' bounds).
BROWSER_TIMEOUT_MS = 240_000
#: Starting Chromium's bound, ms: a hang detector too. A start writes a fresh profile to the
#: disk and waited out a 66-s disk stall beside a loaded run.
BROWSER_LAUNCH_TIMEOUT_MS = 240_000


def need(module: str) -> Any:
    """Import ``module`` (the station extra), skipping without it (failing in CI)."""
    try:
        return __import__(module, fromlist=["_"])
    except ImportError:
        if IN_CI:
            pytest.fail(f"{module} is not installed: .ci/run installs the station extra")
        pytest.skip(f"{module} is not installed (pip install 'spacecal[station]')")


@pytest.fixture(params=["sqlite", "postgresql"])
def record_url(request, tmp_path) -> Iterator[str]:
    """A fresh, empty record: an SQLite file, and a database on the PostgreSQL server."""
    need("sqlalchemy")
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'record.db'}"
        return
    server = os.environ.get(POSTGRES_ENV)
    if not server:
        if IN_CI:
            pytest.fail(f"{POSTGRES_ENV} is not set: .ci/run starts a PostgreSQL server and sets it")
        pytest.skip(f"{POSTGRES_ENV} is not set (bash .ci/start-postgres starts a server)")
    import sqlalchemy as sa

    from spacecal.ledger import ledger_url

    name = f"spacecal_test_{os.getpid()}_{time.monotonic_ns()}"
    admin = sa.create_engine(ledger_url(server), isolation_level="AUTOCOMMIT")
    with admin.connect() as connection:
        connection.execute(sa.text(f'CREATE DATABASE "{name}"'))
    base, _, _ = ledger_url(server).rpartition("/")
    try:
        yield f"{base}/{name}"
    finally:
        with admin.connect() as connection:
            connection.execute(sa.text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        admin.dispose()


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


@dataclass
class Served:
    """A station running on loopback."""

    url: str
    station: Any
    data: Any


@pytest.fixture
def simulated_workspace(tmp_path) -> Iterator[tuple[Any, Any]]:
    """The station (not served: a Starlette test client speaks to it) with a simulated robot
    "UR10 bay 1", a simulated tracker and one workspace for them: ``(station, client)``, every
    run stopped and the record closed on every way out."""
    testclient = need("starlette.testclient")
    from spacecal.station.server import StationOptions, build

    station, application = build(StationOptions(data=str(tmp_path / "station")))
    web = testclient.TestClient(application, base_url="http://127.0.0.1:8770")
    try:
        web.post("/devices", data={"kind": "robot", "name": "UR10 bay 1", "url": "sim"})
        web.post("/devices", data={"kind": "tracker", "name": "Vicra", "url": "sim"})
        web.post("/workspaces", data={"robot": "1", "tracker": "1"})
        yield station, web
    finally:
        station.runs.stop_all("the test ended")
        station.ledger.close()


class StationServer:
    """A station served on 127.0.0.1 in a thread, which can be stopped and started again on the
    same port, data folder and record: a restart, as the operator's tabs see one."""

    def __init__(self, port: int, data: Any, record: str | None = None, pings: dict | None = None) -> None:
        self.port, self.data, self.record, self.pings = port, data, record, pings or {}
        self.served: Served | None = None
        self._server: Any = None
        self._thread: threading.Thread | None = None

    def start(self) -> Served:
        uvicorn = need("uvicorn")
        from spacecal.station.server import StationOptions, build, server_config

        options = StationOptions(port=self.port, data=str(self.data), record=self.record)
        station, application = build(options)
        server = uvicorn.Server(server_config(application, "127.0.0.1", self.port, **self.pings))
        thread = threading.Thread(target=server.run, daemon=True)
        thread.start()
        deadline = time.monotonic() + 20
        while not server.started:
            if time.monotonic() > deadline or not thread.is_alive():
                station.ledger.close()
                raise RuntimeError("the station did not start")
            time.sleep(0.05)
        self._server, self._thread = server, thread
        self.served = Served(f"http://127.0.0.1:{self.port}", station, self.data)
        return self.served

    def stop(self) -> None:
        """Stop its runs, the server and the record (nothing, when it is not running)."""
        if self.served is None:
            return
        station, self.served = self.served.station, None
        try:
            station.runs.stop_all("the test ended")
            self._server.should_exit = True
            assert self._thread is not None
            self._thread.join(timeout=15)
        finally:
            station.ledger.close()


@pytest.fixture
def served(tmp_path, request) -> Iterator[Served]:
    """The station on 127.0.0.1 (a free port) in a thread, stopped on every way out. A test
    may set the pages' ping interval and timeout, s, by parametrizing it indirectly."""
    server = StationServer(free_port(), tmp_path / "station", pings=getattr(request, "param", {}))
    try:
        yield server.start()
    finally:
        server.stop()


@pytest.fixture
def station_server(tmp_path, record_url) -> Iterator[StationServer]:
    """A station that a test starts, stops and starts again (:class:`StationServer`) on one
    port, data folder and record (SQLite and PostgreSQL), stopped on every way out."""
    server = StationServer(free_port(), tmp_path / "station", record=record_url)
    try:
        yield server
    finally:
        server.stop()


def chromium_binary() -> str:
    binary = shutil.which("chromium") or shutil.which("chromium-browser")
    if binary is None:
        if IN_CI:
            pytest.fail("chromium is not installed (.ci/run installs the Debian package)")
        pytest.skip("chromium is not installed")
    return binary


@pytest.fixture
def browser_context() -> Iterator[Any]:
    """A context of headless Chromium (Debian's): its pages share cookies, as one browser's
    tabs do; closed with its browser on every way out."""
    sync_api = need("playwright.sync_api")
    binary = chromium_binary()
    with sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(
            executable_path=binary, args=["--no-sandbox"], timeout=BROWSER_LAUNCH_TIMEOUT_MS
        )
        try:
            context = browser.new_context(viewport={"width": 1280, "height": 900})
            context.set_default_timeout(BROWSER_TIMEOUT_MS)
            yield context
        finally:
            browser.close()


@pytest.fixture
def page(browser_context) -> Any:
    """A page of headless Chromium (Debian's), closed with its browser on every way out."""
    return browser_context.new_page()


#: How often :func:`wait_js` asks the page, s.
WAIT_JS_POLL_S = 0.1


def wait_js(page: Any, expression: str, timeout: float = BROWSER_TIMEOUT_MS) -> None:
    """Wait until the page's JavaScript ``expression`` is true, for ``timeout`` ms.

    Playwright's ``wait_for_function`` evaluates its expression with ``eval`` inside the page,
    which the station's content security policy forbids (as it should); ``page.evaluate`` goes
    through the browser's debugging protocol, which the policy does not govern."""
    from playwright.sync_api import TimeoutError as PageTimeout

    deadline = time.monotonic() + timeout / 1000.0
    while not page.evaluate(expression):
        if time.monotonic() > deadline:
            raise PageTimeout(f"{expression} did not hold within {timeout / 1000.0:.0f} s")
        time.sleep(WAIT_JS_POLL_S)
