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
import re
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from starlette.applications import Starlette
from starlette.convertors import Convertor, register_url_convertor
from starlette.requests import Request
from starlette.responses import FileResponse, RedirectResponse, Response
from starlette.routing import Route, WebSocketRoute
from starlette.templating import Jinja2Templates
from starlette.websockets import WebSocket, WebSocketDisconnect

from spacecal import app as spacecal_app
from spacecal.core.errors import InvalidInputError, RecordError, SpacecalError
from spacecal.core.text import exception_line
from spacecal.ledger import Ledger, NameTakenError
from spacecal.models.robot_kinds import ROBOT_KINDS
from spacecal.station.access import FILE_POLICY, AccessMiddleware, foreign_request, is_loopback
from spacecal.station.device_forms import (
    FIELDS,
    DeviceForm,
    default_device,
    entered_from_row,
    read_device_form,
)
from spacecal.station.error_pages import EXCEPTION_HANDLERS, error_page, refuse
from spacecal.station.guide_step import (
    INSERTIONS,
    PAPER_DIRECTION_DEG,
    PAPER_ENTRY_MM,
    PAPER_TARGET_MM,
    UPLOADS,
    standoff_from_form,
)
from spacecal.station.limits import Notes, RateLimit
from spacecal.station.motions import Runs, Tickets
from spacecal.station.trends import trend_figure
from spacecal.station.verify_step import PAPER_POSITION_MM, PAPER_POSTURE_DEG, poses_from_form
from spacecal.station.workspace import (
    EXPORTS,
    ExportOutcome,
    Workspace,
    new_folder,
    reopened_workspace,
    step_states,
)

HERE = Path(__file__).resolve().parent
templates = Jinja2Templates(directory=str(HERE / "templates"))
#: The live view's update period, s.
PUSH_PERIOD_S = 0.25
#: New calibrations a station starts, at most, in :data:`NEW_WORKSPACE_WINDOW_S` (a person
#: starts one every few minutes; a script that starts hundreds fills the disk with folders).
NEW_WORKSPACES_PER_WINDOW = 10
NEW_WORKSPACE_WINDOW_S = 60.0
#: A file name the station serves from a calibration's folder: the names it writes itself.
FILE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,99}")


class IdConvertor(Convertor[int]):
    """A number in the station's addresses (a calibration, a run): at most 9 digits, so a
    5000-digit one is no route (404) rather than an integer conversion's error."""

    regex = "[0-9]{1,9}"

    def convert(self, value: str) -> int:
        return int(value)

    def to_string(self, value: int) -> str:
        return str(int(value))


register_url_convertor("id", IdConvertor())


@dataclass
class Station:
    """The station's state: the record, the calibrations in progress and the motions."""

    ledger: Ledger
    data: Path
    error_thresholds: spacecal_app.ErrorThresholds | None = None
    runs: Runs = field(default_factory=Runs)
    tickets: Tickets = field(default_factory=Tickets)
    workspaces: dict[int, Workspace] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)
    notes: Notes = field(default_factory=Notes)
    new_workspaces: RateLimit = field(
        default_factory=lambda: RateLimit(NEW_WORKSPACES_PER_WINDOW, NEW_WORKSPACE_WINDOW_S)
    )

    def reopen_workspaces(self) -> None:
        """The record's workspaces as their folders now stand (at start: a restart loses no
        work, and each keeps the id its links carry)."""
        for row in self.ledger.workspaces():
            robot, tracker = self.ledger.robot(row["robot_id"]), self.ledger.tracker(row["tracker_id"])
            if robot is None or tracker is None:
                continue  # the record holds its devices (foreign keys): not reached
            work = reopened_workspace(row, robot, tracker, self.error_thresholds)
            if work.calibration is not None:
                digest = work.calibration.record.content_sha256
                work.calibration_record_id = self.ledger.calibration_id(digest)
            self.workspaces[work.id] = work

    def workspace(self, workspace_id: int) -> Workspace:
        found = self.workspaces.get(workspace_id)
        if found is None:
            raise LookupError(f"no calibration {workspace_id} at this station")
        found.check_files()
        return found


def _row_of(work: Workspace, kind: str) -> dict[str, Any]:
    """The workspace's robot or tracker row (``kind``: robot or tracker)."""
    return work.robot if kind == "robot" else work.tracker


def _station(request: Request | WebSocket) -> Station:
    station: Station = request.app.state.station
    return station


def _page(request: Request, name: str, status: int = 200, **context: Any) -> Response:
    """A page of the station, with the note a step left for it (``?note=KEY``) as its error."""
    note = _station(request).notes.get(request.query_params.get("note"))
    context.setdefault("error", note if isinstance(note, str) else None)
    return templates.TemplateResponse(request, name, context, status_code=status)


# -- robots and trackers --------------------------------------------------------------------


def home(request: Request) -> Response:
    station = _station(request)
    note = station.notes.get(request.query_params.get("note"))
    robots, trackers = station.ledger.robots(), station.ledger.trackers()
    devices = {
        kind: [
            {
                **row,
                "uses": station.ledger.device_uses(kind, row["id"]),
                "entered": entered_from_row(kind, row),
            }
            for row in rows
        ]
        for kind, rows in (("robot", robots), ("tracker", trackers))
    }
    return _page(
        request,
        "home.html",
        devices=devices,
        robots=[r for r in robots if not r.get("retired_utc")],
        trackers=[t for t in trackers if not t.get("retired_utc")],
        default_robot=default_device(robots),
        default_tracker=default_device(trackers),
        device_form=note if isinstance(note, DeviceForm) else None,
        robot_models=list(ROBOT_KINDS),
        workspaces=sorted(station.workspaces.values(), key=lambda w: -w.id),
    )


def back(request: Request, route: str, error: Any = None, fragment: str = "", **params: Any) -> Response:
    """303 to the page ``route``, carrying ``error`` as a note the station keeps (the address
    names the note, never its text: a link from elsewhere cannot make a page say anything):
    one line, or a :class:`~spacecal.station.device_forms.DeviceForm` with its fields' messages."""
    url = request.url_for(route, **params)
    if error is not None:
        url = url.include_query_params(note=_station(request).notes.add(error))
    return RedirectResponse(f"{url}#{fragment}" if fragment else url, 303)


#: Longest device address, model name or tool definition path taken from a form, characters.
FORM_TEXT_LIMIT = 4096


def form_text(form: Any, key: str, default: str = "") -> str:
    """A form's text field, stripped; one that is not text, or too long, is refused.

    Raises
    ------
    InvalidInputError
    """
    value = form.get(key, default)
    if not isinstance(value, str):
        raise InvalidInputError(f"{key} must be text")
    if len(value) > FORM_TEXT_LIMIT:
        raise InvalidInputError(f"{key} is longer than {FORM_TEXT_LIMIT} characters")
    return value.strip()


def _device_form_back(request: Request, device_form: DeviceForm) -> Response:
    """Back to the home page at the form, its messages beside its fields, its values kept."""
    return back(request, "home", device_form, fragment=device_form.form_id)


async def add_device(request: Request) -> Response:
    """POST /devices: a new robot or tracker, under a name no other of its kind has."""
    station = _station(request)
    form = await request.form()
    kind = form.get("kind")
    if kind not in FIELDS:
        return back(request, "home", "add a robot or a tracker")
    device_form = read_device_form(form, str(kind))
    _name_free(station, device_form)
    if not device_form.errors:
        try:
            station.ledger.new_device(
                device_form.kind, device_form.name, device_form.url, device_form.model, device_form.rate_hz
            )
        except NameTakenError as exc:
            device_form.refuse("name", exc)
        except SpacecalError as exc:
            device_form.refuse("device", exc)
    if device_form.errors:
        return _device_form_back(request, device_form)
    return back(request, "home", fragment=f"{device_form.kind}s")


def _name_free(station: Station, device_form: DeviceForm) -> None:
    """A name another device of its kind has: said beside the name, whatever else is wrong."""
    if device_form.name and "name" not in device_form.errors:
        try:
            station.ledger.check_name_free(device_form.kind, device_form.name, device_form.device_id)
        except NameTakenError as exc:
            device_form.refuse("name", exc)


def _device_of(request: Request) -> tuple[str, int, dict[str, Any]]:
    """The kind, id and record row of the device an address names.

    Raises
    ------
    LookupError
        No such device (404).
    """
    kind, device_id = request.path_params["kind"], int(request.path_params["device_id"])
    row = None
    if kind == "robot":
        row = _station(request).ledger.robot(device_id)
    elif kind == "tracker":
        row = _station(request).ledger.tracker(device_id)
    if row is None:
        raise LookupError(f"no {kind[:20]} {device_id} in the record")
    return kind, device_id, row


def _moving_with(station: Station, kind: str, device_id: int) -> Any:
    """The run that moves now with the device, or None."""
    run = station.runs.active()
    if run is None:
        return None
    work = station.workspaces.get(run.workspace)
    return run if work is not None and _row_of(work, kind)["id"] == device_id else None


async def edit_device(request: Request) -> Response:
    """POST /devices/<robot|tracker>/N/edit: its name, address and model or frame rate, checked
    as a new device's are; the calibrations in progress with it take the new values and need a
    new dry run (what they checked was the old device)."""
    station = _station(request)
    kind, device_id, row = _device_of(request)
    device_form = read_device_form(await request.form(), kind, device_id)
    _name_free(station, device_form)
    run = _moving_with(station, kind, device_id)
    if run is not None:
        device_form.refuse("device", f"{row['name']} is in use by run {run.id}: edit it once the run ended")
    if not device_form.errors:
        try:
            station.ledger.edit_device(
                kind, device_id, device_form.name, device_form.url, device_form.model, device_form.rate_hz
            )
        except NameTakenError as exc:
            device_form.refuse("name", exc)
        except SpacecalError as exc:
            device_form.refuse("device", exc)
    if device_form.errors:
        return _device_form_back(request, device_form)
    edited = station.ledger.robot(device_id) if kind == "robot" else station.ledger.tracker(device_id)
    with station.lock:
        for work in station.workspaces.values():
            if edited is not None and _row_of(work, kind)["id"] == device_id:
                work.device_edited(kind, edited)
    return back(request, "home", fragment=f"{kind}s")


async def retire_device(request: Request) -> Response:
    """POST /devices/<robot|tracker>/N/retire (``retired=0``: back in service): kept in the
    record with its calibrations, offered for no new calibration."""
    station = _station(request)
    kind, device_id, _ = _device_of(request)
    form = await request.form()
    try:
        station.ledger.retire_device(kind, device_id, retired=form.get("retired", "1") != "0")
    except SpacecalError as exc:
        return _device_form_back(request, DeviceForm(kind, device_id, errors={"device": exception_line(exc)}))
    return back(request, "home", fragment=f"{kind}s")


async def delete_device(request: Request) -> Response:
    """POST /devices/<robot|tracker>/N/delete: only a device no calibration names (recorded or
    in progress); one that a calibration names is kept, and the page says to retire it."""
    station = _station(request)
    kind, device_id, _ = _device_of(request)
    try:
        station.ledger.delete_device(kind, device_id)
    except SpacecalError as exc:  # DeviceInUseError among them
        return _device_form_back(request, DeviceForm(kind, device_id, errors={"device": exception_line(exc)}))
    return back(request, "home", fragment=f"{kind}s")


async def new_workspace(request: Request) -> Response:
    station = _station(request)
    form = await request.form()
    try:
        robot = station.ledger.robot(int(form_text(form, "robot")))
        tracker = station.ledger.tracker(int(form_text(form, "tracker")))
        rom = form_text(form, "rom") or None
    except (ValueError, InvalidInputError):
        robot = tracker = rom = None
    if robot is None or tracker is None:
        return back(request, "home", "choose a robot and a tracker")
    retired = [row["name"] for row in (robot, tracker) if row.get("retired_utc")]
    if retired:
        return back(request, "home", f"{retired[0]} is retired: put it back in service to calibrate with it")
    tool_id = None
    if rom is not None:
        try:
            found = Path(rom).is_file()
        except (OSError, ValueError):
            found = False
        if not found:
            return back(request, "home", f"no tool definition file {rom[:200]}")
        rom = str(Path(rom).resolve())
        tool_id = station.ledger.add_tool(rom, definition=rom)
    if not station.new_workspaces.allow():
        return back(
            request,
            "home",
            f"at most {NEW_WORKSPACES_PER_WINDOW} new calibrations a minute: "
            f"try again in {station.new_workspaces.wait_s():.0f} s",
        )
    with station.lock:
        folder = new_folder(station.data, robot["name"])
        try:
            # the record gives the id, so it is never reused, and the workspace survives a restart
            workspace_id = station.ledger.add_workspace(robot["id"], tracker["id"], str(folder), rom, tool_id)
        except (SpacecalError, OSError) as exc:
            folder.rmdir()
            return back(request, "home", exception_line(exc))
        station.workspaces[workspace_id] = Workspace(
            workspace_id, robot, tracker, folder, rom, tool_id, error_thresholds=station.error_thresholds
        )
    return RedirectResponse(request.url_for("workspace", workspace_id=workspace_id), 303)


# -- one calibration's steps ----------------------------------------------------------------


async def workspace_page(request: Request) -> Response:
    station = _station(request)
    work = station.workspace(int(request.path_params["workspace_id"]))
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
    verify_run = station.runs.get(work.verify_run_id) if work.verify_run_id is not None else None
    guide_run = station.runs.get(work.guide_run_id) if work.guide_run_id is not None else None
    scene = await asyncio.to_thread(work.scene)
    note = station.notes.get(request.query_params.get("note"))
    moving = station.runs.active()
    steps = step_states(work, moving.motion if moving is not None and moving.workspace == work.id else None)
    return _page(
        request,
        "workspace.html",
        export_outcome=note if isinstance(note, ExportOutcome) else None,
        ur_export_blocked=work.ur_export_blocked(),
        located=work.located(),
        work=work,
        scene=None if scene is None else script_json(scene),
        steps=steps,
        step={s.key: s for s in steps},
        findings=findings,
        run=run,
        verify_run=verify_run,
        guide_run=guide_run,
        standoff_ok=motion_basis(station, work, "standoff") is not None,
        insert_ok={k: motion_basis(station, work, "insert", k) is not None for k in INSERTIONS},
        insertions=INSERTIONS,
        guide_results=work.guide.results,
        paper_guidance=(PAPER_ENTRY_MM, PAPER_TARGET_MM, PAPER_DIRECTION_DEG),
        exports=EXPORTS,
        history=history,
        paper_position=PAPER_POSITION_MM,
        paper_posture=PAPER_POSTURE_DEG,
    )


#: The steps a calibration's page posts (none of them moves the robot).
STEPS = ("doctor", "plan", "dry-run", "calibrate", "report", "verify-dry-run", "guide-dry-run")


async def step(request: Request) -> Response:
    """POST /workspaces/N/step/<step>: doctor, plan, dry-run, calibrate, report, verify-dry-run
    (no motion)."""
    station = _station(request)
    work = station.workspace(int(request.path_params["workspace_id"]))
    if request.path_params["step"] not in STEPS:
        return error_page(404, f"there is no step {request.path_params['step'][:40]!r}")
    form = await request.form()
    try:
        method = form_text(form, "method", "ml")
        poses = poses_from_form(form_text(form, "poses"))
        standoff_mm = standoff_from_form(form_text(form, "standoff_mm"))
    except InvalidInputError as exc:
        return back(request, "workspace", exception_line(exc), workspace_id=work.id)
    return await asyncio.to_thread(_step, request, station, work, method, poses, standoff_mm)


def _step(
    request: Request, station: Station, work: Workspace, method: str, poses: int, standoff_mm: float
) -> Response:
    name = request.path_params["step"]
    try:
        if name == "verify-dry-run":
            work.verify_dry_run(poses)
        elif name == "guide-dry-run":
            work.guide.standoff_mm = standoff_mm
            work.guide_dry_run()
        elif name == "doctor":
            work.doctor()
        elif name == "plan":
            work.plan()
        elif name == "dry-run":
            work.dry_run()
        elif name == "calibrate":
            out = work.calibrate(method)
            try:
                work.calibration_record_id = spacecal_app.record_calibration(
                    station.ledger,
                    out,
                    "station",
                    robot_id=work.robot["id"],
                    tracker_id=work.tracker["id"],
                    tool_id=work.tool_id,
                )
            except RecordError as exc:
                # a calibration the record does not hold is not shown as done
                work.calibration = None
                raise RecordError(
                    f"{out.files_written[0].name} was written but not recorded ({exception_line(exc)}): "
                    "calibrate again once the record can be written"
                ) from exc
        else:
            work.make_report()
    except (SpacecalError, OSError) as exc:
        return back(request, "workspace", exception_line(exc), workspace_id=work.id)
    return back(request, "workspace", workspace_id=work.id)


async def export(request: Request) -> Response:
    """POST /workspaces/N/export: each target ticked, one at a time; the page shows what was
    written and, beside the form, what failed and why, with the ticks kept."""
    station = _station(request)
    work = station.workspace(int(request.path_params["workspace_id"]))
    form = await request.form()
    targets = [key for key in EXPORTS if form.get(key)]
    if not targets:
        outcome = ExportOutcome(message="tick where to export")
    elif work.calibration is None:
        outcome = ExportOutcome(chosen=targets, message="calibrate first")
    else:
        outcome = await asyncio.to_thread(work.export, targets)
    return back(request, "workspace", outcome, fragment="export-form", workspace_id=work.id)


def workspace_file(request: Request) -> Response:
    """A file of the calibration's folder (report, exports), by name only: a name of the kind
    the station writes, a regular file that resolves inside the folder (no link out of it), in
    a sandbox of its own (:data:`~spacecal.station.access.FILE_POLICY`): a report's scripts run,
    but never as the station's page."""
    station = _station(request)
    work = station.workspace(int(request.path_params["workspace_id"]))
    name = request.path_params["name"]
    if not FILE_NAME.fullmatch(name):
        return error_page(404, "no such file")
    folder = work.folder.resolve()
    try:
        path = (work.folder / name).resolve(strict=True)
        inside = path.parent == folder and path.is_file()
    except (OSError, RuntimeError):
        inside = False
    if not inside:
        return error_page(404, "no such file")
    return FileResponse(path, headers={"Content-Security-Policy": FILE_POLICY, "Cache-Control": "no-store"})


# -- motions: confirmation, acquisition, check ----------------------------------------------

MOTIONS = ("acquire", "check", "verify", "standoff", "insert")
#: What a confirmation of each motion needs first.
NEEDED_FIRST = {
    "acquire": "run the dry run first: it must pass",
    "check": "calibrate first",
    "verify": "calibrate, then run the verification's dry run: it must pass",
    "standoff": "upload the plan and its registration, then run the guidance's dry run: it must pass",
    "insert": "the insertion is confirmed only while the robot stands at the plan's standoff, "
    "brought there by the guidance's first motion, with no motion since",
}


def motion_basis(station: Station, work: Workspace, motion: str, insertion: str | None = None) -> str | None:
    """What a confirmation of ``motion`` of ``work`` confirms now (None: nothing to confirm),
    with the devices it names: a robot or tracker edited between the confirmation and the
    start leaves the ticket worthless (the page named the old address)."""
    basis = _step_basis(station, work, motion, insertion)
    return None if basis is None else f"devices {work.devices_sha256()} {basis}"


def _step_basis(station: Station, work: Workspace, motion: str, insertion: str | None) -> str | None:
    if motion not in ("standoff", "insert"):
        return work.motion_basis(motion)
    if work.calibration is None:
        return None
    latest = station.runs.latest()
    awaiting = (
        latest.id
        if latest is not None
        and latest.workspace == work.id
        and latest.active
        and latest.awaiting == "insert"
        else None
    )
    return work.guide.motion_basis(motion, insertion, latest.id if latest is not None else None, awaiting)


def confirm_page(request: Request) -> Response:
    """The confirmation that names the robot and the motion; issues the motion's ticket, bound
    to what was confirmed (the dry run that passed, or the calibration to check)."""
    station = _station(request)
    work = station.workspace(int(request.path_params["workspace_id"]))
    motion = request.path_params["motion"]
    if motion not in MOTIONS:
        return error_page(404, f"there is no motion {motion[:40]!r}")
    insertion = request.query_params.get("insertion") if motion == "insert" else None
    basis = motion_basis(station, work, motion, insertion)
    if basis is None:
        return back(request, "workspace", NEEDED_FIRST[motion], workspace_id=work.id)
    ticket = station.tickets.issue(work.id, work.robot["name"], motion, basis)
    return _page(
        request,
        "confirm.html",
        work=work,
        motion=motion,
        words=work.motion_words(motion, insertion),
        ticket=ticket,
        insertion=insertion,
    )


async def start_motion(request: Request) -> Response:
    """POST /workspaces/N/motion/<acquire|check|verify> with the confirmation's ticket."""
    station = _station(request)
    work = station.workspace(int(request.path_params["workspace_id"]))
    motion = request.path_params["motion"]
    if motion not in MOTIONS:
        return error_page(404, f"there is no motion {motion[:40]!r}")
    form = await request.form()
    insertion = str(form.get("insertion", ""))[:20] if motion == "insert" else None
    ticket = station.tickets.redeem(
        str(form.get("ticket", ""))[:100], work.id, motion, motion_basis(station, work, motion, insertion)
    )
    if ticket is None:
        return back(
            request,
            "workspace",
            "the robot did not move: a motion starts only from its confirmation page, once, "
            "for the dry run or calibration it named (confirm it again)",
            workspace_id=work.id,
        )
    try:
        if motion == "acquire":
            if station.runs.active() is None:
                work.set_aside_earlier_recording(station.runs.next_id())
            run = station.runs.start(work.id, work.robot["name"], work.acquire_settings(dry_run=False))
            work.run_id = run.id
        elif motion == "verify":
            confirmed = ticket.basis.rsplit(" ", 1)[1]  # the calibration's sha256 it was bound to
            run = station.runs.start(
                work.id,
                work.robot["name"],
                work.verify_settings(),
                "verify",
                functools.partial(_verified, work, confirmed),
            )
            work.verify_run_id = run.id
        elif motion == "standoff":
            # on the simulated devices a new process starts a fresh world at home: the standoff
            # and the insertion run in one session, the insertion's confirmation sent to it
            run = station.runs.start(
                work.id,
                work.robot["name"],
                work.guide_settings("standoff"),
                "standoff",
                functools.partial(_guided, work),
            )
            if run.waits_for_confirmation:
                work.guide.live_run = run.id
                work.guide.live_basis = f"{work.guide.basis} inputs {work.guide.inputs_sha256()}"
            # its dry run was planned from where the robot stood: once it moves, that is past
            work.guide.basis = None
            work.guide_run_id = run.id
        elif motion == "insert":
            assert insertion is not None
            live = station.runs.get(work.guide.live_run) if work.guide.live_run is not None else None
            if live is not None and live.awaiting == "insert":
                if not live.proceed(insertion):
                    return back(
                        request, "workspace", "the guidance had ended: nothing moved", workspace_id=work.id
                    )
                run = live
            else:
                run = station.runs.start(
                    work.id,
                    work.robot["name"],
                    work.guide_settings("insert", insertion),
                    "insert",
                    functools.partial(_guided, work),
                )
                work.guide.standoff_run = None  # the robot leaves the standoff
                work.guide_run_id = run.id
        else:
            run = station.runs.start(
                work.id,
                work.robot["name"],
                work.check_settings(),
                "check",
                functools.partial(_checked, station, work),
            )
    except RuntimeError as exc:
        return back(request, "workspace", str(exc), workspace_id=work.id)
    return RedirectResponse(request.url_for("run", run_id=run.id), 303)


def _checked(station: Station, work: Workspace, run: Any) -> None:
    """A check that ran to its end: the record, then the calibration's list (a check the record
    could not hold is not listed as done)."""
    spacecal_app.record_check(station.ledger, work.calibration_path, run.output, "station")
    work.checks.append(run.output.record)


def _verified(work: Workspace, confirmed_sha256: str, run: Any) -> None:
    """A verification that ran to its end: shown as its JSON file says, if the calibration is
    still the one confirmed."""
    work.verification.finished(confirmed_sha256)


def _guided(work: Workspace, run: Any) -> None:
    """A guidance motion that ran to its end: shown as its JSON files say (a standoff and its
    insertion in one session wrote one each); a standoff on the devices that finished there
    (not stopped) lets the insertion be confirmed."""
    output = run.output.record
    for stage in [*(name for name, _ in run.stages if name == "standoff"), output.stage]:
        work.guide.read_result(stage)
    result = output.result
    if output.stage == "standoff" and result is not None and not result.interrupted:
        work.guide.standoff_reached(run.id)


async def guide_upload(request: Request) -> Response:
    """POST /workspaces/N/guide/upload (multipart): the plan and the registration files, kept
    under the station's names (the names given are only shown, as text), then where the plan
    lands. The request's size is bounded by the doors (64 kB)."""
    station = _station(request)
    work = station.workspace(int(request.path_params["workspace_id"]))
    try:
        async with request.form(max_files=len(UPLOADS), max_fields=10) as form:
            work.guide.set_maps(form_text(form, "registration_maps"))
            for kind in UPLOADS:
                upload = form.get(kind)
                if upload is None or isinstance(upload, str):
                    continue
                name = str(upload.filename or "")
                data = await upload.read()
                if not name and not data:
                    continue  # the field left empty
                work.guide.store(kind, name, data)
        await asyncio.to_thread(work.guide.locate)
    except (SpacecalError, OSError) as exc:
        return back(request, "workspace", exception_line(exc), workspace_id=work.id)
    return back(request, "workspace", workspace_id=work.id)


def _run(request: Request | WebSocket) -> Any:
    runs = _station(request).runs
    run_id = int(request.path_params["run_id"])
    run = runs.get(run_id)
    if run is None and run_id < runs.first_id:
        raise LookupError(
            f"run {run_id} was before the station last started: its page is gone, its files are in "
            "its calibration's folder (open the calibration from the home page)"
        )
    if run is None:
        raise LookupError("no such run at this station")
    return run


async def run_page(request: Request) -> Response:
    run = _run(request)
    work = _station(request).workspace(run.workspace)
    # the set-up the live samples are drawn into: the plan in the robot base frame during an
    # acquisition, the tracker frame through the calibration during the motions that use one
    scene = await asyncio.to_thread(work.scene, run.motion)
    return _page(
        request,
        "run.html",
        run=run,
        work=work,
        insertions=INSERTIONS,
        scene=None if scene is None else script_json(scene),
    )


async def stop_run(request: Request) -> Response:
    _run(request).request_stop("STOP pressed at the station")
    return Response("stopping", media_type="text/plain")


async def run_socket(websocket: WebSocket) -> None:
    """The live view: pushes the run's frames and state; STOP arrives here too. A connection
    lost while the run moves stops it (unless another page of the station still watches it).
    Only the station's own pages count as watchers (the doors refuse any other, and this checks
    again), and the socket is closed once the run has ended and its last state was sent."""
    headers = {k.lower(): v for k, v in websocket.headers.items()}
    if foreign_request(websocket.scope, headers, headers.get("host", "")) is not None:
        await websocket.close(code=1008)
        return
    run = _station(websocket).runs.get(int(websocket.path_params["run_id"]))
    if run is None:
        await websocket.close(code=1008)
        return
    await websocket.accept()
    run.page_connected()
    since = 0
    try:
        while True:
            ended = not run.active and run.ended_at is not None
            data = run.snapshot(since)
            since = data["sequence"]
            await websocket.send_text(json.dumps(data))
            if ended:
                await websocket.close(code=1000)
                break
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
    # each recorded calibration still open at this station links to its workspace, file and report
    workspace_of = {
        work.calibration.record.content_sha256: work
        for work in (station.workspace(i) for i in list(station.workspaces))
        if work.calibration is not None
    }
    return _page(
        request,
        "trends.html",
        calibrations=calibrations,
        checks=checks,
        workspace_of=workspace_of,
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


#: The station's own page scripts and style.
STATIC_FILES = ("station.js", "station.css", "trends.js", "scene.js")


def static_file(request: Request) -> Response:
    name = request.path_params["name"]
    if name not in STATIC_FILES:
        return error_page(404, "no such file")
    return FileResponse(HERE / "static" / name)


def create_app(station: Station, token: str | None = None, host: str = "127.0.0.1") -> Any:
    """The station's ASGI application, behind its doors
    (:class:`~spacecal.station.access.AccessMiddleware`)."""
    routes = [
        Route("/", home, name="home"),
        Route("/devices", add_device, methods=["POST"]),
        Route("/devices/{kind}/{device_id:id}/edit", edit_device, methods=["POST"], name="edit_device"),
        Route("/devices/{kind}/{device_id:id}/retire", retire_device, methods=["POST"], name="retire_device"),
        Route("/devices/{kind}/{device_id:id}/delete", delete_device, methods=["POST"], name="delete_device"),
        Route("/workspaces", new_workspace, methods=["POST"]),
        Route("/workspaces/{workspace_id:id}", workspace_page, name="workspace"),
        Route("/workspaces/{workspace_id:id}/step/{step}", step, methods=["POST"]),
        Route("/workspaces/{workspace_id:id}/export", export, methods=["POST"]),
        Route(
            "/workspaces/{workspace_id:id}/guide/upload", guide_upload, methods=["POST"], name="guide_upload"
        ),
        Route("/workspaces/{workspace_id:id}/files/{name}", workspace_file, name="file"),
        Route("/workspaces/{workspace_id:id}/confirm/{motion}", confirm_page, name="confirm"),
        Route("/workspaces/{workspace_id:id}/motion/{motion}", start_motion, methods=["POST"], name="motion"),
        Route("/runs/{run_id:id}", run_page, name="run"),
        Route("/runs/{run_id:id}/stop", stop_run, methods=["POST"], name="stop"),
        WebSocketRoute("/runs/{run_id:id}/ws", run_socket),
        Route("/trends", trends, name="trends"),
        Route("/static/plotly.js", plotly_js, name="plotly"),
        Route("/static/{name}", static_file, name="static"),
    ]
    plotly_bytes()  # read before any run starts, so the live view's page loads at once
    web = Starlette(routes=routes, exception_handlers=EXCEPTION_HANDLERS)
    web.state.station = station
    return AccessMiddleware(web, token, loopback_only=is_loopback(host), refuse=refuse)
