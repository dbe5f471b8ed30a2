"""The station's web application (Starlette): its routes, pages and the live view's websocket.

Every page is a Jinja2 template with autoescaping, so a robot's name or a file name from the
record is shown as text, never as markup. Every step calls one :mod:`spacecal.app` function
(through :class:`~spacecal.station.workspace.Workspace`); a known error is shown on the page
as the one line the command line would print.
"""

from __future__ import annotations

import asyncio
import functools
import json
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import FileResponse, PlainTextResponse, RedirectResponse, Response
from starlette.routing import Route, WebSocketRoute
from starlette.templating import Jinja2Templates
from starlette.websockets import WebSocket, WebSocketDisconnect

from spacecal import app as spacecal_app
from spacecal.core.errors import SpacecalError
from spacecal.core.text import exception_line
from spacecal.ledger import Ledger
from spacecal.station.access import AccessMiddleware, is_loopback
from spacecal.station.motions import Runs, Tickets
from spacecal.station.trends import trend_figure
from spacecal.station.workspace import EXPORTS, Workspace, new_folder

HERE = Path(__file__).resolve().parent
templates = Jinja2Templates(directory=str(HERE / "templates"))
#: The live view's update period, s.
PUSH_PERIOD_S = 0.25


@dataclass
class Station:
    """The station's state: the record, the calibrations in progress and the motions."""

    ledger: Ledger
    data: Path
    runs: Runs = field(default_factory=Runs)
    tickets: Tickets = field(default_factory=Tickets)
    workspaces: dict[int, Workspace] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def workspace(self, workspace_id: int) -> Workspace:
        found = self.workspaces.get(workspace_id)
        if found is None:
            raise LookupError(f"no calibration {workspace_id} at this station")
        return found


def _station(request: Request | WebSocket) -> Station:
    station: Station = request.app.state.station
    return station


def _page(request: Request, name: str, status: int = 200, **context: Any) -> Response:
    return templates.TemplateResponse(request, name, context, status_code=status)


# -- robots and trackers --------------------------------------------------------------------


def home(request: Request) -> Response:
    station = _station(request)
    return _page(
        request,
        "home.html",
        robots=station.ledger.robots(),
        trackers=station.ledger.trackers(),
        workspaces=sorted(station.workspaces.values(), key=lambda w: -w.id),
        error=request.query_params.get("error"),
    )


async def add_device(request: Request) -> Response:
    station = _station(request)
    form = await request.form()
    kind = str(form.get("kind", ""))
    name, url = str(form.get("name", "")).strip(), str(form.get("url", "")).strip() or "sim"
    try:
        if kind == "robot":
            station.ledger.add_robot(name, url, str(form.get("model", "")).strip() or None)
        elif kind == "tracker":
            rate = str(form.get("rate_hz", "")).strip()
            station.ledger.add_tracker(name, url, float(rate) if rate else None)
        else:
            return PlainTextResponse("add a robot or a tracker", status_code=400)
    except (SpacecalError, ValueError) as exc:
        return RedirectResponse(request.url_for("home").include_query_params(error=exception_line(exc)), 303)
    return RedirectResponse(request.url_for("home"), 303)


async def new_workspace(request: Request) -> Response:
    station = _station(request)
    form = await request.form()
    try:
        robot = station.ledger.robot(int(str(form.get("robot", ""))))
        tracker = station.ledger.tracker(int(str(form.get("tracker", ""))))
    except ValueError:
        robot = tracker = None
    if robot is None or tracker is None:
        return RedirectResponse(
            request.url_for("home").include_query_params(error="choose a robot and a tracker"), 303
        )
    rom = str(form.get("rom", "")).strip() or None
    tool_id = None
    if rom is not None:
        if not Path(rom).is_file():
            return RedirectResponse(
                request.url_for("home").include_query_params(error=f"no tool definition file {rom}"), 303
            )
        rom = str(Path(rom).resolve())
        tool_id = station.ledger.add_tool(rom, definition=rom)
    with station.lock:
        workspace_id = len(station.workspaces) + 1
        folder = new_folder(station.data, robot["name"])
        station.workspaces[workspace_id] = Workspace(workspace_id, robot, tracker, folder, rom, tool_id)
    return RedirectResponse(request.url_for("workspace", workspace_id=workspace_id), 303)


# -- one calibration's steps ----------------------------------------------------------------


async def workspace_page(request: Request) -> Response:
    station = _station(request)
    try:
        work = station.workspace(int(request.path_params["workspace_id"]))
    except LookupError as exc:
        return PlainTextResponse(str(exc), status_code=404)
    findings = work.findings
    if findings is None:
        try:
            findings = await asyncio.to_thread(work.doctor)
        except (SpacecalError, OSError) as exc:
            findings = [("devices", "must be fixed before the robot can move", exception_line(exc))]
    run = station.runs.get(work.run_id) if work.run_id is not None else None
    history = []
    if work.calibration_record_id is not None:
        history = station.ledger.checks(work.calibration_record_id)
    return _page(
        request,
        "workspace.html",
        work=work,
        findings=findings,
        run=run,
        exports=EXPORTS,
        history=history,
        error=request.query_params.get("error"),
    )


async def step(request: Request) -> Response:
    """POST /workspaces/N/<step>: doctor, plan, dry-run, calibrate, report (no motion)."""
    form = await request.form()
    method = str(form.get("method", "ml"))
    return await asyncio.to_thread(_step, request, method)


def _step(request: Request, method: str) -> Response:
    station = _station(request)
    work = station.workspace(int(request.path_params["workspace_id"]))
    name = request.path_params["step"]
    here = request.url_for("workspace", workspace_id=work.id)
    try:
        if name == "doctor":
            work.doctor()
        elif name == "plan":
            work.plan()
        elif name == "dry-run":
            work.dry_run()
        elif name == "calibrate":
            out = work.calibrate(method)
            work.calibration_record_id = spacecal_app.record_calibration(
                station.ledger,
                out,
                "station",
                robot_id=work.robot["id"],
                tracker_id=work.tracker["id"],
                tool_id=work.tool_id,
            )
        elif name == "report":
            work.make_report()
        else:
            return PlainTextResponse(f"no step {name}", status_code=404)
    except (SpacecalError, OSError) as exc:
        return RedirectResponse(here.include_query_params(error=exception_line(exc)), 303)
    return RedirectResponse(here, 303)


async def export(request: Request) -> Response:
    station = _station(request)
    work = station.workspace(int(request.path_params["workspace_id"]))
    form = await request.form()
    targets = [key for key in EXPORTS if form.get(key)]
    here = request.url_for("workspace", workspace_id=work.id)
    if not targets:
        return RedirectResponse(here.include_query_params(error="choose where to export"), 303)
    try:
        await asyncio.to_thread(work.export, targets)
    except (SpacecalError, OSError) as exc:
        return RedirectResponse(here.include_query_params(error=exception_line(exc)), 303)
    return RedirectResponse(here, 303)


def workspace_file(request: Request) -> Response:
    """A file of the calibration's folder (report, exports), by name only."""
    station = _station(request)
    work = station.workspace(int(request.path_params["workspace_id"]))
    name = request.path_params["name"]
    path = work.folder / name
    if "/" in name or "\\" in name or name.startswith(".") or not path.is_file():
        return PlainTextResponse("no such file", status_code=404)
    return FileResponse(path)


# -- motions: confirmation, acquisition, check ----------------------------------------------

MOTIONS = ("acquire", "check")


def confirm_page(request: Request) -> Response:
    """The confirmation that names the robot and the motion; issues the motion's ticket."""
    station = _station(request)
    work = station.workspace(int(request.path_params["workspace_id"]))
    motion = request.path_params["motion"]
    if motion not in MOTIONS:
        return PlainTextResponse(f"no motion {motion}", status_code=404)
    here = request.url_for("workspace", workspace_id=work.id)
    if motion == "acquire" and not work.dry_run_ok:
        return RedirectResponse(here.include_query_params(error="run the dry run first: it must pass"), 303)
    if motion == "check" and work.calibration is None:
        return RedirectResponse(here.include_query_params(error="calibrate first"), 303)
    ticket = station.tickets.issue(work.id, work.robot["name"], motion)
    return _page(
        request, "confirm.html", work=work, motion=motion, words=work.motion_words(motion), ticket=ticket
    )


async def start_motion(request: Request) -> Response:
    """POST /workspaces/N/motion/<acquire|check> with the confirmation's ticket."""
    station = _station(request)
    work = station.workspace(int(request.path_params["workspace_id"]))
    motion = request.path_params["motion"]
    form = await request.form()
    ticket = station.tickets.redeem(str(form.get("ticket", "")), work.id, motion)
    if ticket is None:
        return PlainTextResponse(
            "refused: a motion starts only from its confirmation page (confirm it again)", status_code=403
        )
    here = request.url_for("workspace", workspace_id=work.id)
    try:
        if motion == "acquire":
            if station.runs.active() is None:
                work.set_aside_earlier_recording()
            run = station.runs.start(work.id, work.robot["name"], work.acquire_settings(dry_run=False))
            work.run_id = run.id
        else:
            run = station.runs.start(
                work.id,
                work.robot["name"],
                work.check_settings(),
                "check",
                functools.partial(_checked, station, work),
            )
    except RuntimeError as exc:
        return RedirectResponse(here.include_query_params(error=str(exc)), 303)
    return RedirectResponse(request.url_for("run", run_id=run.id), 303)


def _checked(station: Station, work: Workspace, run: Any) -> None:
    """A check that ran to its end: the calibration's list and the record."""
    work.checks.append(run.output.record)
    spacecal_app.record_check(station.ledger, work.calibration_path, run.output, "station")


def run_page(request: Request) -> Response:
    station = _station(request)
    run = station.runs.get(int(request.path_params["run_id"]))
    if run is None:
        return PlainTextResponse("no such run", status_code=404)
    work = station.workspace(run.workspace)
    return _page(request, "run.html", run=run, work=work)


async def stop_run(request: Request) -> Response:
    station = _station(request)
    run = station.runs.get(int(request.path_params["run_id"]))
    if run is None:
        return PlainTextResponse("no such run", status_code=404)
    run.request_stop("STOP pressed at the station")
    return PlainTextResponse("stopping")


async def run_socket(websocket: WebSocket) -> None:
    """The live view: pushes the run's frames and state; STOP arrives here too. A connection
    lost while the run moves stops it (unless another page still watches it)."""
    station = _station(websocket)
    run = station.runs.get(int(websocket.path_params["run_id"]))
    await websocket.accept()
    if run is None:
        await websocket.close(code=1008)
        return
    run.page_connected()
    since = 0
    try:
        while True:
            data = run.snapshot(since)
            since = data["sequence"]
            await websocket.send_text(json.dumps(data))
            try:
                message = await asyncio.wait_for(websocket.receive_text(), timeout=PUSH_PERIOD_S)
            except asyncio.TimeoutError:
                continue
            if message == "stop":
                run.request_stop("STOP pressed at the station")
    except WebSocketDisconnect:
        pass
    finally:
        run.page_disconnected()


def script_json(value: Any) -> str:
    """JSON safe inside a ``<script>`` element: names from the record cannot close it."""
    text = json.dumps(value, allow_nan=False)
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


# -- the record ------------------------------------------------------------------------------


def trends(request: Request) -> Response:
    station = _station(request)
    calibrations = station.ledger.calibrations()
    checks = station.ledger.checks()
    return _page(
        request,
        "trends.html",
        calibrations=calibrations,
        checks=checks,
        figure=script_json(trend_figure(calibrations, checks)),
    )


@functools.lru_cache(maxsize=1)
def plotly_bytes() -> bytes:
    """plotly.js from the installed plotly package (no CDN), read once."""
    from plotly.offline import get_plotlyjs

    return str(get_plotlyjs()).encode("utf-8")


def plotly_js(request: Request) -> Response:
    return Response(
        plotly_bytes(), media_type="application/javascript", headers={"Cache-Control": "max-age=3600"}
    )


def static_file(request: Request) -> Response:
    name = request.path_params["name"]
    if name not in ("station.js", "station.css"):
        return PlainTextResponse("no such file", status_code=404)
    return FileResponse(HERE / "static" / name)


def create_app(station: Station, token: str | None = None, host: str = "127.0.0.1") -> Any:
    """The station's ASGI application, behind its access rules
    (:class:`~spacecal.station.access.AccessMiddleware`)."""
    routes = [
        Route("/", home, name="home"),
        Route("/devices", add_device, methods=["POST"]),
        Route("/workspaces", new_workspace, methods=["POST"]),
        Route("/workspaces/{workspace_id:int}", workspace_page, name="workspace"),
        Route("/workspaces/{workspace_id:int}/step/{step}", step, methods=["POST"]),
        Route("/workspaces/{workspace_id:int}/export", export, methods=["POST"]),
        Route("/workspaces/{workspace_id:int}/files/{name}", workspace_file, name="file"),
        Route("/workspaces/{workspace_id:int}/confirm/{motion}", confirm_page, name="confirm"),
        Route(
            "/workspaces/{workspace_id:int}/motion/{motion}", start_motion, methods=["POST"], name="motion"
        ),
        Route("/runs/{run_id:int}", run_page, name="run"),
        Route("/runs/{run_id:int}/stop", stop_run, methods=["POST"], name="stop"),
        WebSocketRoute("/runs/{run_id:int}/ws", run_socket),
        Route("/trends", trends, name="trends"),
        Route("/static/plotly.js", plotly_js, name="plotly"),
        Route("/static/{name}", static_file, name="static"),
    ]
    plotly_bytes()  # read before any run starts, so the live view's page loads at once
    web = Starlette(routes=routes)
    web.state.station = station
    return AccessMiddleware(web, token, loopback_only=is_loopback(host))
