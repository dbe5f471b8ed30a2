"""The levers on the error at the needle tip under realistic errors, each on and off.

Realistic scenario (``paper-realistic``: volumetric tracker error 0.2 mm RMS, DH length
errors 0.3 mm s.d., twist and joint-offset errors 0.03 deg s.d., 0.1 mm repeatability), the
paper's one-minute sweep, over several seeds (each seed is a different arm and layout). The
same arm behind two controllers:

* ``calibrated``: the controller reports ``actual_TCP_pose`` through its factory calibration
  (the true arm within 0.05 mm / 0.005 deg per DH parameter) and the recording carries that
  model (``robot.kinematic_model``), which identification takes as its prior;
* ``nominal``: the controller reports through the nominal model (``paper-realistic-nominal``),
  the prior is the nominal model.

Estimators: ML; kinematic identification freeing every identifiable DH correction under a fixed
prior (1 mm, 0.002 rad s.d.); the same with subset selection (only the corrections that lower
the held-out misfit); and under a prior whose scale the held-out misfit sets (none freed when
it shows nothing beyond the noise), the default.
Then an arm that matches its nominal model (``paper-white``), where identification must not
cost accuracy.

Verification: the paper's 15-point experiment (§5.2); IK uses the identified model when there
is one, else the controller's.

``--pose-only`` strips each recording to what a pose-only tracker sends (no sphere positions,
no fit RMS: the noise is unknown).

    python benchmarks/levers.py [--seeds 10] [--pose-only]
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from spacecal.estimators import calibrate
from spacecal.experiments.simulation import simulate
from spacecal.experiments.verification import verify_in_simulation
from spacecal.sim.scenario import PRESETS

#: (label, registry method, options)
ESTIMATORS = (
    ("ml", "ml", {}),
    ("kinematic, fixed prior (1 mm, 0.002 rad)", "kinematic", {"prior_from_data": False}),
    (
        "kinematic, fixed prior, subset selection",
        "kinematic",
        {"prior_from_data": False, "model_selection": True},
    ),
    ("kinematic, prior scale from the data (default)", "kinematic", {}),
)

#: (label of the arm and controller, preset)
SET_UPS = (
    ("realistic arm, calibrated controller", "paper-realistic"),
    ("realistic arm, nominal controller", "paper-realistic-nominal"),
    ("arm matching its nominal model", "paper-white"),
)


def run_seed(seed: int, poses_only: bool = False) -> dict[tuple[str, str], tuple[float, ...]]:
    """Per (set-up, estimator): verification mean and max position (mm), mean, min and max
    posture (deg), number of DH corrections freed."""
    rows: dict[tuple[str, str], tuple[float, ...]] = {}
    for set_up, preset in SET_UPS:
        scenario = dataclasses.replace(PRESETS[preset], seed=seed)
        recording = simulate(scenario).recording
        if poses_only:
            recording = recording.as_pose_only()
        for label, method, options in ESTIMATORS:
            calibration = calibrate(recording, method, uncertainty=False, **options)
            result = verify_in_simulation(calibration, scenario)
            identification = calibration.diagnostics.get("kinematic_identification")
            freed = np.nan if identification is None else len(identification["identified"])
            rows[(set_up, label)] = (
                float(np.mean(result.position_error_mm)),
                float(np.max(result.position_error_mm)),
                float(np.mean(result.posture_error_deg)),
                float(np.min(result.posture_error_deg)),
                float(np.max(result.posture_error_deg)),
                float(freed),
            )
    return rows


def cell(values: np.ndarray) -> str:
    spread = values.std(ddof=1) if len(values) > 1 else 0.0
    return f"{values.mean():.3f} ± {spread:.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument(
        "--pose-only", action="store_true", help="strip the recordings to marker poses without fit RMS"
    )
    args = parser.parse_args()
    results = [run_seed(seed, args.pose_only) for seed in range(1, args.seeds + 1)]
    print(
        f"Levers on the needle-tip error, paper sweep{', pose-only tracker' if args.pose_only else ''}, "
        f"{args.seeds} seeds "
        "(mean ± s.d. over seeds; verification: paper §5.2, 15 points)\n"
    )
    print(
        "| arm and controller | estimator | verification mean position (mm) | "
        "verification max position (mm) | verification mean posture (deg) | "
        "posture min–max over the 15 points (deg, mean over seeds) | DH corrections freed |"
    )
    print("|---|---|---|---|---|---|---|")
    for key in results[0]:
        values = np.array([r[key] for r in results])
        freed = "–" if np.isnan(values[:, 5]).any() else f"{values[:, 5].mean():.1f}"
        print(
            f"| {key[0]} | {key[1]} | {cell(values[:, 0])} | {cell(values[:, 1])} | {cell(values[:, 2])} | "
            f"{values[:, 3].mean():.3f}–{values[:, 4].mean():.3f} | {freed} |"
        )
    white = SET_UPS[2][0]
    ml = np.array([r[(white, "ml")][0] for r in results]).mean()
    print()
    for label, _, _ in ESTIMATORS[1:]:
        kinematic = np.array([r[(white, label)][0] for r in results]).mean()
        print(f"{white}: {label} / ml = {kinematic / ml:.3f} (verification mean position, mean over seeds)")


if __name__ == "__main__":
    main()
