"""Forward and inverse kinematics of serial robots in Denavit–Hartenberg form.

Each link i maps frame i-1 to frame i by one of two conventions:

* ``"standard"`` (distal): ``Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``, the convention
  Universal Robots and KUKA tables are published in; joint i turns about z of frame i-1.
* ``"modified"`` (proximal, Craig): ``Rx(alpha_i) Tx(a_i) Rz(theta_i + q_i) Tz(d_i)``, where
  row i holds Craig's ``a_{i-1}, alpha_{i-1}, d_i, theta_i``; the convention Franka publishes
  its tables in; joint i turns about z of frame i.

The chain gives ``base_from_flange``; the configured tool offset ``flange_from_tcp`` gives
``base_from_tcp`` (what a controller reports as its actual TCP pose).

A model has any number of revolute joints (a UR arm six, a Franka or a KUKA LBR iiwa seven).
Inverse kinematics uses the UR family's closed form on UR-shaped arms and a damped
least-squares solve from a seed otherwise. Lengths are in mm, angles in rad.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from spacecal.core.errors import InvalidInputError, UnreachableError
from spacecal.geometry.arrays import ArrayLike, BoolArray, FloatArray
from spacecal.geometry.rotations import skew
from spacecal.geometry.transforms import (
    apply_transform,
    invert_transform,
    make_transform,
    matrix_to_rotvec,
    rotvec_to_matrix,
    transform_points_by_stack,
)

#: The twists every UR arm shares (what :func:`uses_ur_closed_form` recognises); the kinds
#: themselves, UR or not, are :mod:`spacecal.models.robot_kinds`.
UR_ALPHA_RAD = np.array([np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0])
#: Joints of the UR arms (the closed-form IK and the UR driver's files).
N_JOINTS = 6
#: Most joints a model, a recording or a calibration file may have.
MAX_JOINTS = 12
#: The two DH conventions a model may be written in (see the module docstring).
DH_CONVENTIONS = ("standard", "modified")


@dataclass(frozen=True)
class RobotModel:
    """A serial robot of revolute joints in DH form.

    Attributes
    ----------
    name : str
        Model name, e.g. ``"UR10"``.
    a_mm, d_mm, alpha_rad, theta_offset_rad : numpy.ndarray, shape (J,)
        DH link lengths, offsets, twists and joint-zero offsets of the J joints (6 on a UR
        arm); the joint-zero offsets default to zeros.
    flange_from_tcp : numpy.ndarray, shape (4, 4)
        The tool offset configured on the robot, mm.
    joint_lower_rad, joint_upper_rad : numpy.ndarray, shape (J,)
        Joint limits; default +-2 pi.
    controller_hz : float
        Rate at which the controller time-stamps its state.
    dh_convention : str
        ``"standard"`` (distal, the default) or ``"modified"`` (proximal, Craig); see the
        module docstring for the link transform of each.
    """

    name: str
    a_mm: FloatArray
    d_mm: FloatArray
    alpha_rad: FloatArray
    # empty: not given, filled in for the model's joint count by __post_init__
    theta_offset_rad: FloatArray = field(default_factory=lambda: np.zeros(0))
    flange_from_tcp: FloatArray = field(default_factory=lambda: np.eye(4))
    joint_lower_rad: FloatArray = field(default_factory=lambda: np.zeros(0))
    joint_upper_rad: FloatArray = field(default_factory=lambda: np.zeros(0))
    controller_hz: float = 125.0
    dh_convention: str = "standard"

    def __post_init__(self) -> None:
        # a model from a controller or a file is checked here, once: comparisons with NaN are
        # false, so a NaN DH parameter would pass every later range check and yield NaN poses.
        # No bound on the lengths: a UR controller's factory calibration moves d_2 and d_3 by
        # hundreds of metres that cancel along the nearly parallel shoulder and elbow axes
        if self.dh_convention not in DH_CONVENTIONS:
            raise InvalidInputError(
                f"robot model {self.name!r}: DH convention {self.dh_convention!r} "
                f"(one of {', '.join(DH_CONVENTIONS)})"
            )
        joints = np.asarray(self.a_mm, dtype=float).size
        if not 1 <= joints <= MAX_JOINTS:
            raise InvalidInputError(f"robot model {self.name!r}: {joints} joints (1 to {MAX_JOINTS})")
        defaults = {
            "theta_offset_rad": np.zeros(joints),
            "joint_lower_rad": np.full(joints, -2 * np.pi),
            "joint_upper_rad": np.full(joints, 2 * np.pi),
        }
        for name in ("a_mm", "d_mm", "alpha_rad", "theta_offset_rad", "joint_lower_rad", "joint_upper_rad"):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.size == 0 and name in defaults:
                object.__setattr__(self, name, defaults[name])
                continue
            if value.shape != (joints,) or not np.all(np.isfinite(value)):
                raise InvalidInputError(
                    f"robot model {self.name!r}: {name} must be {joints} finite numbers, as a_mm"
                )
        tool = np.asarray(self.flange_from_tcp, dtype=float)
        if tool.shape != (4, 4) or not np.all(np.isfinite(tool)):
            raise InvalidInputError(
                f"robot model {self.name!r}: flange_from_tcp must be a finite 4x4 transform"
            )
        if not (np.isfinite(self.controller_hz) and 0.0 < self.controller_hz <= 100_000.0):
            raise InvalidInputError(f"robot model {self.name!r}: controller rate {self.controller_hz} Hz")

    @property
    def n_joints(self) -> int:
        """The number of joints J."""
        return int(np.asarray(self.a_mm).size)

    def with_tcp(self, flange_from_tcp: ArrayLike) -> RobotModel:
        """A copy with another tool offset (4, 4), mm."""
        return replace(self, flange_from_tcp=np.asarray(flange_from_tcp, dtype=float))

    def with_dh_errors(
        self,
        delta_a_mm: ArrayLike = 0.0,
        delta_d_mm: ArrayLike = 0.0,
        delta_alpha_rad: ArrayLike = 0.0,
        delta_theta_rad: ArrayLike = 0.0,
    ) -> RobotModel:
        """A copy whose DH parameters are offset, e.g. a real robot's deviation from nominal."""
        return replace(
            self,
            a_mm=self.a_mm + np.asarray(delta_a_mm, dtype=np.float64),
            d_mm=self.d_mm + np.asarray(delta_d_mm, dtype=np.float64),
            alpha_rad=self.alpha_rad + np.asarray(delta_alpha_rad, dtype=np.float64),
            theta_offset_rad=self.theta_offset_rad + np.asarray(delta_theta_rad, dtype=np.float64),
        )

    def dh_table(self) -> dict[str, list[float]]:
        """The DH parameters as plain lists (for result files)."""
        return {
            "a_mm": self.a_mm.tolist(),
            "d_mm": self.d_mm.tolist(),
            "alpha_rad": self.alpha_rad.tolist(),
            "theta_offset_rad": self.theta_offset_rad.tolist(),
        }


def _link_transforms(model: RobotModel, joints_rad: FloatArray) -> FloatArray:
    """Per-link transforms, shape (N, J, 4, 4), for joint vectors (N, J), in the model's
    DH convention."""
    theta = joints_rad + model.theta_offset_rad
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(model.alpha_rad), np.sin(model.alpha_rad)
    links = np.zeros(joints_rad.shape[:-1] + (model.n_joints, 4, 4))
    if model.dh_convention == "modified":
        # Rx(alpha) Tx(a) Rz(theta) Tz(d), written out
        links[..., 0, 0] = ct
        links[..., 0, 1] = -st
        links[..., 0, 3] = model.a_mm
        links[..., 1, 0] = st * ca
        links[..., 1, 1] = ct * ca
        links[..., 1, 2] = -sa
        links[..., 1, 3] = -sa * model.d_mm
        links[..., 2, 0] = st * sa
        links[..., 2, 1] = ct * sa
        links[..., 2, 2] = ca
        links[..., 2, 3] = ca * model.d_mm
        links[..., 3, 3] = 1.0
        return links
    links[..., 0, 0] = ct
    links[..., 0, 1] = -st * ca
    links[..., 0, 2] = st * sa
    links[..., 0, 3] = model.a_mm * ct
    links[..., 1, 0] = st
    links[..., 1, 1] = ct * ca
    links[..., 1, 2] = -ct * sa
    links[..., 1, 3] = model.a_mm * st
    links[..., 2, 1] = sa
    links[..., 2, 2] = ca
    links[..., 2, 3] = model.d_mm
    links[..., 3, 3] = 1.0
    return links


def _as_joint_array(model: RobotModel, joints_rad: ArrayLike) -> tuple[FloatArray, bool]:
    q = np.asarray(joints_rad, dtype=float)
    single = q.ndim == 1
    q = np.atleast_2d(q)
    if q.shape[-1] != model.n_joints:
        raise InvalidInputError(
            f"the {model.name} has {model.n_joints} joints; got joint angles of shape {q.shape}"
        )
    return q, single


def forward_kinematics(model: RobotModel, joints_rad: ArrayLike, to_tcp: bool = True) -> FloatArray:
    """``base_from_tcp`` (or ``base_from_flange``) for joint vectors.

    Parameters
    ----------
    model : RobotModel
    joints_rad : array_like, shape (J,) or (N, J)
    to_tcp : bool
        Append the tool offset (default) or stop at the flange.

    Returns
    -------
    numpy.ndarray, shape (4, 4) or (N, 4, 4), mm
    """
    q, single = _as_joint_array(model, joints_rad)
    links = _link_transforms(model, q)
    pose = links[:, 0]
    for i in range(1, model.n_joints):
        pose = pose @ links[:, i]
    if to_tcp:
        pose = pose @ model.flange_from_tcp
    return pose[0] if single else pose


#: Below this rotation (rad) the log map's closed form is well conditioned (sin >= 0.14).
_CLOSED_FORM_LOG_RAD = 3.0


def _rotation_error_vector(rotation: FloatArray) -> FloatArray:
    """Rotation vectors (…, 3) of proper rotations (…, 3, 3), by the closed-form log map
    ``angle / (2 sin angle) * vee(R - R^T)``, with scipy's general conversion only near a half
    turn. Identical to :func:`matrix_to_rotvec` on rotation matrices, about twice as fast on
    the single poses Gauss–Newton IK takes one at a time (measured: 39 against 86 us)."""
    trace = rotation[..., 0, 0] + rotation[..., 1, 1] + rotation[..., 2, 2]
    angle = np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0))
    vee = np.stack(
        [
            rotation[..., 2, 1] - rotation[..., 1, 2],
            rotation[..., 0, 2] - rotation[..., 2, 0],
            rotation[..., 1, 0] - rotation[..., 0, 1],
        ],
        axis=-1,
    )
    sine = np.sin(angle)
    scale = np.where(angle < 1e-8, 0.5, angle / (2.0 * np.where(sine == 0.0, 1.0, sine)))
    result = scale[..., None] * vee
    far = angle > _CLOSED_FORM_LOG_RAD
    if np.any(far):
        result[far] = matrix_to_rotvec(rotation[far])
    return result


def _pose_error_vector(target: FloatArray, reached: FloatArray) -> FloatArray:
    """6-vector (position mm, rotation rad) of the error from reached to target, in base."""
    dp = target[..., :3, 3] - reached[..., :3, 3]
    dr = _rotation_error_vector(target[..., :3, :3] @ np.swapaxes(reached[..., :3, :3], -1, -2))
    return np.concatenate([dp, dr], axis=-1)


def geometric_jacobian(model: RobotModel, joints_rad: ArrayLike) -> FloatArray:
    """Geometric Jacobian of the TCP in the base frame, shape (N, 6, J): rows (v mm, w rad)."""
    q, _ = _as_joint_array(model, joints_rad)
    return _tcp_pose_and_jacobian(model, q)[1]


def _tcp_pose_and_jacobian(model: RobotModel, q: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``base_from_tcp`` (N, 4, 4) and the geometric Jacobian (N, 6, J) of joint vectors
    (N, J), from one pass along the chain: Gauss–Newton IK needs both at every iterate, and
    building the links once for both is most of its cost."""
    links = _link_transforms(model, q)
    joints = model.n_joints
    frames = np.empty((len(q), joints + 1, 4, 4))
    frames[:, 0] = np.eye(4)
    for i in range(joints):
        frames[:, i + 1] = frames[:, i] @ links[:, i]
    tcp = frames[:, -1] @ model.flange_from_tcp
    # Joint i rotates about the z axis of frame i-1 (standard DH) or of frame i (modified DH).
    joint_frames = frames[:, 1:] if model.dh_convention == "modified" else frames[:, :joints]
    axes = joint_frames[..., :3, 2]
    lever = tcp[:, None, :3, 3] - joint_frames[..., :3, 3]
    jac = np.empty((len(q), 6, joints))
    # axes x lever, written out: np.cross costs more than the rest on IK's single poses
    jac[:, 0] = axes[..., 1] * lever[..., 2] - axes[..., 2] * lever[..., 1]
    jac[:, 1] = axes[..., 2] * lever[..., 0] - axes[..., 0] * lever[..., 2]
    jac[:, 2] = axes[..., 0] * lever[..., 1] - axes[..., 1] * lever[..., 0]
    jac[:, 3:] = np.swapaxes(axes, 1, 2)
    return tcp, jac


def inverse_kinematics_gauss_newton(
    model: RobotModel,
    base_from_tcp: ArrayLike,
    start_joints_rad: ArrayLike,
    *,
    max_iterations: int,
    position_tol_mm: float,
    rotation_tol_rad: float,
) -> tuple[FloatArray, bool]:
    """Joint angles reaching ``base_from_tcp`` by Gauss–Newton from a start configuration.

    The one iterative IK of the package: it polishes the closed-form branches of
    :func:`inverse_kinematics` on a model's exact (possibly identified) parameters, and it
    follows a dense Cartesian path continuously (:func:`spacecal.planning.motion.track_path`),
    staying on the branch it starts on. Each step is ``dq = pinv(J) e`` with ``J`` the
    :func:`geometric_jacobian` and ``e`` the pose error (position mm, rotation vector rad)
    in the base frame (a square solve, and the pseudo-inverse where ``J`` is singular, which
    keeps the step finite there).

    Parameters
    ----------
    model : RobotModel
    base_from_tcp : array_like, shape (N, 4, 4)
        Target TCP poses, mm.
    start_joints_rad : array_like, shape (N, J)
        Where each iteration starts.
    max_iterations : int
        Steps allowed; the error is checked before each step.
    position_tol_mm, rotation_tol_rad : float
        Converged when every component of every pose error is below these.

    Returns
    -------
    joints_rad : numpy.ndarray, shape (N, J)
        The last iterate (converged or not).
    converged : bool
        Whether all rows met the tolerances within ``max_iterations`` checks.
    """
    targets = np.asarray(base_from_tcp, dtype=float)
    q = np.array(start_joints_rad, dtype=float)
    for _ in range(max_iterations):
        tcp, jac = _tcp_pose_and_jacobian(model, q)
        err = _pose_error_vector(targets, tcp)
        if np.max(np.abs(err[:, :3])) < position_tol_mm and np.max(np.abs(err[:, 3:])) < rotation_tol_rad:
            return q, True
        try:
            # a square solve is the pseudo-inverse's step wherever J is invertible, at a
            # fraction of an SVD's cost
            step = np.linalg.solve(jac, err[:, :, None])
        except np.linalg.LinAlgError:
            step = np.linalg.pinv(jac) @ err[:, :, None]
        q = q + step[:, :, 0]
    return q, False


def linearised_joints(model: RobotModel, joints_rad: ArrayLike, base_from_tcp: ArrayLike) -> FloatArray:
    """Joint angles (M, 6) predicted for poses near the TCP pose of ``joints_rad`` by one
    linearised step from it: ``q + J(q)^-1 e_k``, with ``J`` the :func:`geometric_jacobian` at
    ``q`` and ``e_k`` the error (position mm, rotation vector rad) from that pose to pose ``k``.

    A start for :func:`inverse_kinematics_gauss_newton` on a stretch of a dense path that
    stays on the branch of ``q`` (one Jacobian for the whole stretch).

    Parameters
    ----------
    model : RobotModel
    joints_rad : array_like, shape (6,)
    base_from_tcp : array_like, shape (M, 4, 4)
        Target TCP poses, mm.
    """
    q = np.asarray(joints_rad, dtype=float)
    tcp, jac = _tcp_pose_and_jacobian(model, q[None])
    err = _pose_error_vector(np.asarray(base_from_tcp, dtype=float), tcp)
    try:
        steps = np.linalg.solve(jac[0], err.T).T
    except np.linalg.LinAlgError:
        steps = err @ np.linalg.pinv(jac[0]).T
    return q + steps


def _wrap_near(angles: FloatArray, reference: FloatArray) -> FloatArray:
    """Add multiples of 2 pi to ``angles`` to bring them nearest to ``reference``."""
    return reference + np.mod(angles - reference + np.pi, 2 * np.pi) - np.pi


def _ur_closed_form(model: RobotModel, base_from_flange: FloatArray) -> FloatArray:
    """The 8 closed-form UR branches (Hawkins 2013) for one flange pose: shape (8, 6), NaN rows
    where a branch does not exist. Exact for the nominal UR geometry; a start for Newton
    otherwise."""
    a2, a3 = model.a_mm[1], model.a_mm[2]
    d4, d6 = model.d_mm[3], model.d_mm[5]
    t06 = base_from_flange
    solutions = np.full((8, 6), np.nan)
    p05 = t06[:3, :3] @ np.array([0.0, 0.0, -d6]) + t06[:3, 3]
    r05 = np.hypot(p05[0], p05[1])
    if r05 < abs(d4):
        return solutions
    psi = np.arctan2(p05[1], p05[0])
    phi = np.arccos(np.clip(d4 / r05, -1.0, 1.0))
    k = 0
    for s1 in (1, -1):
        q1 = psi + s1 * phi + np.pi / 2
        p06 = t06[:3, 3]
        c5 = (p06[0] * np.sin(q1) - p06[1] * np.cos(q1) - d4) / d6
        if abs(c5) > 1 + 1e-9:
            k += 4
            continue
        base5 = np.arccos(np.clip(c5, -1.0, 1.0))
        for s5 in (1, -1):
            q5 = s5 * base5
            t60 = invert_transform(t06)
            x60, y60 = t60[:3, 0], t60[:3, 1]
            s5v = np.sin(q5)
            if abs(s5v) < 1e-12:
                q6 = 0.0  # wrist singularity: q4 and q6 share one axis; pick q6 = 0
            else:
                q6 = np.arctan2(
                    (-x60[1] * np.sin(q1) + y60[1] * np.cos(q1)) / s5v,
                    (x60[0] * np.sin(q1) - y60[0] * np.cos(q1)) / s5v,
                )
            partial = RobotModel(model.name, model.a_mm, model.d_mm, model.alpha_rad, model.theta_offset_rad)
            links = _link_transforms(partial, np.array([[q1, 0, 0, 0, q5, q6]]))[0]
            t01, t45, t56 = links[0], links[4], links[5]
            t14 = invert_transform(t01) @ t06 @ invert_transform(t45 @ t56)
            p13 = t14[:3, :3] @ np.array([0.0, -d4, 0.0]) + t14[:3, 3]
            r13 = np.hypot(p13[0], p13[1])
            c3 = (r13**2 - a2**2 - a3**2) / (2 * a2 * a3)
            for s3 in (1, -1):
                if abs(c3) > 1 + 1e-9:
                    k += 1
                    continue
                q3 = s3 * np.arccos(np.clip(c3, -1.0, 1.0))
                q2 = -np.arctan2(p13[1], -p13[0]) + np.arcsin(np.clip(a3 * np.sin(q3) / r13, -1, 1))
                links23 = _link_transforms(partial, np.array([[0, q2, q3, 0, 0, 0]]))[0]
                t13 = links23[1] @ links23[2]
                t34 = invert_transform(t13) @ t14
                q4 = np.arctan2(t34[1, 0], t34[0, 0])
                solutions[k] = [q1, q2, q3, q4, q5, q6]
                k += 1
    return solutions


def uses_ur_closed_form(model: RobotModel) -> bool:
    """Whether :func:`inverse_kinematics` solves ``model`` by the UR closed form: six joints in
    standard DH with the UR family's twists (to 0.05 rad, so identified corrections keep it).
    Lengths are not compared: a UR controller's calibration moves d_2 and d_3 by metres."""
    return (
        model.n_joints == N_JOINTS
        and model.dh_convention == "standard"
        and bool(np.all(np.abs(model.alpha_rad - UR_ALPHA_RAD) < 0.05))
    )


def inverse_kinematics(
    model: RobotModel,
    base_from_tcp: ArrayLike,
    reference_joints_rad: ArrayLike | None = None,
    tol_mm: float = 1e-9,
) -> FloatArray:
    """Joint angles reaching ``base_from_tcp``, nearest to a reference configuration.

    On a UR-shaped arm (:func:`uses_ur_closed_form`) the UR closed form (8 branches) gives
    candidates from the nominal geometry; each is polished by Gauss–Newton on the model's
    exact parameters (so a model with identified DH corrections is solved exactly too),
    checked against the joint limits, and the candidate nearest the reference (after 2 pi
    wrapping into the limits) is returned. Any other arm (a Franka, a KUKA LBR iiwa, in
    either DH convention) is solved by damped least squares from the reference
    (:func:`_numeric_inverse_kinematics`); a redundant arm's self-motion is resolved by
    staying nearest the reference, inside the joint limits.

    Parameters
    ----------
    model : RobotModel
    base_from_tcp : array_like, shape (4, 4) or (N, 4, 4), mm
    reference_joints_rad : array_like, shape (J,) or (N, J), optional
        Configuration to stay near (e.g. the current one); zeros if omitted (clipped into
        the joint limits for the numeric solve).
    tol_mm : float
        Required position accuracy; rotation accuracy is tol_mm * 1e-3 rad.

    Returns
    -------
    numpy.ndarray, shape (J,) or (N, J)

    Raises
    ------
    UnreachableError
        If no solution reaches a pose within the tolerance and the joint limits.
    """
    joints = model.n_joints
    targets = np.asarray(base_from_tcp, dtype=float)
    single = targets.ndim == 2
    targets = targets.reshape(-1, 4, 4)
    if reference_joints_rad is None:
        reference = np.zeros((len(targets), joints))
    else:
        given = np.asarray(reference_joints_rad, float)
        if given.shape[-1] != joints:
            raise InvalidInputError(
                f"the {model.name} has {joints} joints; got reference joints of shape {given.shape}"
            )
        reference = np.broadcast_to(given, (len(targets), joints))
    closed_form = uses_ur_closed_form(model)
    result = np.empty((len(targets), joints))
    for n, target in enumerate(targets):
        if closed_form:
            result[n] = _ur_inverse_kinematics(model, target, reference[n], tol_mm, n)
        else:
            result[n] = _numeric_inverse_kinematics(model, target, reference[n], tol_mm, n)
    return result[0] if single else result


def _ur_inverse_kinematics(
    model: RobotModel, target: FloatArray, reference: FloatArray, tol_mm: float, n: int
) -> FloatArray:
    """The UR branch nearest ``reference`` (6,) reaching ``target`` (4, 4); pose number ``n``
    names it in errors."""
    candidates = _ur_closed_form(model, target @ invert_transform(model.flange_from_tcp))
    candidates = candidates[np.all(np.isfinite(candidates), axis=1)]
    if len(candidates) == 0:
        raise UnreachableError(f"pose {n} is outside the {model.name}'s workspace")
    # polish on the exact model; unconverged candidates fail the tolerance check below
    candidates, _ = inverse_kinematics_gauss_newton(
        model,
        np.broadcast_to(target, (len(candidates), 4, 4)),
        candidates,
        max_iterations=20,
        position_tol_mm=1e-10,
        rotation_tol_rad=1e-13,
    )
    ok = _reaches(model, target, candidates, tol_mm)
    candidates = _wrap_near(candidates[ok], reference)
    within = np.all((candidates >= model.joint_lower_rad) & (candidates <= model.joint_upper_rad), axis=1)
    candidates = candidates[within]
    if len(candidates) == 0:
        raise UnreachableError(
            f"pose {n} cannot be reached by the {model.name} within tolerance and joint limits"
        )
    return candidates[np.argmin(np.max(np.abs(candidates - reference), axis=1))]


def _reaches(model: RobotModel, target: FloatArray, joints_rad: FloatArray, tol_mm: float) -> BoolArray:
    """Rows of ``joints_rad`` (M, J) whose TCP is within ``tol_mm`` (and tol_mm * 1e-3 rad) of ``target``."""
    err = _pose_error_vector(target, forward_kinematics(model, joints_rad))
    return (np.linalg.norm(err[:, :3], axis=1) < tol_mm) & (
        np.linalg.norm(err[:, 3:], axis=1) < tol_mm * 1e-3
    )


#: Weight of a rotation error (rad) against a position error (mm) in the numeric solve: a
#: radian at a 100 mm lever, the size of a wrist.
_IK_LEVER_MM = 100.0
#: Damping floor of the numeric solve (Sugihara's w-bar, mm^2): keeps a step finite at a
#: singularity and is negligible against J^T J (lengths of hundreds of mm) elsewhere.
_IK_DAMPING_FLOOR = 1e-3
#: Iterations of one numeric start; further starts from spread configurations in the limits.
_IK_ITERATIONS = 300
_IK_RESTARTS = 12
#: A start whose weighted error (mm) stays above 1e-3 and fell by less than 1 % over this many
#: iterations has stalled.
_IK_STALL = 20


def _limited_step(
    jac: FloatArray, err: FloatArray, q: FloatArray, seed: FloatArray, lower: FloatArray, upper: FloatArray
) -> tuple[FloatArray, float]:
    """One step of the numeric solve inside the joint limits: the next joints (J,) and how far
    they moved (rad).

    Jacobian ``jac`` (6, J) and pose error ``err`` (6,) at ``q``; the step is the damped
    least-squares task step plus half the null-space projection of ``seed - q``. A joint the
    step would carry past a limit is put on the limit and held there while the step is
    recomputed with the other joints (an active set, so the task is not fought by clipping).
    """
    weight = np.array([1.0, 1.0, 1.0, _IK_LEVER_MM, _IK_LEVER_MM, _IK_LEVER_MM])
    jw, ew = weight[:, None] * jac, weight * err
    damping = 0.5 * ew @ ew + _IK_DAMPING_FLOOR
    joints = len(q)
    free = np.ones(joints, dtype=bool)
    start = q.copy()
    for _ in range(joints + 1):
        held = jw * free  # a held joint's column is zero, so its step is zero
        step = np.linalg.solve(held.T @ held + damping * np.eye(joints), held.T @ ew)
        null = (np.eye(joints) - np.linalg.pinv(held, rcond=1e-10) @ held) @ ((seed - q) * free)
        new = q + step + 0.5 * null
        over = free & ((new < lower) | (new > upper))
        if not np.any(over):
            break
        q = np.where(over, np.clip(new, lower, upper), q)
        free &= ~over
    new = np.clip(new, lower, upper)
    return new, float(np.max(np.abs(new - start)))


def _numeric_inverse_kinematics(
    model: RobotModel, target: FloatArray, seed: FloatArray, tol_mm: float, n: int
) -> FloatArray:
    """Joint angles (J,) reaching ``target`` (4, 4), by damped least squares from ``seed`` (J,).

    Each step is Levenberg–Marquardt with Sugihara's damping ``E + w_bar`` (E half the squared
    weighted pose error), which is robust far from the solution and converges quadratically
    near it, plus the projection of ``seed - q`` onto the Jacobian's null space, which on a
    redundant arm slides along the self-motion towards the seed without moving the TCP (to
    first order). Joints reaching a limit are held on it (:func:`_limited_step`). A start
    from the seed that does not converge (a limit or a singularity in the way) is followed by
    starts spread over the limits (fixed, so the result is repeatable); of the solutions
    found, the one nearest the seed is returned.
    """
    lower, upper = model.joint_lower_rad, model.joint_upper_rad
    seed = np.clip(seed, lower, upper)
    rotation_tol = tol_mm * 1e-3
    spread = np.random.default_rng(0).uniform(lower, upper, (_IK_RESTARTS, model.n_joints))
    found: list[FloatArray] = []
    for k in range(_IK_RESTARTS + 1):
        q = seed.copy() if k == 0 else spread[k - 1]
        history: list[float] = []
        for iteration in range(_IK_ITERATIONS):
            tcp, jac = _tcp_pose_and_jacobian(model, q[None])
            err = _pose_error_vector(target, tcp)[0]
            converged = np.linalg.norm(err[:3]) < tol_mm and np.linalg.norm(err[3:]) < rotation_tol
            history.append(float(np.linalg.norm(err[:3]) + _IK_LEVER_MM * np.linalg.norm(err[3:])))
            stalled = iteration >= _IK_STALL and history[-1] > max(1e-3, 0.99 * history[-1 - _IK_STALL])
            if stalled:
                break  # stalled (out of reach, or held by limits): a fresh start does better
            q, moved = _limited_step(jac[0], err, q, seed, lower, upper)
            if converged and moved < 1e-12:
                break
        if _reaches(model, target, q[None], tol_mm)[0]:
            found.append(q)
            if k == 0:
                # the seed's own start followed the self-motion to the solution nearest it
                break
    if not found:
        raise UnreachableError(
            f"pose {n} cannot be reached by the {model.name} within {tol_mm:g} mm and its joint limits "
            f"(damped least squares from the reference and {_IK_RESTARTS} other starts)"
        )
    solutions = np.array(found)
    return solutions[np.argmin(np.linalg.norm(solutions - seed, axis=1))]


def within_joint_limits(model: RobotModel, joints_rad: ArrayLike) -> BoolArray:
    """Boolean per row of joints (N, J): inside the model's limits."""
    q, _ = _as_joint_array(model, joints_rad)
    return np.all((q >= model.joint_lower_rad) & (q <= model.joint_upper_rad), axis=1)


def with_dh_corrections(model: RobotModel, delta: ArrayLike) -> RobotModel:
    """``model`` with DH corrections (4 J,): a, d, alpha, theta offset of joints 1..J, in that order."""
    delta = np.asarray(delta, dtype=float).reshape(4, model.n_joints)
    return model.with_dh_errors(delta[0], delta[1], delta[2], delta[3])


def fit_reported_kinematics(
    start: RobotModel,
    joints_rad: ArrayLike,
    base_from_tcp_stack: ArrayLike,
    iterations: int = 12,
    lever_mm: float = 100.0,
) -> tuple[RobotModel, float]:
    """The kinematic model a controller computed its reported poses with, from pairs of
    reported joints and TCP poses (when it does not publish its calibrated DH parameters).

    Gauss–Newton on the 4 J DH corrections and the 6 tool parameters from ``start``; the DH
    parameters of a UR chain are redundant (e.g. the d of parallel joints), so each step is
    the minimum-norm least-squares step: the model found reproduces the poses, its individual
    parameters need not be the controller's.

    Parameters
    ----------
    start : RobotModel
        The nominal model with a first guess of the TCP.
    joints_rad : array_like, shape (N, J)
    base_from_tcp_stack : array_like, shape (N, 4, 4)
        The TCP poses the controller reported at those joints, mm.
    lever_mm : float
        Weight of a rotation residual (rad) against a position residual (mm).

    Returns
    -------
    model : RobotModel
    rms_mm : float
        RMS position misfit of the model on the pairs, mm.
    """
    q, _ = _as_joint_array(start, joints_rad)
    reported = np.asarray(base_from_tcp_stack, dtype=float).reshape(-1, 4, 4)
    if len(q) != len(reported) or len(q) < 6:
        raise InvalidInputError("fitting reported kinematics needs at least 6 pairs of joints and poses")

    dh = 4 * start.n_joints

    def model_of(parameters: FloatArray) -> RobotModel:
        tool = start.flange_from_tcp @ make_transform(
            rotvec_to_matrix(parameters[dh + 3 : dh + 6]), parameters[dh : dh + 3]
        )
        return with_dh_corrections(start, parameters[:dh]).with_tcp(tool)

    def residuals(parameters: FloatArray) -> FloatArray:
        predicted = forward_kinematics(model_of(parameters), q)
        error = _pose_error_vector(reported, predicted)
        return np.concatenate([error[:, :3], lever_mm * error[:, 3:]], axis=1).ravel()

    count = dh + 6
    parameters = np.zeros(count)
    scale = np.array([1.0] * (dh // 2) + [1e-3] * (dh // 2) + [1.0] * 3 + [1e-3] * 3)
    current = residuals(parameters)
    for _ in range(iterations):
        jac = np.empty((len(current), count))
        for k in range(count):
            step = np.zeros(count)
            step[k] = 1e-3 * scale[k]
            jac[:, k] = (residuals(parameters + step) - current) / step[k]
        # directions the poses barely determine (small motion, redundant parameters) are left
        # out of the step (truncated SVD), and a step that does not lower the misfit is halved
        delta = np.linalg.lstsq(jac * scale, -current, rcond=1e-6)[0] * scale
        for _ in range(20):
            trial = residuals(parameters + delta)
            if trial @ trial <= current @ current:
                break
            delta = delta / 2
        else:
            break
        parameters, current = parameters + delta, trial
        if np.max(np.abs(delta / scale)) < 1e-9:
            break
    final = residuals(parameters).reshape(-1, 6)
    return model_of(parameters), float(np.sqrt(np.mean(np.sum(final[:, :3] ** 2, axis=1))))


# -- the calibration chain -----------------------------------------------------------------
#
# Every frame i of a calibration sees marker points s_k through (paper eq. 1)
#
#     p_ik_in_tracker = tracker_from_base @ base_from_tcp_i @ tcp_from_marker @ s_k
#
# The two unknown transforms are perturbed with 12 parameters, one convention for the whole
# package (the ML estimator, its covariance in result files, the bootstrap, kinematic
# identification and motion planning all use it):
#
#     tracker_from_base = [exp(w_t) R_t | t_t + v_t]     (w_t, v_t in the tracker frame)
#     tcp_from_marker   = [R_x exp(w_x) | t_x + v_x]     (w_x in the marker frame)
#
# with the parameter vector (v_t, w_t, v_x, w_x), mm and rad.

#: Names of the 12 pose perturbation parameters, in order (see :func:`apply_pose_step`).
POSE_PARAMETER_NAMES = [
    "tracker_from_base.v_x_mm",
    "tracker_from_base.v_y_mm",
    "tracker_from_base.v_z_mm",
    "tracker_from_base.w_x_rad",
    "tracker_from_base.w_y_rad",
    "tracker_from_base.w_z_rad",
    "tcp_from_marker.v_x_mm",
    "tcp_from_marker.v_y_mm",
    "tcp_from_marker.v_z_mm",
    "tcp_from_marker.w_x_rad",
    "tcp_from_marker.w_y_rad",
    "tcp_from_marker.w_z_rad",
]


def apply_pose_step(
    tracker_from_base: ArrayLike, tcp_from_marker: ArrayLike, step: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """Perturb the two calibration transforms by 12 parameters (v_t, w_t, v_x, w_x).

    Parameters
    ----------
    tracker_from_base, tcp_from_marker : array_like, shape (4, 4), mm
    step : array_like, shape (12,)
        Translations in mm, rotation vectors in rad; see the convention above
        :data:`POSE_PARAMETER_NAMES`.

    Returns
    -------
    tracker_from_base, tcp_from_marker : numpy.ndarray, shape (4, 4)
    """
    tracker_from_base = np.asarray(tracker_from_base, dtype=float)
    tcp_from_marker = np.asarray(tcp_from_marker, dtype=float)
    step = np.asarray(step, dtype=float)
    t_new = make_transform(
        rotvec_to_matrix(step[3:6]) @ tracker_from_base[:3, :3], tracker_from_base[:3, 3] + step[0:3]
    )
    x_new = make_transform(
        tcp_from_marker[:3, :3] @ rotvec_to_matrix(step[9:12]), tcp_from_marker[:3, 3] + step[6:9]
    )
    return t_new, x_new


def pose_step_between(
    reference_tracker_from_base: ArrayLike,
    reference_tcp_from_marker: ArrayLike,
    tracker_from_base: ArrayLike,
    tcp_from_marker: ArrayLike,
) -> FloatArray:
    """The 12 parameters (12,) that :func:`apply_pose_step` needs to go from the reference
    transforms to the given ones (its inverse), mm and rad."""
    reference_t = np.asarray(reference_tracker_from_base, dtype=float)
    reference_x = np.asarray(reference_tcp_from_marker, dtype=float)
    tracker_from_base = np.asarray(tracker_from_base, dtype=float)
    tcp_from_marker = np.asarray(tcp_from_marker, dtype=float)
    return np.concatenate(
        [
            tracker_from_base[:3, 3] - reference_t[:3, 3],
            matrix_to_rotvec(tracker_from_base[:3, :3] @ reference_t[:3, :3].T),
            tcp_from_marker[:3, 3] - reference_x[:3, 3],
            matrix_to_rotvec(reference_x[:3, :3].T @ tcp_from_marker[:3, :3]),
        ]
    )


def chain_points_in_tracker(
    base_from_tcp_stack: ArrayLike,
    tracker_from_base: FloatArray,
    tcp_from_marker: FloatArray,
    points_in_marker: FloatArray,
) -> FloatArray:
    """Marker points (K, 3) placed by the calibration chain at TCP poses (N, 4, 4): (N, K, 3), mm."""
    chain = tracker_from_base @ np.asarray(base_from_tcp_stack, dtype=float) @ tcp_from_marker
    return transform_points_by_stack(chain, points_in_marker)


def pose_point_jacobian(
    base_from_tcp_stack: ArrayLike,
    tracker_from_base: ArrayLike,
    tcp_from_marker: ArrayLike,
    points_in_marker: ArrayLike,
) -> FloatArray:
    """d(:func:`chain_points_in_tracker`)/d(12 pose parameters), analytic: shape (N, K, 3, 12).

    With q = R_t (R_A (R_x s + t_x) + t_A) + t_t and the perturbations of
    :func:`apply_pose_step`: dq/dv_t = I, dq/dw_t = -[R_t p_base]x, dq/dv_x = R_t R_A,
    dq/dw_x = -R_t R_A R_x [s]x.

    Parameters
    ----------
    base_from_tcp_stack : array_like, shape (N, 4, 4), mm
    tracker_from_base, tcp_from_marker : array_like, shape (4, 4), mm
    points_in_marker : array_like, shape (K, 3), mm

    Returns
    -------
    numpy.ndarray, shape (N, K, 3, 12)
        mm per mm or per rad, unwhitened.
    """
    base_from_tcp_stack = np.asarray(base_from_tcp_stack, dtype=float)
    tracker_from_base = np.asarray(tracker_from_base, dtype=float)
    tcp_from_marker = np.asarray(tcp_from_marker, dtype=float)
    points_in_marker = np.asarray(points_in_marker, dtype=float)
    r_t = tracker_from_base[:3, :3]
    r_a = base_from_tcp_stack[:, :3, :3]
    r_x = tcp_from_marker[:3, :3]
    points_in_base = transform_points_by_stack(
        base_from_tcp_stack, apply_transform(tcp_from_marker, points_in_marker)
    )
    rotated = points_in_base @ r_t.T  # R_t p_base
    n, k = rotated.shape[:2]
    jac = np.zeros((n, k, 3, 12))
    jac[..., 0:3] = np.eye(3)
    jac[..., 3:6] = -skew(rotated)
    r_ta = np.einsum("ij,njk->nik", r_t, r_a)  # (N, 3, 3)
    jac[..., 6:9] = r_ta[:, None]
    r_tax = r_ta @ r_x
    jac[..., 9:12] = -np.einsum("nij,kjl->nkil", r_tax, skew(points_in_marker))
    return jac


def points_in_tracker(
    model: RobotModel,
    joints_rad: ArrayLike,
    tracker_from_base: FloatArray,
    tcp_from_marker: FloatArray,
    points_in_marker: FloatArray,
) -> FloatArray:
    """Marker points (K, 3) seen in the tracker at joint configurations (N, J): shape (N, K, 3), mm.

    The calibration chain ``tracker_from_base @ FK(q) @ tcp_from_marker`` applied to the points.
    """
    return chain_points_in_tracker(
        forward_kinematics(model, np.atleast_2d(joints_rad)),
        tracker_from_base,
        tcp_from_marker,
        points_in_marker,
    )


def dh_point_jacobian(
    model: RobotModel,
    joints_rad: ArrayLike,
    tracker_from_base: FloatArray,
    tcp_from_marker: FloatArray,
    points_in_marker: FloatArray,
    step: float = 1e-6,
) -> FloatArray:
    """d(:func:`points_in_tracker`)/d(4 J DH corrections) by central differences: (N, K, 3, 4 J).

    The pose columns that go with these are :func:`pose_point_jacobian` (analytic).
    """
    columns = []
    count = 4 * model.n_joints
    for index in range(count):
        delta = np.zeros(count)
        delta[index] = step
        plus = points_in_tracker(
            with_dh_corrections(model, delta),
            joints_rad,
            tracker_from_base,
            tcp_from_marker,
            points_in_marker,
        )
        minus = points_in_tracker(
            with_dh_corrections(model, -delta),
            joints_rad,
            tracker_from_base,
            tcp_from_marker,
            points_in_marker,
        )
        columns.append((plus - minus) / (2 * step))
    return np.stack(columns, axis=-1)
