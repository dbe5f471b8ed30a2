"""How close any calibration can come behind a tracker with a smooth bias field: the floor.

The ``systematic-*`` presets (:mod:`spacecal.sim.scenario`) put a smooth volumetric error
field of 0.2 mm RMS (correlation length 300 mm) in the tracker, the size of a Polaris Vicra's
0.25 mm RMS volumetric accuracy. Part of such a field cannot be told from the calibration
itself: over the stations, the field's least-squares rigid part ``delta`` (a shift and a small
turn) and the tracker's placement enter the data only as their product. A tracker placed at
``delta @ tracker_from_base`` with the field ``f - (delta - I)`` records the same numbers, to
first order, as the real one; no estimator, whatever it identifies of the arm, can tell the
two apart, and a calibration that takes one for the other aims every target ``delta`` off.

Per scenario and seed this prints, at the paper's 15 verification targets (mean position
error, mm, measured with the simulated laser tracker as :mod:`spacecal.experiments.verification`
does):

* ``kinematic`` (+ tip): what spacecal recommends, on the recording as recorded;
* ``arm known``: ``ml`` on the same tracker data with the arm's true poses in place of the
  controller's (its true DH table and joint deflections, without the repeatability scatter,
  which stays in the data as noise), and IK on the true arm with its deflection compensated:
  every arm-side error any identification could remove, removed;
* ``arm and field known but its rigid part``: the same, with each frame's pose also corrected
  for the field's non-rigid part (what a perfect model of the field could remove);
* ``rigid part at targets``: ``|delta(y) - y|`` at the targets, the unidentifiable part alone,
  computed from the simulated field without noise;
* ``kinematic, field's non-rigid part known``: ``kinematic`` on the recording corrected for the
  field's non-rigid part as in ``arm and field known but its rigid part``, verified as
  spacecal verifies it: the most an identification
  that also modelled the field (short of its rigid part) could gain;
* ``kinematic, no field``: ``kinematic`` on the same scenario and arm with the field off.

With ``--tips``, it prints instead what the needle tip's measurement costs (mean verification
error, mm, and the tip's distance from the true one in the marker frame, mm):

* ``kinematic``, ``kinematic + pivot``: as above (the pivot :func:`simulate_pivot` records);
* ``kinematic + pivot without the field``: the same pivot (tilts and noise) through a tracker
  with no bias field;
* ``kinematic + true tip``: the needle's true tip in the marker frame;
* ``kinematic + tip to 0.05 mm``: a tip measured on the tool itself (a coordinate measuring
  machine), drawn about the true one with :data:`MEASURED_TIP_SD_MM` per axis, its covariance
  that measurement's;
* ``kinematic + mean tip``: the mean of the pivot's tip and the one ``kinematic`` puts at the
  controller's TCP (two measurements of one point, of about equal error);
* ``tip to 0.05 mm: measured / stated``: that calibration's verification error over its
  stated expected error;
* ``pivot tip off``, ``kinematic tip off``, ``mean tip off``: those tips' distances from the
  true one.

With ``--priors``, it prints instead ``kinematic`` under other arm priors on the same seeds:
the prior s.d. taken from the data (the default), the true residual's size (0.1 mm,
0.01 deg per DH parameter, :data:`spacecal.sim.scenario.REALISTIC_CALIBRATION_RESIDUAL`), half
of it, and held-out model selection.

    python benchmarks/tracker_bias_floor.py [--seeds 10] [--preset NAME ...] [--priors | --tips]
"""

from __future__ import annotations

import dataclasses

import numpy as np
from systematic_families import seed_parser  # the benchmarks' folder, on the path when run

from spacecal.estimators import calibrate
from spacecal.experiments.simulation import Simulation, simulate
from spacecal.experiments.verification import (
    DeflectionCompensatedRobot,
    verification_targets,
    verify_in_simulation,
)
from spacecal.geometry.fitting import fit_rigid
from spacecal.geometry.transforms import apply_transform, invert_transform, transform_points_by_stack
from spacecal.records import CalibrationResult, NeedleTip, Recording
from spacecal.sim.devices import SimulatedLaserTracker, SimulatedRobot
from spacecal.sim.pivot import simulate_pivot
from spacecal.sim.scenario import PRESETS, Scenario
from spacecal.sim.world import World, build_world
from spacecal.workflows.verification import run_verification

SCENARIOS = ("systematic-calibrated-compliant", "systematic-nominal")

#: Per-axis s.d. (mm) of a tip measured on the tool itself (a coordinate measuring machine's
#: report of a needle guide: assumed, a few hundredths of a millimetre being usual for one).
MEASURED_TIP_SD_MM = 0.05


def field_at(world: World, points_in_tracker: np.ndarray) -> np.ndarray:
    """The tracker's whole position bias (…, 3), mm, at points (…, 3) in the tracker frame."""
    bias = world.error_field(points_in_tracker)
    if world.bias_field is not None:
        bias = bias + world.bias_field(points_in_tracker)
    return bias


def with_true_arm(recording: Recording, world: World) -> Recording:
    """The recording with the arm's true TCP poses (true DH table and deflection, no scatter)."""
    true_poses = world.true_base_from_tcp(recording.joints_rad, jitter=False)
    return dataclasses.replace(recording, base_from_tcp_stack=true_poses)


def rigid_part(simulation: Simulation) -> np.ndarray:
    """``delta`` (4, 4): the least-squares rigid map of the spheres' true positions onto
    themselves plus the field, over every frame the tracker saw."""
    world, recording = simulation.world, simulation.recording
    poses = simulation.true_tracker_from_marker_stack[recording.visible]
    points = transform_points_by_stack(poses, world.marker.spheres_in_marker).reshape(-1, 3)
    delta, _ = fit_rigid(points_in_source=points, points_in_target=points + field_at(world, points))
    return delta


def without_non_rigid_part(recording: Recording, simulation: Simulation, delta: np.ndarray) -> Recording:
    """The recording with each frame's pose corrected for the field's non-rigid part (at the
    spheres' true positions): the poses a tracker whose bias were exactly ``delta`` would have
    reported, with its noise."""
    spheres = simulation.world.marker.spheres_in_marker
    poses = recording.tracker_from_marker_stack.copy()
    for i in np.flatnonzero(recording.visible):
        true_points = apply_transform(simulation.true_tracker_from_marker_stack[i], spheres)
        rigid = apply_transform(delta, true_points) - true_points
        non_rigid = field_at(simulation.world, true_points) - rigid
        points = apply_transform(poses[i], spheres)
        correction, _ = fit_rigid(points_in_source=points, points_in_target=points - non_rigid)
        poses[i] = correction @ poses[i]
    return dataclasses.replace(recording, tracker_from_marker_stack=poses)


def paper_targets(world: World) -> np.ndarray:
    """The verification targets (15, 4, 4) in the tracker frame that
    :func:`verify_in_simulation` drives to (its default ``seed``)."""
    scenario = world.scenario
    return verification_targets(
        world, scenario.verification_targets, np.random.default_rng([scenario.seed, 2, 0])
    )


def verified_mean(calibration: CalibrationResult, scenario: Scenario) -> float:
    """Mean position error (mm) of :func:`verify_in_simulation` at the paper's targets."""
    return float(np.mean(verify_in_simulation(calibration, scenario).position_error_mm))


def verify_on_true_arm(calibration: CalibrationResult, scenario: Scenario) -> float:
    """Mean position error (mm) at the paper's verification targets, IK on the true arm with its
    deflection compensated, the needle the true TCP; otherwise as :func:`verify_in_simulation`."""
    world = build_world(scenario)
    targets = paper_targets(world)
    robot = SimulatedRobot(world)
    compliance = world.true_compliance()
    commanded = (
        robot if compliance is None else DeflectionCompensatedRobot(robot, world.true_model, compliance)
    )
    laser = SimulatedLaserTracker(world, robot)
    verified = run_verification(
        calibration,
        commanded,
        laser,
        world.true_model,
        targets,
        world.home_joints_rad,
        tcp_from_needle=np.eye(4),
    )
    return float(np.mean(verified.position_error_mm))


def rigid_error_at_targets(world: World, delta: np.ndarray) -> float:
    """Mean ``|delta(y) - y|`` (mm) over the verification targets' needle tips ``y``."""
    tips = paper_targets(world)[:, :3, 3]
    return float(np.mean(np.linalg.norm(apply_transform(delta, tips) - tips, axis=1)))


def run(preset: str, seed: int) -> dict:
    """The row of one scenario and seed: mean verification errors (mm)."""
    scenario = dataclasses.replace(PRESETS[preset], seed=seed)
    simulation = simulate(scenario)
    recording, world = simulation.recording, simulation.world
    tip = NeedleTip.from_pivot(simulate_pivot(build_world(scenario)))
    recommended = {
        variant: verified_mean(calibrate(recording, "kinematic", needle_tip=t), scenario)
        for variant, t in (("kinematic", None), ("kinematic + tip", tip))
    }
    delta = rigid_part(simulation)
    # the correction touches the tracker's frames only, and with_true_arm the robot's
    field_corrected = without_non_rigid_part(recording, simulation, delta)
    field_off = dataclasses.replace(scenario, volumetric_error_rms_mm=0.0)
    no_field = simulate(field_off).recording
    return {
        "scenario": preset,
        "seed": seed,
        **recommended,
        "arm known": verify_on_true_arm(calibrate(with_true_arm(recording, world), "ml"), scenario),
        "arm and field known but its rigid part": verify_on_true_arm(
            calibrate(with_true_arm(field_corrected, world), "ml"), scenario
        ),
        "rigid part at targets": rigid_error_at_targets(world, delta),
        "kinematic, field's non-rigid part known": verified_mean(
            calibrate(field_corrected, "kinematic"), scenario
        ),
        "kinematic, no field": verified_mean(calibrate(no_field, "kinematic"), field_off),
    }


PRIORS = {
    "prior from data": {},
    "prior 0.1 mm, 0.01 deg": {
        "prior_from_data": False,
        "prior_length_sd_mm": 0.1,
        "prior_angle_sd_rad": float(np.radians(0.01)),
    },
    "prior 0.05 mm, 0.005 deg": {
        "prior_from_data": False,
        "prior_length_sd_mm": 0.05,
        "prior_angle_sd_rad": float(np.radians(0.005)),
    },
    "held-out model selection": {"model_selection": True},
}


def run_priors(preset: str, seed: int) -> dict:
    """The row of one scenario and seed: ``kinematic``'s mean verification error (mm) under
    each of :data:`PRIORS`."""
    scenario = dataclasses.replace(PRESETS[preset], seed=seed)
    recording = simulate(scenario).recording
    errors = {
        name: verified_mean(calibrate(recording, "kinematic", **options), scenario)
        for name, options in PRIORS.items()
    }
    return {"scenario": preset, "seed": seed, **errors}


COLUMNS = (
    "kinematic",
    "kinematic + tip",
    "arm known",
    "arm and field known but its rigid part",
    "rigid part at targets",
    "kinematic, field's non-rigid part known",
    "kinematic, no field",
)


def without_bias_fields(world: World) -> World:
    """The world with its tracker's bias fields switched off (noise and everything else kept)."""
    error_field = dataclasses.replace(
        world.error_field, amplitudes_mm=np.zeros_like(world.error_field.amplitudes_mm)
    )
    return dataclasses.replace(world, error_field=error_field, bias_field=None)


def run_tips(preset: str, seed: int) -> dict:
    """The row of one scenario and seed: ``kinematic`` with the needle tip measured in each way
    of :data:`TIP_COLUMNS` (mean verification error, mm), and how far each tip is off (mm)."""
    scenario = dataclasses.replace(PRESETS[preset], seed=seed)
    simulation = simulate(scenario)
    recording, world = simulation.recording, simulation.world
    pivot = NeedleTip.from_pivot(simulate_pivot(build_world(scenario)))
    field_free = NeedleTip.from_pivot(simulate_pivot(without_bias_fields(build_world(scenario))))
    true_tip = invert_transform(world.tcp_from_marker)[:3, 3]
    alone = calibrate(recording, "kinematic")
    own_tip = invert_transform(alone.tcp_from_marker)[:3, 3]
    mean_tip = dataclasses.replace(pivot, tip_in_marker=0.5 * (pivot.tip_in_marker + own_tip))
    sd = MEASURED_TIP_SD_MM
    drawn = true_tip + np.random.default_rng([seed, 31]).normal(scale=sd, size=3)
    # a tip with its own accuracy, not a pivot's: its covariance holds no tracker bias
    measured = NeedleTip(drawn, np.eye(3) * sd**2, "simulated measurement of the tool", 0.0, 1)

    def aimed(tip: NeedleTip) -> float:
        return verified_mean(calibrate(recording, "kinematic", needle_tip=tip), scenario)

    with_measured = calibrate(recording, "kinematic", needle_tip=measured)
    measured_error = verified_mean(with_measured, scenario)

    return {
        "scenario": preset,
        "seed": seed,
        "kinematic": verified_mean(alone, scenario),
        "kinematic + pivot": aimed(pivot),
        "kinematic + pivot without the field": aimed(field_free),
        "kinematic + true tip": aimed(dataclasses.replace(pivot, tip_in_marker=true_tip)),
        "kinematic + tip to 0.05 mm": measured_error,
        "tip to 0.05 mm: measured / stated": measured_error
        / with_measured.expected_error.to_dict()["position_mm"],
        "kinematic + mean tip": aimed(mean_tip),
        "pivot tip off": float(np.linalg.norm(pivot.tip_in_marker - true_tip)),
        "kinematic tip off": float(np.linalg.norm(own_tip - true_tip)),
        "mean tip off": float(np.linalg.norm(mean_tip.tip_in_marker - true_tip)),
    }


TIP_COLUMNS = (
    "kinematic",
    "kinematic + pivot",
    "kinematic + pivot without the field",
    "kinematic + true tip",
    "kinematic + tip to 0.05 mm",
    "tip to 0.05 mm: measured / stated",
    "kinematic + mean tip",
    "pivot tip off",
    "kinematic tip off",
    "mean tip off",
)


def table(rows: list[dict], columns: tuple[str, ...] = COLUMNS) -> str:
    """Per scenario: each column's mean ± s.d. over seeds, and per seed."""
    out = ["| scenario | seed | " + " | ".join(columns) + " |", "|---|---|" + "---|" * len(columns)]
    for scenario in SCENARIOS:
        mine = [r for r in rows if r["scenario"] == scenario]
        if not mine:
            continue
        for r in mine:
            out.append(f"| {scenario} | {r['seed']} | " + " | ".join(f"{r[c]:.3f}" for c in columns) + " |")
        summary = [np.array([r[c] for r in mine]) for c in columns]
        out.append(
            f"| **{scenario}** | **mean of {len(mine)}** | "
            + " | ".join(f"**{v.mean():.3f}** ± {v.std(ddof=1) if len(v) > 1 else 0.0:.3f}" for v in summary)
            + " |"
        )
    return "\n".join(out)


def main() -> None:
    parser = seed_parser(__doc__.splitlines()[0], SCENARIOS)
    modes = parser.add_mutually_exclusive_group()
    modes.add_argument("--priors", action="store_true", help="kinematic under other arm priors instead")
    modes.add_argument("--tips", action="store_true", help="what the needle tip's measurement costs instead")
    args = parser.parse_args()
    one_row, columns = run, COLUMNS
    if args.priors:
        one_row, columns = run_priors, tuple(PRIORS)
    elif args.tips:
        one_row, columns = run_tips, TIP_COLUMNS
    rows = [
        one_row(preset, seed)
        for preset in args.preset or SCENARIOS
        for seed in range(args.first_seed, args.first_seed + args.seeds)
    ]
    print(table(rows, columns))


if __name__ == "__main__":
    main()
