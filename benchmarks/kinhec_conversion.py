"""KinHEC sequences as spacecal recordings, and the true errors of a calibration against them.

KinHEC (``pip install kinhec``) solves ``A_i X = Y B_i`` with, per camera frame,

* ``A_i = T_base_ee``: the robot's flange pose in its base (metres, quaternion w, x, y, z);
* eye-to-hand (camera fixed, marker on the flange): ``B_i = T_cam_marker``, ``X = T_ee_marker``,
  ``Y = T_base_cam``;
* eye-in-hand (camera on the flange, calibration target fixed): ``B_i = T_target_cam =
  inv(T_cam_target)``, ``X = T_ee_cam``, ``Y = T_base_target``.

spacecal solves ``tracker_from_marker = tracker_from_base @ base_from_tcp @ tcp_from_marker``:
the tracker is the fixed frame that measures, the marker the frame on the tool. So

* ``tcp`` is KinHEC's flange (``ee``): ``base_from_tcp_stack = A`` (no tool offset);
* ``tracker`` is the fixed frame of the pair, ``marker`` the one on the flange: the camera and
  the marker eye-to-hand, the target and the camera eye-in-hand;
* then in both configurations ``tracker_from_marker_stack = B``, ``tcp_from_marker = X`` and
  ``tracker_from_base = inv(Y)``, lengths times 1000 (m -> mm).

KinHEC's trackers report poses only (no sphere fit), so the recording's ``marker_rms_mm`` is
NaN: spacecal then takes the noise from the residuals. Joint angles are passed for the UR
arms, whose nominal DH tables are the same in both packages (the metadata names the model),
and for the other arms KinHEC gives in standard DH form (a KUKA LBR iiwa's seven joints): their
nominal DH table, from KinHEC, goes into the metadata as ``robot.kinematic_model``. An arm in
modified DH form (Craig's; the Franka Panda) gets NaN joints: spacecal has no model of it.

This module imports nothing from the tests; the benchmark ``benchmarks/kinhec_tracks.py`` and the
conversion test load it by path.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spacecal.geometry.transforms import invert_transform
from spacecal.models.robot_kinds import ur_kind_names
from spacecal.records import RawRecording, Recording

MM_PER_M = 1000.0

#: Segment label of every converted sample: KinHEC has no sweeps, so spacecal's held-out blocks
#: are contiguous time blocks.
SEGMENT = "kinhec"

#: Largest residual (mm, deg) of KinHEC's noise-free ground truth through the converted chain:
#: beyond it the conversion (frames, units, quaternion order) is wrong. (The angle comes from an
#: arccos, whose rounding near 0 is about 1e-6 deg.)
EXACT_TOLERANCE_MM = 1e-6
EXACT_TOLERANCE_DEG = 1e-4


class ConversionError(ValueError):
    """A KinHEC sequence that the conversion cannot represent, or got wrong."""


def spacecal_robot_model(kinhec_robot: str) -> str | None:
    """spacecal's name of a KinHEC UR arm (``ur5e`` -> ``UR5e``), None for other arms."""
    for name in ur_kind_names():
        if name.lower() == kinhec_robot.lower():
            return name
    return None


def kinematic_model_of(kinhec_robot: str) -> dict | None:
    """The nominal model of a KinHEC arm that is not a UR arm, as spacecal's
    ``robot.kinematic_model`` metadata (standard DH table in mm and rad, KinHEC's flange as the
    TCP); None for a UR arm (named instead) and for an arm spacecal's standard DH cannot describe.

    Two of KinHEC's conventions are rewritten exactly:

    - Craig's modified DH (the Panda): link i is Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(theta_i) Tz(d_i),
      and a rotation and a translation along one axis commute, so the chain regroups into
      standard links Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i) that take the next link's a and
      alpha (the last link's are zero). Exact when the first link's a and alpha are zero, as
      nothing then stands before the first joint.
    - A joint counted the other way (``q_sign`` -1, the IRB 120's axis 3): spacecal's joint value
      is ``q_sign * q`` (:func:`joint_values`), so its limits swap and change sign.
    """
    from kinhec.robots import get_robot

    if spacecal_robot_model(kinhec_robot) is not None:
        return None
    robot = get_robot(kinhec_robot)
    a, alpha = list(robot.a), list(robot.alpha)
    if robot.convention == "modified":
        if a[0] != 0.0 or alpha[0] != 0.0:
            return None
        a, alpha = a[1:] + [0.0], alpha[1:] + [0.0]
    elif robot.convention != "standard":
        return None
    sign = robot.sign
    lower = np.where(sign > 0, robot.q_min, -np.asarray(robot.q_max))
    upper = np.where(sign > 0, robot.q_max, -np.asarray(robot.q_min))
    tool = np.array(robot.tool_matrix, dtype=float)
    tool[:3, 3] *= MM_PER_M
    return {
        "name": robot.name,
        "a_mm": [MM_PER_M * v for v in a],
        "d_mm": [MM_PER_M * v for v in robot.d],
        "alpha_rad": alpha,
        "theta_offset_rad": list(robot.theta_offset),
        "flange_from_tcp": tool.tolist(),
        "joint_lower_rad": lower.tolist(),
        "joint_upper_rad": upper.tolist(),
        "controller_hz": float(robot.control_rate_hz),
    }


def joint_values(kinhec_robot: str, q: np.ndarray) -> np.ndarray:
    """KinHEC's joint angles (N, J) as the joint values of :func:`kinematic_model_of`'s model."""
    from kinhec.robots import get_robot

    return np.asarray(q, dtype=float) * get_robot(kinhec_robot).sign


def in_mm(stack_m: np.ndarray) -> np.ndarray:
    """Poses (..., 4, 4) in metres as poses in mm (a copy)."""
    out = np.array(stack_m, dtype=float, copy=True)
    out[..., :3, 3] *= MM_PER_M
    return out


def truth(seq) -> tuple[np.ndarray, np.ndarray]:
    """KinHEC's ground truth as spacecal transforms: ``(tracker_from_base, tcp_from_marker)``, mm."""
    return invert_transform(in_mm(seq.Y)), in_mm(seq.X)


def kinhec_from_spacecal(
    tracker_from_base: np.ndarray, tcp_from_marker: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """A spacecal calibration (mm) as KinHEC's ``(X, Y)`` (m)."""
    x = np.array(tcp_from_marker, dtype=float, copy=True)
    x[:3, 3] /= MM_PER_M
    y = invert_transform(np.asarray(tracker_from_base, dtype=float))
    y[:3, 3] /= MM_PER_M
    return x, y


def _metadata(seq, model: str | None) -> dict:
    import kinhec

    m = seq.manifest
    robot: dict = {"kinhec_robot": m["robot"], "dof": int(m["dof"])}
    if model is not None:
        robot["model"] = model
    kinematic_model = kinematic_model_of(m["robot"])
    if kinematic_model is not None:
        robot["model"] = kinematic_model["name"]
        robot["kinematic_model"] = kinematic_model
    return {
        "source": f"KinHEC {kinhec.__version__} sequence {seq.id}",
        "simulated": True,
        "units": {"length": "mm"},
        "robot": robot,
        "tracker": {"model": f"KinHEC {m['camera']} camera, pose only"},
        "frames": {
            "configuration": m["configuration"],
            "tracker": "camera" if m["configuration"] == "eye_to_hand" else "calibration target",
            "marker": "marker" if m["configuration"] == "eye_to_hand" else "camera",
            "tcp": "flange",
        },
    }


def _joints(q: np.ndarray | None, rows: int, model: str | None, kinhec_robot: str) -> np.ndarray:
    """KinHEC's joint angles where spacecal has the arm's model, else NaN (six columns)."""
    if q is None or (model is None and kinematic_model_of(kinhec_robot) is None):
        return np.full((rows, 6), np.nan)
    return joint_values(kinhec_robot, q)


def _tracker_from_marker(seq, camera_from_target: np.ndarray) -> np.ndarray:
    """KinHEC's ``B`` (mm) from its ``T_cam_target`` rows (NaN rows stay NaN)."""
    out = np.full(camera_from_target.shape, np.nan)
    ok = np.isfinite(camera_from_target).all(axis=(1, 2))
    b = camera_from_target[ok]
    out[ok] = in_mm(invert_transform(b) if seq.eye_in_hand else b)
    return out


def to_recording(seq, noise_free: bool = False) -> Recording:
    """A synchronous KinHEC sequence as a paired spacecal recording (one sample per camera frame).

    Parameters
    ----------
    seq : kinhec.io.Sequence
        ``seq.synchronous`` must hold (both streams on one clock, row by row).
    noise_free : bool
        Use KinHEC's ground-truth columns instead of the measurements (for checking the frames).
    """
    if not seq.synchronous:
        raise ConversionError(f"{seq.id}: asynchronous streams; use to_raw_recording")
    if len(seq.robot.t) != len(seq.camera.t) or not np.allclose(seq.robot.t, seq.camera.t, atol=1e-9):
        raise ConversionError(f"{seq.id}: the robot and camera rows of a synchronous sequence differ")
    model = spacecal_robot_model(seq.manifest["robot"])
    if noise_free:
        base_from_tcp = in_mm(seq.camera.T_base_ee_gt)
        tracker_from_marker = _tracker_from_marker(seq, seq.camera.T_cam_target_gt)
        joints = _joints(seq.robot.q_gt, len(seq.robot.t), model, seq.manifest["robot"])
    else:
        base_from_tcp = in_mm(seq.robot.T_base_ee_meas)
        tracker_from_marker = _tracker_from_marker(seq, seq.camera.T_cam_target_meas)
        joints = _joints(seq.robot.q_meas, len(seq.robot.t), model, seq.manifest["robot"])
    return Recording(
        time_s=np.asarray(seq.camera.t, dtype=float),
        segment=np.full(len(seq.camera.t), SEGMENT),
        joints_rad=joints,
        base_from_tcp_stack=base_from_tcp,
        tracker_from_marker_stack=tracker_from_marker,
        marker_rms_mm=np.full(len(seq.camera.t), np.nan),
        metadata=_metadata(seq, model),
    )


@dataclass(frozen=True)
class RawConversion:
    """An asynchronous sequence as two raw streams, and how the tracker rows were reordered."""

    raw: RawRecording
    #: spacecal's offset (robot clock minus tracker clock, s) that pairs the streams correctly:
    #: KinHEC stamps a frame captured at robot time t at t + time_offset_s.
    true_offset_s: float
    #: tracker frames whose jittered stamps were out of order and were sorted by stamp
    reordered_frames: int


def to_raw_recording(seq) -> RawConversion:
    """An asynchronous KinHEC sequence as spacecal's two raw streams, each on its own clock."""
    model = spacecal_robot_model(seq.manifest["robot"])
    robot_t = np.asarray(seq.robot.t, dtype=float)
    tracker_t = np.asarray(seq.camera.t, dtype=float)
    # jittered stamps can come out of order; a receiver keeps (stamp, pose) pairs together
    order = np.argsort(tracker_t, kind="stable")
    reordered = int(np.sum(order != np.arange(len(order))))
    tracker_from_marker = _tracker_from_marker(seq, seq.camera.T_cam_target_meas)[order]
    raw = RawRecording(
        robot_time_s=robot_t,
        robot_segment=np.full(len(robot_t), SEGMENT),
        joints_rad=_joints(seq.robot.q_meas, len(robot_t), model, seq.manifest["robot"]),
        base_from_tcp_stack=in_mm(seq.robot.T_base_ee_meas),
        tracker_time_s=tracker_t[order],
        tracker_from_marker_stack=tracker_from_marker,
        marker_rms_mm=np.full(len(tracker_t), np.nan),
        metadata=_metadata(seq, model),
    )
    return RawConversion(raw, -float(seq.time_offset), reordered)


def chain_residuals(
    recording: Recording, tracker_from_base: np.ndarray, tcp_from_marker: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per seen sample: distance (mm) and angle (deg) between the measured marker pose and
    ``tracker_from_base @ base_from_tcp @ tcp_from_marker``."""
    seen = recording.has_pose
    predicted = tracker_from_base @ recording.base_from_tcp_stack[seen] @ tcp_from_marker
    measured = recording.tracker_from_marker_stack[seen]
    distance = np.linalg.norm(predicted[:, :3, 3] - measured[:, :3, 3], axis=1)
    relative = np.einsum("nji,njk->nik", predicted[:, :3, :3], measured[:, :3, :3])
    cosine = np.clip((np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return distance, np.degrees(np.arccos(cosine))


def check_exact(seq) -> tuple[float, float]:
    """Largest residual (mm, deg) of KinHEC's noise-free columns, converted, under its ground
    truth; raises :class:`ConversionError` beyond :data:`EXACT_TOLERANCE_MM` / ``_DEG``.

    Asynchronous sequences are checked on the ground-truth flange poses KinHEC stores at the
    camera instants, which is the same conversion of the same frames.
    """
    model = spacecal_robot_model(seq.manifest["robot"])
    n = len(seq.camera.t)
    recording = Recording(
        time_s=np.arange(n, dtype=float),
        segment=np.full(n, SEGMENT),
        joints_rad=np.full((n, 6), np.nan),
        base_from_tcp_stack=in_mm(seq.camera.T_base_ee_gt),
        tracker_from_marker_stack=_tracker_from_marker(seq, seq.camera.T_cam_target_gt),
        marker_rms_mm=np.full(n, np.nan),
        metadata=_metadata(seq, model),
    )
    distance, angle = chain_residuals(recording, *truth(seq))
    worst = (float(distance.max()), float(angle.max()))
    if worst[0] > EXACT_TOLERANCE_MM or worst[1] > EXACT_TOLERANCE_DEG:
        raise ConversionError(
            f"{seq.id}: KinHEC's noise-free data leave {worst[0]:.3g} mm, {worst[1]:.3g} deg "
            "under its ground truth: the conversion is wrong"
        )
    return worst


def _tail_variance(noise: dict) -> float:
    """Variance factor of KinHEC's Student-t draws (1 for Gaussian ones)."""
    dof = noise.get("student_t_dof")
    if dof is None or not np.isfinite(dof) or dof <= 0:
        return 1.0
    return float(dof / (dof - 2.0)) if dof > 2.0 else float("inf")


def expected_residual_rms(seq) -> tuple[float, float] | None:
    """RMS distance (mm) and angle (deg) of the measurements under the ground truth that
    KinHEC's injected noise gives, to first order; None for noise models without a closed form
    (joint noise, DH errors, PnP, drift).

    Robot: ``A exp(xi)``, xi with per-axis s.d. ``r`` (rad) and ``t`` (m), moves the marker
    (``X``'s origin, in the flange frame) by ``d_theta x t_X + d_t``: mean square
    ``3 t^2 + 2 r^2 |t_X|^2``. Camera: translation noise (x, y, z s.d.) in the camera frame and
    rotation noise (s.d. ``c`` per axis) on the target's orientation: mean square
    ``sum(s_i^2)``, plus eye-in-hand (where the camera's position in the target frame is the
    measurement) ``2 c^2 |t_cam_target|^2``. Angles: ``3 r^2 + 3 c^2``.
    """
    cfg = seq.config
    if cfg is None:
        return None
    rn, cn = cfg.robot_noise, cfg.camera_noise
    if set(rn["models"]) - {"se3_gaussian"} or cn["model"] not in ("se3_gaussian", "none"):
        return None
    if "se3_gaussian" in rn["models"]:
        r, t = float(rn["rot_std_rad"]), float(rn["trans_std_m"])
    else:
        r = t = 0.0
    robot_scale = _tail_variance(rn)
    lever_x = float(np.linalg.norm(seq.X[:3, 3]))
    robot_pos = robot_scale * (3 * t**2 + 2 * r**2 * lever_x**2)
    robot_rot = robot_scale * 3 * r**2
    camera_pos = camera_rot = 0.0
    if cn["model"] == "se3_gaussian":
        c = np.broadcast_to(np.asarray(cn["rot_std_rad"], dtype=float), (3,))
        s = np.broadcast_to(np.asarray(cn["trans_std_m"], dtype=float), (3,))
        scale = _tail_variance(cn)
        camera_pos = float(np.sum(s**2))
        camera_rot = float(np.sum(c**2))
        if seq.eye_in_hand:
            ok = np.isfinite(seq.camera.T_cam_target_gt).all(axis=(1, 2))
            lever = np.linalg.norm(seq.camera.T_cam_target_gt[ok, :3, 3], axis=1)
            camera_pos += float(np.mean(lever**2)) * 2 * float(np.mean(c**2))
        camera_pos *= scale
        camera_rot *= scale
    position_mm = MM_PER_M * np.sqrt(robot_pos + camera_pos)
    angle_deg = np.degrees(np.sqrt(robot_rot + camera_rot))
    return float(position_mm), float(angle_deg)


def pose_error(estimate: np.ndarray, reference: np.ndarray) -> tuple[float, float]:
    """Rotation (deg, geodesic) and translation (same unit as the matrices) error."""
    relative = estimate[:3, :3].T @ reference[:3, :3]
    cosine = np.clip((np.trace(relative) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.degrees(np.arccos(cosine))), float(np.linalg.norm(estimate[:3, 3] - reference[:3, 3]))


def site_error_mm(
    tracker_from_base: np.ndarray, true_tracker_from_base: np.ndarray, points_in_base: np.ndarray
) -> float:
    """Mean distance (mm) between where the estimate and the truth put points of the base
    frame (M, 3), mm, in the tracker frame: the calibration's own error at those targets."""
    homogeneous = np.c_[points_in_base, np.ones(len(points_in_base))]
    difference = homogeneous @ (tracker_from_base - true_tracker_from_base)[:3].T
    return float(np.mean(np.linalg.norm(difference, axis=1)))
