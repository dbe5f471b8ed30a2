"""``spacecal doctor`` against trackers whose poses are not poses: an NDI tracker whose
positions are NaN and an OpenIGTLink sender whose marker is 1e30 mm away. A run keeps such
frames as gaps; the doctor names them as a problem and does not pass the tracker."""

from __future__ import annotations

import itertools
import time

import numpy as np
import pytest

pytest.importorskip("ndicapy")

from spacecal.cli.main import main
from spacecal.testing.fakes.igtl import pack_message, transform_content
from spacecal.testing.fakes.ndi import FakeNDI, serve_commands
from spacecal.testing.fakes.peers import Peer

#: Real client libraries against the protocol fakes, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime

#: The doctor samples the tracker for 1 s; the rest is connecting and closing on a busy machine.
DOCTOR_WITHIN_S = 30.0


def ndi_tracker_sending(pose: np.ndarray):
    """An NDI tracker over TCP (the Combined API fake) whose marker is always at ``pose``."""
    frames = itertools.count(100)

    def serve(connection, peer):
        device = FakeNDI(lambda: (next(frames), pose, 0.1))
        serve_commands(lambda: connection.recv(4096), connection.sendall, device, peer.stop)

    return serve


def igtl_sender_sending(pose: np.ndarray):
    """An OpenIGTLink sender of ``MarkerToTracker`` at ``pose``, 20 times a second."""

    def serve(connection, peer):
        stamp = 1000.0
        while not peer.stop.is_set():
            try:
                connection.sendall(
                    pack_message("TRANSFORM", "MarkerToTracker", transform_content(pose), stamp)
                )
            except OSError:
                return
            stamp += 0.05
            time.sleep(0.05)

    return serve


def pose_at(x_mm: float) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, 3] = [x_mm, 20.0, -1500.0]
    return pose


def doctor(url: str, *extra: str, capsys) -> tuple[int, str]:
    started = time.monotonic()
    code = main(["doctor", "--tracker", url, *extra])
    assert time.monotonic() - started < DOCTOR_WITHIN_S
    return code, capsys.readouterr().out


@pytest.mark.parametrize(("x_mm", "passes"), [(np.nan, False), (10.0, True)])
def test_an_ndi_tracker_sending_nan_positions_does_not_pass(rom_file, capsys, x_mm, passes):
    with Peer(ndi_tracker_sending(pose_at(x_mm))) as peer:
        code, out = doctor(f"ndi://{peer.host}:{peer.port}", "--rom", str(rom_file), capsys=capsys)
    if passes:  # the same tracker with a finite position: the control
        assert code == 0 and "every check passed" in out and "marker poses" not in out, out
    else:
        assert code == 1 and "every check passed" not in out, out
        assert "tracker: marker poses: PROBLEM: " in out and "were not a pose" in out, out


@pytest.mark.parametrize(("x_mm", "passes"), [(1e30, False), (10.0, True)])
def test_an_openigtlink_marker_1e30_mm_away_does_not_pass(capsys, x_mm, passes):
    with Peer(igtl_sender_sending(pose_at(x_mm))) as peer:
        code, out = doctor(f"igtl://{peer.host}:{peer.port}", capsys=capsys)
    if passes:
        assert code == 0 and "every check passed" in out and "marker poses" not in out, out
    else:
        assert code == 1 and "every check passed" not in out, out
        assert "tracker: marker poses: PROBLEM: " in out and "were not a pose" in out, out
