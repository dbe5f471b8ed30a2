"""A durable recording never makes its device loop wait for the disk (``io.background_sync``):
rows are forced to the disk on a thread of their own, all of them by the close, and a failing
disk still stops the run."""

import os
import threading
import time

import numpy as np
import pytest

from spacecal.io.raw_streams import RawStreamWriter, stream_paths

#: How long each forced write takes here: the longest measured on a busy 2-core machine was 6.4 s.
SLOW_FSYNC_S = 0.5
FRAMES = 20


def slow_fsync(calls):
    real = os.fsync

    def fsync(descriptor):
        calls.append(threading.current_thread().name)
        time.sleep(SLOW_FSYNC_S)
        real(descriptor)

    return fsync


def write_frames(writer, count, period_s=0.0):
    for k in range(count):
        writer.add_tracker_frame(float(k) / 20, np.eye(4), 0.1, float(k) / 20)
        time.sleep(period_s)


def test_a_slow_disk_does_not_hold_up_the_writer_and_every_row_reaches_it(tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(os, "fsync", slow_fsync(calls))
    writer = RawStreamWriter(tmp_path / "rec", {"simulated": False})
    started = time.monotonic()
    write_frames(writer, FRAMES, period_s=0.005)
    writing_s = time.monotonic() - started
    # each frame asks for a sync; none waits for one (all twenty would take ten seconds)
    assert writing_s < FRAMES * 0.005 + SLOW_FSYNC_S / 2, writing_s
    closing = time.monotonic()
    writer.close()
    # the close waits for the sync under way, then syncs both files itself
    assert time.monotonic() - closing >= 2 * SLOW_FSYNC_S
    assert calls[-2:] == [threading.current_thread().name] * 2
    assert any(name == "spacecal raw-stream sync" for name in calls), calls
    robot, tracker, _ = stream_paths(tmp_path / "rec")
    assert len(tracker.read_text().splitlines()) == FRAMES + 1


def test_a_failing_disk_stops_the_writer_at_its_next_row(tmp_path, monkeypatch):
    writer = RawStreamWriter(tmp_path / "rec", {"simulated": False})

    def failing(descriptor):
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(os, "fsync", failing)
    with pytest.raises(OSError, match="Input/output error"):
        for _ in range(200):  # the sync thread fails on the first request; a later row raises
            write_frames(writer, 1)
            time.sleep(0.005)
    monkeypatch.undo()
    with pytest.raises(OSError, match="Input/output error"):
        writer.close()  # still closes both files
    assert all(handle.closed for handle in writer._files)


def test_a_simulated_recording_starts_no_sync_thread(tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(os, "fsync", slow_fsync(calls))
    writer = RawStreamWriter(tmp_path / "rec", {"simulated": True}, durable=False)
    written_metadata = len(calls)  # the metadata file is written atomically, synced
    write_frames(writer, 3, period_s=0.005)
    assert len(calls) == written_metadata
    writer.close()
    assert calls[written_metadata:] == ["MainThread"] * 2  # the close alone
