"""Compare every calibration method on simulated data and print a table.

Scenarios: white tracker noise only; realistic (volumetric error 0.2 mm RMS, DH length
errors 0.3 mm s.d., 0.1 mm repeatability); realistic with 10 % outlier frames. Motions:
the paper's sweeps (about 580 frames) and 50 random static stations x 10 frames (500
frames). For each, the world is fixed and the measurement noise is redrawn ``--trials``
times; the table gives RMS over trials of the TRE over a 200 mm cube around the site and
of the rotation error, the ratio of that TRE to the Cramér–Rao bound for the white sphere
noise, the mean verification position error of the paper's 15-point experiment (first
trial), and the median compute time.

    python benchmarks/estimators.py [--trials 20]
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from spacecal.estimators import ESTIMATORS, calibrate
from spacecal.experiments.monte_carlo import cramer_rao_tre_mm, run_monte_carlo
from spacecal.experiments.simulation import simulate
from spacecal.experiments.verification import verify_in_simulation
from spacecal.sim.scenario import PRESETS

ORDER = list(ESTIMATORS)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=50)
    parser.add_argument("--bound-trials", type=int, default=300)
    args = parser.parse_args()

    print(f"Methods x scenarios, {args.trials} noise trials each (RMS over trials)\n")
    print(
        "| scenario | motion | frames | method | TRE RMS (mm) | TRE / bound | rotation error (deg) | "
        "predicted TRE (mm) | verification mean (mm) | compute (ms) |"
    )
    print("|" + "|".join(["---"] * 10) + "|")
    for name in ("paper-white", "paper-realistic", "paper-outliers"):
        for motion in ("paper", "stations"):
            simulation = simulate(dataclasses.replace(PRESETS[name], motion=motion))
            bound = cramer_rao_tre_mm(simulation)
            frames = int(simulation.recording.visible.sum())
            first_trial = simulation.remeasure(0)[0]
            for summary in run_monte_carlo(simulation, ORDER, args.trials):
                if summary.failure:
                    print(
                        f"| {name} | {motion} | {frames} | {summary.method} | fails: {summary.failure[:55]}… "
                        "| | | | | |"
                    )
                    continue
                verification = verify_in_simulation(
                    calibrate(first_trial, summary.method, uncertainty=False), simulation.world.scenario
                ).statistics()
                predicted = f"{summary.predicted_tre_rms_mm:.4f}" if summary.predicted_tre_rms_mm else "–"
                print(
                    f"| {name} | {motion} | {frames} | {summary.method} | {summary.tre_rms_mm:.4f} | "
                    f"{summary.tre_rms_mm / bound:.2f} | {summary.rotation_rms_deg:.4f} | {predicted} | "
                    f"{verification['position_mm']['mean']:.3f} | {summary.compute_s * 1000:.1f} |"
                )

    print(
        f"\nBound check, paper-white, {args.bound_trials} trials (the RMS over trials is then known "
        f"to about +-{100 / np.sqrt(2 * args.bound_trials):.0f} %):\n"
    )
    print(
        "| motion | Cramér–Rao bound (mm) | ML TRE RMS (mm) | ratio | ML predicted TRE (mm) | "
        "predicted / observed |"
    )
    print("|" + "|".join(["---"] * 6) + "|")
    for motion in ("paper", "stations"):
        simulation = simulate(dataclasses.replace(PRESETS["paper-white"], motion=motion))
        bound = cramer_rao_tre_mm(simulation)
        ml = run_monte_carlo(simulation, ["ml"], args.bound_trials)[0]
        print(
            f"| {motion} | {bound:.4f} | {ml.tre_rms_mm:.4f} | {ml.tre_rms_mm / bound:.3f} | "
            f"{ml.predicted_tre_rms_mm:.4f} | {ml.predicted_tre_rms_mm / ml.tre_rms_mm:.3f} |"
        )
    print(
        f"\nCramér–Rao bound: white sphere noise of the scenario at the truth "
        f"({np.sqrt(0.25**2) / np.sqrt(3):.3f} mm per axis in paper-white, "
        f"{0.15 / np.sqrt(3):.3f} mm in the others)."
    )


if __name__ == "__main__":
    main()
