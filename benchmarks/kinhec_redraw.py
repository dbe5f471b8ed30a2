"""Is a small error under a large statement luck? Refit KinHEC sequences on fresh noise draws.

A statement is the mean of an error over the recordings one set-up could have given; one
recording is one draw. For a KinHEC sequence whose ml calibration was graded ``unusable`` while
its site error is small, this script redraws the camera noise KinHEC injected and refits. The
residuals of KinHEC's measured marker poses about its true chain (``B_meas`` against
``Y^-1 A_gt X``, converted to spacecal's frames by ``kinhec_conversion.py``) give the noise's
second moment: the marker's position error (mm) and its turn about itself (rotation vector), in
the tracker's axes, or in the marker's where a camera on the arm carries its noise. Each draw
replaces the measured poses by the true chain perturbed by zero-mean Gaussian noise of that
second moment (the robot's poses as recorded). Printed per sequence: the site error of the
recording itself, its statement, and over the draws the mean and median site error and the
mean statement. A mean site error near the statement says the recording's small error was
luck; one far below it, that the statement is too high. (Eye-to-hand, KinHEC's position and
turn errors are nearly independent in the tracker's axes, as drawn; eye-in-hand much less so,
and the draws are an approximation.)

Needs the sequences of ``kinhec_tracks.py`` (run it first, or pass ``--data``; synchronous
sequences only).

    python benchmarks/kinhec_redraw.py noise-000134 noise-000038 [--draws 20] [--tier small]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parent))
import kinhec_tracks

from spacecal.estimators import calibrate
from spacecal.geometry.transforms import matrix_to_rotvec

conversion = kinhec_tracks.conversion


def noise_frame(configuration: str) -> str:
    """Where KinHEC's camera noise holds still: the tracker's axes when the camera is the
    tracker (eye-to-hand), the marker's when the camera rides on the arm (eye-in-hand)."""
    return "marker" if configuration == "eye_in_hand" else "tracker"


def second_moment(values: np.ndarray) -> np.ndarray:
    """E[v v^T] (3, 3) of rows v about zero: KinHEC's noise has zero mean, and the mean of one
    recording's draws is part of that draw, not a bias to repeat in every refit."""
    return values.T @ values / len(values)


def site_error(truth: kinhec_tracks.Truth, result) -> float:
    x, y = conversion.kinhec_from_spacecal(result.tracker_from_base, result.tcp_from_marker)
    return float(truth.errors(x, y)["site_error_mm"])


def redraw(sequence_id: str, root: Path, draws: int, seed: int) -> dict:
    """The recording's own site error and statement, and those of ``draws`` refits on fresh noise."""
    manifest = pd.read_csv(root / "sequences.csv")
    row = manifest[manifest.sequence_id == sequence_id].iloc[0].to_dict()
    sequence = kinhec_tracks.load_sequence(root, sequence_id, manifest=pd.DataFrame([row]))
    truth = kinhec_tracks.Truth(sequence)
    recording = conversion.to_recording(sequence)
    tracker_from_base, tcp_from_marker = conversion.truth(sequence)
    seen = np.flatnonzero(recording.has_pose)
    true_chain = tracker_from_base @ recording.base_from_tcp_stack[seen] @ tcp_from_marker
    measured = recording.tracker_from_marker_stack[seen]
    frame = noise_frame(row["configuration"])
    # the marker's position error and its turn about itself, in the axes the noise holds in
    # (a turn about the tracker's origin would move the marker by the turn times its distance)
    turns = measured[:, :3, :3] @ np.swapaxes(true_chain[:, :3, :3], 1, 2)
    shifts = measured[:, :3, 3] - true_chain[:, :3, 3]
    if frame == "marker":
        axes = np.swapaxes(true_chain[:, :3, :3], 1, 2)
        turns = axes @ turns @ true_chain[:, :3, :3]
        shifts = np.einsum("nij,nj->ni", axes, shifts)
    translation = shifts
    rotation = np.array([matrix_to_rotvec(turn) for turn in turns])
    own = calibrate(recording, method="ml")
    rng = np.random.default_rng(seed)
    sites, statements = [], []
    for _ in range(draws):
        turn = Rotation.from_rotvec(
            rng.multivariate_normal(np.zeros(3), second_moment(rotation), size=len(seen))
        ).as_matrix()
        shift = rng.multivariate_normal(np.zeros(3), second_moment(translation), size=len(seen))
        if frame == "marker":
            turn = true_chain[:, :3, :3] @ turn @ np.swapaxes(true_chain[:, :3, :3], 1, 2)
            shift = np.einsum("nij,nj->ni", true_chain[:, :3, :3], shift)
        noisy = true_chain.copy()
        noisy[:, :3, :3] = turn @ true_chain[:, :3, :3]
        noisy[:, :3, 3] += shift
        stack = recording.tracker_from_marker_stack.copy()
        stack[seen] = noisy
        result = calibrate(dataclasses.replace(recording, tracker_from_marker_stack=stack), method="ml")
        sites.append(site_error(truth, result))
        statements.append(float(result.diagnostics["expected_error"]["position_mm"]))
    return {
        "sequence": sequence_id,
        "frame": frame,
        "site": site_error(truth, own),
        "stated": float(own.diagnostics["expected_error"]["position_mm"]),
        "draw_site_mean": float(np.mean(sites)),
        "draw_site_median": float(np.median(sites)),
        "draw_stated_mean": float(np.mean(statements)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("sequences", nargs="+", help="KinHEC sequence ids (synchronous)")
    parser.add_argument("--draws", type=int, default=20)
    parser.add_argument("--tier", default="small")
    parser.add_argument("--data", type=Path, help="KinHEC data folder (default: the benchmark's cache)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    root = args.data or kinhec_tracks.default_data_dir(args.tier)
    print(f"ml refits on {args.draws} fresh draws of KinHEC's injected noise (mm)\n")
    print(
        "| sequence | noise held in | site error | stated | draws: site error mean | median | "
        "stated mean |\n|---|---|---|---|---|---|---|"
    )
    for sequence_id in args.sequences:
        r = redraw(sequence_id, root, args.draws, args.seed)
        print(
            f"| {r['sequence']} | {r['frame']} axes | {r['site']:.2f} | {r['stated']:.2f} | "
            f"{r['draw_site_mean']:.2f} | {r['draw_site_median']:.2f} | {r['draw_stated_mean']:.2f} |"
        )


if __name__ == "__main__":
    main()
