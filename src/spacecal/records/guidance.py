"""The record of a needle guidance on the robot (paper §5.3), schema ``spacecal.guidance``.

The plan's entry and target in the image and the tracker, what each stage reached (the needle
measured in the tracker frame) and its errors, the predicted error beside them, and whether the
guidance was interrupted (then it keeps what was measured before).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.records.fields import (
    as_array,
    as_transform,
    check_schema,
    get_mapping,
    get_number,
    get_str,
    plain,
)

GUIDANCE_SCHEMA = "spacecal.guidance"
GUIDANCE_SCHEMA_VERSION = 1


def _finite_number(value: Any, name: str, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InvalidInputError(f"{what}: {name} must be a finite number, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class StageMeasurement:
    """One stage reached and measured.

    Attributes
    ----------
    stage : str
        ``standoff`` or ``insert``.
    planned_tracker_from_needle, measured_tracker_from_needle : numpy.ndarray, shape (4, 4)
        The needle planned and measured at the stage's end, tracker frame, mm.
    joints_rad : numpy.ndarray, shape (6,)
        Where the robot rested.
    tip_error_mm, entry_error_mm, target_error_mm, direction_error_deg : float
        :class:`spacecal.workflows.guidance.NeedleErrors` of the measured needle.
    simulated_true_tracker_from_needle : numpy.ndarray, shape (4, 4), or None
        On the simulated devices only: the simulator's truth of where the needle was during the
        stage's hold (the mean of its true poses over the hold's frames, tracker frame, mm), as
        a verification's simulated laser tracker sees the true pose; what a second CT would
        show. None on real devices (nothing there knows the truth).
    """

    stage: str
    planned_tracker_from_needle: np.ndarray
    measured_tracker_from_needle: np.ndarray
    joints_rad: np.ndarray
    tip_error_mm: float
    entry_error_mm: float
    target_error_mm: float
    direction_error_deg: float
    simulated_true_tracker_from_needle: np.ndarray | None = None

    def __post_init__(self) -> None:
        what = f"guidance stage {self.stage}"
        if self.stage not in ("standoff", "insert"):
            raise InvalidInputError(f"{what}: the stage must be standoff or insert")
        for name in ("planned_tracker_from_needle", "measured_tracker_from_needle"):
            object.__setattr__(self, name, as_transform(getattr(self, name), name, what))
        truth = self.simulated_true_tracker_from_needle
        if truth is not None:
            name = "simulated_true_tracker_from_needle"
            object.__setattr__(self, name, as_transform(truth, name, what))
        object.__setattr__(self, "joints_rad", as_array(self.joints_rad, (6,), "joints_rad", what))
        for name in ("tip_error_mm", "entry_error_mm", "target_error_mm", "direction_error_deg"):
            object.__setattr__(self, name, _finite_number(getattr(self, name), name, what))

    def to_dict(self) -> dict[str, Any]:
        return plain(
            {
                "stage": self.stage,
                "planned_tracker_from_needle": self.planned_tracker_from_needle,
                "measured_tracker_from_needle": self.measured_tracker_from_needle,
                "joints_rad": self.joints_rad,
                "tip_error_mm": self.tip_error_mm,
                "entry_error_mm": self.entry_error_mm,
                "target_error_mm": self.target_error_mm,
                "direction_error_deg": self.direction_error_deg,
                **(
                    {}
                    if self.simulated_true_tracker_from_needle is None
                    else {"simulated_true_tracker_from_needle": self.simulated_true_tracker_from_needle}
                ),
            }
        )

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], what: str) -> StageMeasurement:
        return cls(
            stage=get_str(data, "stage", what),
            planned_tracker_from_needle=data.get("planned_tracker_from_needle"),  # type: ignore[arg-type]
            measured_tracker_from_needle=data.get("measured_tracker_from_needle"),  # type: ignore[arg-type]
            joints_rad=data.get("joints_rad"),  # type: ignore[arg-type]
            tip_error_mm=get_number(data, "tip_error_mm", what),
            entry_error_mm=get_number(data, "entry_error_mm", what),
            target_error_mm=get_number(data, "target_error_mm", what),
            direction_error_deg=get_number(data, "direction_error_deg", what),
            simulated_true_tracker_from_needle=data.get("simulated_true_tracker_from_needle"),
        )


@dataclass(frozen=True)
class GuidanceResult:
    """A needle guidance on the robot (paper §5.3).

    Attributes
    ----------
    plan_name : str
    image_frame : str
        ``image_lps`` or ``image_ras`` (or ``image``): the frame of the image points.
    entry_in_image, target_in_image : numpy.ndarray, shape (3,)
        The plan, mm.
    tracker_frame : str
        The registration's tracker frame.
    entry_in_tracker, target_in_tracker : numpy.ndarray, shape (3,)
        The plan in the tracker frame, mm.
    registration : str
        The registration's name and source.
    insertion : str
        ``advance`` (the robot advances the needle to the target) or ``hold`` (the guide holds
        at the entry for a manual insertion).
    standoff_mm : float
    stages : tuple of StageMeasurement
        The stages reached and measured, in order.
    predicted_entry_error_mm, predicted_target_error_mm, predicted_direction_error_deg : float
        The predicted RMS errors (:func:`spacecal.planning.needle.plan_needle`): the
        calibration's stated error, the registration's TRE and the robot's, in quadrature.
    predicted_contributions : dict
        The predicted error's parts (``registration_mm`` at entry and target,
        ``calibration_mm``, ``robot_mm``).
    measured_by : str
        What measured the needle (the calibrated marker: not independent of the calibration).
    devices : dict of str to str
    simulated : bool
    interrupted : bool
        The guidance stopped before its last stage ended; what was measured before is kept.
    interruption : str
        Why, one line (empty when not interrupted).
    plan_source : str
        Where the plan came from: its file as given, or 3D Slicer over OpenIGTLink (empty in
        records written before it was kept).
    """

    plan_name: str
    image_frame: str
    entry_in_image: np.ndarray
    target_in_image: np.ndarray
    tracker_frame: str
    entry_in_tracker: np.ndarray
    target_in_tracker: np.ndarray
    registration: str
    insertion: str
    standoff_mm: float
    stages: tuple[StageMeasurement, ...]
    predicted_entry_error_mm: float
    predicted_target_error_mm: float
    predicted_direction_error_deg: float
    predicted_contributions: Mapping[str, Any] = field(default_factory=dict)
    measured_by: str = ""
    devices: Mapping[str, str] = field(default_factory=dict)
    simulated: bool = False
    interrupted: bool = False
    interruption: str = ""
    plan_source: str = ""

    SCHEMA = GUIDANCE_SCHEMA
    SCHEMA_VERSION = GUIDANCE_SCHEMA_VERSION

    def __post_init__(self) -> None:
        what = "guidance"
        for name in ("entry_in_image", "target_in_image", "entry_in_tracker", "target_in_tracker"):
            object.__setattr__(self, name, as_array(getattr(self, name), (3,), name, what))
        for name in (
            "standoff_mm",
            "predicted_entry_error_mm",
            "predicted_target_error_mm",
            "predicted_direction_error_deg",
        ):
            object.__setattr__(self, name, _finite_number(getattr(self, name), name, what))
        if self.insertion not in ("advance", "hold"):
            raise InvalidInputError(f"{what}: insertion must be advance or hold, got {self.insertion!r}")
        object.__setattr__(self, "stages", tuple(self.stages))

    @property
    def last(self) -> StageMeasurement | None:
        """The last stage measured (None: none was)."""
        return self.stages[-1] if self.stages else None

    @property
    def entry_error_mm(self) -> float | None:
        """The last stage's entry error, mm."""
        return None if self.last is None else self.last.entry_error_mm

    @property
    def target_error_mm(self) -> float | None:
        """The last stage's target error, mm."""
        return None if self.last is None else self.last.target_error_mm

    @property
    def direction_error_deg(self) -> float | None:
        """The last stage's direction error, deg."""
        return None if self.last is None else self.last.direction_error_deg

    def to_dict(self) -> dict[str, Any]:
        return plain(
            {
                "schema": self.SCHEMA,
                "schema_version": self.SCHEMA_VERSION,
                "units": {"length": "mm", "angle": "deg"},
                "plan": {
                    "name": self.plan_name,
                    "source": self.plan_source,
                    "image_frame": self.image_frame,
                    "entry_in_image_mm": self.entry_in_image,
                    "target_in_image_mm": self.target_in_image,
                    "tracker_frame": self.tracker_frame,
                    "entry_in_tracker_mm": self.entry_in_tracker,
                    "target_in_tracker_mm": self.target_in_tracker,
                    "registration": self.registration,
                },
                "insertion": self.insertion,
                "standoff_mm": self.standoff_mm,
                "stages_reached": [stage.stage for stage in self.stages],
                "stages": [stage.to_dict() for stage in self.stages],
                "entry_error_mm": self.entry_error_mm,
                "target_error_mm": self.target_error_mm,
                "direction_error_deg": self.direction_error_deg,
                "predicted": {
                    "entry_error_mm": self.predicted_entry_error_mm,
                    "target_error_mm": self.predicted_target_error_mm,
                    "direction_error_deg": self.predicted_direction_error_deg,
                    "contributions": dict(self.predicted_contributions),
                },
                "measured_by": self.measured_by,
                "devices": dict(self.devices),
                "simulated": self.simulated,
                "interrupted": self.interrupted,
                "interruption": self.interruption,
            }
        )

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], what: str = "guidance") -> GuidanceResult:
        check_schema(data, GUIDANCE_SCHEMA, (GUIDANCE_SCHEMA_VERSION,), what)
        plan = get_mapping(data, "plan", what)
        predicted = get_mapping(data, "predicted", what)
        stages = data.get("stages")
        if not isinstance(stages, list):
            raise InvalidInputError(f"{what}: 'stages' must be a list")
        devices = get_mapping(data, "devices", what, {})
        return cls(
            plan_name=get_str(plan, "name", what, ""),
            image_frame=get_str(plan, "image_frame", what),
            entry_in_image=plan.get("entry_in_image_mm"),  # type: ignore[arg-type]
            target_in_image=plan.get("target_in_image_mm"),  # type: ignore[arg-type]
            tracker_frame=get_str(plan, "tracker_frame", what),
            entry_in_tracker=plan.get("entry_in_tracker_mm"),  # type: ignore[arg-type]
            target_in_tracker=plan.get("target_in_tracker_mm"),  # type: ignore[arg-type]
            registration=get_str(plan, "registration", what, ""),
            insertion=get_str(data, "insertion", what),
            standoff_mm=get_number(data, "standoff_mm", what),
            stages=tuple(
                StageMeasurement.from_dict(s, f"{what} stage {k + 1}")
                if isinstance(s, Mapping)
                else _not_a_stage(what, k)
                for k, s in enumerate(stages)
            ),
            predicted_entry_error_mm=get_number(predicted, "entry_error_mm", what),
            predicted_target_error_mm=get_number(predicted, "target_error_mm", what),
            predicted_direction_error_deg=get_number(predicted, "direction_error_deg", what),
            predicted_contributions=get_mapping(predicted, "contributions", what, {}),
            measured_by=get_str(data, "measured_by", what, ""),
            devices={str(k): str(v) for k, v in devices.items()},
            simulated=bool(data.get("simulated", False)),
            interrupted=bool(data.get("interrupted", False)),
            interruption=get_str(data, "interruption", what, ""),
            plan_source=get_str(plan, "source", what, ""),
        )


def _not_a_stage(what: str, k: int) -> StageMeasurement:
    raise InvalidInputError(f"{what}: stage {k + 1} must be an object")


__all__ = ["GUIDANCE_SCHEMA", "GuidanceResult", "StageMeasurement"]
