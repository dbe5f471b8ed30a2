"""Forcing open files to the disk (``fsync``) on a thread of their own.

A recording on real devices must survive a power cut, so its rows are forced to the disk as
they are written. ``fsync`` waits for the disk, and on a busy computer that wait was measured
at up to 6.4 s (an ext4 disk shared with other writers): a control loop that waited for it
would see its robot's moves and faults seconds late. The loop therefore only hands each row to
the operating system (which a killed process survives) and asks this thread to force the files
to the disk; the thread does so as often as the disk allows. A power cut can then lose the rows
of the one ``fsync`` under way, as it could before (the loop was waiting in it, not reading
frames). An error of the disk is raised in the loop at its next request.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Sequence
from typing import IO, Any


class BackgroundSync:
    """Force ``files`` to the disk on a daemon thread, whenever :meth:`request` asks.

    Parameters
    ----------
    files : sequence of open file objects
        Synced together (by their descriptors), in order; the caller writes and flushes them.
    name : str
        The thread's name.
    """

    def __init__(self, files: Sequence[IO[Any]], name: str = "spacecal file sync"):
        self._files = list(files)
        self._wanted = threading.Event()
        self._closing = False
        self._error: OSError | None = None
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def request(self) -> None:
        """Ask for a sync of everything flushed so far; raise the last sync's error, if any.

        Raises
        ------
        OSError
            A sync since the last request failed (a full or failing disk).
        """
        if self._error is not None:
            raise self._error
        self._wanted.set()

    def close(self) -> None:
        """Stop the thread once a sync under way has finished (the caller syncs last)."""
        self._closing = True
        self._wanted.set()
        self._thread.join()
        if self._error is not None:
            raise self._error

    def _run(self) -> None:
        while True:
            self._wanted.wait()
            self._wanted.clear()
            if self._closing:
                return
            try:
                for handle in self._files:
                    os.fsync(handle.fileno())
            except OSError as exc:  # handed to the loop at its next request
                self._error = exc
                return
