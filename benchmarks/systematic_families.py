"""Accuracy under the systematic error families the calibration was not designed against.

The ``systematic-*`` presets (:mod:`spacecal.sim.scenario`; 120 static stations, the
tracker's volumetric bias 0.2 mm RMS):

* ``systematic-nominal``: a controller that reports nominal kinematics, DH lengths 0.3 mm s.d.;
* ``systematic-nominal-angles``: the same with 0.05 deg joint offsets and twists;
* ``systematic-calibrated-compliant``: a controller calibrated to a realistic residual (0.1 mm,
  0.01 deg per DH parameter), with shoulder and elbow compliance under gravity and payload;
* ``systematic-nominal-all`` / ``systematic-calibrated-all``: each with every other family
  added (depth-dependent tracker scale, a polynomial tracker bias, marker geometry errors).

Per scenario and seed (each seed a different arm, tracker bias and layout) the recording is
calibrated with ``ml`` and with ``kinematic`` (identification under a prior whose scale the
held-out misfit sets), and each calibration is verified by the paper's 15-point experiment
(§5.2) in the same simulated world: IK uses the identified model when there is one, else the
controller's. Stated: ``expected_error.position_mm``.

The lever ``+ tip``: ``calibrate(..., needle_tip=...)`` (``spacecal calibrate --tip
pivot.json``) with the needle tip a simulated pivot measured in the marker frame
(:func:`spacecal.sim.pivot.simulate_pivot`: the tool turned 25 deg about its tip at the site
in 200 frames, tracked with the world's noise and bias fields); IK aims it through the
calibration's ``tcp_from_marker`` instead of the controller's TCP, and the stated error is at
it. The last link's errors move the tip in the flange frame, which no marker on the tool can
see (``tcp_from_marker`` absorbs them); a measured tip removes them, and brings the pivot's
own error.

The table gives, per scenario and method, the verification mean position error (mean and s.d.
over seeds), the per-seed ratio to ml, and measured / stated (median and largest).

    python benchmarks/systematic_families.py [--seeds 10] [--first-seed 1] [--preset NAME ...]
        [--json PART.json]            # keep the rows (to run seeds in parts)
    python benchmarks/systematic_families.py --table PART.json ...   # one table from parts
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from spacecal.estimators import calibrate
from spacecal.experiments.simulation import simulate
from spacecal.experiments.verification import verify_in_simulation
from spacecal.geometry.transforms import invert_transform
from spacecal.records import NeedleTip
from spacecal.sim.pivot import simulate_pivot
from spacecal.sim.scenario import PRESETS
from spacecal.sim.world import build_world

SCENARIOS = (
    "systematic-nominal",
    "systematic-nominal-angles",
    "systematic-calibrated-compliant",
    "systematic-nominal-all",
    "systematic-calibrated-all",
)
METHODS = ("ml", "kinematic")
VARIANTS = ("ml", "ml + tip", "kinematic", "kinematic + tip")


def run(preset: str, seed: int) -> list[dict]:
    """One row per method and variant: verification mean and max position (mm), stated
    expected error (mm), the pivot's tip error (mm)."""
    scenario = dataclasses.replace(PRESETS[preset], seed=seed)
    started = time.process_time()
    recording = simulate(scenario).recording
    simulated_s = time.process_time() - started
    world = build_world(scenario)
    pivot = simulate_pivot(world)
    tip_error_mm = float(np.linalg.norm(pivot.tip_in_marker - invert_transform(world.tcp_from_marker)[:3, 3]))
    rows = []
    for method in METHODS:
        for variant, tip in ((method, None), (f"{method} + tip", NeedleTip.from_pivot(pivot))):
            started = time.process_time()
            calibration = calibrate(recording, method, needle_tip=tip)
            calibrated_s = time.process_time() - started
            expected = {} if calibration.expected_error is None else calibration.expected_error.to_dict()
            stated = expected.get("position_mm")
            verified = verify_in_simulation(calibration, scenario)  # aims the tip when it has one
            rows.append(
                {
                    "scenario": preset,
                    "seed": seed,
                    "method": variant,
                    "mean_mm": float(np.mean(verified.position_error_mm)),
                    "max_mm": float(np.max(verified.position_error_mm)),
                    "stated_mm": None if stated is None else float(stated),
                    "simulate_cpu_s": simulated_s,
                    "calibrate_cpu_s": calibrated_s,
                    "pivot_tip_error_mm": tip_error_mm if tip is not None else None,
                }
            )
    return rows


def table(rows: list[dict]) -> str:
    """The markdown table of :func:`run`'s rows."""
    out = [
        "| scenario | method | seeds | verification mean (mm) | max over seeds (mm) | "
        "/ ml, mean of per-seed ratios | measured / stated: median, largest |",
        "|---|---|---|---|---|---|---|",
    ]
    scenarios = [s for s in SCENARIOS if any(r["scenario"] == s for r in rows)]
    for scenario in scenarios:
        ml = {r["seed"]: r["mean_mm"] for r in rows if r["scenario"] == scenario and r["method"] == "ml"}
        for method in VARIANTS:
            mine = sorted(
                (r for r in rows if r["scenario"] == scenario and r["method"] == method),
                key=lambda r: r["seed"],
            )
            if not mine:
                continue
            means = np.array([r["mean_mm"] for r in mine])
            ratios = np.array([r["mean_mm"] / ml[r["seed"]] for r in mine if r["seed"] in ml])
            honest = np.array([r["mean_mm"] / r["stated_mm"] for r in mine if r["stated_mm"]])
            spread = means.std(ddof=1) if len(means) > 1 else 0.0
            stated = f"{np.median(honest):.2f}, {honest.max():.2f}" if len(honest) else "none stated"
            out.append(
                f"| {scenario} | {method} | {len(mine)} | {means.mean():.3f} ± {spread:.3f} | "
                f"{max(r['max_mm'] for r in mine):.3f} | {ratios.mean():.3f} | {stated} |"
            )
    return "\n".join(out)


def seed_parser(description: str, scenarios: tuple[str, ...]) -> argparse.ArgumentParser:
    """The options the systematic benchmarks share: ``--seeds``, ``--first-seed``, ``--preset``."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=1)
    parser.add_argument("--preset", action="append", choices=scenarios, help="default: every one")
    return parser


def main() -> None:
    parser = seed_parser(__doc__.splitlines()[0], SCENARIOS)
    parser.add_argument("--json", type=Path, help="write the rows here as they come")
    parser.add_argument("--table", type=Path, nargs="+", help="print one table from rows written before")
    args = parser.parse_args()
    if args.table:
        print(table([row for path in args.table for row in json.loads(path.read_text())]))
        return
    rows: list[dict] = []
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        for preset in args.preset or SCENARIOS:
            rows.extend(run(preset, seed))
            if args.json:
                args.json.write_text(json.dumps(rows, indent=1))
    print(table(rows))


if __name__ == "__main__":
    main()
