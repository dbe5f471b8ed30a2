"""Fake world with a rosbridge in front of its robot -> real roslibpy + real ndicapy ->
``spacecal acquire --robot ros2://...`` -> ``spacecal calibrate`` -> error against the truth.

The world's robot is a UR10 driven through the FollowJointTrajectory action and publishing its
controller ticks on /joint_states; the NDI fake tracks the marker on it.
"""

import json
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

pytest.importorskip("roslibpy")
pytest.importorskip("websockets")
pytest.importorskip("ndicapy")

from spacecal.estimators.methods.likelihood import tre_lower_bound
from spacecal.geometry.metrics import cube_grid, target_registration_errors
from spacecal.io.recording_csv import read_recording
from spacecal.sim.scenario import load_scenario
from spacecal.sim.world import build_world

from .test_end_to_end import SPHERE_SIGMA_MM, paper_estimator_spread  # noqa: F401 (a fixture)
from .ur_runs import last_line, stats, wait_for_rows

#: Real client libraries against the protocol fakes, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime

SPACECAL = [sys.executable, "-m", "spacecal"]


#: From Ctrl-C to the arm standing still, s (the UR stop tests' bound, test_ur_stops).
STILL_WITHIN_S = 1.0
#: From Ctrl-C to the end of the command, s (the UR stop tests' ENDED_WITHIN_S).
ENDED_WITHIN_S = 8.0


@pytest.fixture
def ros_world(make_world):
    return make_world("--rosbridge")


def acquire_argv(world, rom_file, recording) -> list[str]:
    return [
        *SPACECAL,
        "acquire",
        "--robot",
        f"ros2://{world.info['host']}:{world.info['rosbridge_port']}?model=UR10",
        "--tracker",
        f"ndi://{world.info['host']}:{world.info['ndi_port']}",
        "--rom",
        str(rom_file),
        "-o",
        str(recording),
        "--confirm-robot-motion",
        "--rotation-deg",
        "45",
        "--translation-mm",
        "300",
    ]


def test_acquire_through_rosbridge_and_calibrate_against_the_ground_truth(
    ros_world,
    rom_file,
    tmp_path,
    paper_estimator_spread,  # noqa: F811
):
    world = ros_world
    recording = tmp_path / "rec.csv"
    argv = acquire_argv(world, rom_file, recording)
    run = subprocess.run(argv, capture_output=True, text=True, timeout=150)
    assert run.returncode == 0, run.stderr
    assert "18/18 moves" in run.stdout
    calibration = tmp_path / "cal.json"
    run = subprocess.run(
        [*SPACECAL, "calibrate", str(recording), "--method", "paper", "-o", str(calibration)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 0, run.stderr
    estimate = np.array(json.loads(calibration.read_text())["tracker_from_base"])
    truth = world.truth()
    # the URL's model has no TCP: the robot's poses are the flange's, and the marker's truth
    # is taken from the world's TCP to the flange
    flange_from_tcp = build_world(load_scenario("paper-white")).nominal_model.flange_from_tcp
    flange_from_marker = flange_from_tcp @ truth["tcp_from_marker"]
    data = read_recording(recording)
    site = data.base_from_tcp_stack[data.visible, :3, 3].mean(axis=0)
    errors = target_registration_errors(estimate, truth["tracker_from_base"], cube_grid(site))
    tre = float(np.sqrt(np.mean(errors**2)))
    bound = tre_lower_bound(data, truth["tracker_from_base"], flange_from_marker, SPHERE_SIGMA_MM)["cube_rms"]
    print(f"ros2: TRE {tre:.4f} mm, bound {bound:.4f} mm, allowed {paper_estimator_spread:.2f} x bound")
    assert tre < paper_estimator_spread * bound


def test_ctrl_c_stops_the_arm_through_rosbridge_at_once(ros_world, rom_file, tmp_path):
    world = ros_world
    recording = tmp_path / "rec.csv"
    process = subprocess.Popen(
        acquire_argv(world, rom_file, recording), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    wait_for_rows(recording, 40, process)
    assert stats(world)["moving"]
    world.control("ur mark")  # the world's robot watcher measures from here
    sent_at = time.monotonic()
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=60)
    ended_after = time.monotonic() - sent_at
    assert process.returncode == 1, stderr
    line = last_line(stderr)
    assert line.startswith("spacecal: error: acquisition stopped: interrupted") and "Ctrl-C" in line
    assert "Traceback" not in stderr
    assert ended_after < ENDED_WITHIN_S
    after = stats(world)
    print(f"ros2 Ctrl-C: still after {after['fault_to_still_s']:.3f} s, ended after {ended_after:.2f} s")
    assert after["fault_to_still_s"] < STILL_WITHIN_S and not after["moving"]
    # nothing moves it again
    time.sleep(1.0)
    assert stats(world)["still_for_s"] > 1.0
