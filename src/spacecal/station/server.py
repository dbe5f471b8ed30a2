"""``spacecal station``: open the record, build the application, serve it with uvicorn."""

from __future__ import annotations

import webbrowser
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import uvicorn

from spacecal.ledger import SIMULATED_ROBOT, SIMULATED_TRACKER, Ledger
from spacecal.station.access import check_bind
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
        Access token every request must carry.
    data : str
        Folder for each calibration's files; the record defaults to ``DATA/record.db``.
    record : str or None
        The record: SQLite file or database URL.
    open : bool
        Open the station in the default web browser.
    simulated : bool
        Offer the simulated robot and tracker (added to the record when missing), under the
        names the record gives simulated devices of a calibration made with ``--record``.
    """

    host: str = "127.0.0.1"
    port: int = 8770
    token: str | None = None
    data: str = "spacecal-station"
    record: str | None = None
    open: bool = False
    simulated: bool = False


def build(options: StationOptions) -> tuple[Station, Any]:
    """The station's state and its ASGI application (refusing an unsafe bind first)."""
    check_bind(options.host, options.token)
    data = Path(options.data).expanduser().resolve()
    data.mkdir(parents=True, exist_ok=True)
    ledger = Ledger.open(options.record or str(data / "record.db"))
    if options.simulated:
        ledger.add_robot(SIMULATED_ROBOT, "sim")
        ledger.add_tracker(SIMULATED_TRACKER, "sim")
    station = Station(ledger, data)
    return station, create_app(station, options.token, options.host)


def server_config(
    application: Any,
    host: str,
    port: int,
    ping_interval_s: float = PAGE_PING_INTERVAL_S,
    ping_timeout_s: float = PAGE_PING_TIMEOUT_S,
) -> uvicorn.Config:
    """uvicorn's settings for the station: quiet, no lifespan, and the pages' liveness above."""
    return uvicorn.Config(
        application,
        host=host,
        port=port,
        log_level="warning",
        lifespan="off",
        ws_ping_interval=ping_interval_s,
        ws_ping_timeout=ping_timeout_s,
    )


def serve(options: StationOptions) -> None:
    """Serve the station until Ctrl-C (or SIGTERM); every acquisition still running is stopped on
    the way out, through its STOP."""
    station, application = build(options)
    server = uvicorn.Server(server_config(application, options.host, options.port))
    address = f"http://{'localhost' if options.host == '127.0.0.1' else options.host}:{options.port}/"
    shown = address + (f"?token={options.token}" if options.token else "")
    print(f"spacecal station: {shown} (record: {station.ledger.engine.url.render_as_string()})", flush=True)
    if options.open:
        webbrowser.open(shown)
    try:
        server.run()
    except KeyboardInterrupt:
        pass  # Ctrl-C is how a station is closed: every run was stopped and the record is written
    finally:
        station.runs.stop_all("the station shut down")
        station.ledger.close()
