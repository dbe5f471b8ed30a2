"""The OpenIGTLink reader and ``spacecal export --igtl`` against servers that stay silent, send a
byte at a time, announce a huge body (a 612 MB one: a length field of another protocol) or
close in the middle of a message: bounded in time and memory, one line.

The bounds are the deadlines plus a margin for a loaded 2-core machine, never tight times."""

import re
import time

import numpy as np
import pytest

from spacecal.adapters import igtl
from spacecal.adapters.igtl import IGTLTracker
from spacecal.core.errors import DeviceError
from spacecal.testing.fakes.igtl import pack_message, transform_content
from spacecal.testing.fakes.peers import Peer, announce, drip, hang_up, silent

#: Real client libraries against the protocol fakes, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime

#: Time on top of a deadline for a loaded machine, s.
MARGIN_S = 5.0
#: How long the reader waits for the marker's first message in these tests, s.
CONNECT_TIMEOUT_S = 2.0


def transform_message(name: str = "MarkerToTracker", timestamp_s: float = 1000.0) -> bytes:
    pose = np.eye(4)
    pose[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    pose[:3, 3] = [10.0, 20.0, -1500.0]
    return pack_message("TRANSFORM", name, transform_content(pose), timestamp_s)


def huge_header(kind: str = "TRANSFORM", body_bytes: int = 612 * 1000 * 1000) -> bytes:
    """A header announcing ``body_bytes``, its body never sent."""
    message = bytearray(pack_message(kind, "MarkerToTracker", b"", 1000.0))
    message[42:50] = body_bytes.to_bytes(8, "big")
    return bytes(message[:58])


def serving(behaviour, honest: bytes = b""):
    return Peer(lambda connection, peer: behaviour(connection, peer, honest))


READER_PEERS = {
    "silent": (silent, b"", "no MarkerToTracker message from .* within 2 s"),
    "a byte at a time": (drip, transform_message(), "no MarkerToTracker message from .* within 2 s"),
    "huge length": (
        announce(huge_header()),
        b"",
        r"announced a 612000000-byte TRANSFORM message \(at most 65536 bytes are accepted for a pose",
    ),
    "closed mid-message": (hang_up, transform_message(), "closed the connection"),
}


@pytest.mark.parametrize("name", list(READER_PEERS))
def test_connecting_to_a_hostile_sender_ends_by_the_connect_timeout(name):
    behaviour, honest, message = READER_PEERS[name]
    with serving(behaviour, honest) as peer:
        started = time.monotonic()
        with pytest.raises(DeviceError, match=message) as caught:
            IGTLTracker(peer.host, peer.port, connect_timeout_s=CONNECT_TIMEOUT_S)
        assert time.monotonic() - started < CONNECT_TIMEOUT_S + MARGIN_S
        assert "\n" not in str(caught.value)


def good_then(behaviour, honest: bytes = b""):
    """Three frames of the marker, then ``behaviour``."""

    def serve(connection, peer):
        for k in range(3):
            connection.sendall(transform_message(timestamp_s=1000.0 + 0.05 * k))
            time.sleep(0.05)
        time.sleep(igtl.BACKLOG_DRAIN_S + 0.5)  # past the reader's start
        behaviour(connection, peer, honest)

    return Peer(serve)


@pytest.mark.parametrize(
    ("name", "behaviour", "honest", "message"),
    [
        ("silent", silent, b"", "no OpenIGTLink message for 1.0 s"),
        ("a byte at a time", drip, transform_message(timestamp_s=2000.0), "no OpenIGTLink message for 1.0 s"),
        ("huge length", announce(huge_header("IMAGE", 2**40)), b"", "announced a 1099511627776-byte IMAGE"),
        # a peer that closes with the reader's GET_STATUS unread resets the connection (TCP RST)
        (
            "closed mid-message",
            hang_up,
            transform_message(timestamp_s=2000.0),
            "closed the connection|reset the connection",
        ),
    ],
)
def test_a_stream_that_turns_hostile_ends_the_next_frame_by_its_timeout(name, behaviour, honest, message):
    with good_then(behaviour, honest) as peer:
        tracker = IGTLTracker(peer.host, peer.port, connect_timeout_s=CONNECT_TIMEOUT_S)
        started = time.monotonic()
        with pytest.raises(DeviceError, match=message):
            for _ in range(40):
                tracker.next_frame(1.0)
        assert time.monotonic() - started < 1.0 + MARGIN_S
        tracker.close()


def test_a_large_message_that_is_not_a_pose_is_read_past_not_kept():
    image = pack_message("IMAGE", "Image_Reference", bytes(300_000), 999.0)

    def serve(connection, peer):
        connection.sendall(image)
        for k in range(20):
            connection.sendall(transform_message(timestamp_s=1000.0 + 0.05 * k))
            time.sleep(0.05)
        silent(connection, peer)

    with Peer(serve) as peer:
        tracker = IGTLTracker(peer.host, peer.port, connect_timeout_s=CONNECT_TIMEOUT_S)
        frame = tracker.next_frame(2.0)
        tracker.close()
    assert frame.tracker_from_marker is not None
    assert tracker.seen[("IMAGE", "Image_Reference")] == 1


# -- spacecal export --igtl --------------------------------------------------------------------
@pytest.fixture
def calibration_file(tmp_path, white_simulation):
    pytest.importorskip("pyigtl")
    from spacecal.estimators import calibrate
    from spacecal.io.results_json import write_calibration

    result = calibrate(white_simulation.recording, "paper", uncertainty=False)
    return write_calibration(result, tmp_path / "cal.json")


def export(calibration_file, peer, capsys) -> tuple[int, str, float]:
    from spacecal.cli import main

    started = time.monotonic()
    code = main(["export", str(calibration_file), "--igtl", f"{peer.host}:{peer.port}"])
    took = time.monotonic() - started
    return code, capsys.readouterr().err, took


EXPORT_BOUND_S = igtl.PUBLISH_DEADLINE_S + igtl.PUBLISH_LINGER_S + MARGIN_S


@pytest.mark.parametrize(
    ("name", "behaviour", "honest"),
    [("silent", silent, b""), ("a byte at a time", drip, transform_message("ReferenceToTracker"))],
)
def test_export_to_a_server_that_sends_nothing_whole_ends_after_the_linger(
    calibration_file, capsys, name, behaviour, honest
):
    """OpenIGTLink has no acknowledgement for a TRANSFORM: the message handed over is sent."""
    with serving(behaviour, honest) as peer:
        code, err, took = export(calibration_file, peer, capsys)
    assert code == 0, err
    assert took < EXPORT_BOUND_S


@pytest.mark.parametrize(
    ("name", "behaviour", "honest", "message"),
    [
        ("huge length", announce(huge_header("STATUS")), b"", "announced a 612000000-byte STATUS message"),
        (
            "closed mid-message",
            hang_up,
            transform_message("ReferenceToTracker"),
            # closing with our message unread resets the connection, depending on who is first
            "closed the connection in the middle of a message|reset the connection",
        ),
    ],
)
def test_export_to_a_server_that_is_not_one_is_one_line_and_exit_1(
    calibration_file, capsys, name, behaviour, honest, message
):
    with serving(behaviour, honest) as peer:
        code, err, took = export(calibration_file, peer, capsys)
    assert code == 1
    assert took < EXPORT_BOUND_S
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("spacecal: error: ") and re.search(message, lines[0])
    assert "BaseToTracker may not have arrived" in lines[0]


def test_export_to_nothing_listening_is_one_line_and_exit_1(calibration_file, capsys):
    with serving(silent) as peer:
        pass  # closed: nothing listens on its port any more
    code, err, took = export(calibration_file, peer, capsys)
    assert code == 1 and took < EXPORT_BOUND_S
    assert len(err.strip().splitlines()) == 1 and "could not connect to igtl://" in err
