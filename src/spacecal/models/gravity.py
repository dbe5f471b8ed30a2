"""Static gravity torques on the joints of an upright arm.

The one gravity model of the package: the simulator deflects its compliant arm by it
(:meth:`spacecal.sim.world.World.joint_deflections_rad`) and kinematic identification fits the
joints' compliance against it (:mod:`spacecal.models.compliance`). Point masses sit at the
links' published centres of mass; the base z axis points up. Torques in N m, lengths in mm,
angles in rad.
"""

from __future__ import annotations

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.geometry.arrays import ArrayLike, FloatArray
from spacecal.models.kinematics import RobotModel, _link_transforms
from spacecal.models.robot_kinds import ROBOT_KINDS, LinkDynamics

STANDARD_GRAVITY_M_S2 = 9.80665


def link_dynamics_of(model_name: str) -> LinkDynamics | None:
    """The published link dynamics of the kind named ``model_name``; None when the kind
    publishes none or is not registered (then there is no gravity model for it)."""
    kind = ROBOT_KINDS.get(model_name) if isinstance(model_name, str) else None
    return None if kind is None else kind.dynamics


def gravity_joint_torques(
    model: RobotModel,
    joints_rad: ArrayLike,
    payload_kg: float = 0.0,
    dynamics: LinkDynamics | None = None,
) -> FloatArray:
    """Static gravity torques on the joints of an upright arm, N m.

    Point masses at the links' centres of mass (``dynamics``) and the payload half-way between
    the flange and the TCP (a needle guide carrying the marker). The torque about joint ``j``
    is ``z_{j-1} . sum_{i>=j} (c_i - o_{j-1}) x m_i g``, base z up.

    Parameters
    ----------
    model : RobotModel
        The arm (its DH frames place the masses, its tool the payload).
    joints_rad : array_like, shape (N, J) or (J,)
        Joint angles, rad.
    payload_kg : float
        Mass carried on the tool, kg.
    dynamics : LinkDynamics, optional
        Link masses and centres of mass; by default those of the robot kind ``model`` is named
        after (:func:`link_dynamics_of`).

    Returns
    -------
    numpy.ndarray, shape (N, J)
        Torque on each joint, N m (positive about the joint's z axis).

    Raises
    ------
    InvalidInputError
        If no dynamics are given and the kind publishes none: such an arm has no gravity model
        (rather than another arm's).
    """
    if dynamics is None:
        dynamics = link_dynamics_of(model.name)
        if dynamics is None:
            raise InvalidInputError(
                f"the {model.name} has no published link dynamics: no gravity model for it"
            )
    q = np.atleast_2d(np.asarray(joints_rad, float))
    joints = model.n_joints
    if np.shape(dynamics.masses_kg) != (joints,):
        raise InvalidInputError(
            f"link dynamics of the {dynamics.name} ({np.size(dynamics.masses_kg)} links) do not fit "
            f"the {model.name} ({joints} joints)"
        )
    links = _link_transforms(model, q)
    frames = [np.broadcast_to(np.eye(4), (len(q), 4, 4))]
    for i in range(joints):
        frames.append(frames[-1] @ links[:, i])
    masses = list(dynamics.masses_kg)
    centres = [
        frames[i + 1][:, :3, :3] @ dynamics.centres_of_mass_mm[i] + frames[i + 1][:, :3, 3]
        for i in range(joints)
    ]
    if payload_kg > 0:
        tool_mid = 0.5 * np.asarray(model.flange_from_tcp, float)[:3, 3]
        centres.append(frames[joints][:, :3, :3] @ tool_mid + frames[joints][:, :3, 3])
        masses.append(payload_kg)
    weight = np.array([0.0, 0.0, -STANDARD_GRAVITY_M_S2])
    torques = np.zeros((len(q), joints))
    # joint j turns about z of frame j (standard DH) or of frame j + 1 (modified DH)
    shift = 1 if model.dh_convention == "modified" else 0
    for j in range(joints):
        axis, origin = frames[j + shift][:, :3, 2], frames[j + shift][:, :3, 3]
        moment = np.zeros((len(q), 3))
        # link i (0-based) is moved by joints 0..i: joint j carries links j..J-1 and the payload
        for i in range(j, len(masses)):
            moment += np.cross((centres[i] - origin) * 1e-3, masses[i] * weight)
        torques[:, j] = np.sum(moment * axis, axis=1)
    return torques
