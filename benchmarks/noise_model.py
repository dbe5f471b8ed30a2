"""The noise model learnt from the residuals (``ml``, LS-VCE) against the isotropic ML and the closed forms.

(a) White isotropic sphere noise (paper-white; the marker poses only, and the raw spheres):
RMS over noise trials of the cube TRE of ML with estimated components and of the isotropic
ML, each over the Cramér–Rao bound, and the estimated components against the injected ones.

(b) Anisotropic sphere noise (paper-white with ``depth_anisotropy=3``; raw spheres, and the
poses the tracker fits from them): ML with estimated components against the isotropic ML,
and the bound for the true (anisotropic) sphere noise.

(c) Pose-only recordings with depth-dominated translation noise and a precise orientation
(as OpenIGTLink / PLUS sources deliver them): the paper-white motion's true marker poses
with translation noise ``--lateral-mm`` across and ``--depth-mm`` along the line of sight
(at the marker origin) and ``--rotation-deg`` per axis of orientation noise, no spheres and
no tracker RMS. Every closed form, the isotropic ML (Shah's closed form refined by
unweighted least squares on the marker's model points) and ML with estimated components,
over ``--worlds`` x ``--pose-trials`` recordings: median and RMS errors of ``tracker_from_base``
(cube TRE, rotation) and ``tcp_from_marker`` (position, rotation), and the share of
recordings where ML with estimated components is at least as accurate as the best closed
form on that recording.

(d) Systematic errors (paper-realistic, and with ``depth_anisotropy=3``) over
``--realistic-seeds`` worlds: the two ML variants' TRE, their predicted TRE, and the
estimated depth-to-lateral ratio.

(a') The bound check of (a) for ML with estimated components on ``--bound-trials`` trials.

    python benchmarks/noise_model.py [--trials 20] [--worlds 5] [--pose-trials 6] [--realistic-seeds 10]
        [--bound-trials 300] [--only ab|bound|c|d]
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

from spacecal.estimators import calibrate
from spacecal.estimators.methods.likelihood import tre_summary
from spacecal.estimators.methods.ml import covariance_from_information
from spacecal.estimators.methods.noise_model import NoiseProblem, normal_equations
from spacecal.estimators.methods.observations import build_observations
from spacecal.estimators.methods.samples import site_in_base
from spacecal.estimators.registry import Family, estimators_of
from spacecal.experiments.monte_carlo import cramer_rao_tre_mm
from spacecal.experiments.simulation import Simulation, simulate
from spacecal.experiments.truth import calibration_error
from spacecal.geometry.transforms import rotvec_to_matrix
from spacecal.records import Recording
from spacecal.sim.scenario import PRESETS

CLOSED_FORMS = list(estimators_of(Family.ROBOT_WORLD, Family.HAND_EYE))


def pose_only_recording(
    simulation: Simulation,
    trial: int,
    lateral_mm: float,
    depth_mm: float,
    rotation_deg: float,
) -> Recording:
    """The simulation's true marker poses with depth-dominated translation noise and
    isotropic orientation noise, as a pose-only source delivers them (no spheres, no RMS)."""
    rng = np.random.default_rng([simulation.world.scenario.seed, 7, trial])
    rec = simulation.recording
    truth = simulation.true_tracker_from_marker_stack
    poses = truth.copy()
    origin = truth[:, :3, 3]
    sight = origin / np.linalg.norm(origin, axis=1, keepdims=True)
    noise = rng.normal(scale=lateral_mm, size=origin.shape)
    noise += (depth_mm / lateral_mm - 1.0) * np.sum(noise * sight, axis=1, keepdims=True) * sight
    poses[:, :3, 3] += noise
    tilt = rotvec_to_matrix(rng.normal(scale=np.radians(rotation_deg), size=origin.shape))
    poses[:, :3, :3] = tilt @ truth[:, :3, :3]
    poses[~rec.visible] = np.nan
    return Recording(
        time_s=rec.time_s,
        segment=rec.segment,
        joints_rad=rec.joints_rad,
        base_from_tcp_stack=rec.base_from_tcp_stack,
        tracker_from_marker_stack=poses,
        marker_rms_mm=np.full(len(rec), np.nan),
        metadata=rec.metadata,
    )


def anisotropic_sphere_bound(simulation: Simulation) -> float:
    """Cramér–Rao cube RMS TRE at the truth for the scenario's anisotropic white sphere noise."""
    world, scenario = simulation.world, simulation.world.scenario
    lateral = scenario.white_noise_rms_mm / np.sqrt(2.0 + scenario.depth_anisotropy**2)
    recording = simulation.recording
    noise_free = dataclasses.replace(recording, spheres_in_tracker=None)
    obs = build_observations(noise_free)
    exact = dataclasses.replace(
        obs,
        spheres_in_tracker=np.einsum(
            "nij,kj->nki", simulation.true_tracker_from_marker_stack[obs.rows, :3, :3], obs.spheres_in_marker
        )
        + simulation.true_tracker_from_marker_stack[obs.rows, None, :3, 3],
        dof_per_frame=3 * len(obs.spheres_in_marker),
    )
    problem = NoiseProblem(exact, None)
    residuals = problem.residuals(world.tracker_from_base, world.tcp_from_marker)
    theta = np.array([lateral**2, (scenario.depth_anisotropy * lateral) ** 2])
    information, _, _ = normal_equations(residuals, problem.weights(theta))
    site = site_in_base(recording, obs.rows)
    return float(
        tre_summary(world.tracker_from_base, covariance_from_information(information), site)["cube_rms"]
    )


def rms(values: list[float]) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def ml_pair(recording: Recording, simulation: Simulation) -> dict[str, tuple[float, float, dict]]:
    """TRE and compute time of ML with estimated components and of the isotropic ML."""
    out = {}
    for model in ("estimated", "isotropic"):
        start = time.perf_counter()
        result = calibrate(recording, "ml", noise_model=model)
        elapsed = time.perf_counter() - start
        out[model] = (
            calibration_error(result, simulation.world)["tre_rms_mm"],
            elapsed,
            result.diagnostics.get("noise_model", {}),
        )
    return out


def white_and_anisotropic_spheres(trials: int) -> None:
    print(f"(a, b) ML with estimated components vs isotropic ML, {trials} noise trials (RMS over trials)\n")
    print(
        "| scenario | observations | frames | bound (mm) | ML estimated TRE (mm) | / bound | "
        "ML isotropic TRE (mm) | / bound | estimated / isotropic | lateral (mm) est / true | "
        "depth (mm) est / true | compute est / iso (ms) |"
    )
    print("|" + "|".join(["---"] * 12) + "|")
    for anisotropy in (1.0, 3.0):
        for spheres in (False, True):
            scenario = dataclasses.replace(
                PRESETS["paper-white"], depth_anisotropy=anisotropy, record_spheres=spheres
            )
            simulation = simulate(scenario)
            sigma = scenario.white_noise_rms_mm / np.sqrt(2.0 + anisotropy**2)
            if anisotropy == 1.0:
                bound = cramer_rao_tre_mm(simulation)
            else:
                bound = anisotropic_sphere_bound(simulation) if spheres else float("nan")
            errors: dict[str, list[float]] = {"estimated": [], "isotropic": []}
            times: dict[str, list[float]] = {"estimated": [], "isotropic": []}
            lateral, depth = [], []
            for trial in range(trials):
                recording, _ = simulation.remeasure(trial)
                for model, (tre, elapsed, summary) in ml_pair(recording, simulation).items():
                    errors[model].append(tre)
                    times[model].append(elapsed)
                    if summary:
                        lateral.append(summary["lateral_mm"])
                        depth.append(summary["depth_mm"])
            # pose components are per-axis s.d. of the marker's centroid: sigma / sqrt(K) if isotropic
            scale = 1.0 if spheres else 1.0 / np.sqrt(len(simulation.world.marker.spheres_in_marker))
            true_lateral, true_depth = sigma * scale, anisotropy * sigma * scale
            est, iso = rms(errors["estimated"]), rms(errors["isotropic"])
            label = "paper-white" if anisotropy == 1.0 else f"paper-white, depth_anisotropy={anisotropy:g}"
            bound_text = "–" if np.isnan(bound) else f"{bound:.4f}"
            print(
                f"| {label} | {'spheres' if spheres else 'poses'} | "
                f"{int(simulation.recording.visible.sum())} | {bound_text} | {est:.4f} | "
                f"{'–' if np.isnan(bound) else f'{est / bound:.3f}'} | {iso:.4f} | "
                f"{'–' if np.isnan(bound) else f'{iso / bound:.3f}'} | {est / iso:.3f} | "
                f"{np.mean(lateral):.4f} / {true_lateral:.4f} | {np.mean(depth):.4f} / {true_depth:.4f} | "
                f"{1000 * np.median(times['estimated']):.0f} / {1000 * np.median(times['isotropic']):.0f} |"
            )
    print(
        "\nFor poses fitted from anisotropic spheres the 'true' lateral/depth columns are the "
        "sphere values / sqrt(K), an approximation (the marker's spheres see slightly different lines "
        "of sight)."
    )


def pose_only(worlds: int, trials: int, lateral_mm: float, depth_mm: float, rotation_deg: float) -> None:
    methods = [*CLOSED_FORMS, "ml isotropic", "ml estimated"]
    keys = (
        "tre_rms_mm",
        "rotation_error_deg",
        "tcp_from_marker_position_error_mm",
        "tcp_from_marker_rotation_error_deg",
    )
    errors: dict[str, dict[str, list[float]]] = {m: {k: [] for k in keys} for m in methods}
    wins = {k: 0 for k in keys}
    components: dict[str, list[float]] = {"lateral_mm": [], "depth_mm": [], "rotation_isotropic_deg": []}
    count = 0
    for world_seed in range(1, worlds + 1):
        simulation = simulate(dataclasses.replace(PRESETS["paper-white"], seed=world_seed))
        for trial in range(trials):
            recording = pose_only_recording(simulation, trial, lateral_mm, depth_mm, rotation_deg)
            for method in methods:
                if method.startswith("ml"):
                    result = calibrate(recording, "ml", noise_model=method.split()[1])
                else:
                    result = calibrate(recording, method, uncertainty=False)
                error = calibration_error(result, simulation.world)
                for k in keys:
                    errors[method][k].append(error[k])
                if method == "ml estimated":
                    for name in components:
                        components[name].append(result.diagnostics["noise_model"][name])
            for k in keys:
                best = min(errors[m][k][-1] for m in CLOSED_FORMS)
                wins[k] += errors["ml estimated"][k][-1] <= best
            count += 1
    print(
        f"\n(c) Pose-only, depth-dominated translation noise ({lateral_mm:g} mm across, {depth_mm:g} mm "
        f"along the line of sight, per axis), orientation noise {rotation_deg:g} deg per axis; "
        f"{worlds} worlds x {trials} trials = {count} recordings, median (RMS)\n"
    )
    print(
        "| method | tracker_from_base TRE (mm) | tracker_from_base rotation (deg) | "
        "tcp_from_marker position (mm) | tcp_from_marker rotation (deg) |"
    )
    print("|" + "|".join(["---"] * 5) + "|")
    for method in methods:
        cells = [f"{np.median(errors[method][k]):.4f} ({rms(errors[method][k]):.4f})" for k in keys]
        print(f"| {method} | " + " | ".join(cells) + " |")
    best_median = {k: min(np.median(errors[m][k]) for m in CLOSED_FORMS) for k in keys}
    print(
        "| ml estimated / best closed form (medians) | "
        + " | ".join(f"{np.median(errors['ml estimated'][k]) / best_median[k]:.3f}" for k in keys)
        + " |"
    )
    print(
        "| recordings where ml estimated <= best closed form on it | "
        + " | ".join(f"{wins[k]}/{count}" for k in keys)
        + " |"
    )
    print(
        f"\nEstimated components (mean over recordings): lateral {np.mean(components['lateral_mm']):.4f} mm "
        f"(injected {lateral_mm:g}), depth {np.mean(components['depth_mm']):.4f} mm (injected {depth_mm:g}), "
        f"orientation {np.mean(components['rotation_isotropic_deg']):.4f} deg (injected {rotation_deg:g})."
    )


def bound_check(trials: int) -> None:
    """ML with estimated components against the Cramér–Rao bound on many trials (paper-white poses)."""
    simulation = simulate(PRESETS["paper-white"])
    bound = cramer_rao_tre_mm(simulation)
    errors = []
    for trial in range(trials):
        recording, _ = simulation.remeasure(trial)
        errors.append(calibration_error(calibrate(recording, "ml"), simulation.world)["tre_rms_mm"])
    print(
        f"\n(a') Bound check, paper-white (marker poses), ML with estimated components, {trials} trials "
        f"(the RMS over trials is known to about +-{100 / np.sqrt(2 * trials):.0f} %): bound {bound:.4f} mm, "
        f"ML {rms(errors):.4f} mm, ratio {rms(errors) / bound:.3f}"
    )


def realistic(seeds: int) -> None:
    """ML with estimated components vs isotropic ML where systematic errors dominate."""
    print(
        f"\n(d) Systematic errors (paper-realistic: volumetric tracker error, DH errors, repeatability), "
        f"{seeds} worlds, one recording each (marker poses)\n"
    )
    print(
        "| scenario | ML estimated TRE median (mm) | ML isotropic TRE median (mm) | estimated / isotropic "
        "(median of ratios) | predicted TRE est / iso (median, mm) | depth / lateral (median) |"
    )
    print("|" + "|".join(["---"] * 6) + "|")
    for anisotropy in (1.0, 3.0):
        tre: dict[str, list[float]] = {"estimated": [], "isotropic": []}
        predicted: dict[str, list[float]] = {"estimated": [], "isotropic": []}
        ratio = []
        for seed in range(1, seeds + 1):
            scenario = dataclasses.replace(PRESETS["paper-realistic"], seed=seed, depth_anisotropy=anisotropy)
            simulation = simulate(scenario)
            for model in tre:
                result = calibrate(simulation.recording, "ml", noise_model=model)
                tre[model].append(calibration_error(result, simulation.world)["tre_rms_mm"])
                predicted[model].append(result.predicted_tre_mm["cube_rms"])
                if model == "estimated":
                    ratio.append(result.diagnostics["noise_model"]["depth_to_lateral"])
        label = "paper-realistic" + ("" if anisotropy == 1.0 else f", depth_anisotropy={anisotropy:g}")
        print(
            f"| {label} | {np.median(tre['estimated']):.4f} | {np.median(tre['isotropic']):.4f} | "
            f"{np.median(np.divide(tre['estimated'], tre['isotropic'])):.3f} | "
            f"{np.median(predicted['estimated']):.4f} / {np.median(predicted['isotropic']):.4f} | "
            f"{np.median(ratio):.2f} |"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--worlds", type=int, default=5)
    parser.add_argument("--pose-trials", type=int, default=6, help="noise trials per world in (c)")
    parser.add_argument("--lateral-mm", type=float, default=0.05)
    parser.add_argument("--depth-mm", type=float, default=0.20)
    parser.add_argument("--rotation-deg", type=float, default=0.02)
    parser.add_argument("--realistic-seeds", type=int, default=10, help="worlds in (d)")
    parser.add_argument("--bound-trials", type=int, default=300, help="trials of the bound check (a')")
    parser.add_argument("--only", choices=("ab", "bound", "c", "d"), help="print one table only")
    args = parser.parse_args()
    if args.only in (None, "ab"):
        white_and_anisotropic_spheres(args.trials)
    if args.only in (None, "bound"):
        bound_check(args.bound_trials)
    if args.only in (None, "c"):
        pose_only(args.worlds, args.pose_trials, args.lateral_mm, args.depth_mm, args.rotation_deg)
    if args.only in (None, "d"):
        realistic(args.realistic_seeds)


if __name__ == "__main__":
    main()
