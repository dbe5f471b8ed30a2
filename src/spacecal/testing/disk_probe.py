"""How long the disk stalls, measured beside a run: a row of its own forced to the disk on a
thread, again and again.

A durable recording is forced to the disk before an acquisition ends (nothing recorded may be
lost, :mod:`spacecal.io.background_sync`), so on a disk that stalls, up to 34.6 s measured on a
busy 2-core machine sharing a virtual disk, a run's end waits with it. A test that bounds how
fast a run ends applies its bound to the rest of the time (:meth:`DiskProbe.stalled_s`);
``benchmarks/fsync_latency.py`` prints how the waits were distributed.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from pathlib import Path

#: How often the probe forces a row to the disk, s.
PERIOD_S = 0.02
#: A sync that waits longer than this is a stall, s.
STALL_S = 0.1
#: The row the probe appends: 200 bytes, about one tracker row of a raw-stream recording.
ROW = "x" * 199 + "\n"


class DiskProbe:
    """Forces :data:`ROW` to ``folder/disk-probe.dat`` every ``period_s`` on a thread of its own,
    keeps every wait, and each span it waited longer than ``stall_s``.

    Parameters
    ----------
    folder : path
        Where the probe's file goes (removed on :meth:`close`).
    period_s, stall_s : float
        The pause between syncs and the wait that counts as a stall, s.
    on_stall : callable, optional
        Called with each stall's wait, s, as it ends (a benchmark prints it).
    """

    def __init__(
        self,
        folder: str | Path,
        period_s: float = PERIOD_S,
        stall_s: float = STALL_S,
        on_stall: Callable[[float], None] | None = None,
    ):
        self._path = Path(folder) / "disk-probe.dat"
        self.period_s = period_s
        self.stall_s = stall_s
        self._on_stall = on_stall
        self.waits: list[float] = []
        self._stalls: list[tuple[float, float]] = []
        self._waiting_since: float | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="disk probe", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        with open(self._path, "w") as handle:
            while not self._stop.is_set():
                started = time.monotonic()
                with self._lock:
                    self._waiting_since = started
                handle.write(ROW)
                handle.flush()
                os.fsync(handle.fileno())
                ended = time.monotonic()
                with self._lock:
                    self._waiting_since = None
                    self.waits.append(ended - started)
                    stalled = ended - started > self.stall_s
                    if stalled:
                        self._stalls.append((started, ended))
                if stalled and self._on_stall is not None:
                    self._on_stall(ended - started)
                self._stop.wait(self.period_s)

    def _spans(self, until: float) -> list[tuple[float, float]]:
        """Each stall's span, with a sync still waiting at ``until`` counted up to it."""
        with self._lock:
            spans = list(self._stalls)
            if self._waiting_since is not None and until - self._waiting_since > self.stall_s:
                spans.append((self._waiting_since, until))
        return spans

    def _inside(self, since: float, until: float) -> list[float]:
        return [max(0.0, min(end, until) - max(start, since)) for start, end in self._spans(until)]

    def stalled_s(self, since: float, until: float) -> float:
        """Seconds of ``[since, until]`` (``time.monotonic``) the probe spent in stalled syncs,
        counting a sync still waiting at ``until`` up to it."""
        return sum(self._inside(since, until))

    def longest_stall_s(self, since: float, until: float) -> float:
        """The longest single stall's part inside ``[since, until]``, s (0 when none)."""
        return max(self._inside(since, until), default=0.0)

    def close(self) -> None:
        """Stops the probe (after its current sync, which may be a stall) and removes its file."""
        self._stop.set()
        self._thread.join(60.0)
        self._path.unlink(missing_ok=True)
