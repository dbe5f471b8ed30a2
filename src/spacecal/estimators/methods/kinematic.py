"""Robot kinematic identification jointly with the calibration (registry method ``kinematic``).

The robot's absolute accuracy is limited by how far its true DH parameters differ from the
nominal model. With the tracker as the measuring instrument, the chain

    sphere_ik_in_tracker = tracker_from_base @ FK(q_i; dh + delta) @ tcp_from_marker @ s_k

is fitted for the 12 pose parameters and corrections ``delta`` to the 24 DH parameters
(a, d, alpha, theta offset of each joint). Many corrections cannot be told apart from the
two unknown transforms or from each other (e.g. the first joint's d and theta offset move the
base, the last joint's move the tool); others are weakly determined by a given motion. So:

1. The DH columns of the Jacobian are scaled (angles by a 1000 mm lever) and projected onto the
   complement of the 12 pose columns; a column-pivoted QR picks the corrections that add
   independent information; those with a diagonal below ``rank_tolerance`` of the largest are
   *unidentifiable* and stay at zero.
2. How much to correct is set by the data (``prior_from_data``, on by default), an empirical
   Bayes choice of the prior. The ML fit on the controller's model is cross-validated as for
   the expected error (:mod:`spacecal.estimators.assessment.expected_error`: its sweeps, else six time
   blocks, left out one at a time); the held-out misfit beyond the tracker's noise, divided
   by what DH errors of unit scale would show there, is the scale ``l`` (mm) of the arm's DH
   errors. The prior s.d. of the corrections is ``l`` for lengths and ``0.002 l`` rad for
   angles. When the held-out misfit is within :data:`IDENTIFY_MIN_SIGNIFICANCE` standard
   errors of what the noise explains (an arm that matches its model) no correction is freed
   and the result is the ML calibration itself.
3. The identifiable corrections and the pose are refined by Gauss–Newton with that zero-mean
   Gaussian prior on the corrections (or ``prior_length_sd_mm``, ``prior_angle_sd_rad`` when
   ``prior_from_data`` is off or the scale cannot be computed).

Optional subset selection (``model_selection``, off by default): of the identifiable
corrections only those that reduce the held-out misfit are freed, by greedy forward selection
on the held-out sum of squared sphere errors (:func:`select_corrections`; each freed
correction must lower it by more than :data:`SELECTION_MIN_GAIN`). It was measured
(``benchmarks/levers.py``) not to pay at the needle tip: the marker's held-out misfit is met
by a few corrections, which leave the rest of the arm's error to the pose and the tip, while
all identifiable corrections under a prior of the right scale spread it as the arm does.

The prior model is the controller's own where the recording carries it
(``robot.kinematic_model``, a factory-calibrated arm), else the nominal model.

Joint compliance (:func:`identify_kinematics` with ``joint_compliance``; off in the registry's
``kinematic``, :func:`calibrate_kinematic`; only for an arm whose link dynamics the
package holds, :func:`spacecal.models.gravity.link_dynamics_of`): the shoulder and elbow deflect
under gravity by ``c_j tau_j(q)`` (:mod:`spacecal.models.compliance`), which the encoders do not
see. The two compliances ``c_2``, ``c_3`` (rad per N m) are two more candidates beside the 24
DH corrections: their columns are the joint-offset columns of joints 2 and 3 times each frame's
gravity torque less its mean over the recording, they pass the same identifiability test
(scaled by the torques' RMS about that mean) and are refined in the same Gauss–Newton under a
zero-mean prior of s.d. :data:`COMPLIANCE_PRIOR_SD_RAD_PER_NM`. The model holds at the mean
torques (:class:`~spacecal.models.compliance.JointCompliance`'s reference torques): the sag at
the mean is a constant joint offset, which the joint-offset corrections and the pose take up
under their own priors, and the compliance explains only how the sag changes over the motion.
Left free, the constant part would be a joint offset with the compliance's loose prior (a few
mrad), free to fit the tracker's bias. Without tracker noise the compliances are recovered to
their stated s.d. and the sag's change is removed from the verification error
(``tests/estimators/test_kinematic_compliance.py``). It is off by default because it was
measured not to pay behind a biased tracker: in ``systematic-calibrated-compliant`` (120
stations in a 150 mm cube, 0.2 mm RMS tracker bias) the sag changes by about 0.2 mm over the
stations, as much as the bias does, and the fit trades the one for the other (the shoulder's
compliance came out between 1.5e-5 and 5.6e-5 rad/N m for a true 3.3e-5 on seeds 1–4);
``benchmarks/systematic_families.py`` over seeds 1–10 with it on: ``kinematic`` 0.315 mm
against 0.313 off, ``kinematic`` + tip 0.305 against 0.304, the nominal scenarios 0.305 and
0.306 mm with the tip against 0.300 and 0.301. The same scenario with a rigid arm verifies at
0.317 mm with ``kinematic``: the arm's compliance is not what limits that scenario.

The result holds the corrected model (used by IK in verification and planning), the
identified corrections with standard deviations, the rank and the condition number; an
identified compliance rides in ``diagnostics["kinematic_identification"]["joint_compliance"]``
(read it back with :func:`joint_compliance_of`) and is applied with the corrected model
(:func:`spacecal.models.compliance.compliant_forward_kinematics` for the residuals this
estimator states, :func:`~spacecal.models.compliance.encoder_joints_for` where the simulated
verification and phantom experiments command the arm).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
from scipy.linalg import qr

from spacecal.core.errors import DegenerateDataError, InvalidInputError

# the one method that reads the assessment: its data-driven prior is the DH error scale the
# expected error's held-out misfit shows (pyproject.toml's import contracts name this import)
from spacecal.estimators.assessment.expected_error import expected_error
from spacecal.estimators.methods.held_out import held_out_blocks
from spacecal.estimators.methods.likelihood import (
    calibrate_ml,
    fit_ml,
    residual_noise_level,
    variance_factor_of,
)
from spacecal.estimators.methods.ml import covariance_from_information, information_matrix
from spacecal.estimators.methods.observations import Observations
from spacecal.estimators.methods.recorded_model import recorded_robot_model
from spacecal.estimators.methods.solution import Solution
from spacecal.geometry.arrays import FloatArray, IntArray
from spacecal.models.compliance import COMPLIANT_JOINTS, JointCompliance, compliant_forward_kinematics
from spacecal.models.gravity import LinkDynamics, gravity_joint_torques, link_dynamics_of
from spacecal.models.kinematics import (
    RobotModel,
    apply_pose_step,
    chain_points_in_tracker,
    dh_point_jacobian,
    pose_point_jacobian,
    with_dh_corrections,
)
from spacecal.models.robot_kinds import robot_kind
from spacecal.records import CalibrationResult, NeedleTip, Recording

DH_FIELDS = ("a_mm", "d_mm", "alpha_rad", "theta_offset_rad")


def dh_names(joints: int) -> list[str]:
    """Names of the 4 J DH corrections of an arm of J joints, in the order of
    :func:`~spacecal.models.kinematics.with_dh_corrections` (1-based joints)."""
    return [f"{field}[{joint + 1}]" for field in DH_FIELDS for joint in range(joints)]


#: The DH corrections of a six-joint (UR) arm, the only ones with compliance candidates.
DH_NAMES = dh_names(6)
N_DH = len(DH_NAMES)
#: Names of the compliance candidates (joints 2 and 3, 1-based as in :data:`DH_NAMES`).
COMPLIANCE_NAMES = [f"compliance_rad_per_nm[{joint + 1}]" for joint in COMPLIANT_JOINTS]
#: Every candidate of the identification, in the order of its parameter vector.
PARAMETER_NAMES = DH_NAMES + COMPLIANCE_NAMES
ANGLE_LEVER_MM = 1000.0


def dh_column_scale(joints: int) -> FloatArray:
    """About how far one unit of each DH correction of an arm of ``joints`` joints moves the
    points, mm, (4 J,): lengths 1, angles :data:`ANGLE_LEVER_MM`."""
    return np.repeat([1.0, 1.0, ANGLE_LEVER_MM, ANGLE_LEVER_MM], joints)


#: About how far one unit of each DH correction moves the points, mm (lengths 1, angles
#: :data:`ANGLE_LEVER_MM`): the columns' common footing in the identifiability test, for a
#: six-joint arm.
DH_COLUMN_SCALE = dh_column_scale(6)


#: Prior s.d. of a joint's compliance, rad per N m. Zero mean: a rigid arm is the model the
#: controller states, and the data must show the sag. The scale: the strain-wave gears of a
#: UR10-sized shoulder and elbow have catalogue torsional stiffness of a few 1e4 N m/rad
#: (Harmonic Drive CSG/SHG sizes 25-32), and the whole joint (bearings, housing) is softer
#: than its gear, so compliances of 1e-5 to 1e-4 rad/N m are expected. 5e-5 puts a stiffness
#: of 3e4 N m/rad (3.3e-5) at 0.7 s.d. and 1e4 (1e-4) at 2 s.d.: loose enough not to pull a
#: real compliance towards zero, while a fit to noise cannot run to a compliance no arm of
#: this class has. The data decide well inside it: on the 120 stations of the systematic
#: scenarios the shoulder's posterior s.d. is about 4 % of a 3e4 N m/rad joint's compliance,
#: the elbow's (whose torque changes less over the stations) about a third of it.
COMPLIANCE_PRIOR_SD_RAD_PER_NM = 5e-5
#: Prior s.d. of the angle corrections per mm of the length corrections' (the ratio of the
#: unit DH errors of :data:`spacecal.estimators.assessment.unseen_kinematics.UNIT_DH_SD`).
ANGLE_PER_LENGTH_RAD_PER_MM = 0.002

#: Least held-out misfit beyond the tracker's noise, in standard errors of the noise's, that
#: counts as evidence of DH errors (``prior_from_data``). The held-out errors of neighbouring
#: frames are correlated (every refit moves them together), so the nominal standard error is
#: too small: on white noise alone the misfit reaches 2.4 of them in ten seeds; the realistic
#: arm's exceeds 70.
IDENTIFY_MIN_SIGNIFICANCE = 5.0

#: Least drop of the held-out sum of squared whitened sphere errors (units of the white noise
#: variance) for which model selection frees one more correction. A correction that fits only
#: noise raises the held-out error by about one unit on average; the best of some twenty such
#: candidates lowers it by chance by a few units at most.
SELECTION_MIN_GAIN = 10.0


def robot_model_of(recording: Recording) -> RobotModel:
    """The robot model the identification starts from (its prior): the controller's own model
    where the recording's metadata carries it (a factory-calibrated arm), else the nominal
    model named there (with its TCP)."""
    recorded = recorded_robot_model(recording)
    if recorded is not None:
        return recorded
    robot = recording.metadata.get("robot", {})
    if "model" not in robot:
        raise InvalidInputError("kinematic identification needs the robot model in the recording metadata")
    return robot_kind(robot["model"]).model(np.asarray(robot.get("flange_from_tcp", np.eye(4)), dtype=float))


def identifiable_corrections(
    dh_jacobian: FloatArray,
    pose_jacobian: FloatArray,
    rank_tolerance: float,
    column_scale: FloatArray | None = None,
    dh_count: int = N_DH,
) -> tuple[FloatArray, float]:
    """Indices of the corrections the data determines beyond the pose, and their condition.

    Parameters
    ----------
    dh_jacobian : numpy.ndarray, shape (N, K, 3, M)
        Jacobian of the sphere positions in the tracker (mm) by the M candidate corrections.
    pose_jacobian : numpy.ndarray, shape (N, K, 3, 12)
        Jacobian by the 12 pose parameters.
    rank_tolerance : float
        Relative size of a pivot below which a candidate counts as unidentifiable.
    column_scale : numpy.ndarray, shape (M,), optional
        About how far one unit of each candidate moves the points, mm, to put the columns on
        one footing; default the 24 DH corrections' (lengths 1, angles :data:`ANGLE_LEVER_MM`).
        Candidates beyond the 24 DH corrections (the compliances) are taken after them, each
        only where it adds to the DH corrections chosen: the DH set stays what it is without
        them, and a compliance the DH corrections can mimic is left out.
    dh_count : int
        How many of the candidates are DH corrections (4 J for an arm of J joints).
    """
    scale = DH_COLUMN_SCALE if column_scale is None else column_scale
    dh = dh_jacobian.reshape(-1, len(scale)) / scale
    pose = pose_jacobian.reshape(-1, 12)
    # projection off the pose columns by the normal equations (12 columns: cheaper than a QR)
    projected = dh - pose @ np.linalg.solve(pose.T @ pose, pose.T @ dh)
    _, r, order = qr(projected[:, :dh_count], mode="economic", pivoting=True)
    diagonal = np.abs(np.diag(r))
    keep = diagonal > rank_tolerance * diagonal[0]
    selected = np.sort(order[keep])
    for extra in range(dh_count, projected.shape[1]):
        basis = projected[:, selected]
        beyond = projected[:, extra] - basis @ np.linalg.lstsq(basis, projected[:, extra], rcond=None)[0]
        if np.linalg.norm(beyond) > rank_tolerance * diagonal[0]:
            selected = np.append(selected, extra)
    singular = np.linalg.svd(projected[:, selected], compute_uv=False)
    return selected, float(singular[0] / singular[-1])


def select_corrections(
    pose_jacobian: FloatArray,
    dh_jacobian: FloatArray,
    residual: FloatArray,
    prior_sd: FloatArray,
    blocks: list[IntArray],
    min_gain: float = SELECTION_MIN_GAIN,
) -> tuple[list[int], list[dict[str, Any]]]:
    """Greedy forward selection of DH corrections by their held-out misfit.

    Linearised at the full-data ML solution: a fit to the training blocks is the Gauss–Newton
    step ``delta = -(A_t + P)^-1 g_t`` with ``A_t``, ``g_t`` the normal matrix and gradient
    summed over the training blocks and ``P`` the prior's information on the freed
    corrections; the held-out block's squared error is then ``c_b + 2 delta.g_b +
    delta.A_b.delta``. Each block's ``A_b``, ``g_b``, ``c_b`` are formed once.

    Parameters
    ----------
    pose_jacobian : numpy.ndarray, shape (N, R, 12)
        Whitened Jacobian of the R residuals of each of the N frames (spheres x 3) by the pose
        step (:func:`~spacecal.models.kinematics.pose_point_jacobian` over sigma).
    dh_jacobian : numpy.ndarray, shape (N, R, M)
        Whitened Jacobian by the M candidate corrections (mm or rad).
    residual : numpy.ndarray, shape (N, R)
        Whitened residuals (predicted minus measured sphere coordinates, over sigma) at the ML
        solution.
    prior_sd : numpy.ndarray, shape (M,)
        Prior s.d. of the candidates (mm or rad).
    blocks : list of numpy.ndarray of int
        Frame indices of the held-out blocks.
    min_gain : float
        Least drop of the held-out sum of squares that frees one more correction.

    Returns
    -------
    chosen : list of int
        Indices into the M candidates, in the order they were freed.
    path : list of dict
        ``{"freed": index or None, "held_out_ss": value}`` per step, starting with no
        correction freed (whitened units).
    """
    n, rows, m = dh_jacobian.shape
    jac = np.concatenate([pose_jacobian, dh_jacobian], axis=2)
    gram, gradient, constant = [], [], []
    for block in blocks:
        j = jac[block].reshape(-1, 12 + m)
        r = residual[block].reshape(-1)
        gram.append(j.T @ j)
        gradient.append(j.T @ r)
        constant.append(float(r @ r))
    gram_total, gradient_total = np.sum(gram, axis=0), np.sum(gradient, axis=0)
    prior_information = np.concatenate([np.zeros(12), 1.0 / np.asarray(prior_sd, float) ** 2])

    def held_out_ss(freed: list[int]) -> float:
        columns = np.r_[np.arange(12), 12 + np.asarray(freed, dtype=int)]
        total = 0.0
        for a_b, g_b, c_b in zip(gram, gradient, constant):
            a_t = (gram_total - a_b)[np.ix_(columns, columns)] + np.diag(prior_information[columns])
            g_t = (gradient_total - g_b)[columns]
            try:
                delta = -np.linalg.solve(a_t, g_t)
            except np.linalg.LinAlgError:
                return np.inf
            total += c_b + 2.0 * delta @ g_b[columns] + delta @ a_b[np.ix_(columns, columns)] @ delta
        return float(total)

    chosen: list[int] = []
    current = held_out_ss(chosen)
    path: list[dict[str, Any]] = [{"freed": None, "held_out_ss": current}]
    while len(chosen) < m:
        trials = {c: held_out_ss([*chosen, c]) for c in range(m) if c not in chosen}
        best = min(trials, key=lambda c: trials[c])
        if not current - trials[best] > min_gain:
            break
        chosen.append(best)
        current = trials[best]
        path.append({"freed": best, "held_out_ss": current})
    return chosen, path


def compliance_torques(
    model: RobotModel, joints_rad: FloatArray, payload_kg: float, dynamics: LinkDynamics
) -> FloatArray:
    """Gravity torques (N, 2), N m, on the compliant joints (:data:`COMPLIANT_JOINTS`) at
    encoder angles (N, 6), rad: what each compliance multiplies."""
    return gravity_joint_torques(model, joints_rad, payload_kg, dynamics)[:, list(COMPLIANT_JOINTS)]


def compliance_point_jacobian(dh_jacobian: FloatArray, torques_nm: FloatArray) -> FloatArray:
    """d(sphere positions)/d(compliances), shape (N, K, 3, 2), mm per (rad/N m).

    A compliance turns joint j by ``c_j tau_j`` at each frame, as a joint offset of that size
    would: its column is the joint-offset column of joint j times the frame's torque.

    Parameters
    ----------
    dh_jacobian : numpy.ndarray, shape (N, K, 3, 24)
        :func:`~spacecal.models.kinematics.dh_point_jacobian` (mm per mm or rad).
    torques_nm : numpy.ndarray, shape (N, 2)
        :func:`compliance_torques` less the reference torques, N m.
    """
    offsets = [DH_NAMES.index(f"theta_offset_rad[{joint + 1}]") for joint in COMPLIANT_JOINTS]
    return dh_jacobian[..., offsets] * torques_nm[:, None, None, :]


def torque_rms_nm(torques_nm: FloatArray) -> FloatArray:
    """RMS (2,), N m, of each compliant joint's torque (about its reference) over the frames: a
    compliance's lever in the identifiability test (1 where it is zero: so is its column)."""
    rms = np.sqrt(np.mean(torques_nm**2, axis=0))
    return np.where(rms > 0.0, rms, 1.0)


def compliance_report(
    compliance: JointCompliance | None, corrections: list[dict[str, Any]]
) -> dict[str, Any] | None:
    """``diagnostics["kinematic_identification"]["joint_compliance"]``: the identified
    compliance (rad/N m, joints 1-based), the torque model it goes with, and each compliance's
    s.d. (None where it was not freed); None when no compliance was identified."""
    if compliance is None:
        return None
    sd = {c["parameter"]: c["sd"] for c in corrections}
    return {
        "joints": [joint + 1 for joint in COMPLIANT_JOINTS],
        "rad_per_nm": compliance.rad_per_nm.tolist(),
        "sd_rad_per_nm": [sd.get(name) for name in COMPLIANCE_NAMES],
        "reference_torques_nm": compliance.reference_torques_nm.tolist(),
        "payload_kg": compliance.payload_kg,
        "link_dynamics": compliance.dynamics.name,
    }


def joint_compliance_of(calibration: CalibrationResult) -> JointCompliance | None:
    """The joint compliance a kinematic calibration identified, to apply with its robot model
    wherever it predicts or reaches a pose; None when it holds none (a rigid model).

    Raises
    ------
    InvalidInputError
        If the calibration names link dynamics the package does not hold.
    """
    identification = calibration.diagnostics.get("kinematic_identification") or {}
    entry = identification.get("joint_compliance")
    if not entry:
        return None
    dynamics = link_dynamics_of(str(entry.get("link_dynamics")))
    if dynamics is None:
        raise InvalidInputError(
            f"the calibration's joint compliance goes with the link dynamics of "
            f"{entry.get('link_dynamics')!r}, which spacecal does not hold"
        )
    return JointCompliance(
        np.asarray(entry["rad_per_nm"], dtype=float),
        np.asarray(entry["reference_torques_nm"], dtype=float),
        float(entry["payload_kg"]),
        dynamics,
    )


def dh_error_scale_of(
    recording: Recording,
    obs: Observations,
    tracker_from_base: FloatArray,
    tcp_from_marker: FloatArray,
    model: RobotModel,
    joints_rad: FloatArray,
) -> tuple[float | None, float | None]:
    """The robot's DH error scale from the held-out misfit of the ML fit on ``model``.

    Returns
    -------
    scale_mm : float or None
        ``dh_error_scale_mm`` of :func:`~spacecal.estimators.assessment.expected_error.expected_error`:
        the held-out misfit beyond the tracker's noise over what unit-scale DH errors show.
    significance : float or None
        That misfit beyond the noise's, in standard errors of the noise's (chi-square with
        ``dof_per_frame`` degrees of freedom a frame, frames taken as independent). None
        when nothing could be cross-validated.

    Notes
    -----
    A tracker that reports no fit RMS (a pose-only stream, as PLUS sends over OpenIGTLink)
    leaves the noise unknown. It is then taken from the fit's own residuals (the a posteriori
    variance factor), so held-out misfit is compared with in-sample misfit: only the misfit that
    the pose cannot absorb where the fit did not see it counts as DH error. That is weaker
    evidence than a known noise level gives (in-sample residuals carry part of the systematic
    error too), but a fixed prior instead frees every correction on every pose-only recording,
    which on an arm that matches its model multiplied the tip error 3.6 to 6.2 times
    (``benchmarks/hardware_paths.py``, UR + OpenIGTLink).
    """
    if not obs.sigma_known:
        obs = replace(
            obs, sigma_mm=residual_noise_level(obs, tracker_from_base, tcp_from_marker), sigma_known=True
        )
    try:
        covariance = covariance_from_information(information_matrix(obs, tracker_from_base, tcp_from_marker))
        expected = expected_error(
            obs,
            recording.segment[obs.rows],
            tracker_from_base,
            tcp_from_marker,
            covariance,
            robot_model=model,
            joints_rad=joints_rad,
        )
    except (DegenerateDataError, np.linalg.LinAlgError):
        return None, None
    components = expected["components"]
    scale = components.get("dh_error_scale_mm")
    significance = None
    held_out, noise = components.get("held_out_sphere_rms_mm"), components.get("noise_sphere_rms_mm")
    if obs.sigma_known and held_out is not None and noise is not None:
        spheres = len(obs.spheres_in_marker)
        standard_error = obs.sigma_mm**2 * np.sqrt(2.0 * obs.dof_per_frame / len(obs.rows))
        significance = float((held_out**2 - noise**2) * spheres / standard_error)
    return (None if scale is None else float(scale)), significance


def calibrate_kinematic(
    recording: Recording,
    sigma_mm: float | None = None,
    targets_in_base: FloatArray | None = None,
    prior_length_sd_mm: float = 1.0,
    prior_angle_sd_rad: float = 0.002,
    rank_tolerance: float = 0.02,
    iterations: int = 15,
    model_selection: bool = False,
    prior_from_data: bool = True,
    needle_tip: NeedleTip | None = None,
) -> Solution:
    """Identify DH corrections jointly with ``tracker_from_base`` and ``tcp_from_marker``
    (registry method ``kinematic``): :func:`identify_kinematics` with a rigid arm. Its
    signature is the registry's declared options (a test holds them equal), which leave the
    compliance out.

    Parameters
    ----------
    recording : Recording
        Needs joint angles and the robot model in its metadata.
    sigma_mm : float, optional
    targets_in_base : numpy.ndarray, shape (M, 3), optional
    prior_length_sd_mm, prior_angle_sd_rad : float
    rank_tolerance : float
    iterations : int
    model_selection, prior_from_data : bool
    needle_tip : NeedleTip, optional
        Each as :func:`identify_kinematics` takes it.
    """
    return identify_kinematics(
        recording,
        sigma_mm=sigma_mm,
        targets_in_base=targets_in_base,
        prior_length_sd_mm=prior_length_sd_mm,
        prior_angle_sd_rad=prior_angle_sd_rad,
        rank_tolerance=rank_tolerance,
        iterations=iterations,
        model_selection=model_selection,
        prior_from_data=prior_from_data,
        needle_tip=needle_tip,
    )


def identify_kinematics(
    recording: Recording,
    sigma_mm: float | None = None,
    targets_in_base: FloatArray | None = None,
    prior_length_sd_mm: float = 1.0,
    prior_angle_sd_rad: float = 0.002,
    rank_tolerance: float = 0.02,
    iterations: int = 15,
    model_selection: bool = False,
    prior_from_data: bool = True,
    needle_tip: NeedleTip | None = None,
    joint_compliance: bool = False,
    payload_kg: float = 0.0,
) -> Solution:
    """Identify DH corrections, and optionally the joints' compliance, jointly with
    ``tracker_from_base`` and ``tcp_from_marker`` (see the module).

    Parameters
    ----------
    recording : Recording
        Needs joint angles and the robot model in its metadata.
    prior_length_sd_mm, prior_angle_sd_rad : float
        Prior s.d. of the corrections (the spread of real arms around their nominal model).
    rank_tolerance : float
        Relative size below which a projected, scaled correction counts as unidentifiable.
        Used as given when ``prior_from_data`` is False or the data's scale cannot be computed.
    iterations : int
        Most Gauss–Newton iterations.
    model_selection : bool
        Free only the identifiable corrections that lower the held-out misfit
        (:func:`select_corrections`); False (the default) frees every identifiable one.
    prior_from_data : bool
        Take the prior s.d. from the DH error scale the ML fit's held-out misfit shows (see
        the module); none freed when that misfit is within :data:`IDENTIFY_MIN_SIGNIFICANCE`
        standard errors of the noise's. A tracker that reports no fit RMS has its noise taken
        from the fit's residuals (:func:`dh_error_scale_of`).
    needle_tip : NeedleTip, optional
        A tip measured by a pivot, which IK aims: the expected error is stated at it.
    joint_compliance : bool
        Identify the shoulder's and elbow's compliance under gravity with the DH corrections
        (see the module, and why it is off by default); only for an arm whose link dynamics are
        published (:func:`~spacecal.models.gravity.link_dynamics_of`); for another the
        identification is rigid and ``joint_compliance_skipped`` in its diagnostics says why.
    payload_kg : float
        Mass on the tool, kg, that the gravity torques include. An unknown small payload may
        stay 0: on the shoulder and elbow its torque varies over the workspace nearly as the
        arm's own does, and the compliance takes it up.
    """
    model = robot_model_of(recording)
    # identification starts from the ML solution (the bare fit, without its diagnostics)
    obs, start = fit_ml(recording, sigma_mm=sigma_mm)
    joints = recording.joints_rad[obs.rows]
    if not np.all(np.isfinite(joints)):
        raise DegenerateDataError("kinematic identification needs the joint angles of every used frame")
    spheres = obs.spheres_in_marker
    tracker_from_base, tcp_from_marker = start.tracker_from_base, start.tcp_from_marker
    dynamics = link_dynamics_of(model.name) if joint_compliance else None
    # an arm without published link dynamics has no gravity model (not another arm's): say so
    compliance_skipped = (
        f"the {model.name} has no published link dynamics, so no gravity model: "
        "joint compliance not identified"
        if joint_compliance and dynamics is None
        else None
    )
    torques = None if dynamics is None else compliance_torques(model, joints, payload_kg, dynamics)
    reference_torques = None if torques is None else np.mean(torques, axis=0)
    n_dh = 4 * model.n_joints
    names = PARAMETER_NAMES if torques is not None else dh_names(model.n_joints)
    delta = np.zeros(len(names))
    # the robot's DH error scale as the ML start's held-out misfit shows it (before the
    # corrections absorb it)
    dh_scale, significance = dh_error_scale_of(
        recording, obs, start.tracker_from_base, start.tcp_from_marker, model, joints
    )
    scale_from_data = prior_from_data and dh_scale is not None and significance is not None
    if scale_from_data and dh_scale is not None:
        if significance is not None and significance < IDENTIFY_MIN_SIGNIFICANCE:
            dh_scale = 0.0  # a misfit the noise explains is no evidence of DH errors
        # zero when the arm matches its model: then nothing is freed below
        prior_length_sd_mm = dh_scale
        prior_angle_sd_rad = dh_scale * ANGLE_PER_LENGTH_RAD_PER_MM
    prior_sd = np.array(
        [prior_length_sd_mm] * (n_dh // 2)
        + [prior_angle_sd_rad] * (n_dh // 2)
        + [COMPLIANCE_PRIOR_SD_RAD_PER_NM] * (len(names) - n_dh)
    )

    def model_of(parameters: FloatArray) -> tuple[RobotModel, JointCompliance | None]:
        """The rigid model and the compliance a parameter vector (M,) describes."""
        rigid = with_dh_corrections(model, parameters[:n_dh])
        if dynamics is None or reference_torques is None:
            return rigid, None
        return rigid, JointCompliance(parameters[n_dh:], reference_torques, payload_kg, dynamics)

    corrected, compliance = model_of(delta)
    obs_model = replace(obs, base_from_tcp_stack=compliant_forward_kinematics(corrected, compliance, joints))
    j_dh = dh_point_jacobian(corrected, joints, tracker_from_base, tcp_from_marker, spheres)
    column_scale = dh_column_scale(model.n_joints)
    if torques is not None and reference_torques is not None:
        varying = torques - reference_torques
        j_dh = np.concatenate([j_dh, compliance_point_jacobian(j_dh, varying)], axis=-1)
        column_scale = np.concatenate([column_scale, ANGLE_LEVER_MM * torque_rms_nm(varying)])
    selected, condition = identifiable_corrections(
        j_dh,
        pose_point_jacobian(obs_model.base_from_tcp_stack, tracker_from_base, tcp_from_marker, spheres),
        rank_tolerance,
        column_scale,
        dh_count=n_dh,
    )
    if len(selected) == 0:
        raise DegenerateDataError(
            "this motion identifies no kinematic correction: use more varied joint configurations"
        )

    identifiable = selected
    if scale_from_data and dh_scale is not None and dh_scale <= 0.0:
        # the held-out misfit shows nothing beyond the tracker's noise: the arm matches its
        # model, no correction is freed, and the result is the ML calibration itself
        ml = calibrate_ml(
            recording,
            sigma_mm=sigma_mm,
            targets_in_base=targets_in_base,
            fitted=(obs, start),
            needle_tip=needle_tip,
        )
        report = {
            "identified": [],
            "unidentifiable": [names[i] for i in range(len(names)) if i not in set(identifiable.tolist())],
            "not_selected": [names[i] for i in identifiable],
            "rank": int(len(identifiable)),
            "condition_number": condition,
            "prior_sd": {"length_mm": 0.0, "angle_rad": 0.0, "from_data": True},
            "held_out_significance": significance,
            "model_selection": None,
            "joint_compliance": None,
            "joint_compliance_skipped": compliance_skipped,
        }
        return replace(
            ml,
            method="kinematic",
            diagnostics={**ml.diagnostics, "kinematic_identification": report},
            identified_model=model,
        )
    if not obs.sigma_known:
        # no tracker fit RMS: the data are weighed against the prior by the noise level the ML
        # start's residuals show (its a posteriori variance factor), never by the 1 mm
        # placeholder, which made the prior's pull depend on the tracker's units of noise
        level = residual_noise_level(obs, tracker_from_base, tcp_from_marker)
        obs = replace(obs, sigma_mm=level)
        obs_model = replace(obs_model, sigma_mm=level)
    selection = None
    if model_selection:
        n_frames = len(joints)
        start_residual = (
            chain_points_in_tracker(
                obs_model.base_from_tcp_stack, tracker_from_base, tcp_from_marker, spheres
            )
            - obs.spheres_in_tracker
        ).reshape(n_frames, -1) / obs.sigma_mm
        j_pose_start = pose_point_jacobian(
            obs_model.base_from_tcp_stack, tracker_from_base, tcp_from_marker, spheres
        ).reshape(n_frames, -1, 12)
        chosen, path = select_corrections(
            j_pose_start / obs.sigma_mm,
            j_dh.reshape(n_frames, -1, len(names))[..., selected] / obs.sigma_mm,
            start_residual,
            prior_sd[selected],
            held_out_blocks(recording.segment[obs.rows]),
        )
        selected = np.sort(selected[chosen]).astype(int)
        selection = {
            "criterion": "held-out sum of squared whitened sphere errors (blocks left out one at a time)",
            "min_gain": SELECTION_MIN_GAIN,
            "path": [
                {
                    "freed": None if step["freed"] is None else names[identifiable[step["freed"]]],
                    "held_out_ss": step["held_out_ss"],
                }
                for step in path
            ],
        }

    # The DH columns barely change over the iterations (the corrections are fractions of a
    # millimetre, the deflections a few mrad): Gauss-Newton keeps the first ones (a chord
    # iteration), whose fixed point is the same optimum, and saves a finite-difference Jacobian
    # per iteration.
    j_dh_selected = j_dh.reshape(-1, len(names))[:, selected] / obs.sigma_mm
    for _ in range(iterations):
        corrected, compliance = model_of(delta)
        obs_model = replace(
            obs, base_from_tcp_stack=compliant_forward_kinematics(corrected, compliance, joints)
        )
        predicted = chain_points_in_tracker(
            obs_model.base_from_tcp_stack, tracker_from_base, tcp_from_marker, spheres
        )
        residual = (predicted - obs.spheres_in_tracker).reshape(-1) / obs.sigma_mm
        j_pose = (
            pose_point_jacobian(
                obs_model.base_from_tcp_stack, tracker_from_base, tcp_from_marker, spheres
            ).reshape(-1, 12)
            / obs.sigma_mm
        )
        jac = np.hstack([j_pose, j_dh_selected])
        prior_rows = np.zeros((len(selected), 12 + len(selected)))
        prior_rows[:, 12:] = np.diag(1.0 / prior_sd[selected])
        jac_all = np.vstack([jac, prior_rows])
        res_all = np.concatenate([residual, delta[selected] / prior_sd[selected]])
        # normal equations: the whitened Jacobian is tall and well-conditioned by the prior rows
        step = np.linalg.solve(jac_all.T @ jac_all, -(jac_all.T @ res_all))
        tracker_from_base, tcp_from_marker = apply_pose_step(tracker_from_base, tcp_from_marker, step[:12])
        delta[selected] += step[12:]
        if np.max(np.abs(step[:12])) < 1e-7 and np.all(np.abs(step[12:] / prior_sd[selected]) < 1e-6):
            break

    corrected, compliance = model_of(delta)
    obs_model = replace(obs, base_from_tcp_stack=compliant_forward_kinematics(corrected, compliance, joints))
    information = jac_all.T @ jac_all
    variance_factor = variance_factor_of(obs_model, tracker_from_base, tcp_from_marker)
    scale = max(variance_factor, 1.0) if obs.sigma_known else variance_factor
    covariance_all = np.linalg.inv(information) * scale
    corrections = [
        {
            "parameter": names[i],
            "correction": float(delta[i]),
            "sd": float(np.sqrt(covariance_all[12 + k, 12 + k])),
        }
        for k, i in enumerate(selected)
    ]
    extra = {
        "kinematic_identification": {
            "identified": corrections,
            "unidentifiable": [names[i] for i in range(len(names)) if i not in set(identifiable.tolist())],
            "not_selected": [names[i] for i in identifiable if i not in set(selected.tolist())],
            "rank": int(len(identifiable)),
            "model_selection": selection,
            "condition_number": condition,
            "prior_sd": {
                "length_mm": prior_length_sd_mm,
                "angle_rad": prior_angle_sd_rad,
                "from_data": bool(scale_from_data),
            },
            "held_out_significance": significance,
            "joint_compliance": compliance_report(compliance, corrections),
            "joint_compliance_skipped": compliance_skipped,
        },
    }
    # residuals, site and spread as the identified model places the TCP: what the report
    # recomputes from the recording with the calibration's robot model
    as_identified = replace(
        recording,
        base_from_tcp_stack=compliant_forward_kinematics(corrected, compliance, recording.joints_rad),
    )
    # the joint ML fit of obs_model: its held-out refits are its own
    return Solution(
        "kinematic",
        as_identified if bool(np.all(np.isfinite(recording.joints_rad))) else recording,
        obs_model,
        tracker_from_base,
        tcp_from_marker,
        covariance_all[:12, :12],
        variance_factor,
        extra,
        robot_model=corrected,
        absorbed_dh=[int(i) for i in selected if i < n_dh],
        dh_error_scale_mm=dh_scale,
        likelihood_based=True,
        covariance_note="pose block of the joint (pose + DH) covariance; mm, rad",
        targets_in_base=targets_in_base,
        needle_tip=needle_tip,
        identified_model=corrected,
    )
