"""The robot kinds spacecal knows: every fact about an arm, as data.

One entry of ``data/robot_kinds.json`` per kind (a UR arm, a Franka, a KUKA LBR iiwa) holds its
DH table and convention, joint limits and speeds, controller rate, datasheet repeatability,
stated accuracy, payload, link dynamics where published, and the sources of those numbers.
Code asks :func:`robot_kind` for a kind by name and builds its kinematic model with
:meth:`RobotKind.model`; a kind made at run time (e.g. from a URDF) joins the registry by
:func:`register_robot_kind`. Adding an arm is adding a JSON entry.

Lengths are in mm, angles in rad, speeds in deg/s, masses in kg.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, replace
from importlib import resources
from types import MappingProxyType
from typing import Any

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.geometry.arrays import ArrayLike, FloatArray
from spacecal.models.kinematics import DH_CONVENTIONS, MAX_JOINTS, RobotModel

#: How :func:`~spacecal.models.kinematics.inverse_kinematics` solves a kind.
INVERSE_KINEMATICS = ("ur_closed_form", "numeric")


@dataclass(frozen=True, eq=False)
class LinkDynamics:
    """Masses and centres of mass of an arm's links.

    Attributes
    ----------
    name : str
        The arm they belong to, e.g. ``"UR10"``.
    masses_kg : numpy.ndarray, shape (J,)
        Link masses, kg.
    centres_of_mass_mm : numpy.ndarray, shape (J, 3)
        Each link's centre of mass in its own DH frame (frame i for link i), mm.
    """

    name: str
    masses_kg: FloatArray
    centres_of_mass_mm: FloatArray

    def same_as(self, other: LinkDynamics | None) -> bool:
        """Whether ``other`` holds the same numbers (arrays make ``==`` ambiguous)."""
        return (
            other is not None
            and self.name == other.name
            and np.array_equal(self.masses_kg, other.masses_kg)
            and np.array_equal(self.centres_of_mass_mm, other.centres_of_mass_mm)
        )


@dataclass(frozen=True)
class RobotKind:
    """One kind of arm, as its vendor publishes it.

    Attributes
    ----------
    name : str
        ``"UR10"``, ``"UR5e"``, ``"FR3"``, ``"Panda"``, ``"LBR iiwa 7 R800"``, ...
    vendor : str
        ``"Universal Robots"``, ``"Franka Robotics"``, ``"KUKA"``.
    dh_convention : str
        ``"standard"`` or ``"modified"`` (Craig), see :mod:`spacecal.models.kinematics`.
    a_mm, d_mm, alpha_rad, theta_offset_rad : tuple of float, length J
        The DH table from the base to the flange, in ``dh_convention``.
    joint_lower_rad, joint_upper_rad : tuple of float, length J
        Joint limits, rad.
    joint_speed_deg_s : tuple of float, length J
        Maximum joint speeds, deg/s.
    controller_hz : float
        Rate at which the controller time-stamps its state.
    repeatability_mm : float
        ISO 9283 pose repeatability RP from the datasheet, mm.
    kinematic_accuracy_mm : tuple of (float or None), length 2
        Stated absolute accuracy at the flange (nominal, after the vendor's calibration), mm;
        None where the vendor publishes none. The registry never substitutes a number for a
        missing one: code that needs an accuracy must say it has none (or use its own
        identification) rather than borrow another arm's.
    payload_kg : float
        Rated payload, kg.
    dynamics : LinkDynamics or None
        Link masses and centres of mass where published; None otherwise (no gravity model).
    inverse_kinematics : str
        ``"ur_closed_form"`` or ``"numeric"``.
    sources : tuple of str
        Where each number comes from.
    """

    name: str
    vendor: str
    dh_convention: str
    a_mm: tuple[float, ...]
    d_mm: tuple[float, ...]
    alpha_rad: tuple[float, ...]
    theta_offset_rad: tuple[float, ...]
    joint_lower_rad: tuple[float, ...]
    joint_upper_rad: tuple[float, ...]
    joint_speed_deg_s: tuple[float, ...]
    controller_hz: float
    repeatability_mm: float
    kinematic_accuracy_mm: tuple[float | None, float | None]
    payload_kg: float
    dynamics: LinkDynamics | None
    inverse_kinematics: str
    sources: tuple[str, ...]

    def __post_init__(self) -> None:
        what = f"robot kind {self.name!r}"
        if not isinstance(self.name, str) or not self.name.strip():
            raise InvalidInputError("a robot kind needs a name")
        if self.dh_convention not in DH_CONVENTIONS:
            raise InvalidInputError(
                f"{what}: DH convention {self.dh_convention!r} (one of {', '.join(DH_CONVENTIONS)})"
            )
        if self.inverse_kinematics not in INVERSE_KINEMATICS:
            raise InvalidInputError(
                f"{what}: inverse kinematics {self.inverse_kinematics!r} "
                f"(one of {', '.join(INVERSE_KINEMATICS)})"
            )
        joints = len(self.a_mm)
        if not 1 <= joints <= MAX_JOINTS:
            raise InvalidInputError(f"{what}: {joints} joints (1 to {MAX_JOINTS})")
        for field_name in (
            "d_mm",
            "alpha_rad",
            "theta_offset_rad",
            "joint_lower_rad",
            "joint_upper_rad",
            "joint_speed_deg_s",
        ):
            values = np.asarray(getattr(self, field_name), dtype=float)
            if values.shape != (joints,) or not np.all(np.isfinite(values)):
                raise InvalidInputError(f"{what}: {field_name} must be {joints} finite numbers, as a_mm")
        if not np.all(np.asarray(self.joint_lower_rad) < np.asarray(self.joint_upper_rad)):
            raise InvalidInputError(f"{what}: every joint's lower limit must be below its upper limit")
        if not np.all(np.asarray(self.joint_speed_deg_s) > 0):
            raise InvalidInputError(f"{what}: joint speeds must be positive")
        for field_name in ("repeatability_mm", "payload_kg", "controller_hz"):
            value = getattr(self, field_name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value >= 0):
                raise InvalidInputError(f"{what}: {field_name} must be a finite number >= 0, got {value!r}")
        if len(self.kinematic_accuracy_mm) != 2 or not all(
            v is None or (np.isfinite(v) and v > 0) for v in self.kinematic_accuracy_mm
        ):
            raise InvalidInputError(
                f"{what}: kinematic_accuracy_mm is (nominal, calibrated) mm, each > 0 or None"
            )
        if self.dynamics is not None and (
            np.shape(self.dynamics.masses_kg) != (joints,)
            or np.shape(self.dynamics.centres_of_mass_mm) != (joints, 3)
        ):
            raise InvalidInputError(
                f"{what}: dynamics must give {joints} masses and {joints} centres of mass"
            )
        if self.inverse_kinematics == "ur_closed_form" and joints != 6:
            raise InvalidInputError(
                f"{what}: the UR closed-form inverse kinematics needs 6 joints, not {joints}"
            )

    @property
    def n_joints(self) -> int:
        """The number of joints J."""
        return len(self.a_mm)

    @property
    def is_ur(self) -> bool:
        """Whether the kind is a Universal Robots arm (what a UR controller can be)."""
        return self.vendor == "Universal Robots"

    def model(self, flange_from_tcp: ArrayLike | None = None) -> RobotModel:
        """The kind's nominal kinematic model.

        Parameters
        ----------
        flange_from_tcp : array_like, shape (4, 4), optional
            Tool offset in the flange frame, mm; identity if omitted.
        """
        return RobotModel(
            name=self.name,
            a_mm=np.array(self.a_mm, dtype=float),
            d_mm=np.array(self.d_mm, dtype=float),
            alpha_rad=np.array(self.alpha_rad, dtype=float),
            theta_offset_rad=np.array(self.theta_offset_rad, dtype=float),
            flange_from_tcp=np.eye(4)
            if flange_from_tcp is None
            else np.asarray(flange_from_tcp, dtype=float),
            joint_lower_rad=np.array(self.joint_lower_rad, dtype=float),
            joint_upper_rad=np.array(self.joint_upper_rad, dtype=float),
            controller_hz=float(self.controller_hz),
            dh_convention=self.dh_convention,
        )

    @property
    def joint_speed_rad_s(self) -> FloatArray:
        """Maximum joint speeds (J,), rad/s."""
        return np.radians(np.asarray(self.joint_speed_deg_s, dtype=float))


def _angles(
    entry: Mapping[str, Any], stem: str, what: str, default: float | None = None
) -> tuple[float, ...] | None:
    """``stem_rad`` or ``stem_deg`` of an entry, in rad (the file keeps the vendor's unit)."""
    if f"{stem}_rad" in entry:
        return tuple(float(v) for v in entry[f"{stem}_rad"])
    if f"{stem}_deg" in entry:
        return tuple(float(v) for v in np.radians(np.asarray(entry[f"{stem}_deg"], dtype=float)))
    if default is not None:
        return (default,) * len(entry["a_mm"])
    raise InvalidInputError(f"{what}: needs {stem}_rad or {stem}_deg")


def kind_from_dict(entry: Mapping[str, Any]) -> RobotKind:
    """A :class:`RobotKind` from one entry of ``robot_kinds.json`` (the keys its comment describes)."""
    name = entry.get("name")
    what = f"robot kind {name!r}"
    try:
        convention = entry.get("dh_convention", "standard")
        d_mm = [float(v) for v in entry["d_mm"]]
        if "flange_d_mm" in entry:
            # a fixed flange row (a = alpha = theta = 0) after the last joint's Rz(q) Tz(d) of a
            # modified table translates along the same z axis, so it adds to that d exactly
            if convention != "modified":
                raise InvalidInputError(f"{what}: flange_d_mm is for modified-DH tables only")
            d_mm[-1] += float(entry["flange_d_mm"])
        if "joint_limit_deg" in entry:
            limit = np.radians(np.asarray(entry["joint_limit_deg"], dtype=float))
            lower, upper = tuple(float(v) for v in -limit), tuple(float(v) for v in limit)
        else:
            lower = _angles(entry, "joint_lower", what)
            upper = _angles(entry, "joint_upper", what)
        if "joint_speed_deg_s" in entry:
            speeds = tuple(float(v) for v in entry["joint_speed_deg_s"])
        else:
            speeds = tuple(float(v) for v in np.degrees(np.asarray(entry["joint_speed_rad_s"], dtype=float)))
        dynamics = None
        if entry.get("dynamics") is not None:
            dynamics = LinkDynamics(
                name=str(name),
                masses_kg=np.asarray(entry["dynamics"]["masses_kg"], dtype=float),
                centres_of_mass_mm=np.asarray(entry["dynamics"]["centres_of_mass_mm"], dtype=float),
            )
        accuracy = entry.get("kinematic_accuracy_mm") or [None, None]
        return RobotKind(
            name=str(name),
            vendor=str(entry["vendor"]),
            dh_convention=str(convention),
            a_mm=tuple(float(v) for v in entry["a_mm"]),
            d_mm=tuple(d_mm),
            alpha_rad=_angles(entry, "alpha", what),
            theta_offset_rad=_angles(entry, "theta_offset", what, default=0.0),
            joint_lower_rad=lower,
            joint_upper_rad=upper,
            joint_speed_deg_s=speeds,
            controller_hz=float(entry["controller_hz"]),
            repeatability_mm=float(entry["repeatability_mm"]),
            kinematic_accuracy_mm=tuple(None if v is None else float(v) for v in accuracy),
            payload_kg=float(entry["payload_kg"]),
            dynamics=dynamics,
            inverse_kinematics=str(entry.get("inverse_kinematics", "numeric")),
            sources=tuple(str(s) for s in entry.get("sources", ())),
        )
    except (KeyError, TypeError, ValueError) as error:
        raise InvalidInputError(f"{what}: bad entry ({error!s})") from None


def _load_kinds() -> dict[str, RobotKind]:
    text = resources.files("spacecal.models").joinpath("data/robot_kinds.json").read_text()
    kinds = [kind_from_dict(entry) for entry in json.loads(text)["kinds"]]
    return {kind.name: kind for kind in kinds}


_KINDS: dict[str, RobotKind] = _load_kinds()
#: The registered kinds by name (a read-only view; :func:`register_robot_kind` adds to it).
ROBOT_KINDS: Mapping[str, RobotKind] = MappingProxyType(_KINDS)


def robot_kind(name: str) -> RobotKind:
    """The registered kind called ``name``.

    Raises
    ------
    InvalidInputError
        ``unknown robot kind 'X'; known: ...`` for a name not registered.
    """
    kind = _KINDS.get(name) if isinstance(name, str) else None
    if kind is None:
        raise InvalidInputError(f"unknown robot kind {name!r}; known: {', '.join(_KINDS)}")
    return kind


def is_robot_kind(name: object) -> bool:
    """Whether ``name`` is a registered kind's name."""
    return isinstance(name, str) and name in _KINDS


def register_robot_kind(kind: RobotKind) -> None:
    """Add ``kind`` to the registry (e.g. one made from a URDF at run time).

    Registering a kind under a name already held replaces it only if it is the same kind;
    a different kind under a known name is refused, so a name means one arm in a run.
    """
    if not isinstance(kind, RobotKind):
        raise InvalidInputError(f"register_robot_kind takes a RobotKind, got {type(kind).__name__}")
    held = _KINDS.get(kind.name)
    same = held is not None and replace(held, dynamics=None) == replace(kind, dynamics=None)
    if same and held.dynamics is not None:
        same = held.dynamics.same_as(kind.dynamics)
    elif same:
        same = kind.dynamics is None
    if held is not None and not same:
        raise InvalidInputError(f"robot kind {kind.name!r} is already registered with other parameters")
    _KINDS[kind.name] = kind


def ur_kind_names() -> tuple[str, ...]:
    """Names of the registered Universal Robots kinds (what a UR controller may report)."""
    return tuple(name for name, kind in _KINDS.items() if kind.is_ur)
