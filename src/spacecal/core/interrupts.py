"""A stop asked for by a signal (Ctrl-C, SIGTERM, SIGHUP), kept until the loop that moves the
robot has seen it.

The signal handler of :func:`signals_as_interrupts` raises :class:`StopRequested`, a
``KeyboardInterrupt``, so a blocking wait ends at once. Python loses such an exception when the
signal lands while it runs code whose exceptions cannot propagate: a weakref callback
(importlib's module-lock clean-up, measured: one of 20 interruption points in one test run), a
``__del__``. It prints "Exception
ignored in ..." and goes on, and a run would carry on moving the robot. So the request is also
kept here, and the loops that move a robot call :func:`raise_if_stop_requested` at every
tracker frame: a stop asked for is never lost.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from collections.abc import Iterator

_lock = threading.Lock()
_requested: str | None = None
#: The signals that ask for a stop (SIGHUP does not exist everywhere).
_STOP_SIGNALS = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)
)
#: True from :func:`hold_stops_while_starting` until :func:`signals_as_interrupts` takes over.
_held = False


class StopRequested(KeyboardInterrupt):
    """Ctrl-C, SIGTERM or SIGHUP: the robot stops and files stay readable. ``args[0]`` names
    the signal (``Ctrl-C``, ``SIGTERM``, ``SIGHUP``)."""


def request_stop(reason: str) -> bool:
    """Keep a stop request; True for the first since :func:`clear` (later ones are the same
    stop, asked for again)."""
    global _requested
    with _lock:
        if _requested is not None:
            return False
        _requested = reason
        return True


def stop_requested() -> str | None:
    """The reason of the stop asked for, or None."""
    return _requested


def clear() -> None:
    """Forget the request: a new command starts."""
    global _requested
    with _lock:
        _requested = None


def raise_if_stop_requested() -> None:
    """Raise :class:`StopRequested` when a stop was asked for (its exception may have been
    lost on the way)."""
    reason = _requested
    if reason is not None:
        raise StopRequested(reason)


def _reason(signum: int) -> str:
    return "Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name


def _keep_stop(signum, frame) -> None:
    """The signal handler while a program starts: keep the request, raise nothing."""
    request_stop(_reason(signum))


def hold_stops_while_starting() -> None:
    """For a program's entry point, before it imports its modules: SIGINT, SIGTERM and SIGHUP
    are kept, not raised, until :func:`signals_as_interrupts` takes over, which then raises a
    stop kept meanwhile at once, before the command does anything.

    A ``KeyboardInterrupt`` raised while a C extension initialises (scipy's, numpy's) turns
    into ``ImportError: initialization failed`` with a traceback, not the command line's one
    line (measured: a SIGINT 2.9 s after ``spacecal acquire`` started on a busy machine).
    """
    global _held
    for number in _STOP_SIGNALS:
        signal.signal(number, _keep_stop)
    _held = True


def _raise_interrupt(signum, frame) -> None:
    """The signal handler: keep the stop request and raise it (once)."""
    reason = _reason(signum)
    if not request_stop(reason):
        # a second signal while the run stops (Ctrl-C pressed twice, a service manager's
        # repeated SIGTERM) must not abort the robot's stop half-way: it is ignored
        return
    raise StopRequested(reason)


def _quiet_about_stops(hook):
    """``sys.unraisablehook`` that stays quiet about a stop request Python could not raise (it
    landed in a weakref callback or a ``__del__``): the request is kept, and the loop moving the
    robot raises it at its next frame (:func:`raise_if_stop_requested`)."""

    def quiet(unraisable) -> None:
        if not isinstance(unraisable.exc_value, StopRequested):
            hook(unraisable)

    return quiet


@contextlib.contextmanager
def signals_as_interrupts() -> Iterator[None]:
    """SIGINT, SIGTERM and SIGHUP raise KeyboardInterrupt once while a command runs (main
    thread only), and the request is kept until the run has seen it; later ones are ignored
    until the command has cleaned up."""
    global _held
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    kept = _requested if _held else None  # a stop while the program started
    _held = False
    clear()
    previous = {}
    for number in _STOP_SIGNALS:
        previous[number] = signal.signal(number, _raise_interrupt)
    previous_hook = sys.unraisablehook
    sys.unraisablehook = _quiet_about_stops(previous_hook)
    try:
        if kept is not None:
            request_stop(kept)
            raise StopRequested(kept)
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
        sys.unraisablehook = previous_hook
        clear()  # the command has stopped and cleaned up: the request is spent


def signal_named(exc: BaseException, text: str) -> str:
    """A run stopped by SIGTERM or SIGHUP says so (the acquisition names every interruption
    Ctrl-C)."""
    cause = exc.__context__
    if isinstance(cause, StopRequested) and cause.args and cause.args[0] != "Ctrl-C":
        return text.replace("interrupted by the user (Ctrl-C)", f"interrupted ({cause.args[0]})")
    return text
