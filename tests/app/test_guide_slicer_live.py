"""``spacecal guide --slicer-live``: the reference OpenIGTLink C++ library, standing in for 3D
Slicer (``tests/igtl_reference/slicer_planner.cxx``), sends the plan as two transform nodes
(EntryToRAS, TargetToRAS); the guidance runs on the simulated devices in real time, and the
needle's pose comes back at 10 Hz or more, measured at the receiver, while the robot moves and
while it holds; the plan guided is the one sent."""

import json
import subprocess
import sys

import numpy as np
import pytest

from spacecal.app._common import simulated_scenario
from spacecal.io.results_json import read_calibration
from spacecal.sim.world import build_world
from tests.adapters.igtl_reference_programs import build_reference_programs, free_port
from tests.app.guide_files import make_calibration, write_registration

#: Real time: the simulated devices at real speed and a C++ peer on a socket (run apart, -m realtime).
pytestmark = pytest.mark.realtime

#: The needle's pose at a stage's end stands this close to the pose measured there (mm): the
#: marker's noise is tenths of a millimetre, a move passes by in a frame or two.
HOLDING_MM = 1.0
#: The rate asked for, Hz.
LEAST_RATE_HZ = 10.0


def rate_and_gap(times):
    """Mean rate (Hz) and largest gap (s) over runs of consecutive messages (times, s)."""
    gaps = np.concatenate([np.diff(run) for run in times if len(run) > 1])
    return len(gaps) / gaps.sum(), gaps.max()


def runs(times, inside):
    """The runs of consecutive messages for which ``inside`` holds."""
    found, current = [], []
    for t, keep in zip(times, inside):
        if keep:
            current.append(t)
        elif current:
            found.append(np.array(current))
            current = []
    if current:
        found.append(np.array(current))
    return found


def test_the_needle_streams_to_the_slicer_stand_in_while_moving_and_holding(tmp_path):
    planner = build_reference_programs(tmp_path, ("slicer_planner",))["slicer_planner"]
    calibration = make_calibration(tmp_path)
    world = build_world(simulated_scenario(read_calibration(calibration), None))
    registration = write_registration(tmp_path / "TrackerToRAS.tfm", world.phantom.tracker_from_image)
    path = world.phantom.paths[0]
    ras = np.array([-1.0, -1.0, 1.0])
    sent = np.concatenate([ras * path.entry_in_image, ras * path.target_in_image]).astype(np.float32)
    port = free_port()
    out = tmp_path / "guide.json"
    guide = subprocess.Popen(
        [
            *(sys.executable, "-m", "spacecal", "guide", str(calibration)),
            *("--slicer-live", str(port), "--registration", str(registration)),
            *("--robot", "sim", "--tracker", "sim", "--simulated-speed", "1", "-o", str(out)),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        peer = subprocess.run(
            [str(planner), str(port), "120", *(repr(float(v)) for v in sent)],
            capture_output=True,
            text=True,
            timeout=180,
        )
        stdout, stderr = guide.communicate(timeout=60)
    finally:
        guide.kill()
    assert guide.returncode == 0, stderr
    assert "needle frames sent" in stdout and "plan changed" not in stdout, stdout
    assert peer.returncode == 0 and "SENT" in peer.stdout and "CRCFAIL 0" in peer.stdout, peer.stdout[-500:]
    result = json.loads(out.read_text())
    # the plan guided is the one sent (float32 on the wire; image_lps is RAS with x, y negated)
    assert np.allclose(result["plan"]["entry_in_image_mm"], ras * sent[:3].astype(float), atol=1e-9)
    assert np.allclose(result["plan"]["target_in_image_mm"], ras * sent[3:].astype(float), atol=1e-9)
    poses = np.array(
        [[float(v) for v in line.split()[1:]] for line in peer.stdout.splitlines() if line.startswith("POSE")]
    )
    times, tips = poses[:, 0], poses[:, 1:]
    held = np.array([s["measured_tracker_from_needle"] for s in result["stages"]])[:, :3, 3]
    near = np.min(np.linalg.norm(tips[:, None, :] - held[None], axis=2), axis=1)
    holding = near <= HOLDING_MM
    # moving: away from both holds and from where the robot stood before it moved
    moving = ~holding & (np.linalg.norm(tips - tips[0], axis=1) > HOLDING_MM)
    hold_rate, hold_gap = rate_and_gap(runs(times, holding))
    move_rate, move_gap = rate_and_gap(runs(times, moving))
    print(
        f"{len(times)} needle poses over {times[-1] - times[0]:.2f} s; holding {holding.sum()} at "
        f"{hold_rate:.1f} Hz (largest gap {hold_gap:.3f} s), moving {moving.sum()} at {move_rate:.1f} Hz "
        f"(largest gap {move_gap:.3f} s)"
    )
    assert hold_rate >= LEAST_RATE_HZ and move_rate >= LEAST_RATE_HZ
    assert holding.sum() >= 10 and moving.sum() >= 10
