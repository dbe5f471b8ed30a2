"""Motions the station runs: confirmation tickets, and each motion (an acquisition or a check) in
a process of its own with its STOP.

A motion starts only from a ticket (:class:`Tickets`): the confirmation page issues one that
names the robot, the motion and what was confirmed (the dry run that passed, with its plan's
hash, or the calibration to check); the start request must hand it back, once, within
:data:`TICKET_LIFETIME_S`, while that is still what the workspace holds. No ticket, no motion.

Each motion runs as the command line runs it, in a child process
(:mod:`spacecal.station.motion_process`), followed by a thread of the station that shows its
progress and frames. The process starts only once the run's page has connected: a motion is
never without someone watching it. STOP, or the page's connection lost, sends the child
SIGINT: Ctrl-C, the command line's own stop path. The robot is stopped, every sample is kept and the run says
where it stopped. A stopped run is over: the robot moves again only after a new confirmation.
The web server and the robot's loop do not share an interpreter, and a robot library that
crashes takes only its motion's process with it.
"""

from __future__ import annotations

import json
import math
import pickle
import secrets
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from spacecal import app
from spacecal.core.errors import InvalidInputError
from spacecal.core.text import exception_line
from spacecal.io.atomic import write_text_atomic
from spacecal.report.live import LiveView
from spacecal.station.guide_step import guidance_line
from spacecal.station.motion_process import LAST_MESSAGES, one_session
from spacecal.station.verify_step import verification_line

#: How long a confirmation stays valid, s.
TICKET_LIFETIME_S = 300.0
#: Confirmations open at once (a person has one or two; each page load issues one).
MAX_OPEN_TICKETS = 32
#: A run's motion starts only once its page watches it; a run whose page has not connected
#: within this time after the confirmation ends without moving the robot, s. Generous: nothing
#: moves while it waits, and a browser on a busy machine may take long to open a page.
PAGE_CONNECT_WITHIN_S = 120.0
#: The words of the command line's Ctrl-C stop, replaced by the station's own reason.
CTRL_C_WORDS = "interrupted by the user (Ctrl-C)"
#: How long a motion's process may take to end once its last message arrived, s.
PROCESS_EXIT_WITHIN_S = 30.0
#: The command line's hint after a stopped acquisition, and the station's own way on instead
#: (:meth:`spacecal.station.workspace.Workspace.set_aside_earlier_recording`).
RESUME_WORDS = "resume with --resume"
STATION_RESUME_WORDS = "acquiring again starts over and keeps these files (in earlier-N/)"
#: Why a run stops when no page watches it any more.
PAGE_LOST = "the station's page was closed or lost its connection"
#: What each motion is called on its page.
MOTION_WORDS = {
    "acquire": "acquisition",
    "check": "check",
    "verify": "verification",
    "standoff": "guidance",
    "insert": "guidance",
}
#: What each motion's run page is headed with.
MOTION_TITLES = {
    "acquire": "Acquiring",
    "check": "Checking",
    "verify": "Verifying",
    "standoff": "Guiding the needle to its standoff",
    "insert": "Inserting along the plan",
}
#: What a run's page says while it waits for a second confirmation.
AWAIT_WORDS = {
    "insert": "at the standoff: the robot holds still; confirm the insertion (a second confirmation) or STOP"
}


@dataclass(frozen=True)
class Ticket:
    """A confirmed motion: which workspace, robot and motion it is for, and what was confirmed
    (``basis``: the dry run that passed, or the calibration to check)."""

    workspace: int
    robot: str
    motion: str
    basis: str
    issued: float


class Tickets:
    """Single-use confirmations of motions, at most :data:`MAX_OPEN_TICKETS` open at once
    (every confirmation page issues one: the oldest go first, and expired ones are dropped at
    each issue)."""

    def __init__(self) -> None:
        self._open: dict[str, Ticket] = {}
        self._lock = threading.Lock()

    def __len__(self) -> int:
        with self._lock:
            return len(self._open)

    def issue(self, workspace: int, robot: str, motion: str, basis: str) -> str:
        """A new ticket for the motion ``motion`` of robot ``robot``, confirmed on ``basis``."""
        key = secrets.token_urlsafe(24)
        now = time.monotonic()
        with self._lock:
            for old in [k for k, t in self._open.items() if now - t.issued > TICKET_LIFETIME_S]:
                del self._open[old]
            while len(self._open) >= MAX_OPEN_TICKETS:
                del self._open[next(iter(self._open))]  # dicts keep their order: the oldest
            self._open[key] = Ticket(workspace, robot, motion, basis, now)
        return key

    def redeem(self, key: str | None, workspace: int, motion: str, basis: str | None) -> Ticket | None:
        """The ticket ``key`` when it was issued for this workspace and motion on the same
        ``basis`` (a dry run run again, or one that failed since, leaves no basis or another)
        and is still valid; it is used up either way."""
        if not key:
            return None
        with self._lock:
            ticket = self._open.pop(key, None)
        if ticket is None or ticket.workspace != workspace or ticket.motion != motion:
            return None
        if basis is None or not secrets.compare_digest(ticket.basis, basis):
            return None
        if time.monotonic() - ticket.issued > TICKET_LIFETIME_S:
            return None
        return ticket


@dataclass
class Run:
    """One motion the station runs in a process of its own.

    Attributes
    ----------
    motion : str
        ``acquire`` (settings :class:`spacecal.app.AcquireSettings`) or ``check``
        (:class:`spacecal.app.CheckSettings`).
    view : LiveView
        Keeps the frames for the page (its server is not started: the station serves them).
    state : str
        ``starting``, ``running``, ``finished``, ``stopped`` or ``failed``.
    message : str
        How it ended, in the command line's words.
    output : CommandResult or None
        What the app function returned, once finished.
    on_done : callable or None
        Called with the run when it finished (the station records a check).
    """

    id: int
    workspace: int
    robot: str
    settings: Any
    motion: str = "acquire"
    on_done: Callable[[Run], None] | None = None
    view: LiveView = field(default_factory=lambda: LiveView(0))
    state: str = "starting"
    message: str = ""
    moves_total: int = 0
    move_index: int = 0
    samples: int = 0
    visible: int = 0
    output: app.CommandResult[Any] | None = None
    stop_requested_at: float | None = None
    stop_reason: str = ""
    ended_at: float | None = None
    last_frame_at: float | None = None
    first_frame_at: float | None = None
    started_at: float = field(default_factory=time.monotonic)
    watchers: int = 0
    _watched_or_stopped: threading.Event = field(default_factory=threading.Event)
    exit_code: int | None = None
    started: bool = False
    thread: threading.Thread | None = None
    _process: subprocess.Popen[bytes] | None = None
    #: What the run waits for, between its stages (``"insert"``), or None.
    awaiting: str | None = None
    #: Its stages so far, as its process reported them (``(stage, payload)``).
    stages: list[tuple[str, Any]] = field(default_factory=list)
    #: Each move's planned duration (s, at the run's pace), when it runs a plan file whose
    #: moves are the run's: what the page counts its time left from.
    move_durations_s: list[float] | None = None
    #: When the move of ``move_index`` was first seen (``time.monotonic``).
    move_seen_at: float | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock)

    @property
    def active(self) -> bool:
        return self.state in ("starting", "running")

    @property
    def words(self) -> str:
        """What the motion is called on its page."""
        return MOTION_WORDS.get(self.motion, self.motion)

    @property
    def waits_for_confirmation(self) -> bool:
        """Its process waits for a second confirmation between its stages."""
        return one_session(self.motion, self.settings)

    def proceed(self, word: str) -> bool:
        """Send the waiting process the second confirmation (``word``, e.g. the insertion);
        whether it was waiting for one (it is sent once)."""
        with self._lock:
            process, awaiting = self._process, self.awaiting
            if awaiting is None or process is None or process.stdin is None or self.stop_requested_at:
                return False
            self.awaiting = None
            try:
                pickle.dump(("proceed", word), process.stdin, protocol=pickle.HIGHEST_PROTOCOL)
                process.stdin.flush()
                process.stdin.close()
            except OSError:  # it has just ended
                return False
        self.message = f"confirmed: {word}"
        return True

    @property
    def title(self) -> str:
        """The heading of its page."""
        return MOTION_TITLES.get(self.motion, self.motion)

    def page_connected(self) -> None:
        """A page watches the run (its live view connected): the motion may start."""
        self.watchers += 1
        self._watched_or_stopped.set()

    def page_disconnected(self) -> None:
        """A page stopped watching; the last one gone stops the run."""
        self.watchers -= 1
        if self.active and self.watchers <= 0:
            self.request_stop(PAGE_LOST)

    def request_stop(self, reason: str) -> None:
        """Stop the run: SIGINT to its process, the command line's Ctrl-C path, once. STOP comes
        both as the page's socket message and as its POST; a second SIGINT would interrupt the
        process's own stop and clean-up (closing the devices) rather than stop anything more."""
        with self._lock:
            first = self.stop_requested_at is None
            if first:
                self.stop_requested_at = time.monotonic()
                self.stop_reason = reason
            process = self._process
        self._watched_or_stopped.set()
        if first and process is not None and process.poll() is None:
            try:
                process.send_signal(signal.SIGINT)
            except OSError:  # it has just ended
                pass

    def work(self) -> None:
        """The following thread's body: start the motion's process, show what it reports, keep
        how it ended."""
        try:
            self._follow()
        except Exception as exc:  # the page must say so rather than spin
            self.state, self.message = "failed", f"the {self.words} could not be run: {exception_line(exc)}"
        finally:
            self.ended_at = time.monotonic()
            self.view.finish(f"{self.state}: {self.message}")

    def _follow(self) -> None:
        self.message = "waiting for the run's page to connect"
        if not self._watched_or_stopped.wait(PAGE_CONNECT_WITHIN_S):
            self.request_stop("the station's page never connected")
        self.message = "starting"
        with self._lock:
            if self.stop_requested_at is not None:
                self.state, self.message = "stopped", f"stopped before the robot moved: {self.stop_reason}"
                return
            process = subprocess.Popen(
                [sys.executable, "-m", "spacecal.station.motion_process"],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
            )
            self._process = process
        assert process.stdin is not None and process.stdout is not None
        pickle.dump((self.motion, self.settings), process.stdin, protocol=pickle.HIGHEST_PROTOCOL)
        process.stdin.flush()
        if not self.waits_for_confirmation:
            process.stdin.close()
        last: tuple[str, Any] | None = None
        with process.stdout:
            while True:
                try:
                    kind, payload = pickle.load(process.stdout)
                except (EOFError, pickle.UnpicklingError):
                    break
                if kind in LAST_MESSAGES:
                    last = (kind, payload)
                else:
                    self._progress(kind, payload)
        try:
            self.exit_code = process.wait(timeout=PROCESS_EXIT_WITHIN_S)
        except subprocess.TimeoutExpired:
            process.kill()  # it has said all it will say; the robot was stopped by then
            self.exit_code = process.wait()
        self._ended(last)

    def _progress(self, kind: str, payload: Any) -> None:
        if kind == "started":
            self.started = True
            self.message = f"connecting to {self.robot} and the tracker"
            if self.motion != "acquire":
                self.state = "running"  # only an acquisition shows frames: the others run from here
        elif kind == "plan":
            self.moves_total = int(payload)
            self.move_durations_s = planned_durations(self.settings, self.moves_total)
            self.message = ""
        elif kind == "sample":
            move = self.move_index
            self.samples, self.visible, self.move_index, _ = payload
            if self.move_seen_at is None or self.move_index != move:
                self.move_seen_at = time.monotonic()
        elif kind == "stage":
            self.stages.append(payload)
        elif kind == "await":
            self.awaiting = str(payload)
            self.message = AWAIT_WORDS.get(self.awaiting, f"waiting for the confirmation of {self.awaiting}")
        elif kind == "frame":
            self.state = "running"
            self.last_frame_at = time.monotonic()
            if self.first_frame_at is None:
                self.first_frame_at = self.last_frame_at
                self.message = ""
            self.view.observe(*payload)

    def _ended(self, last: tuple[str, Any] | None) -> None:
        self.awaiting = None
        stopped = self.stop_requested_at is not None
        if last is None and stopped and not self.started:
            self.state, self.message = "stopped", f"stopped before the robot moved: {self.stop_reason}"
        elif last is None:
            self.state = "stopped" if stopped else "failed"
            self.message = (
                f"the {self.words}'s process ended without a word (exit code {self.exit_code}); "
                "every file it wrote is complete up to its last line"
            )
        elif last[0] == "done":
            self.output = last[1]
            self.state, self.message = "finished", _finished(self.motion, last[1].record)
            if self.on_done is not None:
                try:
                    self.on_done(self)
                except Exception as exc:  # the motion ran; only its record is missing
                    self.message += f"; it could not be recorded: {exception_line(exc)}"
        elif last[0] == "interrupted":
            reason = self.stop_reason if stopped else str(last[1])
            self.state = "stopped"
            self.message = (
                f"stopped: {reason}" if self.started else f"stopped before the robot moved: {reason}"
            )
        else:
            text = str(last[1])
            if stopped:
                text = text.replace(CTRL_C_WORDS, f"interrupted by the user ({self.stop_reason})")
            text = text.replace(RESUME_WORDS, STATION_RESUME_WORDS)
            self.state, self.message = ("stopped" if stopped else "failed"), text

    def moves_shown(self) -> int:
        """The move the page counts: the one the last sample came from while the run moves; once
        it finished, the moves it completed (its last move, back home, takes no samples, so the
        samples alone would leave a finished check at one move short of its total)."""
        if self.state == "finished":
            record = self.output.record if self.output is not None else None
            result = record.result if isinstance(record, app.AcquireOutput) else None
            return result.moves_completed if result is not None else self.moves_total
        return self.move_index + 1 if self.samples else 0

    def snapshot(self, since: int) -> dict[str, Any]:
        """What the page shows: the live view's frames after ``since`` and the run's state."""
        data = self.view.snapshot(since)
        data.update(
            run_state=self.state,
            message=self.message,
            moves_total=self.moves_total,
            move=self.moves_shown(),
            # the motion's own counts: only an acquisition's frames reach the live view, so the
            # view's counts stay 0 through a check, a verification or a guidance
            samples=self.samples,
            visible=self.visible,
            stop_reason=self.stop_reason,
            awaiting=self.awaiting,
            remaining_s=self.remaining_s(),
        )
        return data

    def remaining_s(self) -> float | None:
        """About how long the run still moves, s: the rest of the current move and the planned
        durations of those after it; None without a plan's durations or once it ended."""
        if not self.active or self.move_durations_s is None or self.move_seen_at is None:
            return None
        durations = self.move_durations_s
        current = min(self.move_index, len(durations) - 1)
        into = time.monotonic() - self.move_seen_at
        return round(max(durations[current] - into, 0.0) + sum(durations[current + 1 :]), 1)


def planned_durations(settings: Any, moves_total: int) -> list[float] | None:
    """The planned duration of each move of an acquisition's plan file ``settings.plan`` (s),
    at the pace ``settings.simulated_speed`` runs it; None for another motion, without a plan
    file, when it cannot be read, or when its moves are not the run's ``moves_total``."""
    if not isinstance(settings, app.AcquireSettings) or not settings.plan:
        return None
    path = settings.plan
    try:
        moves = json.loads(Path(path).read_text(encoding="utf-8")).get("moves") or []
        durations = [float(move["duration_s"]) for move in moves]
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        return None
    if len(durations) != moves_total or not all(math.isfinite(d) and d >= 0 for d in durations):
        return None
    speed = settings.simulated_speed or 1.0
    return [d / speed for d in durations]


def _finished(motion: str, output: Any) -> str:
    """How a motion that ran to its end ended, in the command line's words."""
    if motion == "verify":
        return verification_line(output)
    if motion in ("standoff", "insert"):
        return guidance_line(output)
    if motion == "check":
        result = output.result
        if result is None:
            return "nothing was run"
        verdict = "PASS" if result.passed else "FAIL"
        return (
            f"{verdict}: largest departure {max(result.tcp_error_mm):.3f} mm "
            f"(tolerance up to {result.threshold_mm:.2f} mm)"
        )
    result = output.result
    if result is None:
        return "nothing was run"
    return (
        f"wrote {result.recording_path.name}: {result.samples_written} samples, {result.visible_written} "
        f"with the marker seen; {result.moves_completed}/{result.moves_total} moves"
    )


class Runs:
    """The station's acquisitions; at most one moves at a time."""

    def __init__(self, counter: Path | None = None) -> None:
        """``counter``: a file that keeps the last run id across restarts (None: ids start at
        1 each time), so an address ``/runs/N`` of yesterday never names today's run."""
        self._runs: dict[int, Run] = {}
        self._lock = threading.Lock()
        self._counter = counter
        self._next = 1
        if counter is not None and counter.is_file():
            text = counter.read_text(encoding="utf-8", errors="replace").strip()
            if not text.isdigit() or len(text) > 9:
                raise InvalidInputError(f"{counter}: not a run number ({text[:20]!r}); restore or remove it")
            self._next = int(text) + 1
        #: Runs of an earlier start of the station: ids below this one (their pages are gone).
        self.first_id = self._next

    def get(self, run_id: int) -> Run | None:
        return self._runs.get(run_id)

    def active(self) -> Run | None:
        return next((run for run in self._runs.values() if run.active), None)

    def next_id(self) -> int:
        """The id the next run started gets (runs are numbered from 1, never reused)."""
        with self._lock:
            return self._next

    def latest(self) -> Run | None:
        """The run started last (the robot stands where it left it)."""
        return self._runs[max(self._runs)] if self._runs else None

    def start(
        self,
        workspace: int,
        robot: str,
        settings: Any,
        motion: str = "acquire",
        on_done: Callable[[Run], None] | None = None,
    ) -> Run:
        """Start a motion (``acquire`` or ``check``) in its process, followed by a thread.

        Raises
        ------
        RuntimeError
            Another run is still moving a robot.
        """
        with self._lock:
            running = self.active()
            if running is not None:
                raise RuntimeError(f"another {running.words} is running: stop it or let it finish first")
            run = Run(self._next, workspace, robot, settings, motion, on_done)
            if self._counter is not None:
                write_text_atomic(f"{run.id}\n", self._counter)  # before it moves: never reused
            self._next += 1
            self._runs[run.id] = run
        run.thread = threading.Thread(target=run.work, name=f"spacecal-station-run-{run.id}", daemon=True)
        run.thread.start()
        return run

    def stop_all(self, reason: str) -> None:
        """Stop every active run and wait for it to end (the station shutting down)."""
        for run in list(self._runs.values()):
            if run.active:
                run.request_stop(reason)
        for run in list(self._runs.values()):
            if run.thread is not None:
                run.thread.join(timeout=30)
