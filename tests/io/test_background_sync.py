"""A durable recording never makes its device loop wait for the disk (``io.background_sync``):
rows are forced to the disk on a thread of their own, all of them by the close, and a failing
disk still stops the run."""

import os
import threading
import time

import numpy as np
import pytest

from spacecal.io.raw_streams import RawStreamWriter, stream_paths

#: Bound on waits that return at once when the code is right (a busy machine may be slow).
WAIT_S = 30.0
FRAMES = 20
SYNC_THREAD = "spacecal raw-stream sync"


def recording_fsync(calls, hold=None):
    """An ``os.fsync`` that records which thread called it; with ``hold`` (an Event), the sync
    thread's calls wait until it is set, as on a disk that takes its time."""
    real = os.fsync

    def fsync(descriptor):
        calls.append(threading.current_thread().name)
        if hold is not None and threading.current_thread().name == SYNC_THREAD:
            hold.wait(WAIT_S)
        real(descriptor)

    return fsync


def write_frames(writer, count):
    for k in range(count):
        writer.add_tracker_frame(float(k) / 20, np.eye(4), 0.1, float(k) / 20)


def test_a_slow_disk_does_not_hold_up_the_writer_and_every_row_reaches_it(tmp_path, monkeypatch):
    calls, disk_busy = [], threading.Event()
    monkeypatch.setattr(os, "fsync", recording_fsync(calls, hold=disk_busy))
    writer = RawStreamWriter(tmp_path / "rec", {"simulated": False})
    # the header asked for a sync: the sync thread is now waiting for the disk
    deadline = time.monotonic() + WAIT_S
    while SYNC_THREAD not in calls and time.monotonic() < deadline:
        time.sleep(0.01)
    assert SYNC_THREAD in calls
    # every frame is written while that sync waits (had the writer waited, it would still be)
    writing = threading.Thread(target=write_frames, args=(writer, FRAMES))
    writing.start()
    writing.join(WAIT_S)
    assert not writing.is_alive()
    disk_busy.set()
    writer.close()
    # the close waited for the sync under way, then synced both files itself
    assert calls[-2:] == [threading.current_thread().name] * 2
    robot, tracker, _ = stream_paths(tmp_path / "rec")
    assert len(tracker.read_text().splitlines()) == FRAMES + 1


def test_a_failing_disk_stops_the_writer_at_its_next_row(tmp_path, monkeypatch):
    def failing(descriptor):
        raise OSError(5, "Input/output error")

    writer = RawStreamWriter(tmp_path / "rec", {"simulated": False})
    monkeypatch.setattr(os, "fsync", failing)
    # the row asks for a sync, which fails on the sync thread; on a busy machine the sync the
    # header asked for may not have run yet, fail first, and this row raise already
    try:
        write_frames(writer, 1)
    except OSError as exc:
        assert "Input/output error" in str(exc)
    writer._sync._thread.join(WAIT_S)
    assert not writer._sync._thread.is_alive()  # a failed sync ends the thread
    with pytest.raises(OSError, match="Input/output error"):
        write_frames(writer, 1)
    monkeypatch.undo()
    with pytest.raises(OSError, match="Input/output error"):
        writer.close()  # still closes both files
    assert all(handle.closed for handle in writer._files)


def test_a_simulated_recording_starts_no_sync_thread(tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(os, "fsync", recording_fsync(calls))
    writer = RawStreamWriter(tmp_path / "rec", {"simulated": True}, durable=False)
    written_metadata = len(calls)  # the metadata file is written atomically, synced
    write_frames(writer, 3)
    assert len(calls) == written_metadata
    writer.close()
    assert calls[written_metadata:] == ["MainThread"] * 2  # the close alone
