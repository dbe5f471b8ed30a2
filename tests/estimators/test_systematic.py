"""Kinematic identification and clock-offset estimation: tests that fail if either regresses."""

import dataclasses

import numpy as np
import pytest

from spacecal.core.errors import DegenerateDataError
from spacecal.estimators import calibrate, time_offset
from spacecal.estimators.methods.kinematic import DH_NAMES
from spacecal.estimators.time_offset import estimate_time_offset, pair_streams
from spacecal.experiments.simulation import simulate, simulate_raw
from spacecal.experiments.truth import calibration_error
from spacecal.experiments.verification import verify_in_simulation
from spacecal.io.raw_streams import read_raw_recording, write_raw_recording
from spacecal.sim.scenario import PRESETS

from ..conftest import NOISE_FREE


@pytest.fixture(scope="module")
def realistic_stations():
    scenario = dataclasses.replace(PRESETS["paper-realistic"], motion="stations")
    return scenario, simulate(scenario)


def test_identification_beats_calibration_alone_on_varied_poses(realistic_stations):
    scenario, simulation = realistic_stations
    alone = verify_in_simulation(
        calibrate(simulation.recording, "ml", uncertainty=False), scenario
    ).statistics()
    identified = calibrate(simulation.recording, "kinematic", uncertainty=False)
    with_model = verify_in_simulation(identified, scenario).statistics()
    assert with_model["position_mm"]["mean"] < 0.7 * alone["position_mm"]["mean"]
    report = identified.diagnostics["kinematic_identification"]
    assert 0 < report["rank"] < 24 and set(report["unidentifiable"]) <= set(DH_NAMES)
    # the first joint's d and theta offset only move the base frame: never identifiable
    assert {"d_mm[1]", "theta_offset_rad[1]"} <= set(report["unidentifiable"])
    assert all(c["sd"] > 0 for c in report["identified"])
    # the residuals it states are those of its own model: what the report recomputes
    from spacecal.report.summary import residuals_of

    recomputed = residuals_of(identified, simulation.recording)
    stated = identified.assessment.residuals.position_rms_mm
    assert abs(recomputed.position_rms_mm - stated) < 1e-6 * max(stated, 1.0)
    assert abs(recomputed.rotation_rms_deg - identified.assessment.residuals.rotation_rms_deg) < 1e-6


def test_identification_recovers_length_errors_without_tracker_error():
    scenario = dataclasses.replace(NOISE_FREE, dh_length_error_sd_mm=0.3, motion="stations", stations=40)
    simulation = simulate(scenario)
    result = calibrate(simulation.recording, "kinematic", uncertainty=False, prior_length_sd_mm=10.0)
    verification = verify_in_simulation(result, scenario).statistics()
    alone = verify_in_simulation(
        calibrate(simulation.recording, "ml", uncertainty=False), scenario
    ).statistics()
    assert verification["position_mm"]["mean"] < 0.8 * alone["position_mm"]["mean"]


def test_identification_needs_joints(white_simulation):
    recording = dataclasses.replace(
        white_simulation.recording, joints_rad=np.full_like(white_simulation.recording.joints_rad, np.nan)
    )
    with pytest.raises(DegenerateDataError, match="joint angles"):
        calibrate(recording, "kinematic", uncertainty=False)


@pytest.fixture(scope="module")
def offset_streams():
    return simulate_raw(PRESETS["paper-white"], clock_offset_s=0.030)


def test_a_30_ms_clock_offset_is_recovered_within_2_ms(offset_streams):
    raw, world = offset_streams
    estimate = estimate_time_offset(raw)
    assert abs(estimate.offset_s - 0.030) < 0.002
    naive = calibration_error(calibrate(pair_streams(raw, 0.0), "ml", uncertainty=False), world)["tre_rms_mm"]
    corrected = calibration_error(calibrate(pair_streams(raw, estimate.offset_s), "ml"), world)["tre_rms_mm"]
    assert corrected < 0.1 * naive and corrected < 0.05


def test_a_misleading_coarse_offset_is_followed_to_the_fit_s_optimum(offset_streams, monkeypatch):
    # a noisy tracker's angular speeds can put the coarse offset 60 ms off (a camera-grade
    # pose tracker did, and the refinement stopped at the edge of its wider bracket, 23 ms off)
    raw, _ = offset_streams
    original = time_offset.coarse_offset_from_angular_speed

    def misled(raw, search_s):
        offsets, _ = original(raw, search_s)
        return offsets, (offsets - 0.090) ** 2

    monkeypatch.setattr(time_offset, "coarse_offset_from_angular_speed", misled)
    # the scan alone: its 90 ms is the start, and the brackets follow the fit down to 30 ms
    scan_only = estimate_time_offset(raw, whole_overlap=False)
    assert abs(scan_only.coarse_offset_s - 0.090) < 1e-9
    assert abs(scan_only.offset_s - 0.030) < 0.002
    # with the whole-overlap correlation, the two coarse values disagree and the fit picks
    # the correlation's, which is within the fine search of the truth
    both = estimate_time_offset(raw)
    assert abs(both.coarse_offset_s - 0.090) > 0.01
    assert abs(both.coarse_offset_s - 0.030) < 0.01
    assert abs(both.offset_s - 0.030) < 0.002


def test_raw_streams_round_trip(offset_streams, tmp_path):
    raw, _ = offset_streams
    robot_path, tracker_path = write_raw_recording(raw, tmp_path / "rec")
    again = read_raw_recording(robot_path, tracker_path)
    assert np.array_equal(again.robot_time_s, raw.robot_time_s) and np.array_equal(
        again.tracker_time_s, raw.tracker_time_s
    )
    seen = np.isfinite(raw.tracker_from_marker_stack[:, 0, 0])
    assert np.allclose(again.tracker_from_marker_stack[seen], raw.tracker_from_marker_stack[seen], atol=1e-12)
    assert again.metadata["simulated_clock_offset_s"] == 0.030


def test_pairing_interpolates_the_robot_state(offset_streams):
    raw, _ = offset_streams
    paired = pair_streams(raw, 0.030)
    # a tracker frame at t pairs with the robot's state at t + 30 ms: between two controller ticks
    k = len(paired) // 2
    query = paired.time_s[k] + 0.030
    upper = np.searchsorted(raw.robot_time_s, query)
    lo, hi = raw.joints_rad[upper - 1], raw.joints_rad[upper]
    assert np.all(np.minimum(lo, hi) - 1e-12 <= paired.joints_rad[k]) and np.all(
        paired.joints_rad[k] <= np.maximum(lo, hi) + 1e-12
    )
