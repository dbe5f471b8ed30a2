"""App function ``plan``: a calibration motion for the smallest predicted error at the site,
compared with the paper's sweeps."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spacecal.app._common import refuse_overwriting_inputs
from spacecal.app.result import CommandResult, paths
from spacecal.app.simulation import DEFAULT_SCENARIO
from spacecal.core.errors import InvalidInputError
from spacecal.io.results_json import write_json
from spacecal.planning.motion import planned_moves
from spacecal.planning.optimal import PlannerSettings, needle_site, paper_sweep_site_error, plan_for_site
from spacecal.planning.visibility import VisibilityModel
from spacecal.records import PlanRecord
from spacecal.sim.motion import plan_for_world
from spacecal.sim.scenario import load_scenario
from spacecal.sim.world import build_world


@dataclass(frozen=True)
class PlanSettings:
    """``spacecal plan``: a calibration motion for the smallest predicted error at the site.

    Attributes
    ----------
    budget_s : float
        Motion time allowed, s.
    scenario : str
        The (simulated) set-up to plan for: tracker placement, marker, robot and its home.
    frames_per_station : int
        Tracker frames held at each station.
    site_mm : (x, y, z) or None
        Where the needle tip will work, mm in the robot base; default the TCP at home.
    needle_path_mm : (entry x, y, z, target x, y, z) or None
        A planned needle path in the robot base, mm: the site is its target, with the needle
        along the path (instead of ``site_mm``).
    paper_sweeps : bool
        Write the paper's six sweeps (paper §4) from home as the plan instead.
    output : str or None
        Plan JSON to write (``docs/formats.md``); ``acquire --plan`` and ``simulate --plan`` run it.
    """

    budget_s: float = PlannerSettings.budget_s
    scenario: str = DEFAULT_SCENARIO
    frames_per_station: int = PlannerSettings.frames_per_station
    site_mm: tuple[float, float, float] | None = None
    paper_sweeps: bool = False
    output: str | None = None
    force: bool = False
    needle_path_mm: tuple[float, float, float, float, float, float] | None = None

    def __post_init__(self) -> None:
        if self.budget_s <= 0:
            raise InvalidInputError(f"--budget must be positive, got {self.budget_s:g} s")
        if not (math.isfinite(self.budget_s) and 1 <= self.budget_s <= 3600):
            raise InvalidInputError(f"--budget must be between 0 and 3600 s, got {self.budget_s}")
        if not 1 <= self.frames_per_station <= 1000:
            raise InvalidInputError(f"--frames-per-station must be 1..1000, got {self.frames_per_station}")
        if self.site_mm is not None:
            site = np.asarray(self.site_mm, dtype=float)
            if site.shape != (3,) or not np.all(np.isfinite(site)) or np.any(np.abs(site) > 5000):
                raise InvalidInputError("--site takes finite x,y,z in mm (robot base), each within +-5000 mm")
        if self.needle_path_mm is not None:
            path = np.asarray(self.needle_path_mm, dtype=float)
            if path.shape != (6,) or not np.all(np.isfinite(path)) or np.any(np.abs(path) > 5000):
                raise InvalidInputError(
                    "--needle-path takes the entry and target x,y,z in mm (robot base), each within +-5000 mm"
                )
            if self.site_mm is not None:
                raise InvalidInputError("give --site or --needle-path, not both")


def plan(settings: PlanSettings) -> CommandResult[PlanRecord]:
    """Plan the motion and compare it with the paper's sweeps.

    Returns
    -------
    CommandResult of PlanRecord
        The plan; the plan JSON written, if asked.
    """
    refuse_overwriting_inputs(settings.output, settings.scenario, force=settings.force, any_file=True)
    world = build_world(load_scenario(settings.scenario))
    visibility = VisibilityModel(world.tracker, world.marker, world.tracker_from_base, world.tcp_from_marker)
    planner = PlannerSettings(
        budget_s=settings.budget_s,
        frames_per_station=settings.frames_per_station,
        sphere_sigma_mm=world.scenario.white_noise_rms_mm / np.sqrt(3) or 0.1,
    )
    paper = plan_for_world(world)
    site: np.ndarray | None = None
    if settings.site_mm is not None:
        site = np.asarray(settings.site_mm, dtype=float)
    elif settings.needle_path_mm is not None:
        needle = np.asarray(settings.needle_path_mm, dtype=float)
        site = needle_site(world.nominal_model, world.home_joints_rad, needle[:3], needle[3:])
    paper_error = paper_sweep_site_error(world.nominal_model, paper, visibility, planner, site_in_base=site)
    common = dict(
        home_joints_rad=world.home_joints_rad,
        home_base_from_tcp=paper.home_base_from_tcp,
        robot_model=world.nominal_model.name,
        flange_from_tcp=world.nominal_model.flange_from_tcp,
        site_in_base=None if site is None else (site[:3, 3] if site.shape == (4, 4) else site),
        site_base_from_tcp=site if site is not None and site.shape == (4, 4) else None,
        paper_sweep={"motion_time_s": paper.motion_time_s, "predicted_error_mm": paper_error},
        scenario=world.scenario.name,
    )
    if settings.paper_sweeps:
        record = PlanRecord(
            kind="paper-sweeps",
            motion_time_s=paper.motion_time_s,
            moves=planned_moves(paper),
            predicted_error_mm=paper_error,
            **common,  # type: ignore[arg-type]
        )
    else:
        planned = plan_for_site(
            world.nominal_model,
            world.home_joints_rad,
            visibility,
            np.random.default_rng([world.scenario.seed, 7]),
            planner,
            site_in_base=site,
        )
        record = PlanRecord(
            kind="site-optimal",
            motion_time_s=planned.motion_time_s,
            moves=planned_moves(planned.plan),
            budget_s=planner.budget_s,
            predicted_error_mm=planned.predicted_error_mm,
            station_joints_rad=planned.station_joints_rad,
            **common,  # type: ignore[arg-type]
        )
    path = write_json(record.to_dict(), settings.output) if settings.output else None
    return plan_result(record, path, settings.scenario)


def plan_result(
    record: PlanRecord, path: Path | None = None, setup: str | None = None
) -> CommandResult[PlanRecord]:
    """The result of ``plan`` from its plan, the file it was written to (None: not written) and
    the set-up as it was named (default: the plan's scenario)."""
    setup = record.scenario if setup is None else setup
    site = (
        "the TCP at home"
        if record.site_in_base is None
        else "(" + ", ".join(f"{v:.1f}" for v in record.site_in_base) + ") mm"
    )
    if record.kind == "paper-sweeps":
        lines = [
            f"the paper's sweeps for the simulated set-up {setup}: {len(record.moves)} moves, "
            f"{record.motion_time_s:.1f} s of motion, predicted tip error at {site} "
            f"{record.predicted_error_mm:.3f} mm"
        ]
    else:
        lines = [
            f"planned for the simulated set-up {setup}: {len(record.station_joints_rad)} stations, "
            f"{record.motion_time_s:.1f} s of motion, predicted tip error at {site} "
            f"{record.predicted_error_mm:.3f} mm",
            f"paper's sweeps: {record.paper_sweep['motion_time_s']:.1f} s of motion, predicted tip error "
            f"there {record.paper_sweep['predicted_error_mm']:.3f} mm",
        ]
    lines.append(
        "(predicted for a joint fit of the calibration and the robot's DH corrections: "
        "spacecal calibrate --method kinematic)"
    )
    if path:
        lines.append(f"wrote {path}; run it with: spacecal acquire --plan {path} ... (or simulate --plan)")
    return CommandResult(record, paths(path), lines=tuple(lines))
