"""Joint compliance under gravity: where a compliant arm's joints really are, and how to command it.

The shoulder and elbow (joints 2 and 3) of an arm like a UR10 twist in their strain-wave
gears under the static gravity torque (:func:`spacecal.models.gravity.gravity_joint_torques`);
the encoders sit on the motor side and do not see it. With a compliance ``c_j`` (rad per N m)
a joint's true angle is

    q_true_j = q_encoder_j + c_j * (tau_j(q_encoder) - tau_ref_j)

the torque taken at the encoder angles (its change over a deflection of a few mrad is of second
order). ``tau_ref`` is the torque at which the kinematic model holds: zero for a model of the
unloaded arm; a model whose joint offsets were fitted under gravity (a calibration) already
holds the sag at the torques it was fitted at, and only the change from them deflects it.
Predicting a pose is forward kinematics at ``q_true``; reaching a pose is inverse kinematics
to ``q_true`` and then the encoder angles that deflect onto it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.geometry.arrays import ArrayLike, FloatArray
from spacecal.models.gravity import LinkDynamics, gravity_joint_torques
from spacecal.models.kinematics import N_JOINTS, RobotModel, forward_kinematics, inverse_kinematics

#: The compliant joints, 0-based: the shoulder and elbow carry the arm's weight on the longest
#: levers; the wrist joints' torques are a few N m and deflect the TCP by microns.
COMPLIANT_JOINTS = (1, 2)

#: Fixed-point steps that invert the deflection (:func:`encoder_joints_for`): each shrinks the
#: error by ``c |d tau / d q|``, about 5e-3 at a stiffness of 3e4 N m/rad, so four reach 1e-9 rad.
ENCODER_SOLVE_STEPS = 6


@dataclass(frozen=True)
class JointCompliance:
    """The shoulder's and elbow's compliance under gravity.

    Attributes
    ----------
    rad_per_nm : numpy.ndarray, shape (2,)
        Compliance of joints 2 and 3 (:data:`COMPLIANT_JOINTS`), rad per N m (the inverse of
        a torsional stiffness).
    reference_torques_nm : numpy.ndarray, shape (2,)
        Torques on joints 2 and 3 at which the kinematic model holds (no deflection), N m.
    payload_kg : float
        Mass on the tool the torques include, kg (half-way between flange and TCP).
    dynamics : LinkDynamics, optional
        Link masses and centres of mass the torques are computed with; None: those of the
        robot kind the model is named after (an arm without published dynamics has none, and
        :func:`~spacecal.models.gravity.gravity_joint_torques` says so).
    """

    rad_per_nm: FloatArray
    reference_torques_nm: FloatArray = field(default_factory=lambda: np.zeros(len(COMPLIANT_JOINTS)))
    payload_kg: float = 0.0
    dynamics: LinkDynamics | None = None

    def __post_init__(self) -> None:
        for name, unit in (("rad_per_nm", "rad/N m"), ("reference_torques_nm", "N m")):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != (len(COMPLIANT_JOINTS),) or not np.all(np.isfinite(value)):
                raise InvalidInputError(
                    f"joint compliance: {name} must be {len(COMPLIANT_JOINTS)} finite numbers ({unit})"
                )
            object.__setattr__(self, name, value)
        if not (np.isfinite(self.payload_kg) and self.payload_kg >= 0.0):
            raise InvalidInputError(f"payload {self.payload_kg} kg")

    def deflections_rad(self, model: RobotModel, joints_rad: ArrayLike) -> FloatArray:
        """How far (N, 6), rad, the joints are from encoder angles (N, 6) or (6,) under gravity."""
        q = np.atleast_2d(np.asarray(joints_rad, dtype=float))
        torques = gravity_joint_torques(model, q, self.payload_kg, self.dynamics)
        deflection = np.zeros_like(q)
        deflection[:, COMPLIANT_JOINTS] = (
            torques[:, COMPLIANT_JOINTS] - self.reference_torques_nm
        ) * self.rad_per_nm
        return deflection


def deflected_joints(
    model: RobotModel, compliance: JointCompliance | None, joints_rad: ArrayLike
) -> FloatArray:
    """The true joint angles (N, 6), rad, of encoder angles (N, 6) or (6,); the encoder
    angles themselves when ``compliance`` is None (a rigid arm)."""
    q = np.atleast_2d(np.asarray(joints_rad, dtype=float))
    if compliance is None:
        return q
    return q + compliance.deflections_rad(model, q)


def compliant_forward_kinematics(
    model: RobotModel, compliance: JointCompliance | None, joints_rad: ArrayLike
) -> FloatArray:
    """``base_from_tcp`` (N, 4, 4), mm, of a compliant arm at encoder angles (N, 6) or (6,), rad."""
    return forward_kinematics(model, deflected_joints(model, compliance, joints_rad))


def encoder_joints_for(
    model: RobotModel, compliance: JointCompliance | None, true_joints_rad: ArrayLike
) -> FloatArray:
    """The encoder angles (N, 6), rad, at which gravity deflects the joints onto
    ``true_joints_rad`` (N, 6) or (6,), rad: the fixed point of
    ``q = q_true - c tau(q)`` (a contraction, see :data:`ENCODER_SOLVE_STEPS`)."""
    target = np.atleast_2d(np.asarray(true_joints_rad, dtype=float))
    if target.shape[-1] != N_JOINTS:
        raise InvalidInputError(f"expected {N_JOINTS} joint angles per row, got shape {target.shape}")
    if compliance is None:
        return target
    encoder = target.copy()
    for _ in range(ENCODER_SOLVE_STEPS):
        encoder = target - compliance.deflections_rad(model, encoder)
    return encoder


def compliant_inverse_kinematics(
    model: RobotModel,
    compliance: JointCompliance | None,
    base_from_tcp: ArrayLike,
    reference_joints_rad: ArrayLike | None = None,
) -> FloatArray:
    """Encoder angles (N, 6), rad, that put a compliant arm's TCP at ``base_from_tcp``.

    :func:`~spacecal.models.kinematics.inverse_kinematics` gives the true joint angles of the
    pose (the branch nearest the reference), :func:`encoder_joints_for` the angles to command.

    Parameters
    ----------
    model : RobotModel
    compliance : JointCompliance or None
        None for a rigid arm (plain inverse kinematics).
    base_from_tcp : array_like, shape (4, 4) or (N, 4, 4)
        Target TCP poses, mm.
    reference_joints_rad : array_like, shape (6,) or (N, 6), optional
        Configuration to stay near.
    """
    true_joints = inverse_kinematics(model, base_from_tcp, reference_joints_rad)
    return encoder_joints_for(model, compliance, true_joints)
