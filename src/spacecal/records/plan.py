"""The plan file written by ``spacecal plan`` (schema ``spacecal.plan``, version 1)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.records.fields import as_array, check_schema, get_mapping, get_number, plain


@dataclass(frozen=True)
class PlanRecord:
    """A planned calibration motion and its predicted error.

    Attributes
    ----------
    budget_s : float
        Motion time allowed, s.
    motion_time_s : float
        Motion time of the plan, s.
    predicted_error_mm : float
        Predicted needle-tip error at the site after ``--method kinematic``, mm.
    paper_sweep : dict
        ``motion_time_s`` and ``predicted_error_mm`` of the paper's sweeps for comparison.
    home_joints_rad : numpy.ndarray, shape (6,)
    station_joints_rad : numpy.ndarray, shape (S, 6)
    moves : list of dict
        Each move's label, duration and sampling (``MotionPlan.summary()``).
    simulated_setup : bool
        True when the set-up (tracker placement, marker) came from a simulated scenario.
    """

    budget_s: float
    motion_time_s: float
    predicted_error_mm: float
    paper_sweep: dict[str, Any]
    home_joints_rad: np.ndarray
    station_joints_rad: np.ndarray
    moves: list[dict[str, Any]] = field(default_factory=list)
    simulated_setup: bool = True

    def __post_init__(self) -> None:
        what = "plan"
        object.__setattr__(
            self, "home_joints_rad", as_array(self.home_joints_rad, (6,), "home_joints_rad", what)
        )
        object.__setattr__(
            self,
            "station_joints_rad",
            as_array(self.station_joints_rad, (None, 6), "station_joints_rad", what),
        )
        if not (self.budget_s > 0 and self.motion_time_s >= 0):
            raise InvalidInputError(f"{what}: budget_s must be positive and motion_time_s not negative")

    def to_dict(self) -> dict[str, Any]:
        return plain(
            {
                "schema": "spacecal.plan",
                "schema_version": 1,
                "units": {"angle": "rad", "time": "s", "length": "mm"},
                "simulated_setup": self.simulated_setup,
                "budget_s": self.budget_s,
                "motion_time_s": self.motion_time_s,
                "predicted_error_mm": self.predicted_error_mm,
                "paper_sweep": self.paper_sweep,
                "home_joints_rad": self.home_joints_rad,
                "station_joints_rad": self.station_joints_rad,
                "moves": self.moves,
            }
        )

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], what: str = "plan") -> PlanRecord:
        check_schema(data, "spacecal.plan", (1,), what)
        moves = data.get("moves", [])
        if not isinstance(moves, list) or not all(isinstance(m, Mapping) for m in moves):
            raise InvalidInputError(f"{what}: 'moves' must be a list of objects")
        simulated = data.get("simulated_setup", True)
        if not isinstance(simulated, bool):
            raise InvalidInputError(f"{what}: 'simulated_setup' must be true or false")
        return cls(
            budget_s=get_number(data, "budget_s", what),
            motion_time_s=get_number(data, "motion_time_s", what),
            predicted_error_mm=get_number(data, "predicted_error_mm", what),
            paper_sweep=get_mapping(data, "paper_sweep", what),
            home_joints_rad=as_array(data.get("home_joints_rad"), (6,), "home_joints_rad", what),
            station_joints_rad=as_array(
                data.get("station_joints_rad"), (None, 6), "station_joints_rad", what
            ),
            moves=[dict(m) for m in moves],
            simulated_setup=simulated,
        )
