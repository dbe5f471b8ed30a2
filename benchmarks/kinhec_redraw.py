"""Is a small error under a large statement luck? Refit KinHEC sequences on fresh noise draws.

A statement is the mean of an error over the recordings one set-up could have given; one
recording is one draw. For a KinHEC sequence whose ml calibration was graded ``unusable`` while
its site error is small, this script draws the sequence's measurement noise again, with
KinHEC's own noise functions and the sequence's own noise parameters (its manifest:
``kinhec.noise.camera_se3_gaussian`` on the true target poses, ``robot_se3_gaussian`` on the
true flange poses), and refits the same poses on every draw with spacecal's ``ml`` and with
KinHEC's own reference solver (``shah+lm``, KinHEC's keyframe protocol). Nothing of spacecal
shapes the draws.

Printed per sequence: the recording's own site error and statement; ``ml``'s statement split
into the part the noise alone gives (the Cramér-Rao part: the inverse Fisher information of
the fit carried to the site) and the rest; and over the draws the mean site error of ``ml``
and of ``shah+lm``, the mean statement, and how often a draw's ``ml`` site error is 1 mm or
less. A mean site error near the statement says the recording's small error was luck; a mean
far below it, that the statement is too high. A mean above the ``unusable`` limit (2 mm) for
both solvers says an honest statement must grade the set-up ``unusable``, whatever one draw
gave.

Each fit goes the way ``kinhec_tracks.py`` runs it: files through ``spacecal calibrate``, raw
streams with the clock offset estimated where the sequence is asynchronous (the redrawn poses
keep the recorded times, drops and clock faults), and KinHEC's keyframe protocol. Needs the
sequences of ``kinhec_tracks.py`` (run it first, or pass ``--data``); sequences with KinHEC's
``se3_gaussian`` camera and robot noise only.

    python benchmarks/kinhec_redraw.py noise-000134 noise-000038 [--draws 50] [--tier small]
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
import kinhec_tracks
from kinhec import noise as kinhec_noise

#: The noise models this script can draw again (KinHEC's manifest names).
DRAWABLE = "se3_gaussian"
#: KinHEC's reference solver, refitted on the same draws.
REFERENCE = "shah+lm"


def redrawn(seq, row: dict, rng: np.random.Generator):
    """A copy of ``seq`` whose measured camera and robot poses are drawn again about the true
    ones, by KinHEC's noise functions with the sequence's own parameters (metres, rad). The
    streams' times, drops and any clock faults stay as recorded."""
    camera, robot = seq.camera, seq.robot
    seen = np.isfinite(camera.T_cam_target_meas).all(axis=(1, 2))
    measured = camera.T_cam_target_meas.copy()
    trans_std = (row["camera_trans_std_m"], row["camera_trans_std_m"], row["camera_trans_std_z_m"])
    measured[seen] = kinhec_noise.camera_se3_gaussian(
        rng, camera.T_cam_target_gt[seen], row["camera_rot_std_rad"], trans_std
    )
    flange = robot.T_base_ee_gt.copy()
    if row["robot_rot_std_rad"] > 0 or row["robot_trans_std_m"] > 0:
        flange = kinhec_noise.robot_se3_gaussian(
            rng, robot.T_base_ee_gt, row["robot_rot_std_rad"], row["robot_trans_std_m"]
        )
    out = copy.copy(seq)
    out.camera = dataclasses.replace(camera, T_cam_target_meas=measured)
    out.robot = dataclasses.replace(robot, T_base_ee_meas=flange)
    return out


def fitted(seq, truth: kinhec_tracks.Truth, folder: Path) -> dict:
    """``ml`` on the sequence as the track benchmark runs it (files, ``spacecal calibrate``; raw
    streams with the clock offset estimated where the sequence is asynchronous), and KinHEC's
    ``shah+lm`` under KinHEC's protocol: site errors, the statement and its parts."""
    (ml,) = kinhec_tracks.run_spacecal(seq, truth, ["ml"], folder)
    keyframes = kinhec_tracks.kinhec_keyframe_data(seq, kinhec_tracks.kinhec_offset(seq))
    reference = kinhec_tracks.solve_kinhec(REFERENCE, keyframes, truth, seed=0)
    if ml.get("status") != "result":
        raise SystemExit(f"{seq.id}: ml gave no result: {ml.get('message')}")
    return {
        "site": ml["site_error_mm"],
        "stated": ml["expected_position_mm"],
        "noise_only_rms": ml.get("noise_only_rms_mm") or 0.0,
        "unseen_rms": ml.get("unseen_rms_mm") or 0.0,
        "reference_site": reference.get("site_error_mm", np.nan),
    }


def redraw(sequence_id: str, root: Path, draws: int, seed: int) -> dict:
    """The recording's own fit and those of ``draws`` refits on fresh noise."""
    manifest = pd.read_csv(root / "sequences.csv")
    row = manifest[manifest.sequence_id == sequence_id].iloc[0].to_dict()
    models = (row["camera_noise_model"], row["robot_noise_models"])
    if any(model != DRAWABLE for model in models):
        raise SystemExit(
            f"{sequence_id}: only sequences with {DRAWABLE} noise can be drawn again "
            f"(this one: camera {models[0]}, robot {models[1]})"
        )
    sequence = kinhec_tracks.load_sequence(root, sequence_id, manifest=pd.DataFrame([row]))
    truth = kinhec_tracks.Truth(sequence)
    rng = np.random.default_rng(seed)
    with tempfile.TemporaryDirectory() as folder:
        own = fitted(sequence, truth, Path(folder))
        runs = [fitted(redrawn(sequence, row, rng), truth, Path(folder)) for _ in range(draws)]
    sites = np.array([r["site"] for r in runs])
    return {
        "sequence": sequence_id,
        "configuration": row["configuration"],
        "own": own,
        "draw_site_mean": float(np.mean(sites)),
        "draw_site_se": float(np.std(sites, ddof=1) / np.sqrt(len(sites))),
        "draw_within_1mm": float(np.mean(sites <= 1.0)),
        "draw_stated_mean": float(np.mean([r["stated"] for r in runs])),
        "draw_reference_mean": float(np.nanmean([r["reference_site"] for r in runs])),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("sequences", nargs="+", help="KinHEC sequence ids")
    parser.add_argument("--draws", type=int, default=50)
    parser.add_argument("--tier", default="small")
    parser.add_argument("--data", type=Path, help="KinHEC data folder (default: the benchmark's cache)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    root = args.data or kinhec_tracks.default_data_dir(args.tier)
    print(f"refits on {args.draws} fresh draws of each sequence's KinHEC noise (site errors, mm)\n")
    print(
        "| sequence | set-up | site error | stated | of it the noise alone (RMS) | unseen (RMS) | "
        "draws: ml mean ± s.e. | shah+lm mean | ml within 1 mm | ml stated mean |\n"
        "|---|---|---|---|---|---|---|---|---|---|"
    )
    for sequence_id in args.sequences:
        r = redraw(sequence_id, root, args.draws, args.seed)
        own = r["own"]
        print(
            f"| {r['sequence']} | {r['configuration'].replace('_', '-')} | {own['site']:.2f} | "
            f"{own['stated']:.2f} | {own['noise_only_rms']:.2f} | {own['unseen_rms']:.2f} | "
            f"{r['draw_site_mean']:.2f} ± {r['draw_site_se']:.2f} | {r['draw_reference_mean']:.2f} | "
            f"{r['draw_within_1mm']:.0%} | {r['draw_stated_mean']:.2f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
