"""Motions the station runs: confirmation tickets, and the acquisition's worker thread with its
STOP.

A motion starts only from a ticket (:class:`Tickets`): the confirmation page issues one that
names the robot and the motion; the start request must hand it back, once, within
:data:`TICKET_LIFETIME_S`. No ticket, no motion.

STOP takes the command line's Ctrl-C path: the acquisition loop calls the station's frame
observer at every tracker frame, and once STOP was pressed (or the page's connection was lost)
the observer raises :class:`StationStop`, a ``KeyboardInterrupt`` as Ctrl-C raises, which the
acquisition catches as it catches Ctrl-C: it stops the robot, keeps every sample and records
where it stopped. A stopped run is over: the robot moves again only after a new confirmation.
"""

from __future__ import annotations

import secrets
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from spacecal import app
from spacecal.report.live import LiveView

#: How long a confirmation stays valid, s.
TICKET_LIFETIME_S = 300.0
#: A run whose page has not connected within this time after the robot started moving (its
#: first tracker frame) is stopped, s.
PAGE_CONNECT_WITHIN_S = 15.0
#: The words of the acquisition's Ctrl-C stop, replaced by the station's own reason.
CTRL_C_WORDS = "interrupted by the user (Ctrl-C)"


class StationStop(KeyboardInterrupt):
    """STOP on the station's page, or its connection lost: the acquisition stops as on Ctrl-C."""


@dataclass(frozen=True)
class Ticket:
    """A confirmed motion: which workspace, robot and motion it is for."""

    workspace: int
    robot: str
    motion: str
    issued: float


class Tickets:
    """Single-use confirmations of motions."""

    def __init__(self) -> None:
        self._open: dict[str, Ticket] = {}
        self._lock = threading.Lock()

    def issue(self, workspace: int, robot: str, motion: str) -> str:
        """A new ticket for the motion ``motion`` of robot ``robot``."""
        key = secrets.token_urlsafe(24)
        with self._lock:
            self._open[key] = Ticket(workspace, robot, motion, time.monotonic())
        return key

    def redeem(self, key: str | None, workspace: int, motion: str) -> Ticket | None:
        """The ticket ``key`` when it was issued for this workspace and motion and is still
        valid; it is used up either way."""
        if not key:
            return None
        with self._lock:
            ticket = self._open.pop(key, None)
        if ticket is None or ticket.workspace != workspace or ticket.motion != motion:
            return None
        if time.monotonic() - ticket.issued > TICKET_LIFETIME_S:
            return None
        return ticket


@dataclass
class Run:
    """One acquisition the station runs in its worker thread.

    Attributes
    ----------
    view : LiveView
        Keeps the frames for the page (its server is not started: the station serves them).
    state : str
        ``starting``, ``running``, ``finished``, ``stopped`` or ``failed``.
    message : str
        How it ended, in the command line's words.
    """

    id: int
    workspace: int
    robot: str
    settings: app.AcquireSettings
    view: LiveView = field(default_factory=lambda: LiveView(0))
    state: str = "starting"
    message: str = ""
    moves_total: int = 0
    move_index: int = 0
    samples: int = 0
    visible: int = 0
    output: app.CommandResult[app.AcquireOutput] | None = None
    stop_requested_at: float | None = None
    stop_reason: str = ""
    ended_at: float | None = None
    last_frame_at: float | None = None
    first_frame_at: float | None = None
    started_at: float = field(default_factory=time.monotonic)
    watchers: int = 0
    ever_watched: bool = False
    _stop: threading.Event = field(default_factory=threading.Event)
    thread: threading.Thread | None = None

    @property
    def active(self) -> bool:
        return self.state in ("starting", "running")

    def request_stop(self, reason: str) -> None:
        """Stop the run (the same path as Ctrl-C) at its next tracker frame."""
        if self.stop_requested_at is None:
            self.stop_requested_at = time.monotonic()
            self.stop_reason = reason
        self._stop.set()

    # -- the acquisition's callbacks (worker thread) ---------------------------------------

    def _check_stop(self) -> None:
        if self._stop.is_set():
            raise StationStop(self.stop_reason)

    def on_plan(self, moves: int) -> None:
        self.moves_total = moves
        self._check_stop()  # a STOP before anything moved ends the run before the motion

    def on_sample(self, samples: int, visible: int, move_index: int, label: str) -> None:
        self.samples, self.visible, self.move_index = samples, visible, move_index

    def observe(
        self,
        time_s: float,
        segment: str,
        tracker_from_marker: np.ndarray | None,
        base_from_tcp: np.ndarray,
        recorded: bool,
    ) -> None:
        self._check_stop()
        self.state = "running"
        self.last_frame_at = time.monotonic()
        if self.first_frame_at is None:
            self.first_frame_at = self.last_frame_at
        self.view.observe(time_s, segment, tracker_from_marker, base_from_tcp, recorded)

    def work(self) -> None:
        """The worker thread's body: run the acquisition, keep how it ended."""
        try:
            self.output = app.acquire(
                self.settings, on_sample=self.on_sample, observer=self.observe, on_plan=self.on_plan
            )
            self.state, self.message = "finished", _finished(self.output.record)
        except StationStop:
            # stopped before the motion started (while planning): nothing moved
            self.state, self.message = "stopped", f"stopped before the robot moved: {self.stop_reason}"
        except Exception as exc:  # every way out is shown on the page, in the CLI's words
            stopped = self.stop_requested_at is not None
            text = " ".join(str(exc).split()) or type(exc).__name__
            if stopped:
                text = text.replace(CTRL_C_WORDS, f"interrupted by the user ({self.stop_reason})")
            self.state, self.message = ("stopped" if stopped else "failed"), text
        finally:
            self.ended_at = time.monotonic()
            self.view.finish(f"{self.state}: {self.message}")

    def snapshot(self, since: int) -> dict[str, Any]:
        """What the page shows: the live view's frames after ``since`` and the run's state."""
        data = self.view.snapshot(since)
        data.update(
            run_state=self.state,
            message=self.message,
            moves_total=self.moves_total,
            move=self.move_index + 1 if self.samples else 0,
            stop_reason=self.stop_reason,
        )
        return data


def _finished(output: app.AcquireOutput) -> str:
    result = output.result
    if result is None:
        return "nothing was run"
    return (
        f"wrote {result.recording_path.name}: {result.samples_written} samples, {result.visible_written} "
        f"with the marker seen; {result.moves_completed}/{result.moves_total} moves"
    )


class Runs:
    """The station's acquisitions; at most one moves at a time."""

    def __init__(self) -> None:
        self._runs: dict[int, Run] = {}
        self._lock = threading.Lock()

    def get(self, run_id: int) -> Run | None:
        return self._runs.get(run_id)

    def active(self) -> Run | None:
        return next((run for run in self._runs.values() if run.active), None)

    def start(self, workspace: int, robot: str, settings: app.AcquireSettings) -> Run:
        """Start an acquisition in a worker thread.

        Raises
        ------
        RuntimeError
            Another run is still moving a robot.
        """
        with self._lock:
            if self.active() is not None:
                raise RuntimeError("another acquisition is running: stop it or let it finish first")
            run = Run(len(self._runs) + 1, workspace, robot, settings)
            self._runs[run.id] = run
        run.thread = threading.Thread(target=run.work, name=f"spacecal-station-run-{run.id}", daemon=True)
        run.thread.start()
        threading.Thread(target=self._watch_page, args=(run,), daemon=True).start()
        return run

    @staticmethod
    def _watch_page(run: Run) -> None:
        """Stop a run whose page never connected (the browser went away before it opened)."""
        while run.active and (
            run.first_frame_at is None or time.monotonic() - run.first_frame_at < PAGE_CONNECT_WITHIN_S
        ):
            if run.ever_watched:
                return
            time.sleep(0.2)
        if run.active and not run.ever_watched:
            run.request_stop("the station's page never connected")

    def stop_all(self, reason: str) -> None:
        """Stop every active run and wait for it to end (the station shutting down)."""
        for run in list(self._runs.values()):
            if run.active:
                run.request_stop(reason)
        for run in list(self._runs.values()):
            if run.thread is not None:
                run.thread.join(timeout=30)
