"""Clock offsets of any size between the raw streams: how close, and how fast.

Each scenario is recorded once on one clock; the robot's stamps are then moved ahead by each
true offset (what ``simulate_raw(clock_offset_s=...)`` does), and
:func:`spacecal.estimators.time_offset.estimate_time_offset` is timed on the result. Per
scenario and offset the table gives the error of the whole-overlap correlation peak (coarse)
and of the final, fitted offset, in ms, the peak's correlation beside its runner-up's, and
the estimate's wall time.

Scenarios (paper-white tracker noise, 0.25 mm RMS per sphere):

* ``sweeps 125/10-20 Hz``: the paper's sweeps, a UR10's 125 Hz states, tracker frames every
  100 ms in the rotations and 50 ms in the translations;
* the same with timing noise: each tracker stamp off by N(0, 2 ms), 10 % of the frames lost,
  a 2 s hole in the robot stream;
* ``sweeps 500/60 Hz``: a UR10e's 500 Hz states and every frame of a 60 Hz tracker (shorter
  sweeps: 30 degrees each way, 200 mm strokes), with the same timing noise;
* ``stations``: 12 static stations, 5 frames each, the robot moving only between them
  (stop-and-go): expected to be refused;
* ``KinHEC temporal``: the KinHEC benchmark's smoke-tier temporal-track sequence (UR10e at
  500 Hz, a 30 Hz camera on the flange, 2 ms jitter, 10 % frames dropped, 5 s) at each
  offset, beside KinHEC's own cross-correlation solver (``kinhec.solvers.temporal``; it
  searches a 500 Hz grid spanning both streams and the offset, lag by lag, so it is run only
  up to 10 s), and over ``--kinhec-seeds`` other sequences at the track's 0.05 s.

    python benchmarks/clock_offset.py [--kinhec-seeds 20] [--skip-fast]
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import time

import numpy as np

from spacecal.core.errors import DegenerateDataError
from spacecal.estimators.time_offset import estimate_time_offset
from spacecal.experiments.simulation import simulate_raw
from spacecal.geometry.transforms import invert_transform
from spacecal.records import RawRecording
from spacecal.sim.scenario import PRESETS

OFFSETS_S = (0.03, 7.0, -45.0, 3600.0)
JITTER_S = 0.002


def degraded(raw: RawRecording, seed: int = 7) -> RawRecording:
    """Stamp jitter N(0, JITTER_S), 10 % of the frames lost, a 2 s hole in the robot stream."""
    rng = np.random.default_rng(seed)
    keep = rng.uniform(size=len(raw.tracker_time_s)) >= 0.1
    stamps = raw.tracker_time_s + rng.normal(0.0, JITTER_S, len(raw.tracker_time_s))
    keep &= np.concatenate([[True], np.diff(stamps) > 0])
    middle = 0.5 * (raw.robot_time_s[0] + raw.robot_time_s[-1])
    robot = ~((raw.robot_time_s > middle - 1.0) & (raw.robot_time_s < middle + 1.0))
    return dataclasses.replace(
        raw,
        tracker_time_s=stamps[keep],
        tracker_from_marker_stack=raw.tracker_from_marker_stack[keep],
        marker_rms_mm=raw.marker_rms_mm[keep],
        robot_time_s=raw.robot_time_s[robot],
        robot_segment=raw.robot_segment[robot],
        joints_rad=raw.joints_rad[robot],
        base_from_tcp_stack=raw.base_from_tcp_stack[robot],
    )


def kinhec_sequence(time_offset_s: float, seed: int | None = None):
    """The smoke tier's temporal-track sequence with 2 ms jitter, at another offset (KinHEC's
    sign: the camera's stamp is the capture's robot time plus the offset) and seed."""
    from kinhec.generator import generate_sequence
    from kinhec.io import Sequence
    from kinhec.plans import load_tier, plan_temporal

    config = next(c for c in plan_temporal(load_tier("smoke")) if c.timing["jitter_std_s"] == JITTER_S)
    config = copy.deepcopy(config)
    config.timing["time_offset_s"] = float(time_offset_s)
    if seed is not None:
        config.seed = seed
    record = generate_sequence(config)
    return Sequence(record.manifest, record.robot_table, record.camera_table)


def raw_from_kinhec(sequence) -> RawRecording:
    """KinHEC's eye-in-hand streams (m) as ours (mm): the flange as ``base_from_tcp``,
    target_from_camera as ``tracker_from_marker``."""
    base_from_tcp = sequence.robot.T_base_ee_meas.copy()
    base_from_tcp[:, :3, 3] *= 1000.0
    camera_from_target = sequence.camera.T_cam_target_meas
    seen = np.isfinite(camera_from_target).all(axis=(1, 2))
    target_from_camera = np.full_like(camera_from_target, np.nan)
    target_from_camera[seen] = invert_transform(camera_from_target[seen])
    target_from_camera[seen, :3, 3] *= 1000.0
    return RawRecording(
        robot_time_s=sequence.robot.t,
        robot_segment=np.full(len(sequence.robot.t), "move"),
        joints_rad=sequence.robot.q_meas,
        base_from_tcp_stack=base_from_tcp,
        tracker_time_s=sequence.camera.t,
        tracker_from_marker_stack=target_from_camera,
        marker_rms_mm=np.full(len(sequence.camera.t), np.nan),
    )


def kinhec_solver(sequence, time_offset_s: float) -> tuple[float, float]:
    """KinHEC's own estimate's error (ms) and wall time (s), searching +-1.2 |offset| (>= 0.5 s)."""
    from kinhec.solvers.temporal import estimate_time_offset as kinhec_estimate

    start = time.perf_counter()
    theirs, _ = kinhec_estimate(
        sequence.robot.t,
        sequence.robot.T_base_ee_meas,
        sequence.camera.t,
        sequence.camera.T_cam_target_meas,
        max_offset_s=max(0.5, 1.2 * abs(time_offset_s)),
    )
    return 1000.0 * (theirs - time_offset_s), time.perf_counter() - start


def ours(raw: RawRecording, true_offset_s: float) -> dict:
    """Our estimate on ``raw``: errors (ms), peak / runner-up, wall time (s); or the refusal."""
    start = time.perf_counter()
    try:
        estimate = estimate_time_offset(raw)
    except DegenerateDataError as exc:
        return {"refused": str(exc), "time_s": time.perf_counter() - start}
    elapsed = time.perf_counter() - start
    coarse = estimate.whole_overlap
    assert coarse is not None
    runner = "–" if coarse.runner_up_correlation is None else f"{coarse.runner_up_correlation:.2f}"
    return {
        "coarse_ms": 1000.0 * (coarse.offset_s - true_offset_s),
        "final_ms": 1000.0 * (estimate.offset_s - true_offset_s),
        "peaks": f"{coarse.correlation:.2f} / {runner}",
        "time_s": elapsed,
    }


def row(scenario: str, true_offset_s: float, result: dict, kinhec: tuple[float, float] | None = None) -> str:
    theirs = "– | –" if kinhec is None else f"{kinhec[0]:+.2f} | {kinhec[1]:.1f}"
    if "refused" in result:
        reason = result["refused"].split(":")[0]
        time_s = result["time_s"]
        return f"| {scenario} | {true_offset_s:+g} | refused ({reason}) | | | {time_s:.2f} | {theirs} |"
    return (
        f"| {scenario} | {true_offset_s:+g} | {result['coarse_ms']:+.2f} | {result['final_ms']:+.3f} | "
        f"{result['peaks']} | {result['time_s']:.2f} | {theirs} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kinhec-seeds", type=int, default=20, help="other KinHEC sequences at 0.05 s")
    parser.add_argument("--skip-fast", action="store_true", help="leave out the 500/60 Hz simulation (slow)")
    args = parser.parse_args()

    scenarios: dict[str, RawRecording] = {}
    sweeps, _ = simulate_raw(PRESETS["paper-white"])
    scenarios["sweeps 125/10-20 Hz"] = sweeps
    scenarios["sweeps 125/10-20 Hz, jitter 2 ms, drops, gap"] = degraded(sweeps)
    if not args.skip_fast:
        fast = dataclasses.replace(
            PRESETS["paper-white"],
            robot_model="UR10e",
            tracker_rate_hz=60.0,
            rotation_sample_period_s=1 / 60,
            translation_sample_period_s=1 / 60,
            rotation_deg=30.0,
            translation_mm=200.0,
        )
        scenarios["sweeps 500/60 Hz, jitter 2 ms, drops, gap"] = degraded(simulate_raw(fast)[0])
    stations = dataclasses.replace(
        PRESETS["paper-white"], motion="stations", stations=12, frames_per_station=5
    )
    scenarios["stations (stop-and-go), 125/20 Hz"] = simulate_raw(stations)[0]

    print(
        "| scenario | true offset (s) | coarse error (ms) | final error (ms) | peak / runner-up "
        "| time (s) | KinHEC solver error (ms) | KinHEC solver time (s) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for name, raw in scenarios.items():
        for offset in OFFSETS_S:
            moved = dataclasses.replace(raw, robot_time_s=raw.robot_time_s + offset)
            print(row(name, offset, ours(moved, offset)), flush=True)
    # KinHEC's offset is the camera's clock ahead of the robot's: ours negated
    for offset in OFFSETS_S:
        sequence = kinhec_sequence(-offset)
        kinhec = kinhec_solver(sequence, -offset) if abs(offset) <= 10.0 else None
        # KinHEC's error is of its own sign: negate it to compare
        kinhec = None if kinhec is None else (-kinhec[0], kinhec[1])
        print(
            row("KinHEC temporal (smoke), 500/30 Hz", offset, ours(raw_from_kinhec(sequence), offset), kinhec)
        )

    if args.kinhec_seeds:
        mine, theirs, refused = [], [], 0
        for seed in range(args.kinhec_seeds):
            sequence = kinhec_sequence(0.05, seed)
            result = ours(raw_from_kinhec(sequence), -0.05)
            theirs.append(kinhec_solver(sequence, 0.05)[0])
            if "refused" in result:
                refused += 1
            else:
                mine.append(result["final_ms"])
        print()
        print(f"KinHEC temporal (smoke, 2 ms jitter) at 0.05 s, {args.kinhec_seeds} sequences (seeds 0..):")
        print("| solver | error RMS (ms) | error max (ms) | refused |")
        print("|---|---|---|---|")
        for label, errors, count in (("spacecal", mine, str(refused)), ("KinHEC", theirs, "–")):
            errors_ms = np.asarray(errors)
            rms, largest = np.sqrt(np.mean(errors_ms**2)), np.max(np.abs(errors_ms))
            print(f"| {label} | {rms:.2f} | {largest:.2f} | {count} |")


if __name__ == "__main__":
    main()
