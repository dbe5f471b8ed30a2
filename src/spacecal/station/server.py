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


def serve(options: StationOptions) -> None:
    """Serve the station until Ctrl-C (or SIGTERM); every acquisition still running is stopped on
    the way out, through its STOP."""
    station, application = build(options)
    config = uvicorn.Config(
        application, host=options.host, port=options.port, log_level="warning", lifespan="off"
    )
    server = uvicorn.Server(config)
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
