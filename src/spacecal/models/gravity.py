"""Static gravity torques on the joints of an upright UR arm.

The one gravity model of the package: the simulator deflects its compliant arm by it
(:meth:`spacecal.sim.world.World.joint_deflections_rad`) and kinematic identification fits the
joints' compliance against it (:mod:`spacecal.models.compliance`). Point masses sit at the
links' published centres of mass; the base z axis points up. Torques in N m, lengths in mm,
angles in rad.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spacecal.geometry.arrays import ArrayLike, FloatArray
from spacecal.models.kinematics import N_JOINTS, RobotModel, _link_transforms

STANDARD_GRAVITY_M_S2 = 9.80665


@dataclass(frozen=True)
class LinkDynamics:
    """Masses and centres of mass of an arm's six links.

    Attributes
    ----------
    name : str
        The arm they belong to, e.g. ``"UR10"``.
    masses_kg : numpy.ndarray, shape (6,)
        Link masses, kg.
    centres_of_mass_mm : numpy.ndarray, shape (6, 3)
        Each link's centre of mass in its own DH frame (frame i for link i), mm.
    """

    name: str
    masses_kg: FloatArray
    centres_of_mass_mm: FloatArray


#: UR10 link masses (kg) and centres of mass (mm) in each link's DH frame, as Universal Robots
#: publishes them ("DH parameters for calculations of kinematics and dynamics", UR support
#: article for the CB3 arms).
UR10_DYNAMICS = LinkDynamics(
    name="UR10",
    masses_kg=np.array([7.1, 12.7, 4.27, 2.0, 2.0, 0.365]),
    centres_of_mass_mm=np.array(
        [
            [21.0, 0.0, 27.0],
            [380.0, 0.0, 158.0],
            [240.0, 0.0, 68.0],
            [0.0, 7.0, 18.0],
            [0.0, 7.0, 18.0],
            [0.0, 0.0, -26.0],
        ]
    ),
)
UR10_LINK_MASSES_KG = UR10_DYNAMICS.masses_kg
UR10_LINK_COM_MM = UR10_DYNAMICS.centres_of_mass_mm

#: The arms whose published link dynamics the package holds, by model name.
LINK_DYNAMICS = {UR10_DYNAMICS.name: UR10_DYNAMICS}


def link_dynamics_of(model_name: str) -> LinkDynamics | None:
    """The published link dynamics of the arm named ``model_name``, None when not held."""
    return LINK_DYNAMICS.get(model_name)


def gravity_joint_torques(
    model: RobotModel,
    joints_rad: ArrayLike,
    payload_kg: float = 0.0,
    dynamics: LinkDynamics = UR10_DYNAMICS,
) -> FloatArray:
    """Static gravity torques on the joints of an upright arm, N m.

    Point masses at the links' centres of mass (``dynamics``) and the payload half-way between
    the flange and the TCP (a needle guide carrying the marker). The torque about joint ``j``
    is ``z_{j-1} . sum_{i>=j} (c_i - o_{j-1}) x m_i g``, base z up.

    Parameters
    ----------
    model : RobotModel
        The arm (its DH frames place the masses, its tool the payload).
    joints_rad : array_like, shape (N, 6) or (6,)
        Joint angles, rad.
    payload_kg : float
        Mass carried on the tool, kg.
    dynamics : LinkDynamics
        Link masses and centres of mass (default the UR10's).

    Returns
    -------
    numpy.ndarray, shape (N, 6)
        Torque on each joint, N m (positive about the joint's z axis).
    """
    q = np.atleast_2d(np.asarray(joints_rad, float))
    links = _link_transforms(model, q)
    frames = [np.broadcast_to(np.eye(4), (len(q), 4, 4))]
    for i in range(N_JOINTS):
        frames.append(frames[-1] @ links[:, i])
    masses = list(dynamics.masses_kg)
    centres = [
        frames[i + 1][:, :3, :3] @ dynamics.centres_of_mass_mm[i] + frames[i + 1][:, :3, 3]
        for i in range(N_JOINTS)
    ]
    if payload_kg > 0:
        tool_mid = 0.5 * np.asarray(model.flange_from_tcp, float)[:3, 3]
        centres.append(frames[N_JOINTS][:, :3, :3] @ tool_mid + frames[N_JOINTS][:, :3, 3])
        masses.append(payload_kg)
    weight = np.array([0.0, 0.0, -STANDARD_GRAVITY_M_S2])
    torques = np.zeros((len(q), N_JOINTS))
    for j in range(N_JOINTS):
        axis, origin = frames[j][:, :3, 2], frames[j][:, :3, 3]
        moment = np.zeros((len(q), 3))
        # link i (0-based) is moved by joints 0..i: joint j carries links j..5 and the payload
        for i in range(j, len(masses)):
            moment += np.cross((centres[i] - origin) * 1e-3, masses[i] * weight)
        torques[:, j] = np.sum(moment * axis, axis=1)
    return torques
