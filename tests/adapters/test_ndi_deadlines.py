"""Every NDI call over TCP ends by its deadline, against trackers that answer like the Combined API
fake until one command, then stop answering, answer a byte at a time, announce a huge binary
reply, or close the connection in the middle of the reply.

The bounds are the deadlines plus a margin for a loaded 2-core machine, never tight times."""

import itertools
import os
import signal
import struct
import threading
import time

import numpy as np
import pytest

pytest.importorskip("ndicapy")

from spacecal.adapters import ndi
from spacecal.adapters.ndi import NDITracker
from spacecal.core.errors import DeviceError
from spacecal.testing.fakes.ndi import FakeNDI, crc16, split_command
from spacecal.testing.fakes.peers import Peer, announce, drip, hang_up, silent

#: Real client libraries against the protocol fakes, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime

#: Time on top of a deadline for a loaded machine, s.
MARGIN_S = 5.0


def ndi_peer(trigger: str, behaviour, skip: int = 0, commands: list | None = None):
    """A tracker that answers like the Combined API fake until the ``skip + 1``-th command
    starting with ``trigger``, then hands the connection to ``behaviour`` (with the reply the
    fake would have sent); a behaviour that returns True has answered, and the tracker goes on.
    Every command received is appended to ``commands``."""
    pose = np.eye(4)
    pose[:3, 3] = [10.0, 20.0, -1500.0]
    frames = itertools.count(100)

    def serve(connection, peer):
        device = FakeNDI(lambda: (next(frames), pose, 0.1))
        seen = 0
        buffer = b""
        connection.settimeout(0.1)
        while not peer.stop.is_set():
            try:
                chunk = connection.recv(4096)
            except TimeoutError:
                continue
            if not chunk:
                peer.ended.set()
                return
            buffer += chunk
            while b"\r" in buffer:
                line, buffer = buffer.split(b"\r", 1)
                command = split_command(line)
                if commands is not None:
                    commands.append(command)
                reply = device.handle(command) or b""
                if command.upper().startswith(trigger):
                    seen += 1
                    if seen > skip:
                        if behaviour(connection, peer, reply):
                            continue
                        return
                connection.sendall(reply)

    return serve


def huge_binary_reply(connection, peer, honest=b""):
    """A BX reply header announcing the largest body there is (64 kB), then nothing."""
    header = struct.pack("<HH", 0xA5C4, 0xFFFF)
    announce(header + struct.pack("<H", crc16(header)))(connection, peer, honest)


def held_until(event: threading.Event, at_most: float = 30.0):
    """A behaviour that answers only once ``event`` is set (or ``at_most`` seconds passed)."""

    def behave(connection, peer, honest=b""):
        event.wait(at_most)
        connection.sendall(honest)
        return True

    return behave


def open_tracker(peer, rom_file, **options):
    return NDITracker(peer.host, peer.port, [rom_file], **options)


def test_a_tracker_silent_on_init_ends_by_the_init_deadline(rom_file):
    with Peer(ndi_peer("INIT", silent)) as peer:
        started = time.monotonic()
        with pytest.raises(DeviceError, match=r"INIT within 7 s") as caught:
            open_tracker(peer, rom_file)
        assert time.monotonic() - started < ndi.NDI_INIT_DEADLINE_S + MARGIN_S
        assert "\n" not in str(caught.value)
        assert peer.ended.wait(MARGIN_S)  # the connection given up is closed


@pytest.mark.parametrize(
    ("name", "behaviour"),
    [("silent", silent), ("a byte at a time", drip), ("huge length", huge_binary_reply)],
)
def test_a_frame_request_ends_by_the_reply_deadline(rom_file, name, behaviour):
    # the second BX: the first has shown that this firmware answers BX
    with Peer(ndi_peer("BX", behaviour, skip=1)) as peer:
        tracker = open_tracker(peer, rom_file)
        tracker.next_frame(2.0)
        started = time.monotonic()
        with pytest.raises(DeviceError, match=r"NDI tracker lost: no answer while sending BX within 3 s"):
            tracker.next_frame(30.0)
        assert time.monotonic() - started < ndi.NDI_TCP_REPLY_DEADLINE_S + MARGIN_S
        started = time.monotonic()
        with pytest.raises(DeviceError, match="NDI tracker lost"):  # lost: nothing more is sent
            tracker.next_frame(1.0)
        tracker.close()
        assert time.monotonic() - started < MARGIN_S
        assert peer.ended.wait(MARGIN_S)


def test_a_reply_cut_off_by_a_closed_connection_is_a_lost_tracker(rom_file):
    with Peer(ndi_peer("BX", hang_up, skip=1)) as peer:
        tracker = open_tracker(peer, rom_file)
        tracker.next_frame(2.0)
        started = time.monotonic()
        with pytest.raises(DeviceError, match="NDI tracker"):
            tracker.next_frame(30.0)
        assert time.monotonic() - started < ndi.NDI_TCP_REPLY_DEADLINE_S + MARGIN_S
        tracker.close()


def test_the_read_only_checks_end_by_the_reply_deadline(rom_file):
    """``spacecal doctor``'s tracker checks: VER unanswered."""
    with Peer(ndi_peer("VER", silent)) as peer:
        tracker = open_tracker(peer, rom_file)
        started = time.monotonic()
        with pytest.raises(DeviceError, match="VER within 3 s"):
            tracker.preflight(duration_s=0.5)
        assert time.monotonic() - started < ndi.NDI_TCP_REPLY_DEADLINE_S + MARGIN_S
        tracker.close()


def test_the_doctor_reports_a_tracker_that_stops_answering_in_one_line(rom_file, capsys):
    from spacecal.cli.main import main

    with Peer(ndi_peer("VER", silent)) as peer:
        started = time.monotonic()
        code = main(["doctor", "--tracker", f"ndi://{peer.host}:{peer.port}", "--rom", str(rom_file)])
        assert time.monotonic() - started < ndi.NDI_TCP_REPLY_DEADLINE_S + ndi.NDI_CLOSE_DEADLINE_S + MARGIN_S
    out, err = capsys.readouterr()
    assert code == 1
    assert "tracker: connection: PROBLEM: NDI tracker lost: no answer while sending VER within 3 s" in out
    assert len(err.strip().splitlines()) == 1


def test_an_interrupted_frame_request_ends_at_once_and_the_tracker_is_still_stopped(rom_file):
    """Ctrl-C (or a signal) while a frame is on its way: the caller goes on at once (it has a
    robot to stop), and closing waits for the reply before it sends ``TSTOP``, so the tracker
    is left stopped, not tracking (an interrupt once made the tracker count as lost, and it was
    left tracking)."""
    commands: list = []
    interrupted = threading.Event()
    # The reply is held until the interrupt has reached the caller, so the caller went on
    # before the reply, however late a busy machine delivers the signal.
    with Peer(ndi_peer("BX", held_until(interrupted), skip=1, commands=commands)) as peer:
        tracker = open_tracker(peer, rom_file)
        tracker.next_frame(2.0)
        timer = threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGINT))
        timer.start()
        try:
            with pytest.raises(KeyboardInterrupt):
                tracker.next_frame(30.0)
        finally:
            interrupted.set()
        tracker.close()
        assert any(command.upper().startswith("TSTOP") for command in commands), commands


def test_a_silent_serial_port_is_one_line_by_the_probes_deadlines(rom_file, capsys):
    """A serial port where nothing answers (a pseudo-terminal nobody serves): ``doctor`` ends
    within the probes' deadlines (each ``ndiProbe`` waits 5 s at most, bounded at 10 s) with one
    line, not ndicapi's own waits."""
    from spacecal.cli.main import main
    from spacecal.testing.fakes.ndi import open_pty

    master, path = open_pty()
    try:
        started = time.monotonic()
        code = main(["doctor", "--tracker", f"ndi://{path}", "--rom", str(rom_file)])
        took = time.monotonic() - started
    finally:
        os.close(master)
    out, err = capsys.readouterr()
    assert code == 1
    assert f"tracker: connection: PROBLEM: no NDI tracker answers on {path}" in out, out
    assert len(err.strip().splitlines()) == 1
    assert took < ndi.PROBE_ATTEMPTS * ndi.NDI_OPEN_DEADLINE_S + MARGIN_S, took
