"""How well any estimator can do on KinHEC's robot-error track: the Bayesian Cramér–Rao bound.

KinHEC's robot-error track draws each arm's DH errors from a Gaussian (``dh_len_std_mm`` on the
link lengths a, d and ``dh_ang_std_deg`` on the angles alpha, theta offset; ``perturbed_model``
in ``kinhec.kinematics``) and records 30 static views through a camera whose noise it states
(``camera_se3_gaussian`` in ``kinhec.noise``: translation noise in the camera frame, rotation
noise on the target's orientation; level ``c2`` of its tier). With that prior and that noise,
the posterior covariance of the 12 pose parameters and the 4 J DH corrections,
``(sum_f J_f^T S_f^+ J_f + P^-1)^-1``, bounds the mean square error of every estimator of the
calibration averaged over the arms KinHEC draws (the Bayesian Cramér–Rao bound; for this
linearised Gaussian model the MAP estimate with the true prior attains it). Mapped to the
sequence's site targets, it is the least site error any method can expect, whatever it
identifies; the joint noise KinHEC adds (1e-4 rad) is left out, which only lowers the bound.

It is printed beside KinHEC's shah+lm and spacecal's ml site errors on each DH-error sequence:
a target below the bound cannot be met on these recordings.

    python benchmarks/kinhec_identification_bound.py [--tier small]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
import kinhec_tracks
from kinhec.io import load_manifest, load_sequence
from kinhec.plans import load_tier

from spacecal.estimators import calibrate
from spacecal.estimators.assessment.gaussian import mean_gaussian_length
from spacecal.estimators.methods.kinematic import DH_FIELDS
from spacecal.estimators.methods.ml import point_covariances
from spacecal.estimators.methods.observations import build_observations
from spacecal.estimators.methods.recorded_model import nominal_robot_model
from spacecal.geometry.rotations import skew
from spacecal.models.kinematics import dh_point_jacobian, pose_point_jacobian

conversion = kinhec_tracks.conversion


def camera_noise_covariances(
    tracker_from_marker: np.ndarray,
    spheres_in_marker: np.ndarray,
    eye_in_hand: bool,
    rot_sd: np.ndarray,
    trans_sd_mm: np.ndarray,
) -> np.ndarray:
    """Per frame, the covariance (N, 3K, 3K), mm^2, of the stacked spheres in the tracker frame
    under KinHEC's camera noise: ``T_cam_target = (R exp(dr), t + dt)``.

    Eye to hand (tracker = camera, marker = target): dq = -R [p]x dr + dt. Eye in hand (tracker =
    target, marker = camera, the measurement inverted): dq = [q]x dr - R^T dt, with q the
    sphere in the target frame and R the camera-from-target rotation.
    """
    frames, spheres = len(tracker_from_marker), len(spheres_in_marker)
    rotation = tracker_from_marker[:, :3, :3]
    if eye_in_hand:
        points = np.einsum("nij,kj->nki", rotation, spheres_in_marker) + tracker_from_marker[:, None, :3, 3]
        by_rotation = skew(points)  # (N, K, 3, 3)
        by_translation = np.broadcast_to(
            -rotation[:, None], (frames, spheres, 3, 3)
        )  # R^T of camera_from_target
    else:
        by_rotation = -np.einsum("nij,kjl->nkil", rotation, skew(spheres_in_marker))
        by_translation = np.broadcast_to(np.eye(3), (frames, spheres, 3, 3))
    design = np.concatenate([by_rotation, by_translation], axis=-1).reshape(frames, 3 * spheres, 6)
    variances = np.concatenate([rot_sd**2, trans_sd_mm**2])
    return np.einsum("nij,j,nkj->nik", design, variances, design)


def camera_noise_of(tier: dict, seq) -> tuple[np.ndarray, np.ndarray]:
    """The camera noise KinHEC's tier states for a sequence: rotation s.d. (3,), rad, and
    translation s.d. (3,), mm. The level is the sequence's ``camera=`` factor, or its track's
    fixed ``camera_level`` (the robot-error track)."""
    level = seq.manifest["level"]
    if "camera=" in level:
        name = level.split("camera=")[1].split("|")[0]
    else:
        name = tier["tracks"][seq.manifest["track"]]["camera_level"]
    rotation_sd, translation_sd_m = tier["noise_levels"]["camera"][name]
    return np.full(3, float(rotation_sd)), 1000.0 * np.asarray(translation_sd_m, dtype=float)


def site_error_bound(
    seq, truth: kinhec_tracks.Truth, dh_len_sd_mm: float, dh_ang_sd_rad: float, rot_sd, trans_sd_mm
) -> float:
    """The least mean site error (mm) any estimator can expect on this sequence's arm draws, at
    ``truth``'s site targets."""
    clean = conversion.to_recording(seq, noise_free=True)
    model = nominal_robot_model(clean)
    obs = build_observations(clean)
    tracker_from_base, tcp_from_marker = conversion.truth(seq)
    joints = clean.joints_rad[obs.rows]
    points = obs.spheres_in_marker
    pose = pose_point_jacobian(obs.base_from_tcp_stack, tracker_from_base, tcp_from_marker, points)
    dh = dh_point_jacobian(model, joints, tracker_from_base, tcp_from_marker, points)
    count, spheres = pose.shape[:2]
    design = np.concatenate([pose, dh], axis=-1).reshape(count, 3 * spheres, -1)
    raw = clean.tracker_from_marker_stack[obs.rows]
    # the recording's tracker_from_marker: for eye in hand the inverse of camera_from_target,
    # whose rotation R^T is what the translation noise turns by
    covariances = camera_noise_covariances(raw, points, seq.eye_in_hand, rot_sd, trans_sd_mm)
    information = np.zeros((design.shape[-1],) * 2)
    for jacobian, covariance in zip(design, covariances):
        information += jacobian.T @ np.linalg.pinv(covariance, rcond=1e-10, hermitian=True) @ jacobian
    joints_count = model.n_joints
    prior_sd = np.concatenate(
        [
            np.full(joints_count, dh_len_sd_mm if field.endswith("_mm") else dh_ang_sd_rad)
            for field in DH_FIELDS
        ]
    )
    information[12:, 12:] += np.diag(1.0 / prior_sd**2)
    posterior = np.linalg.inv(information)
    covariances_at_site = point_covariances(tracker_from_base, posterior[:6, :6], truth.reported_tcp_mm)
    return float(np.mean([mean_gaussian_length(c) for c in covariances_at_site]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tier", default="small")
    args = parser.parse_args()
    root = kinhec_tracks.default_data_dir(args.tier)
    kinhec_tracks.ensure_data(args.tier, root, ["robot_error"], 1)
    tier = load_tier(str(kinhec_tracks.tier_config(args.tier)))
    manifest = load_manifest(root)
    rows = manifest[manifest.sequence_id.str.startswith("robot_error") & manifest.level.str.startswith("dh_")]
    print(f"## KinHEC robot-error track ({args.tier} tier): the least site error any estimator can expect")
    print()
    print(
        "| sequence | arm | DH errors (mm, deg) | bound (mm) | spacecal ml | KinHEC shah+lm | 0.3x shah+lm "
        "| below the bound |"
    )
    print("|---|---|---|---|---|---|---|---|")
    below = 0
    for _, m in rows.iterrows():
        seq = load_sequence(root, m["sequence_id"], manifest=pd.DataFrame([m]))
        length_mm = float(m["level"].split("dh_len_mm=")[1].split("|")[0])
        angle_deg = float(m["level"].split("dh_ang_deg=")[1])
        truth = kinhec_tracks.Truth(seq)
        bound = site_error_bound(seq, truth, length_mm, np.radians(angle_deg), *camera_noise_of(tier, seq))
        ml = calibrate(conversion.to_recording(seq), "ml")
        x, y = conversion.kinhec_from_spacecal(ml.tracker_from_base, ml.tcp_from_marker)
        ml_site = truth.errors(x, y)["site_error_mm"]
        shah = kinhec_tracks.run_kinhec(seq, truth, ["shah+lm"], 0)[0].get("site_error_mm", np.nan)
        target = 0.3 * shah
        below += target < bound
        print(
            f"| {m['sequence_id']} | {m['robot']} | {length_mm:g}, {angle_deg:g} | {bound:.2f} "
            f"| {ml_site:.2f} | {shah:.2f} | {target:.2f} | {'yes' if target < bound else 'no'} |"
        )
    print()
    print(
        f"{below} of {len(rows)} targets of 0.3x shah+lm lie below the least error any estimator can expect."
    )


if __name__ == "__main__":
    main()
