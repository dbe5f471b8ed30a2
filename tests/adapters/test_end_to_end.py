"""Fake world -> real ur_rtde + real ndicapy (or pyigtl) -> ``spacecal acquire`` -> ``spacecal
calibrate`` -> error against the fake's ground truth; and every fault on the way.

The commands run as the real console script in a subprocess, as a user would run them.
"""

import json
import signal
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("rtde_control")
pytest.importorskip("ndicapy")
pytest.importorskip("pyigtl")

from spacecal.estimators.methods.likelihood import tre_lower_bound
from spacecal.geometry.metrics import cube_grid, target_registration_errors
from spacecal.io.acquisition_progress import progress_path
from spacecal.io.raw_streams import read_raw_recording
from spacecal.io.recording_csv import read_recording

from .ur_runs import WhenRecorded, outside_the_robot_stream, wait_for_rows

#: Real client libraries against the protocol fakes, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime

SPACECAL = [sys.executable, "-m", "spacecal"]
#: The fake world runs the paper-white scenario: 0.25 mm RMS white noise per sphere.
SPHERE_SIGMA_MM = 0.25 / np.sqrt(3)


def tracker_url(world, kind):
    if kind == "ndi":
        return f"ndi://{world.info['host']}:{world.info['ndi_port']}"
    if kind == "ndi-serial":
        return f"ndi://{world.info['ndi_pty']}"
    if kind == "natnet":
        return f"natnet://{world.info['host']}:{world.info['natnet_port']}?body=Marker"
    return f"igtl://127.0.0.1:{world.info['igtl_port']}"


def acquire_command(world, kind, output, rom, rotation_deg="45", translation_mm="300", *extra):
    return [
        *SPACECAL,
        "acquire",
        "--robot",
        f"ur://{world.info['host']}",
        "--tracker",
        tracker_url(world, kind),
        "--rom",
        str(rom),
        "-o",
        str(output),
        "--confirm-robot-motion",
        "--tool-offset-mm",
        "0,0,200",
        "--rotation-deg",
        rotation_deg,
        "--translation-mm",
        translation_mm,
        *extra,
    ]


@pytest.fixture(scope="module")
def paper_estimator_spread():
    """The paper estimator's TRE / Cramér–Rao bound for this motion and noise: its 99.5th
    percentile over 1000 noise draws in simulation (same scenario, sweeps and speeds; 8 s).

    The ratio's tail is long (its square is gamma-like with shape 0.7). Over 200 draws the
    99.5th percentile is about their second largest, here 5.92, which 2.7 % of 600 further
    draws exceeded: the test then failed a correct acquisition that often. 1000 draws put
    five beyond the percentile they estimate (7.39; 7.53 from 600 others)."""
    import dataclasses

    from spacecal.estimators import calibrate
    from spacecal.experiments.monte_carlo import cramer_rao_tre_mm
    from spacecal.experiments.simulation import simulate
    from spacecal.experiments.truth import calibration_error
    from spacecal.sim.scenario import PRESETS

    scenario = dataclasses.replace(PRESETS["paper-white"], rotation_deg=45.0, translation_mm=300.0)
    simulation = simulate(scenario)
    bound = cramer_rao_tre_mm(simulation)
    ratios = [
        calibration_error(
            calibrate(simulation.remeasure(trial)[0], "paper", uncertainty=False), simulation.world
        )["tre_rms_mm"]
        / bound
        for trial in range(1000)
    ]
    return float(np.percentile(ratios, 99.5))


@pytest.mark.parametrize("kind", ["ndi", "igtl", "natnet"])
def test_acquire_and_calibrate_against_the_ground_truth(
    world, rom_file, tmp_path, kind, paper_estimator_spread
):
    recording = tmp_path / "rec.csv"
    run = subprocess.run(
        acquire_command(world, kind, recording, rom_file), capture_output=True, text=True, timeout=150
    )
    assert run.returncode == 0, run.stderr
    assert "18/18 moves" in run.stdout
    calibration = tmp_path / "cal.json"
    # the frames are paired with the robot's own state stream at the estimated clock offset:
    # calibrated at the default verdict thresholds (the grade itself varies with the host's
    # load, which delays the fake tracker's captures)
    run = subprocess.run(
        [*SPACECAL, "calibrate", str(recording), "--method", "paper", "-o", str(calibration)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 0, run.stderr  # not unusable
    # the calibration names the devices it belongs to, as they named themselves (the fake
    # controller is a CB3, which has no serial number to give; the NDI fake's VER says P6-00042)
    devices = json.loads(calibration.read_text())["provenance"]["devices"]
    assert devices["robot"]["firmware"] == "PolyScope 3.15.7.106331" and "serial" not in devices["robot"]
    if kind.startswith("ndi"):
        assert devices["tracker"]["serial"] == "P6-00042", devices
    if kind == "natnet":
        # Motive's own name and versions, and the rigid body the marker was (the URL's query)
        tracker = devices["tracker"]
        assert (tracker["model"], tracker["firmware"]) == ("Motive", "3.1.0.0 (NatNet 4.1.0.0)"), devices
        assert tracker["url"].endswith("?body=Marker") and "serial" not in tracker, devices
    pairing = json.loads(recording.with_name("rec.meta.json").read_text())["pairing"]
    assert pairing["estimated"], pairing
    estimate = np.array(json.loads(calibration.read_text())["tracker_from_base"])
    truth = world.truth()
    data = read_recording(recording)
    site = data.base_from_tcp_stack[data.visible, :3, 3].mean(axis=0)
    errors = target_registration_errors(estimate, truth["tracker_from_base"], cube_grid(site))
    tre = float(np.sqrt(np.mean(errors**2)))
    # The bound the injected noise allows for exactly this recording (Cramér–Rao, at the truth).
    bound = tre_lower_bound(data, truth["tracker_from_base"], truth["tcp_from_marker"], SPHERE_SIGMA_MM)[
        "cube_rms"
    ]
    print(f"{kind}: TRE {tre:.4f} mm, bound {bound:.4f} mm, allowed {paper_estimator_spread:.2f} x bound")
    # Through the real clients the error must stay within what the injected noise gives the
    # paper estimator in simulation (its 99.5th percentile, about 5-6x the bound here).
    assert tre < paper_estimator_spread * bound


def tracker_stream(recording):
    """The raw tracker stream ``acquire`` writes frame by frame beside ``rec.csv``."""
    return recording.with_name(recording.stem + ".tracker.csv")


#: Frames inside the robot stream before a fault or Ctrl-C is sent (``ur_runs.pairable_rows``):
#: the kept recording is checked to hold more than ten.
PAIRABLE_BEFORE_STOP = 20


FAULTS = {
    "protective stop": ("ndi", "protective_stop", "robot protective stop"),
    "emergency stop": ("ndi", "emergency_stop", "robot emergency stop"),
    "tracker unplugged": ("ndi-serial", "unplug", "tracker lost"),
    "stale stream": ("igtl", "stale", "tracker lost"),
}


@pytest.mark.parametrize("fault", sorted(FAULTS))
def test_faults_stop_the_run_and_keep_every_sample(world, rom_file, tmp_path, fault):
    kind, command, message = FAULTS[fault]
    recording = tmp_path / "rec.csv"
    # once samples are recorded, not after a fixed delay: on a loaded machine the command may
    # take seconds to start, and the fault would land first
    WhenRecorded(world, command, recording, rows=30, pairable=PAIRABLE_BEFORE_STOP)
    run = subprocess.run(
        acquire_command(world, kind, recording, rom_file, "15", "120"),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 1
    last = run.stderr.strip().splitlines()[-1]
    assert (
        last.startswith("spacecal: error: acquisition stopped")
        and message in last
        and "Traceback" not in run.stderr
    )
    kept = read_recording(recording)  # readable, derived from the raw streams
    frames = read_raw_recording(recording.with_name("rec.robot.csv"), tracker_stream(recording))
    written = len(frames.tracker_time_s)  # every frame recorded before the stop
    # the paired recording holds the frames captured while the robot's stream was kept
    assert len(kept) > 10 and f"{written} samples kept" in last and len(kept) <= written
    assert np.isin(kept.time_s, frames.tracker_time_s).all()
    progress = json.loads(progress_path(recording).read_text())
    assert progress["moves_completed"] < progress["moves_total"]
    if command == "protective_stop":  # resuming is the same after every stop (test_ur_stops)
        world.control("clear")
        resumed = subprocess.run(
            acquire_command(world, kind, recording, rom_file, "15", "120", "--resume"),
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert resumed.returncode == 0, resumed.stderr
        again = read_recording(recording)
        # the paired recording is derived again from the whole run, at the whole run's offset:
        # a kept frame missing from it is one the pairing rule leaves out there (outside the
        # robot stream or in a gap a loaded poller left), never one lost
        assert len(again) > len(kept)
        lost = kept.time_s[~np.isin(kept.time_s, again.time_s)]
        whole = read_raw_recording(recording.with_name("rec.robot.csv"), tracker_stream(recording))
        offset_s = again.metadata["paired_with_offset_s"]
        assert np.all(outside_the_robot_stream(whole.robot_time_s, lost + offset_s)), lost
        assert tracker_stream(recording).read_bytes().count(b"\n") - 1 > written


def test_ctrl_c_stops_the_robot_and_keeps_the_data(world, rom_file, tmp_path):
    recording = tmp_path / "rec.csv"
    process = subprocess.Popen(
        acquire_command(world, "ndi", recording, rom_file, "15", "120"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    # interrupted once frames are being recorded (a fixed sleep interrupted a loaded machine's
    # run before it had opened the devices)
    wait_for_rows(recording, 40, process, pairable=PAIRABLE_BEFORE_STOP, world=world)
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 1
    assert "interrupted by the user" in stderr.strip().splitlines()[-1]
    assert len(read_recording(recording)) > 10


def test_dry_run_moves_nothing(world, rom_file, tmp_path):
    before = world.truth()
    run = subprocess.run(
        acquire_command(world, "ndi", tmp_path / "rec.csv", rom_file) + ["--dry-run"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 0 and "nothing moved" in run.stdout
    assert not (tmp_path / "rec.csv").exists()
    assert before is not None


def test_moving_a_real_robot_needs_confirmation(world, rom_file, tmp_path):
    command = [
        c
        for c in acquire_command(world, "ndi", tmp_path / "rec.csv", rom_file)
        if c != "--confirm-robot-motion"
    ]
    run = subprocess.run(command, capture_output=True, text=True, timeout=60)
    assert run.returncode == 1 and "--confirm-robot-motion" in run.stderr
