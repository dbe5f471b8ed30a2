"""A factory-calibrated arm with a rotated TCP set on its pendant: spacecal reads the
controller's own model (primary interface ``KinematicsInfo`` + ``CartesianInfo``), plans and
records with it, and calibrates within the noise bound; and the controller's ``movel``
semantics give our rotation moves the duration the plan gives them."""

import json
import subprocess

import numpy as np
import pytest

pytest.importorskip("rtde_control")
pytest.importorskip("ndicapy")

from spacecal.estimators.methods.kinematic import robot_model_of
from spacecal.estimators.methods.likelihood import tre_lower_bound
from spacecal.geometry.metrics import cube_grid, target_registration_errors
from spacecal.geometry.transforms import make_transform, rotvec_to_matrix
from spacecal.io.raw_streams import read_raw_recording, stream_paths
from spacecal.io.recording_csv import read_recording
from spacecal.models.kinematics import forward_kinematics
from spacecal.models.robot_kinds import robot_kind

from .ur_runs import SPACECAL, acquire_argv, assert_everything_closed, run, stats, ur_world

#: Real client libraries against the protocol fakes, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime

PENDANT_TCP = "5,-3,195,0.02,0.25,-0.1"
#: The fake world runs the paper-white scenario: 0.25 mm RMS white noise per sphere.
SPHERE_SIGMA_MM = 0.25 / np.sqrt(3)
#: ML is efficient: its cube-RMS error squared is a quadratic form of a Gaussian whose mean is the
#: bound squared, and three times the bound lies beyond its 99.5th percentile. The frames are
#: paired with the controller's own state stream at the estimated clock offset, so the
#: hardware path adds no timing error the bound leaves out.
ALLOWED_RATIO = 3.0


def test_a_calibrated_arm_with_a_rotated_pendant_tcp_calibrates_within_the_noise(rom_file, tmp_path):
    # a CB3 (125 Hz states) at half the default speeds, a factory-calibrated arm with a rotated
    # TCP on its pendant (the fake's 500 Hz e-Series stream, computing calibrated kinematics in
    # motion, falls behind on a busy test machine and is then rightly called stale; the
    # e-Series's own paths are the stop tests')
    world = ur_world("cb3", "--calibrated-kinematics", "--pendant-tcp", PENDANT_TCP)
    try:
        recording = tmp_path / "rec.csv"
        slow = ["--speed-mm-s", "50", "--accel-mm-s2", "200", "--angular-speed-deg-s", "20"]
        argv = acquire_argv(world, "cb3", recording, rom_file, *slow, rotation_deg="25", brisk=False)
        result = run(argv + ["--translation-mm", "150"], timeout_s=200)
        assert result.returncode == 0, result.stderr
        assert "18/18 moves" in result.stdout
        assert_everything_closed(world)
        data = read_recording(recording)
        robot = data.metadata["robot"]
        assert robot["kinematics_source"].startswith("the controller's calibrated kinematics")
        recorded = robot_model_of(data)  # the prior of --method kinematic
        nominal = robot_kind("UR10").model()
        # the recorded model is the controller's: calibrated DH (a few mm from nominal) ...
        assert 0.5 < np.max(np.abs(recorded.d_mm - nominal.d_mm)) < 10.0
        values = np.array([float(v) for v in PENDANT_TCP.split(",")])
        tcp = make_transform(rotvec_to_matrix(values[3:]), values[:3])
        # ... with the pendant's rotated TCP, and it reproduces every pose the controller reported
        np.testing.assert_allclose(recorded.flange_from_tcp, tcp, atol=1e-9)
        # (the controller's own states, as its raw stream holds them: the paired recording
        # interpolates joints linearly and the pose along its geodesic, which differ between
        # two states that a loaded machine recorded far apart)
        robot_stream, tracker_stream, _ = stream_paths(recording.with_suffix(""))
        reported = read_raw_recording(robot_stream, tracker_stream)
        predicted = forward_kinematics(recorded, reported.joints_rad)[:, :3, 3]
        assert np.max(np.linalg.norm(predicted - reported.base_from_tcp_stack[:, :3, 3], axis=1)) < 0.01
        nominal_error = (
            forward_kinematics(nominal.with_tcp(tcp), data.joints_rad)[:, :3, 3]
            - (data.base_from_tcp_stack[:, :3, 3])
        )
        assert np.max(np.linalg.norm(nominal_error, axis=1)) > 1.0  # what used to be refused

        calibration = tmp_path / "cal.json"
        result = subprocess.run(
            [*SPACECAL, "calibrate", str(recording), "--method", "ml", "-o", str(calibration)]
            + ["--thresholds-mm", "0.5,1,20"],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert result.returncode == 0, result.stderr
        estimate = np.array(json.loads(calibration.read_text())["tracker_from_base"])
        truth = world.truth()
        site = data.base_from_tcp_stack[data.visible, :3, 3].mean(axis=0)
        errors = target_registration_errors(estimate, truth["tracker_from_base"], cube_grid(site))
        tre = float(np.sqrt(np.mean(errors**2)))
        bound = tre_lower_bound(data, truth["tracker_from_base"], truth["tcp_from_marker"], SPHERE_SIGMA_MM)[
            "cube_rms"
        ]
        print(f"calibrated arm, rotated TCP: ML TRE {tre:.4f} mm, bound {bound:.4f} mm ({tre / bound:.1f} x)")
        assert tre < ALLOWED_RATIO * bound
    finally:
        world.stop()


def test_without_the_primary_interface_the_model_is_identified_from_the_reported_poses(rom_file, tmp_path):
    """The fallback: the controller's kinematics cannot be read (primary interface closed); the
    run goes on with the nominal DH and a warning, and the recording's own pairs of joints and
    reported TCP poses identify the controller's model afterwards."""
    # a CB3 (125 Hz): the fallback does not depend on the generation, and the fake's 500 Hz
    # stream with calibrated kinematics in motion falls behind on a busy machine, leaving gaps
    # the pairing rightly will not interpolate across (the e-Series is the test above)
    world = ur_world("cb3", "--calibrated-kinematics", "--pendant-tcp", PENDANT_TCP)
    try:
        world.control("ur primary off")
        recording = tmp_path / "rec.csv"
        dry = run(acquire_argv(world, "cb3", recording, rom_file, "--dry-run"))
        assert dry.returncode == 0, dry.stderr
        assert "robot: kinematics: warning: the controller's kinematics could not be read" in dry.stdout
        result = run(acquire_argv(world, "cb3", recording, rom_file))
        assert result.returncode == 0, result.stderr
        data = read_recording(recording)
        assert data.metadata["robot"]["identify_kinematics_from_poses"] is True
        identified = robot_model_of(data)
        # scored on the states the controller reported (the raw stream), as the model is meant to
        # reproduce them; the paired recording's interpolation adds its own small inconsistency
        reported = read_raw_recording(*stream_paths(recording.with_suffix(""))[:2])
        reported_in_base = reported.base_from_tcp_stack[:, :3, 3]
        predicted = forward_kinematics(identified, reported.joints_rad)
        misfit = np.linalg.norm(predicted[:, :3, 3] - reported_in_base, axis=1)
        nominal_model = robot_kind("UR10").model().with_tcp(identified.flange_from_tcp)
        nominal = forward_kinematics(nominal_model, reported.joints_rad)
        print(
            f"identified from the poses: misfit max {misfit.max():.4f} mm (nominal DH: up to "
            f"{np.linalg.norm(nominal[:, :3, 3] - reported_in_base, axis=1).max():.2f} mm)"
        )
        # the brisk run's small sweeps leave some directions weakly determined: 0.05 mm
        assert misfit.max() < 0.05
    finally:
        world.stop()


def test_rotation_moves_take_the_planned_time_on_the_controller(rom_file, tmp_path):
    """movel limits the rotation to 4 v rad/s: a pure rotation commanded with the linear speed
    would take about twice the planned time at our defaults; the adapter commands it so the
    controller takes the plan's time."""
    from spacecal.adapters.ur import URRobot
    from spacecal.geometry.transforms import make_transform as transform
    from spacecal.planning.motion import MotionLimits, trapezoid_duration

    world = ur_world("eseries")
    limits = MotionLimits()
    robot = URRobot(world.info["host"], robot_model="UR10e", limits=limits)
    try:
        start = robot.state().base_from_tcp
        cases = {
            "rotation": start @ transform(rotvec_to_matrix([0.0, np.radians(20.0), 0.0]), np.zeros(3)),
            "translation": start @ transform(np.eye(3), [0.0, 0.0, 60.0]),
        }
        for label, target in cases.items():
            robot.move_linear(target, limits.linear_speed_mm_s, limits.linear_accel_mm_s2)
            took = stats(world)["last_movel_s"]  # the duration the controller gave the movel
            if label == "rotation":
                planned = trapezoid_duration(
                    np.radians(20.0), limits.angular_speed_rad_s, limits.angular_accel_rad_s2
                )
            else:
                planned = trapezoid_duration(60.0, limits.linear_speed_mm_s, limits.linear_accel_mm_s2)
            print(f"{label}: planned {planned[0]:.3f} s, the controller's movel {took:.3f} s")
            assert took == pytest.approx(planned[0], rel=0.01)
            robot.move_linear(start, limits.linear_speed_mm_s, limits.linear_accel_mm_s2)
        # the same rotation commanded with the linear speed (as before) would take 1.4x as long
        unconverted = trapezoid_duration(np.radians(20.0), 4 * 0.1, 4 * 0.4)[0]
        assert unconverted > 1.3 * trapezoid_duration(np.radians(20.0), limits.angular_speed_rad_s, 3.14)[0]
    finally:
        robot.close()
        world.stop()
