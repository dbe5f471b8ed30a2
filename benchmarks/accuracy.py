"""Expected error vs measured verification error, and the cost of the slower paths.

(a) For each scenario and seed: calibrate the paper's sweep by ML, read the expected error at
a target near the site that the result states (``diagnostics["expected_error"]``), and run
the paper's 15-point verification (§5.2) in the same world. The table gives, over seeds, the
mean measured and expected position errors, the median ratio expected / measured, the share
of seeds within +-30 % and the number below half.

Scenarios: white (paper-white), realistic (paper-realistic), anisotropic (realistic with
the tracker's noise 3x larger along its line of sight), clock offset (realistic recorded as
raw streams with the robot clock 30 ms ahead, paired at the estimated offset).

(b) Wall time of whole ``python -m spacecal.cli calibrate`` processes on the realistic sweep:
ML on the paired recording, ML on the raw streams with the clock offset estimated, and
kinematic identification on the paired recording. Runs are interleaved, five of each; the
median is reported with its ratio to ML.

    python benchmarks/accuracy.py [--seeds 10] [--runs 5] [--jobs 2]
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from spacecal.estimators import calibrate
from spacecal.estimators.time_offset import estimate_time_offset, pair_streams
from spacecal.experiments.simulation import simulate, simulate_raw
from spacecal.experiments.verification import verify_in_simulation
from spacecal.io.raw_streams import write_raw_recording
from spacecal.io.recording_csv import write_recording
from spacecal.sim.scenario import PRESETS, Scenario

SCENARIOS: dict[str, Scenario] = {
    "white": PRESETS["paper-white"],
    "realistic": PRESETS["paper-realistic"],
    "anisotropic": dataclasses.replace(PRESETS["paper-realistic"], depth_anisotropy=3.0),
    "clock offset 30 ms": PRESETS["paper-realistic"],
}


def run_case(case: tuple[str, int, str]) -> tuple[str, float, float, float, float]:
    """(scenario, measured mean position, expected position, measured posture, expected posture)."""
    name, seed, method = case
    scenario = dataclasses.replace(SCENARIOS[name], seed=seed)
    if name.startswith("clock offset"):
        raw, _ = simulate_raw(scenario, clock_offset_s=0.030)
        recording = pair_streams(raw, estimate_time_offset(raw).offset_s)
    else:
        recording = simulate(scenario).recording
    result = calibrate(recording, method)
    measured = verify_in_simulation(result, scenario).statistics()
    expected = result.diagnostics["expected_error"]
    return (
        name,
        float(measured["position_mm"]["mean"]),
        float(expected["position_mm"]),
        float(measured["posture_deg"]["mean"]),
        float(expected["posture_deg"]),
    )


def accuracy_table(seeds: int, jobs: int, method: str) -> None:
    cases = [(name, seed, method) for name in SCENARIOS for seed in range(1, seeds + 1)]
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        rows = list(pool.map(run_case, cases))
    print(f"(a) Expected vs measured error at the verification targets, {method}, seeds 1-{seeds}\n")
    print(
        "| scenario | measured position (mm) | expected position (mm) | median expected/measured | "
        "within ±30 % | below half | measured posture (deg) | expected posture (deg) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for name in SCENARIOS:
        values = np.array([r[1:] for r in rows if r[0] == name])
        ratio = values[:, 1] / values[:, 0]
        print(
            f"| {name} | {values[:, 0].mean():.3f} | {values[:, 1].mean():.3f} | {np.median(ratio):.2f} | "
            f"{np.mean(np.abs(ratio - 1.0) <= 0.3):.0%} | {int(np.sum(ratio < 0.5))} of {len(ratio)} | "
            f"{values[:, 2].mean():.3f} | {values[:, 3].mean():.3f} |"
        )


def timing_table(runs: int) -> None:
    scenario = PRESETS["paper-realistic"]
    with tempfile.TemporaryDirectory() as folder:
        base = Path(folder)
        write_recording(simulate(scenario).recording, base / "rec.csv")
        raw, _ = simulate_raw(scenario, clock_offset_s=0.030)
        robot, tracker = write_raw_recording(raw, base / "raw")
        commands = {
            "ml, paired recording": [str(base / "rec.csv"), "--method", "ml"],
            "ml, raw streams, offset estimated": [
                str(robot),
                "--tracker-stream",
                str(tracker),
                "--method",
                "ml",
            ],
            "kinematic, paired recording": [str(base / "rec.csv"), "--method", "kinematic"],
        }
        times: dict[str, list[float]] = {label: [] for label in commands}
        for _ in range(runs):
            for label, args in commands.items():
                start = time.perf_counter()
                subprocess.run(
                    [sys.executable, "-m", "spacecal.cli", "calibrate", *args, "-o", str(base / "out.json")],
                    check=False,
                    capture_output=True,
                )
                times[label].append(time.perf_counter() - start)
    reference = statistics.median(times["ml, paired recording"])
    print(f"\n(b) Wall time of `python -m spacecal.cli calibrate`, median of {runs} interleaved runs\n")
    print("| command | median (s) | × ml |")
    print("|---|---|---|")
    for label, values in times.items():
        print(f"| {label} | {statistics.median(values):.2f} | {statistics.median(values) / reference:.2f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--method", default="ml")
    parser.add_argument("--only", choices=("accuracy", "timing"), help="print one table only")
    args = parser.parse_args()
    if args.only != "timing":
        accuracy_table(args.seeds, args.jobs, args.method)
    if args.only != "accuracy":
        timing_table(args.runs)


if __name__ == "__main__":
    main()
