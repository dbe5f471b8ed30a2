"""Probe a station's doors from outside, as a foreign page's browser and a local program would,
and print a table: each attack and what the station did.

    python benchmarks/station_doors.py            # this checkout's station, on loopback

The station is started here on simulated devices, on 127.0.0.1 at a free port, in a thread.
Each attack sends what a browser sends for the page it names (its ``Origin`` and
``Sec-Fetch-*`` headers; a browser cannot forge them) and reports whether it changed anything:
a robot added, a calibration created, a plan or dry run done, a ticket minted, a run started
or watched, a file read. The Chromium tests (``tests/station/test_browser_foreign_pages.py``)
run the same attacks from real pages; this table is the quick look.
"""

from __future__ import annotations

import argparse
import asyncio
import re
import socket
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Callable
from pathlib import Path
from typing import Any


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


class NoRedirect(urllib.request.HTTPRedirectHandler):
    def redirect_request(self, *args: Any, **kwargs: Any) -> None:
        return None


OPENER = urllib.request.build_opener(NoRedirect)


def request(
    url: str, data: dict[str, str] | None = None, headers: dict[str, str] | None = None
) -> tuple[int, str]:
    body = urllib.parse.urlencode(data).encode() if data is not None else None
    req = urllib.request.Request(
        url, data=body, headers=headers or {}, method="POST" if body is not None else "GET"
    )
    try:
        with OPENER.open(req, timeout=60) as answer:
            return answer.status, answer.read().decode("utf-8", "replace")
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read().decode("utf-8", "replace")


def page_headers(origin: str, site: str, dest: str = "document", mode: str = "navigate") -> dict[str, str]:
    """What Chromium sends with a request of a page of ``origin``."""
    headers = {"Sec-Fetch-Site": site, "Sec-Fetch-Dest": dest, "Sec-Fetch-Mode": mode}
    if origin:
        headers["Origin"] = origin
    return headers


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.parse_args()
    import uvicorn

    from spacecal.station.server import StationOptions, build, server_config

    data = Path(tempfile.mkdtemp(prefix="spacecal-doors-"))
    port = free_port()
    station, application = build(StationOptions(port=port, data=str(data), simulated=True))
    server = uvicorn.Server(server_config(application, "127.0.0.1", port))
    threading.Thread(target=server.run, daemon=True).start()
    while not server.started:
        time.sleep(0.05)
    base = f"http://127.0.0.1:{port}"
    own = page_headers(base, "same-origin")
    foreign_pages = {
        "another address's page": page_headers("http://127.0.0.2:8000", "cross-site"),
        "another port's page": page_headers("http://127.0.0.1:8000", "same-site"),
        "a sandboxed frame (Origin: null)": page_headers("null", "cross-site"),
    }
    rows: list[tuple[str, str]] = []

    def probe(name: str, attempt: Callable[[], str]) -> None:
        try:
            rows.append((name, attempt()))
        except Exception as exc:  # a probe that breaks is a finding too
            rows.append((name, f"probe error: {type(exc).__name__}: {exc}"))

    # the operator's own page: a calibration planned and dry-run
    request(base + "/workspaces", {"robot": "1", "tracker": "1"}, own)
    request(base + "/workspaces/1/step/plan", {}, own)
    request(base + "/workspaces/1/step/dry-run", {}, own)
    work = station.workspaces[1]

    for who, headers in foreign_pages.items():

        def add(headers: dict[str, str] = headers) -> str:
            before = len(station.ledger.robots())
            status, _ = request(base + "/devices", {"kind": "robot", "name": "x", "url": "sim"}, headers)
            return f"{status}; robot added: {len(station.ledger.robots()) > before}"

        def create(headers: dict[str, str] = headers) -> str:
            before = len(station.workspaces)
            status, _ = request(base + "/workspaces", {"robot": "1", "tracker": "1"}, headers)
            return f"{status}; calibration created: {len(station.workspaces) > before}"

        def framed(headers: dict[str, str] = headers) -> str:
            frame = {k: v for k, v in headers.items() if k != "Origin"} | {"Sec-Fetch-Dest": "iframe"}
            status, text = request(base + "/workspaces/1/confirm/acquire", None, frame)
            got = re.search(r'name="ticket" value="([^"]+)"', text)
            policy = "frame-ancestors 'none'" in urllib.request.urlopen(base + "/").headers.get(
                "content-security-policy", ""
            )
            return f"{status}; ticket shown: {got is not None}; framing forbidden: {policy}"

        def start(headers: dict[str, str] = headers) -> str:
            _, text = request(base + "/workspaces/1/confirm/acquire", None, own)
            found = re.search(r'name="ticket" value="([^"]+)"', text)
            if found is None:
                return "no ticket to try"
            status, _ = request(base + "/workspaces/1/motion/acquire", {"ticket": found.group(1)}, headers)
            started = station.runs.get(1) is not None
            return f"{status}; motion started: {started}"

        probe(f"{who}: add a robot", add)
        probe(f"{who}: create a calibration", create)
        probe(f"{who}: frame the confirmation", framed)
        probe(f"{who}: post the operator's ticket", start)

    # a run the operator started; a foreign socket tries to watch it and keep it alive
    _, text = request(base + "/workspaces/1/confirm/acquire", None, own)
    ticket = re.search(r'name="ticket" value="([^"]+)"', text)
    run_id = None
    if ticket is not None:
        status, _ = request(base + "/workspaces/1/motion/acquire", {"ticket": ticket.group(1)}, own)
        run = station.runs.active()
        run_id = run.id if run is not None else None

    async def socket_attempt(origin: str) -> str:
        import websockets

        url = f"ws://127.0.0.1:{port}/runs/{run_id}/ws"
        try:
            async with websockets.connect(url, origin=origin, open_timeout=20) as ws:  # type: ignore[arg-type]
                await asyncio.wait_for(ws.recv(), 10)
                return "accepted: saw the run"
        except Exception as exc:
            return f"refused ({type(exc).__name__})"

    if run_id is not None:
        for origin in ("null", "http://127.0.0.1:8000", "http://127.0.0.2:8000"):
            probe(
                f"websocket of Origin {origin}: watch the run",
                lambda o=origin: asyncio.run(socket_attempt(o)),
            )
        station.runs.get(run_id).request_stop("the probe ended")

    # files, names and bounds
    folder = work.folder
    (folder / "passwd").symlink_to("/etc/passwd")
    probe("a symlink out of the folder", lambda: str(request(base + "/workspaces/1/files/passwd")[0]))
    probe("a 300-character file name", lambda: str(request(base + "/workspaces/1/files/" + "a" * 300)[0]))
    probe("an unknown calibration", lambda: str(request(base + "/workspaces/77")[0]))
    probe("a 5000-digit calibration id", lambda: str(request(base + "/workspaces/" + "9" * 5000)[0]))

    def tickets() -> str:
        for _ in range(200):
            request(base + "/workspaces/1/confirm/acquire", None, own)
        return f"{len(station.tickets._open)} open after 200 confirmation pages"

    probe("confirmation pages loaded 200 times", tickets)

    def workspaces() -> str:
        before = len(station.workspaces)
        started = time.monotonic()
        for _ in range(100):
            request(base + "/workspaces", {"robot": "1", "tracker": "1"}, own)
        return f"{len(station.workspaces) - before} made in {time.monotonic() - started:.1f} s"

    probe("100 new calibrations at once", workspaces)

    def slow() -> str:
        connection = socket.create_connection(("127.0.0.1", port), timeout=60)
        connection.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n")
        started = time.monotonic()
        try:
            closed = connection.recv(1) == b""
        except OSError:
            closed = True
        finally:
            connection.close()
        return f"closed by the station after {time.monotonic() - started:.1f} s: {closed}"

    probe("half a request, then nothing", slow)

    width = max(len(name) for name, _ in rows)
    print(f"{'attack':<{width}}  outcome")
    for name, outcome in rows:
        print(f"{name:<{width}}  {outcome}")
    station.runs.stop_all("the probe ended")
    server.should_exit = True
    station.ledger.close()
    sys.stdout.flush()


if __name__ == "__main__":
    main()
