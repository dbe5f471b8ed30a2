"""The plan file: a calibration motion that ``spacecal acquire --plan`` and ``spacecal simulate
--plan`` run (schema ``spacecal.plan``, version 2; version 1, which held only a summary of each
move, is read for its numbers but cannot be run). The format is documented in ``docs/formats.md``.
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

PLAN_SCHEMA = "spacecal.plan"
PLAN_VERSION = 2
#: Kinds of plan: the paper's six sweeps (paper §4) or stations chosen for a site.
PLAN_KINDS = ("paper-sweeps", "site-optimal")


@dataclass(frozen=True)
class PlannedMove:
    """One move of a plan: a straight TCP move (or a hold when ``start`` equals ``end``).

    Attributes
    ----------
    label : str
        Segment label written into the recording.
    start, end : numpy.ndarray, shape (4, 4)
        ``base_from_tcp`` at the ends, mm.
    duration_s, accel_time_s : float
        Planned duration and the time spent accelerating at each end (trapezoid), s.
    sample_period_s : float
        Tracker sampling period during the move, s; 0 for a transit that is not recorded.
    """

    label: str
    start: np.ndarray
    end: np.ndarray
    duration_s: float
    accel_time_s: float
    sample_period_s: float

    def to_dict(self) -> dict[str, Any]:
        return plain(
            {
                "label": self.label,
                "start_base_from_tcp": self.start,
                "end_base_from_tcp": self.end,
                "duration_s": self.duration_s,
                "accel_time_s": self.accel_time_s,
                "sample_period_s": self.sample_period_s,
            }
        )

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], what: str) -> PlannedMove:
        label = get_str(data, "label", what)
        duration = get_number(data, "duration_s", what)
        accel = get_number(data, "accel_time_s", what)
        period = get_number(data, "sample_period_s", what)
        if not (0 <= duration <= 3600 and 0 <= accel <= duration / 2 + 1e-9 and 0 <= period <= 60):
            raise InvalidInputError(
                f"{what}: needs 0 <= duration_s <= 3600, 0 <= accel_time_s <= duration_s/2 and "
                "0 <= sample_period_s <= 60"
            )
        return cls(
            label,
            as_transform(data.get("start_base_from_tcp"), "start_base_from_tcp", what),
            as_transform(data.get("end_base_from_tcp"), "end_base_from_tcp", what),
            duration,
            accel,
            period,
        )


@dataclass(frozen=True)
class PlanRecord:
    """A planned calibration motion, runnable on any devices, and its predicted error.

    Attributes
    ----------
    kind : str
        ``paper-sweeps`` or ``site-optimal``.
    motion_time_s : float
        Motion time of the plan, s.
    home_joints_rad : numpy.ndarray, shape (6,)
        The configuration the plan starts and ends at; the robot must stand there.
    home_base_from_tcp : numpy.ndarray, shape (4, 4)
        The TCP pose at home, mm.
    robot_model : str
        The robot model the plan was made for (reach, joint limits).
    flange_from_tcp : numpy.ndarray, shape (4, 4)
        The tool (TCP in the flange frame, mm) the plan was made for.
    moves : list of PlannedMove
        In execution order; empty for a version-1 file (not runnable).
    site_in_base : numpy.ndarray, shape (3,), or None
        The point (mm, base frame) the plan minimises the error at; None: the TCP at home.
    site_base_from_tcp : numpy.ndarray, shape (4, 4), or None
        The needle's pose at the site when planned for a needle path (its target), mm.
    budget_s : float or None
        Motion time allowed, s (site-optimal plans).
    predicted_error_mm : float or None
        Predicted needle-tip error at the site after ``--method kinematic``, mm.
    paper_sweep : dict
        ``motion_time_s`` and ``predicted_error_mm`` of the paper's sweeps, for comparison.
    station_joints_rad : numpy.ndarray, shape (S, 6)
        The stations of a site-optimal plan (empty for the paper's sweeps).
    simulated_setup : bool
        True when the set-up (tracker placement, marker, home) came from a simulated scenario.
    scenario : str or None
        That scenario's name.
    workspace_box_mm : numpy.ndarray, shape (6,), or None
        ``xmin, xmax, ymin, ymax, zmin, zmax`` in the robot base (mm) the TCP must stay in;
        None: the motion gate's default box around home.
    """

    kind: str
    motion_time_s: float
    home_joints_rad: np.ndarray
    home_base_from_tcp: np.ndarray
    robot_model: str
    flange_from_tcp: np.ndarray
    moves: list[PlannedMove] = field(default_factory=list)
    site_in_base: np.ndarray | None = None
    site_base_from_tcp: np.ndarray | None = None
    budget_s: float | None = None
    predicted_error_mm: float | None = None
    paper_sweep: dict[str, Any] = field(default_factory=dict)
    station_joints_rad: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))
    simulated_setup: bool = True
    scenario: str | None = None
    workspace_box_mm: np.ndarray | None = None

    def __post_init__(self) -> None:
        what = "plan"
        if self.kind not in PLAN_KINDS:
            raise InvalidInputError(f"{what}: kind must be one of {', '.join(PLAN_KINDS)}, got {self.kind!r}")
        object.__setattr__(
            self, "home_joints_rad", as_array(self.home_joints_rad, (6,), "home_joints_rad", what)
        )
        object.__setattr__(
            self, "home_base_from_tcp", as_transform(self.home_base_from_tcp, "home_base_from_tcp", what)
        )
        object.__setattr__(
            self, "flange_from_tcp", as_transform(self.flange_from_tcp, "flange_from_tcp", what)
        )
        object.__setattr__(
            self,
            "station_joints_rad",
            as_array(self.station_joints_rad, (None, 6), "station_joints_rad", what),
        )
        if self.site_in_base is not None:
            object.__setattr__(self, "site_in_base", as_array(self.site_in_base, (3,), "site_in_base", what))
        if self.site_base_from_tcp is not None:
            object.__setattr__(
                self, "site_base_from_tcp", as_transform(self.site_base_from_tcp, "site_base_from_tcp", what)
            )
        if self.workspace_box_mm is not None:
            box = as_array(self.workspace_box_mm, (6,), "workspace_box_mm", what)
            if np.any(box[0::2] >= box[1::2]):
                raise InvalidInputError(
                    f"{what}: workspace_box_mm is xmin, xmax, ymin, ymax, zmin, zmax with each min < max"
                )
            object.__setattr__(self, "workspace_box_mm", box)
        if not (math.isfinite(self.motion_time_s) and self.motion_time_s >= 0):
            raise InvalidInputError(f"{what}: motion_time_s must not be negative")
        if self.budget_s is not None and not self.budget_s > 0:
            raise InvalidInputError(f"{what}: budget_s must be positive")

    @property
    def runnable(self) -> bool:
        """True when the file holds every move (version 2)."""
        return bool(self.moves)

    def to_dict(self) -> dict[str, Any]:
        return plain(
            {
                "schema": PLAN_SCHEMA,
                "schema_version": PLAN_VERSION,
                "units": {"angle": "rad", "time": "s", "length": "mm"},
                "kind": self.kind,
                "simulated_setup": self.simulated_setup,
                "scenario": self.scenario,
                "robot_model": self.robot_model,
                "flange_from_tcp": self.flange_from_tcp,
                "home_joints_rad": self.home_joints_rad,
                "home_base_from_tcp": self.home_base_from_tcp,
                "site_in_base_mm": self.site_in_base,
                "site_base_from_tcp": self.site_base_from_tcp,
                "budget_s": self.budget_s,
                "motion_time_s": self.motion_time_s,
                "predicted_error_mm": self.predicted_error_mm,
                "paper_sweep": self.paper_sweep,
                "station_joints_rad": self.station_joints_rad,
                "workspace_box_mm": self.workspace_box_mm,
                "moves": [move.to_dict() for move in self.moves],
            }
        )

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], what: str = "plan") -> PlanRecord:
        version = check_schema(data, PLAN_SCHEMA, (1, PLAN_VERSION), what)
        moves = data.get("moves", [])
        if not isinstance(moves, list) or not all(isinstance(m, Mapping) for m in moves):
            raise InvalidInputError(f"{what}: 'moves' must be a list of objects")
        simulated = data.get("simulated_setup", True)
        if not isinstance(simulated, bool):
            raise InvalidInputError(f"{what}: 'simulated_setup' must be true or false")
        if version == 1:  # a summary only: no poses to run, no tool or model recorded
            return cls(
                kind="site-optimal",
                motion_time_s=get_number(data, "motion_time_s", what),
                home_joints_rad=as_array(data.get("home_joints_rad"), (6,), "home_joints_rad", what),
                home_base_from_tcp=np.eye(4),
                robot_model="unknown",
                flange_from_tcp=np.eye(4),
                budget_s=get_number(data, "budget_s", what),
                predicted_error_mm=get_number(data, "predicted_error_mm", what),
                paper_sweep=get_mapping(data, "paper_sweep", what),
                station_joints_rad=as_array(
                    data.get("station_joints_rad"), (None, 6), "station_joints_rad", what
                ),
                simulated_setup=simulated,
            )
        if not moves:
            raise InvalidInputError(f"{what}: the plan has no moves")
        if len(moves) > 100_000:
            raise InvalidInputError(f"{what}: {len(moves)} moves is more than any plan holds")
        site = data.get("site_in_base_mm")
        site_pose = data.get("site_base_from_tcp")
        scenario = data.get("scenario")
        if scenario is not None and not isinstance(scenario, str):
            raise InvalidInputError(f"{what}: 'scenario' must be a name or null")
        budget = data.get("budget_s")
        predicted = data.get("predicted_error_mm")
        box = data.get("workspace_box_mm")
        return cls(
            kind=get_str(data, "kind", what),
            motion_time_s=get_number(data, "motion_time_s", what),
            home_joints_rad=as_array(data.get("home_joints_rad"), (6,), "home_joints_rad", what),
            home_base_from_tcp=as_transform(data.get("home_base_from_tcp"), "home_base_from_tcp", what),
            robot_model=get_str(data, "robot_model", what),
            flange_from_tcp=as_transform(data.get("flange_from_tcp"), "flange_from_tcp", what),
            moves=[PlannedMove.from_dict(m, f"{what}: move {k + 1}") for k, m in enumerate(moves)],
            site_in_base=None if site is None else as_array(site, (3,), "site_in_base_mm", what),
            site_base_from_tcp=None
            if site_pose is None
            else as_transform(site_pose, "site_base_from_tcp", what),
            budget_s=None if budget is None else get_number(data, "budget_s", what),
            predicted_error_mm=None if predicted is None else get_number(data, "predicted_error_mm", what),
            paper_sweep=get_mapping(data, "paper_sweep", what, default={}),
            station_joints_rad=as_array(
                data.get("station_joints_rad") or np.zeros((0, 6)), (None, 6), "station_joints_rad", what
            ),
            simulated_setup=simulated,
            scenario=scenario,
            workspace_box_mm=None if box is None else as_array(box, (6,), "workspace_box_mm", what),
        )
