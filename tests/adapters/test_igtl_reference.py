"""Our OpenIGTLink reader and export against programs built on the OpenIGTLink C++ library
(``tests/igtl_reference``; Debian package ``libopenigtlink-dev``, which speaks header version 1).

Outside CI the tests skip when the library or a C++ compiler is missing; in CI (``CI=true``)
that is a failure, so the reference check can never be skipped silently there.
"""

import subprocess

import numpy as np
import pytest

from spacecal.adapters.igtl import IGTLTracker, publish_transform
from spacecal.core.ports import FRAME_MISSING, FRAME_OK

from .igtl_reference_programs import build_reference_programs, free_port

#: Real client libraries against the protocol fakes, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime

#: The pose the reference sender sends: 30 deg about z, then (12.5, -40, -1450) mm.
c, s = np.cos(np.pi / 6), np.sin(np.pi / 6)
MARKER = np.array([[c, -s, 0, 12.5], [s, c, 0, -40.0], [0, 0, 1, -1450.0], [0, 0, 0, 1]])


@pytest.fixture(scope="session")
def reference_programs(tmp_path_factory):
    """The reference sender and receiver, compiled once per session into a temporary folder."""
    return build_reference_programs(tmp_path_factory.mktemp("igtl_reference"), ("sender", "receiver"))


def start(program, *arguments):
    process = subprocess.Popen([str(program), *map(str, arguments)], stdout=subprocess.PIPE, text=True)
    assert process.stdout.readline().strip() == "READY"
    return process


@pytest.mark.parametrize("form", ["transform", "position", "tdata"])
def test_reading_the_reference_senders_forms(reference_programs, form):
    port = free_port()
    sender = start(reference_programs["sender"], port, form)
    try:
        tracker = IGTLTracker("127.0.0.1", port)
        frames = [tracker.next_frame(1.0) for _ in range(16)]
        tracker.close()
    finally:
        sender.kill()
        sender.wait(timeout=10)
    statuses = [f.status for f in frames]
    assert FRAME_MISSING in statuses and statuses.count(FRAME_OK) >= 8  # every 4th frame lacks it
    for frame in frames:
        if frame.status == FRAME_OK:
            assert np.allclose(frame.tracker_from_marker, MARKER, atol=1e-4)
        else:
            assert frame.tracker_from_marker is None
    assert tracker.header_versions == {1} and tracker.crc_errors == 0
    assert np.all(np.diff([f.time_s for f in frames]) > 0)


def test_the_calibration_export_reaches_the_reference_receiver(reference_programs):
    pytest.importorskip("pyigtl")  # the export sends with pyigtl (extra igtl)
    port = free_port()
    receiver = start(reference_programs["receiver"], port)
    calibration = np.array(
        [[0.0, -1.0, 0.0, 250.5], [1.0, 0.0, 0.0, -120.25], [0, 0, 1, 1300.0], [0, 0, 0, 1]]
    )
    try:
        publish_transform("127.0.0.1", port, "BaseToTracker", calibration)
        out, _ = receiver.communicate(timeout=20)
    finally:
        receiver.kill()
    assert receiver.returncode == 0, out  # the library's CRC check passed
    words = out.split()
    assert words[:2] == ["TRANSFORM", "BaseToTracker"]
    assert np.allclose(np.array(words[2:], dtype=float).reshape(3, 4), calibration[:3], atol=1e-4)
