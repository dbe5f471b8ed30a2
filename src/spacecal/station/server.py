"""``spacecal station``: open the record, build the application, serve it with uvicorn."""

from __future__ import annotations

import os
import tempfile
import threading
import webbrowser
from dataclasses import dataclass
from html import escape
from pathlib import Path
from typing import Any

import uvicorn

from spacecal.app import ErrorThresholds
from spacecal.ledger import SIMULATED_ROBOT, SIMULATED_TRACKER, Ledger
from spacecal.station.access import check_bind, load_token
from spacecal.station.limits import MAX_CONNECTIONS, HeaderDeadlineProtocol
from spacecal.station.motions import Runs
from spacecal.station.web import Station, create_app

#: How often the station pings each page's live view, and how long a page may take to answer,
#: s. A page that does not answer in time cannot show the run or send its STOP, so it counts as
#: lost, and a run no page watches stops (:meth:`spacecal.station.motions.Run.page_disconnected`):
#: a frozen or unplugged station computer stops the robot within 25 s at most. A closed tab or
#: a dropped connection is seen at once, without waiting for a ping.
PAGE_PING_INTERVAL_S = 5.0
PAGE_PING_TIMEOUT_S = 20.0


@dataclass(frozen=True)
class StationOptions:
    """How the station is served.

    Attributes
    ----------
    host : str
        Interface to listen on; anything but loopback needs ``token``.
    port : int
        TCP port (0: any free one).
    token : str or None
        Access token every request must carry (from a program: the command line reads it
        from ``token_file`` or the environment, never from its own arguments).
    token_file : str or None
        File holding the token (created with a fresh one, readable by its owner only, when it
        does not exist); without it, ``SPACECAL_STATION_TOKEN`` when set
        (:func:`spacecal.station.access.load_token`). On loopback too: a shared station PC.
    data : str
        Folder for each calibration's files; the record defaults to ``DATA/record.db``.
    record : str or None
        The record: SQLite file or database URL.
    open : bool
        Open the station in the default web browser.
    error_thresholds : ErrorThresholds or None
        The site's limits of the verdict's grades (``--thresholds-mm``); every calibration made
        at the station is graded against them (default: 0.5, 1, 2 mm).
    simulated : bool
        Offer the simulated robot and tracker (added to the record when missing), under the
        names the record gives simulated devices of a calibration made with ``--record``.
    """

    host: str = "127.0.0.1"
    port: int = 8770
    token: str | None = None
    token_file: str | None = None
    data: str = "spacecal-station"
    record: str | None = None
    open: bool = False
    simulated: bool = False
    error_thresholds: ErrorThresholds | None = None


def build(options: StationOptions) -> tuple[Station, Any]:
    """The station's state and its ASGI application (refusing an unsafe bind first)."""
    token = options.token if options.token is not None else load_token(options.token_file)
    check_bind(options.host, token)
    data = Path(options.data).expanduser().resolve()
    data.mkdir(parents=True, exist_ok=True)
    runs = Runs(data / RUN_COUNTER_NAME)
    ledger = Ledger.open(options.record or str(data / "record.db"))
    try:
        if options.simulated:
            ledger.add_robot(SIMULATED_ROBOT, "sim")
            ledger.add_tracker(SIMULATED_TRACKER, "sim")
        station = Station(ledger, data, error_thresholds=options.error_thresholds, runs=runs)
        station.reopen_workspaces()
    except BaseException:
        ledger.close()  # a station that does not start leaves its record closed
        raise
    return station, create_app(station, token, options.host)


#: The file in the station's folder that keeps the last run id across restarts.
RUN_COUNTER_NAME = "last-run-id"


def server_config(
    application: Any,
    host: str,
    port: int,
    ping_interval_s: float = PAGE_PING_INTERVAL_S,
    ping_timeout_s: float = PAGE_PING_TIMEOUT_S,
) -> uvicorn.Config:
    """uvicorn's settings for the station: quiet, no lifespan, the pages' liveness above, a
    deadline on every request's headers and a bound on the connections served at once
    (:mod:`spacecal.station.limits`)."""
    return uvicorn.Config(
        application,
        host=host,
        port=port,
        log_level="warning",
        lifespan="off",
        http=HeaderDeadlineProtocol,
        limit_concurrency=MAX_CONNECTIONS,
        ws_ping_interval=ping_interval_s,
        ws_ping_timeout=ping_timeout_s,
        server_header=False,
        proxy_headers=False,  # a local program's X-Forwarded-Proto must not change the origin
    )


def serve(options: StationOptions) -> None:
    """Serve the station until Ctrl-C (or SIGTERM); every acquisition still running is stopped on
    the way out, through its STOP."""
    station, application = build(options)
    server = uvicorn.Server(server_config(application, options.host, options.port))
    address = f"http://{'localhost' if options.host == '127.0.0.1' else options.host}:{options.port}/"
    token = application.token
    where = f"token in {options.token_file}" if options.token_file else "token from SPACECAL_STATION_TOKEN"
    signing = f" (sign in with the access token: {where})" if token else ""
    record = station.ledger.engine.url.render_as_string(hide_password=True)
    print(f"spacecal station: {address}{signing} (record: {record})", flush=True)
    if options.open:
        open_in_browser(address, token)
    try:
        server.run()
    except KeyboardInterrupt:
        pass  # Ctrl-C is how a station is closed: every run was stopped and the record is written
    finally:
        station.runs.stop_all("the station shut down")
        station.ledger.close()


#: How long the page that hands the browser its token lives on disk, s.
HANDOVER_FILE_LIFETIME_S = 60.0


def open_in_browser(address: str, token: str | None) -> None:
    """Open the station in the default web browser, signed in when it has a token. The token
    never goes on the browser's command line (every user reads that in the process list): the
    browser opens a page in a private file (mode 600) that goes on to the station's address
    with the token, which the station swaps for its cookie at once; the file is removed soon
    after."""
    if token is None:
        webbrowser.open(address)
        return
    target = escape(f"{address}?token={token}", quote=True)
    descriptor, name = tempfile.mkstemp(prefix="spacecal-station-", suffix=".html")
    with os.fdopen(descriptor, "w") as page:
        page.write(f'<!DOCTYPE html><meta http-equiv="refresh" content="0; url={target}">')
    webbrowser.open(Path(name).as_uri())
    timer = threading.Timer(HANDOVER_FILE_LIFETIME_S, lambda: Path(name).unlink(missing_ok=True))
    timer.daemon = True
    timer.start()
