"""A planned motion and the pre-operative check, on the fake devices through the real clients.

``spacecal plan`` -> ``spacecal acquire --plan`` (UR over RTDE + NDI over TCP) -> ``spacecal
calibrate --method ml`` and ``--method kinematic`` -> error against the fake's truth; then
``spacecal check`` moves the real-protocol robot to three poses and passes each calibration, fails
it after the marker is knocked by 1 degree and after the tracker is pushed by 2 mm, and logs every
check as real. The check expects at each pose the misfit the calibration left there (from its
recording), so its tolerances follow the set-up's repeatability, not the stated expected error.
"""

import json
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("rtde_control")
pytest.importorskip("ndicapy")

from spacecal.estimators.methods.likelihood import tre_lower_bound
from spacecal.geometry.metrics import cube_grid, target_registration_errors
from spacecal.io.check_history import read_history
from spacecal.io.recording_csv import read_recording

#: Real client libraries against the protocol fakes, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime

SPACECAL = [sys.executable, "-m", "spacecal"]
#: The fake world runs the paper-white scenario: 0.25 mm RMS white noise per sphere.
SPHERE_SIGMA_MM = 0.25 / np.sqrt(3)
#: ML is efficient here: its cube-RMS error squared is a quadratic form of a Gaussian whose mean
#: is the bound squared; three times the bound is beyond its 99.5th percentile for any number of
#: degrees of freedom (chi-square with one: 2.8 times).
EFFICIENT_SPREAD = 3.0


def run(command, timeout):
    return subprocess.run(command, capture_output=True, text=True, timeout=timeout)


def test_planned_motion_then_checks_on_the_fake_devices(world, rom_file, tmp_path):
    plan = tmp_path / "plan.json"
    planned = run([*SPACECAL, "plan", "--scenario", "paper-white", "--budget", "30s", "-o", str(plan)], 120)
    assert planned.returncode == 0, planned.stderr
    host = world.info["host"]
    devices = [
        "--robot",
        f"ur://{host}",
        "--tracker",
        f"ndi://{host}:{world.info['ndi_port']}",
        "--rom",
        str(rom_file),
        "--tool-offset-mm",
        "0,0,200",
    ]
    recording = tmp_path / "rec.csv"
    acquired = run(
        [*SPACECAL, "acquire", *devices, "--plan", str(plan), "--confirm-robot-motion", "-o", str(recording)],
        180,
    )
    assert acquired.returncode == 0, acquired.stderr
    calibration = tmp_path / "cal.json"
    calibrated = run([*SPACECAL, "calibrate", str(recording), "--method", "ml", "-o", str(calibration)], 120)
    assert calibrated.returncode == 0, calibrated.stderr
    kinematic = tmp_path / "cal-kinematic.json"
    identified = run(
        [*SPACECAL, "calibrate", str(recording), "--method", "kinematic", "-o", str(kinematic)], 120
    )
    assert identified.returncode == 0, identified.stderr

    truth = world.truth()
    data = read_recording(recording)
    estimate = np.array(json.loads(calibration.read_text())["tracker_from_base"])
    site = data.base_from_tcp_stack[data.visible, :3, 3].mean(axis=0)
    tre = float(
        np.sqrt(
            np.mean(target_registration_errors(estimate, truth["tracker_from_base"], cube_grid(site)) ** 2)
        )
    )
    bound = tre_lower_bound(data, truth["tracker_from_base"], truth["tcp_from_marker"], SPHERE_SIGMA_MM)[
        "cube_rms"
    ]
    print(f"planned motion through UR + NDI: ML TRE {tre:.4f} mm, Cramér–Rao bound {bound:.4f} mm")
    assert tre < EFFICIENT_SPREAD * bound

    checks = {
        path: [*SPACECAL, "check", str(path), *devices, "--confirm-robot-motion"]
        for path in (calibration, kinematic)
    }
    for path, check in checks.items():
        passed = run(check, 120)
        assert passed.returncode == 0 and "PASS (real robot and tracker)" in passed.stdout, (
            f"{path.name}: {passed.stdout}{passed.stderr}"
        )
        assert "departures from the misfit the calibration left" in passed.stdout, passed.stdout
    world.control("bump_marker 1.0")
    for path, check in checks.items():
        bumped = run(check, 120)
        assert bumped.returncode == 1 and "FAIL" in bumped.stdout, (
            f"{path.name}: {bumped.stdout}{bumped.stderr}"
        )
    world.control("bump_marker -1.0")
    world.control("move_tracker 2.0")
    for path, check in checks.items():
        moved = run(check, 120)
        assert moved.returncode == 1 and "FAIL" in moved.stdout, f"{path.name}: {moved.stdout}{moved.stderr}"
    simulated = run([*SPACECAL, "check", str(calibration), "--scenario", "paper-white"], 120)
    assert "simulated robot and tracker" in simulated.stdout

    history, unreadable, others = read_history(calibration)
    assert (
        unreadable == 0
        and others == 0
        and [h.passed for h in history] == [True, False, False, simulated.returncode == 0]
    )
    assert [h.simulated for h in history] == [False, False, False, True]
    identified_history, unreadable, _ = read_history(kinematic)
    assert unreadable == 0 and [h.passed for h in identified_history] == [True, False, False]
    # the devices as they named themselves: the CB3 fake has no serial number to give (PolyScope
    # 3), the NDI fake's VER 4 text names its serial and freeze tag
    assert history[0].devices == {
        "robot": f"ur://{host}",
        "tracker": f"ndi://{host}:{world.info['ndi_port']}",
        "robot_model": "UR10",
        "robot_firmware": "PolyScope 3.15.7.106331",
        "tracker_model": "Polaris Vicra",
        "tracker_serial": "P6-00042",
        "tracker_firmware": "Polaris Vicra Rev 007.000",
    }


def test_a_plan_the_motion_gate_refuses_moves_nothing_on_the_fake_robot(world, rom_file, tmp_path):
    """A plan file whose last move ends at the robot's base, run for real (confirmed): the gate
    refuses it in one line before the control program is uploaded or a command is sent."""
    from .ur_runs import stats

    plan = tmp_path / "plan.json"
    planned = run([*SPACECAL, "plan", "--scenario", "paper-white", "--paper-sweeps", "-o", str(plan)], 120)
    assert planned.returncode == 0, planned.stderr
    data = json.loads(plan.read_text())
    last = np.array(data["moves"][-1]["end_base_from_tcp"])
    at_base = last.copy()
    at_base[:3, 3] = [0.0, 0.0, 50.0]
    data["moves"].append(
        {
            "label": "transit",
            "start_base_from_tcp": last.tolist(),
            "end_base_from_tcp": at_base.tolist(),
            "duration_s": 8.0,
            "accel_time_s": 0.25,
            "sample_period_s": 0.0,
        }
    )
    hostile = tmp_path / "hostile.json"
    hostile.write_text(json.dumps(data))
    host = world.info["host"]
    recording = tmp_path / "rec.csv"
    refused = run(
        [
            *SPACECAL,
            "acquire",
            "--robot",
            f"ur://{host}",
            "--tracker",
            f"ndi://{host}:{world.info['ndi_port']}",
            "--rom",
            str(rom_file),
            "--tool-offset-mm",
            "0,0,200",
            "--plan",
            str(hostile),
            "--confirm-robot-motion",
            "-o",
            str(recording),
        ],
        180,
    )
    lines = refused.stderr.strip().splitlines()
    assert refused.returncode == 1 and len(lines) == 1, refused.stdout + refused.stderr
    n = len(data["moves"])
    assert lines[0].startswith(f"spacecal: error: motion refused, nothing moved: move {n}/{n} (transit)")
    after = stats(world)
    assert after["scripts_uploaded"] == 0 and after["commands"] == [], after
    assert not recording.exists()
