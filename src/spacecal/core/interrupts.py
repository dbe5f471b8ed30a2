"""A stop asked for by a signal (Ctrl-C, SIGTERM, SIGHUP), kept until the loop that moves the
robot has seen it.

The command line's signal handler raises :class:`StopRequested`, a ``KeyboardInterrupt``, so a
blocking wait ends at once. Python loses such an exception when the signal lands while it runs
code whose exceptions cannot propagate: a weakref callback (importlib's module-lock clean-up,
measured: one of 20 interruption points in one test run), a ``__del__``. It prints "Exception
ignored in ..." and goes on, and a run would carry on moving the robot. So the request is also
kept here, and the loops that move a robot call :func:`raise_if_stop_requested` at every
tracker frame: a stop asked for is never lost.
"""

from __future__ import annotations

import threading

_lock = threading.Lock()
_requested: str | None = None


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
