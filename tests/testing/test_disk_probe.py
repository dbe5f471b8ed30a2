"""The disk probe the stop tests run beside each run (``spacecal.testing.disk_probe``): what it
counts as a stall, and what of it falls inside a run's end."""

from __future__ import annotations

import threading
import types

from spacecal.testing import disk_probe
from spacecal.testing.disk_probe import DiskProbe


def test_the_disk_probe_counts_only_stalls_inside_the_window(tmp_path):
    """What the end bound leaves out is the part of each stalled sync inside the window."""
    probe = DiskProbe(tmp_path)
    probe.close()
    probe._stalls = [(0.0, 1.0), (2.0, 5.0), (9.0, 9.5)]
    assert probe.stalled_s(0.5, 4.0) == 0.5 + 2.0
    assert probe.stalled_s(6.0, 8.0) == 0.0
    probe._waiting_since = 7.0  # a sync still waiting at the window's end counts up to it
    assert probe.stalled_s(6.0, 8.0) == 1.0
    # the longest single stall: the 3-s one, cut to the window; none in an empty window
    assert probe.longest_stall_s(0.0, 10.0) == 3.0
    assert probe.longest_stall_s(0.5, 3.0) == 1.0
    assert probe.longest_stall_s(5.5, 6.5) == 0.0


def test_a_slow_sync_is_reported_and_counted_and_a_quick_one_is_not(tmp_path, monkeypatch):
    """One sync is made to wait 0.3 s (the disk stalls), the others return at once; the probe
    reports that wait, counts it as a stall, keeps every wait, and leaves no file behind. (On a
    busy machine a write may stall too: those count as well, so the test counts what it sees.)"""
    stalled_once = threading.Event()

    def fsync(descriptor):
        if not stalled_once.is_set():
            stalled_once.set()
            threading.Event().wait(0.3)

    monkeypatch.setattr(disk_probe, "os", types.SimpleNamespace(fsync=fsync))
    reported: list[float] = []
    probe = DiskProbe(tmp_path, period_s=0.01, stall_s=0.2, on_stall=reported.append)
    threading.Event().wait(0.5)
    probe.close()
    assert max(reported) >= 0.3
    assert reported == [wait for wait in probe.waits if wait > 0.2]
    assert len(probe._stalls) == len(reported)
    assert any(wait < 0.2 for wait in probe.waits)  # a quick sync is kept, not reported
    started, ended = probe._stalls[0]
    assert probe.stalled_s(started - 1.0, ended + 1.0) >= ended - started
    assert not (tmp_path / "disk-probe.dat").exists()
