"""App functions for the simulated system: ``simulate``, ``verify``, ``demo``, ``phantom``,
``scenario``. Everything here runs in spacecal's simulator and says so in what it returns."""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from spacecal.app._common import guard_outputs
from spacecal.app.gate import default_box_half_mm, gate_plan, plan_workspace, world_visibility
from spacecal.app.phantom_devices import phantom_on_devices
from spacecal.app.phantom_settings import PhantomCommandSettings
from spacecal.app.result import CommandResult, note_lines
from spacecal.core.errors import InvalidInputError
from spacecal.experiments.demo import DemoResult, run_demo
from spacecal.experiments.phantom import PhantomSettings, phantom_table, run_phantom_experiment
from spacecal.experiments.simulation import simulate as simulate_run
from spacecal.experiments.simulation import simulate_raw
from spacecal.io.atomic import atomic_path
from spacecal.io.recordings import (
    metadata_path,
    open_path,
    paired_files,
    recording_in,
    stream_paths,
    write_raw_recording,
    write_recording,
)
from spacecal.io.results_json import read_json_object, write_calibration, write_json
from spacecal.planning.motion import MotionPlan, motion_plan_from_record
from spacecal.planning.motion_gate import MotionGateReport
from spacecal.records import PhantomResult, PlanRecord
from spacecal.report.figures import plot_phantom_errors, plot_verification_errors
from spacecal.sim.motion import motion_limits, plan_for_world
from spacecal.sim.scenario import DEFAULT_SCENARIO, Scenario, load_scenario
from spacecal.sim.world import World, build_world


@dataclass(frozen=True)
class SimulateSettings:
    """``spacecal simulate``: run the scenario's calibration motion on the simulated system.

    Attributes
    ----------
    output : str
        Recording CSV to write (with ``raw``: the stem of the two stream files).
    scenario : str
        Preset name or scenario JSON file.
    seed : int or None
        Overrides the scenario's seed.
    raw : bool
        Write the two raw streams (``STEM.robot.csv``, ``STEM.tracker.csv``) instead.
    clock_offset_ms : float
        With ``raw``: how far the robot clock runs ahead of the tracker's, ms.
    plan : str or None
        A plan file (``spacecal plan -o``) to run instead of the paper's sweeps; it must have
        been made for this scenario's robot, tool and home.
    """

    output: str
    scenario: str = DEFAULT_SCENARIO
    seed: int | None = None
    raw: bool = False
    clock_offset_ms: float = 0.0
    force: bool = False
    plan: str | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.clock_offset_ms) and abs(self.clock_offset_ms) <= 10_000):
            raise InvalidInputError(
                f"--clock-offset-ms must be within +-10000 ms, got {self.clock_offset_ms}"
            )
        check_seed(self.seed)


@dataclass(frozen=True)
class SimulateOutput:
    """What ``simulate`` wrote."""

    scenario: str
    seed: int
    samples: int
    visible: int = 0
    robot_states: int = 0
    motion_time_s: float = 0.0
    clock_offset_ms: float = 0.0
    simulated: bool = True
    #: What the motion gate checked before the simulated robot moved.
    gate: MotionGateReport | None = None


def check_seed(seed: int | None) -> None:
    """Refuse a seed numpy cannot take."""
    if seed is not None and not 0 <= seed < 2**32:
        raise InvalidInputError(f"--seed must be a whole number 0..{2**32 - 1}, got {seed}")


def scenario_with_seed(name: str, seed: int | None) -> Scenario:
    """A scenario (preset or file) with its seed overridden when ``seed`` is given."""
    scenario = load_scenario(name)
    if seed is not None:
        check_seed(seed)
        scenario = dataclasses.replace(scenario, seed=seed)
    return scenario


def plan_for_scenario(path: str, scenario: Scenario) -> MotionPlan:
    """The runnable plan in a plan file, refused unless made for the scenario's robot, tool and home."""
    record = PlanRecord.from_dict(read_json_object(path, "plan"), what=path)
    plan = motion_plan_from_record(record)
    world = build_world(scenario)
    model = world.nominal_model
    if (
        record.robot_model != model.name
        or not np.allclose(record.flange_from_tcp, model.flange_from_tcp, atol=1e-6)
        or not np.allclose(record.home_joints_rad, world.home_joints_rad, atol=1e-6)
    ):
        raise InvalidInputError(
            f"{path} was planned for another set-up (robot, tool or home) than scenario '{scenario.name}'; "
            f"plan it with: spacecal plan --scenario {scenario.name}"
        )
    return plan


def simulation_gate(world: World, plan: MotionPlan, from_file: bool) -> MotionGateReport:
    """Pass a simulated run's plan through the motion gate, as ``acquire`` does on hardware: from
    the home the simulated robot starts at, with the scenario's limits and its tracker's view.
    The default box grows to cover the scenario's own sweeps or stations, not a plan file's."""
    s = world.scenario
    reach = (s.translation_mm / 2, s.station_cube_mm / 2 if s.motion == "stations" else 0.0)
    model = world.controller_model
    return gate_plan(
        plan,
        model,
        None,
        motion_limits(s),
        plan_workspace(
            model, plan, None, default_box_half_mm() if from_file else default_box_half_mm(*reach)
        ),
        visibility=world_visibility(world),
        commanded_by=f"the scenario's linear_speed_mm_s and angular_speed_deg_s ({s.name})",
    )


def simulate(settings: SimulateSettings) -> CommandResult[SimulateOutput]:
    """Simulate a calibration run and write its recording (paired CSV, or raw streams).

    Returns
    -------
    CommandResult of SimulateOutput
        What was simulated; the recording (and its metadata) or the two streams written.
    """
    stem = settings.output[:-4] if settings.output.endswith(".csv") else settings.output
    outputs: list[str | Path | None] = (
        list(stream_paths(stem)) if settings.raw else [settings.output, metadata_path(settings.output)]
    )
    guard_outputs(outputs, [settings.scenario, settings.plan], settings.force)
    scenario = scenario_with_seed(settings.scenario, settings.seed)
    world = build_world(scenario)
    plan = plan_for_world(world) if settings.plan is None else plan_for_scenario(settings.plan, scenario)
    gate = simulation_gate(world, plan, from_file=settings.plan is not None)
    if settings.raw:
        raw, _ = simulate_raw(scenario, settings.clock_offset_ms / 1000.0, plan)
        robot_path, tracker_path = write_raw_recording(raw, stem)
        out = SimulateOutput(
            scenario.name,
            scenario.seed,
            samples=len(raw.tracker_time_s),
            robot_states=len(raw.robot_time_s),
            clock_offset_ms=settings.clock_offset_ms,
            gate=gate,
        )
        return simulate_result(out, (robot_path, tracker_path), ())
    simulation = simulate_run(scenario, plan)
    recording = simulation.recording
    path = write_recording(recording, settings.output)
    out = SimulateOutput(
        scenario.name,
        scenario.seed,
        samples=len(recording),
        visible=int(recording.visible.sum()),
        motion_time_s=simulation.plan.motion_time_s,
        gate=gate,
    )
    return simulate_result(out, (path, metadata_path(path)), tuple(simulation.plan.messages))


def simulate_result(
    out: SimulateOutput, files: tuple[Path, ...], notes: tuple[str, ...]
) -> CommandResult[SimulateOutput]:
    """The result of ``simulate`` from what it simulated, the files written (the recording and
    its metadata, or the robot and tracker streams) and its notes."""
    if out.robot_states:
        lines = [
            f"wrote {files[0]} ({out.robot_states} robot states) and {files[1]} ({out.samples} tracker "
            f"frames); robot clock {out.clock_offset_ms} ms ahead (simulated)"
        ]
    else:
        lines = [
            f"wrote {files[0]} ({out.samples} samples, {out.visible} with the marker visible) and {files[1]}",
            f"simulated: scenario {out.scenario}, seed {out.seed}; planned motion time "
            f"{out.motion_time_s:.1f} s",
            *([out.gate.summary()] if out.gate is not None else []),
            *note_lines(notes),
        ]
    return CommandResult(out, files, notes, tuple(lines))


@dataclass(frozen=True)
class DemoSettings:
    """``spacecal demo``: simulate, calibrate (paper and ML) and verify on one scenario."""

    scenario: str = DEFAULT_SCENARIO
    out: str | None = None
    force: bool = False


def demo(settings: DemoSettings) -> CommandResult[DemoResult]:
    """The whole chain on the simulated system, with a table beside the paper's figures.

    Returns
    -------
    CommandResult of DemoResult
        The simulation, calibrations and verification; with ``out``, the files written there.
    """
    names = (
        *(path.name for path in paired_files(recording_in("."))),
        "calibration.json",
        "verification.json",
        "verification_errors.png",
    )
    if settings.out:
        guard_outputs(
            [Path(settings.out) / n for n in names], [settings.scenario], settings.force, any_file=True
        )
    result = run_demo(load_scenario(settings.scenario))
    paths: list[Path] = []
    if settings.out:
        out = Path(settings.out)
        recording_path = write_recording(result.simulation.recording, recording_in(out))
        calibration = result.calibration.replace(
            provenance=dataclasses.replace(
                result.calibration.provenance,
                source=open_path(recording_path).source,
                simulated=True,
                scenario=result.simulation.world.scenario.to_dict(),
            )
        )
        paths += [
            recording_path,
            write_calibration(calibration, out / "calibration.json"),
            write_json(result.verification.to_dict(), out / "verification.json"),
        ]
        with atomic_path(out / "verification_errors.png") as temporary:
            plot_verification_errors(
                result.verification.position_error_mm, result.verification.posture_error_deg, temporary
            )
        paths.append(out / "verification_errors.png")
    lines = result.table().split("\n")
    if paths:
        lines += ["", f"wrote {', '.join(p.name for p in paths)} to {settings.out}"]
    return CommandResult(result, tuple(paths), lines=tuple(lines))


def phantom(settings: PhantomCommandSettings) -> CommandResult[PhantomResult]:
    """Run the phantom experiment: in simulation, or on the devices (``robot``, ``tracker``).

    Returns
    -------
    CommandResult of PhantomResult
        The errors of each needle path; the results JSON and figure written, if asked.
    """
    if settings.robot is not None:
        result, steps = phantom_on_devices(settings)
    else:
        guard_outputs([settings.output, settings.figure], [settings.scenario], settings.force, any_file=True)
        result = run_phantom_experiment(
            load_scenario(settings.scenario), settings.method, PhantomSettings(cases=settings.cases)
        )
        steps = []
    paths = []
    if settings.output:
        paths.append(write_json(result.to_dict(), settings.output))
    if settings.figure:
        with atomic_path(settings.figure) as temporary:
            plot_phantom_errors(
                result.entry_error_mm, result.target_error_mm, result.direction_error_deg, temporary
            )
        paths.append(Path(settings.figure))
    lines = [
        *steps,
        *phantom_table(result).split("\n"),
        "(simulated; measured errors include the second CT's localisation error, as in the paper's "
        "experiment)",
        *(f"wrote {path}" for path in paths),
    ]
    return CommandResult(result, tuple(paths), lines=tuple(lines))


def scenario(preset: str = DEFAULT_SCENARIO) -> CommandResult[dict[str, Any]]:
    """A scenario as JSON-ready values, to copy and edit (``spacecal scenario``).

    Returns
    -------
    CommandResult of dict
        The scenario's values; ``lines`` are its JSON text.
    """
    values = load_scenario(preset).to_dict()
    return CommandResult(values, lines=tuple(json.dumps(values, indent=2).splitlines()))
