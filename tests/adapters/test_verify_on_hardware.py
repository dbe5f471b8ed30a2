"""``spacecal verify`` (paper §5.2) on the UR + NDI protocol fakes through the real clients.

A calibration is acquired and fitted on the fakes (``plan`` -> ``acquire --plan`` -> ``calibrate
--method ml``), then ``verify`` reaches 15 needle poses around where the needle stands, measured
by the calibrated marker and then by the reference tool on the needle guide (a further NDI
tool definition), and stopped by a protective stop partway. The reported errors are compared
with the TRUE reached poses: the fake world's true tracker pose and kinematics at the joints
the robot came to rest at (the same deterministic world built here, checked against the fake's
``truth``).
"""

import json
import subprocess
import sys
import time

import numpy as np
import pytest

pytest.importorskip("rtde_control")
pytest.importorskip("ndicapy")

from spacecal.io.ndi_rom import rom_bytes
from spacecal.io.results_json import read_calibration
from spacecal.models.marker import ndi_8700339_like
from spacecal.records import VerificationResult
from spacecal.registration.points import predicted_tre
from spacecal.sim.scenario import load_scenario
from spacecal.sim.tools import reference_geometry
from spacecal.sim.world import build_world

#: Real client libraries against the protocol fakes, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime

SPACECAL = [sys.executable, "-m", "spacecal"]
#: The fake UR controller's motion commands (MOVEJ, MOVEL).
MOTIONS = (1, 3)


def motions(world):
    from .ur_runs import stats

    return sum(command in MOTIONS for command in stats(world)["commands"])


#: Frames averaged at each pose (verify's default); a hold is refused with fewer than half.
FRAMES_PER_POSE = 10
#: The RMS over 15 poses of a 3-D Gaussian error is within 1.5 times its own RMS beyond the
#: 99.9th percentile (chi-square with 45 degrees of freedom: 80.1 / 45 = 1.78 = 1.33 squared).
RMS_SPREAD = 1.5


def measurement_mm(spheres_in_tool, needle_in_tool, sphere_noise_rms_mm):
    """The noise (mm, 3-D RMS) of the needle's position as a tool measures it at a pose:
    Fitzpatrick's TRE of the tool's spheres at the needle, the sphere noise as the FLE, averaged
    over the fewest frames a hold keeps."""
    single = predicted_tre(spheres_in_tool, np.asarray(needle_in_tool)[None], sphere_noise_rms_mm)[0]
    return float(single / np.sqrt(FRAMES_PER_POSE // 2))


def run(command, timeout):
    return subprocess.run(command, capture_output=True, text=True, timeout=timeout)


def true_reached(world, result):
    """The true needle (TCP) pose (N, 4, 4) in the true tracker frame at each pose's rest joints."""
    return np.array(
        [
            world.tracker_from_base @ world.true_base_from_tcp(q, jitter=False).reshape(4, 4)
            for q in result.joints_rad
        ]
    )


def scored(world, result, stated, what):
    """Compare a verification with the truth; print and return (reported-vs-truth RMS, max)."""
    truth = true_reached(world, result)
    true_errors = np.linalg.norm(truth[:, :3, 3] - result.desired_tracker_from_needle[:, :3, 3], axis=1)
    off = np.linalg.norm(truth[:, :3, 3] - result.reached_tracker_from_needle[:, :3, 3], axis=1)
    rms = float(np.sqrt(np.mean(off**2)))
    print(
        f"{what}: stated {stated:.3f} mm; reported mean {result.position_error_mm.mean():.3f}, true mean "
        f"{true_errors.mean():.3f} mm; reported pose off the truth RMS {rms:.3f}, max {off.max():.3f} mm"
    )
    # the reported errors differ from the true ones by no more than the reported pose is off
    assert np.all(np.abs(result.position_error_mm - true_errors) <= off + 1e-9)
    return rms, float(off.max())


def test_verify_on_the_fake_devices_reports_the_true_errors(world, rom_file, tmp_path):
    host = world.info["host"]
    truth = world.truth()
    simulated = build_world(load_scenario("paper-white"))
    # the world built here is the fake's (the same deterministic scenario)
    assert np.allclose(simulated.tracker_from_base, truth["tracker_from_base"], atol=1e-9)
    assert np.allclose(simulated.tcp_from_marker, truth["tcp_from_marker"], atol=1e-9)
    plan = tmp_path / "plan.json"
    planned = run([*SPACECAL, "plan", "--scenario", "paper-white", "--budget", "30s", "-o", str(plan)], 120)
    assert planned.returncode == 0, planned.stderr
    devices = ["--robot", f"ur://{host}", "--tracker", f"ndi://{host}:{world.info['ndi_port']}"]
    offset = ["--tool-offset-mm", "0,0,200"]
    recording = tmp_path / "rec.csv"
    acquire = [*SPACECAL, "acquire", *devices, "--rom", str(rom_file), *offset, "--plan", str(plan)]
    acquired = run([*acquire, "--confirm-robot-motion", "-o", str(recording)], 180)
    assert acquired.returncode == 0, acquired.stderr
    calibration = tmp_path / "cal.json"
    calibrated = run([*SPACECAL, "calibrate", str(recording), "--method", "ml", "-o", str(calibration)], 120)
    assert calibrated.returncode == 0, calibrated.stderr
    cal = read_calibration(calibration)
    stated = cal.assessment.position_mm
    noise = simulated.scenario.white_noise_rms_mm
    # the marker's measurement of the needle (the TCP: no needle tip given) at each pose
    needle_in_marker = np.linalg.inv(cal.tcp_from_marker)[:3, 3]
    marker_noise = measurement_mm(ndi_8700339_like().spheres_in_marker, needle_in_marker, noise)
    reference_noise = measurement_mm(
        reference_geometry().spheres_in_marker, np.array(truth["reference_from_needle"])[:3, 3], noise
    )
    print(
        f"measurement noise at the needle: marker {marker_noise:.3f} mm, reference {reference_noise:.3f} mm"
    )

    # 1. measured by the calibrated marker
    out = tmp_path / "ver.json"
    verify = [*SPACECAL, "verify", str(calibration), *devices, *offset, "--confirm-robot-motion"]
    started = time.monotonic()
    verified = run([*verify, "--rom", str(rom_file), "-o", str(out)], 300)
    took = time.monotonic() - started
    assert verified.returncode == 0, verified.stderr
    assert "verification on the robot: 15 needle poses, measured by the calibrated marker" in verified.stdout
    result = VerificationResult.from_dict(json.loads(out.read_text()))
    assert not result.simulated and len(result.position_error_mm) == 15
    rms, _ = scored(simulated, result, stated, f"UR + NDI fakes, calibrated marker ({took:.0f} s)")
    # the marker measures its pose through this calibration's tcp_from_marker: its reached pose is
    # off the true one by the calibration's own error at the needle, which it states, and by the
    # marker's measurement noise there
    assert rms <= RMS_SPREAD * np.hypot(stated, marker_noise)

    # 2. measured by the reference tool on the needle guide (a further NDI tool definition)
    reference_rom = tmp_path / "guide.rom"
    reference_rom.write_bytes(rom_bytes(reference_geometry().spheres_in_marker))
    definition = tmp_path / "guide.json"
    definition.write_text(
        json.dumps({"reference_from_needle": np.asarray(truth["reference_from_needle"]).tolist()})
    )
    out_reference = tmp_path / "ver-reference.json"
    tools = ["--rom", str(rom_file), "--rom", str(reference_rom)]
    reference = ["--reference-tool", "guide", "--reference-from-needle", str(definition)]
    verified = run([*verify, *tools, *reference, "-o", str(out_reference)], 300)
    assert verified.returncode == 0, verified.stderr
    assert "measured by reference tool guide" in verified.stdout
    result = VerificationResult.from_dict(json.loads(out_reference.read_text()))
    rms, _ = scored(simulated, result, stated, "UR + NDI fakes, reference tool")
    # independent of this calibration: off the truth by the tracker's noise at the tool only
    assert rms <= RMS_SPREAD * reference_noise

    # 3. a protective stop partway: the poses held so far are written, the robot stays stopped
    from .ur_runs import stats

    out_stopped = tmp_path / "ver-stopped.json"
    before = motions(world)
    process = subprocess.Popen(
        [*verify, "--rom", str(rom_file), "-o", str(out_stopped)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 120
    # each pose is reached from home: two moves a pose; stop during the sixth pose's
    while motions(world) - before < 11:
        assert time.monotonic() < deadline and process.poll() is None
        time.sleep(0.05)
    world.control("protective_stop")
    _, err = process.communicate(timeout=60)
    lines = err.strip().splitlines()
    assert process.returncode == 1 and len(lines) == 1, err
    kept = VerificationResult.from_dict(json.loads(out_stopped.read_text()))
    k = len(kept.position_error_mm)
    assert f"interrupted after {k} of 15 poses" in lines[0] and str(out_stopped) in lines[0]
    assert 4 <= k <= 6 and kept.poses_planned == 15 and "protective" in kept.interrupted
    scored(simulated, kept, stated, f"UR + NDI fakes, stopped after {k} poses")
    moved = motions(world)
    time.sleep(1.0)
    assert motions(world) == moved and not stats(world)["moving"]
