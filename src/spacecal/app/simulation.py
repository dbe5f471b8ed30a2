"""App functions for the simulated system: ``simulate``, ``verify``, ``demo``, ``phantom``,
``scenario``. Everything here runs in spacecal's simulator and says so in what it returns."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from spacecal.app._common import guard_outputs, open_calibration
from spacecal.app.gate import default_box_half_mm, gate_plan, plan_workspace, world_visibility
from spacecal.core.errors import InvalidInputError
from spacecal.experiments.demo import DemoResult, run_demo
from spacecal.experiments.phantom import PhantomSettings, run_phantom_experiment
from spacecal.experiments.simulation import simulate as simulate_run
from spacecal.experiments.simulation import simulate_raw
from spacecal.experiments.verification import verify_in_simulation
from spacecal.io.atomic import atomic_path
from spacecal.io.csv_core import metadata_path
from spacecal.io.raw_streams import stream_paths, write_raw_recording
from spacecal.io.recording_csv import write_recording
from spacecal.io.results_json import read_json_object, write_calibration, write_json
from spacecal.planning.motion import MotionPlan, motion_plan_from_record
from spacecal.planning.motion_gate import MotionGateReport
from spacecal.records import CalibrationResult, PhantomResult, PlanRecord, VerificationResult
from spacecal.report.figures import plot_phantom_errors, plot_verification_errors
from spacecal.sim.motion import motion_limits, plan_for_world
from spacecal.sim.scenario import Scenario, load_scenario, scenario_from_dict
from spacecal.sim.world import World, build_world

#: The scenario every simulated command uses unless told otherwise.
DEFAULT_SCENARIO = "paper-realistic"


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

    paths: tuple[Path, ...]
    scenario: str
    seed: int
    samples: int
    visible: int = 0
    robot_states: int = 0
    motion_time_s: float = 0.0
    clock_offset_ms: float = 0.0
    messages: list[str] = field(default_factory=list)
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


def simulate(settings: SimulateSettings) -> SimulateOutput:
    """Simulate a calibration run and write its recording (paired CSV, or raw streams)."""
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
        return SimulateOutput(
            (robot_path, tracker_path),
            scenario.name,
            scenario.seed,
            samples=len(raw.tracker_time_s),
            robot_states=len(raw.robot_time_s),
            clock_offset_ms=settings.clock_offset_ms,
            gate=gate,
        )
    simulation = simulate_run(scenario, plan)
    recording = simulation.recording
    path = write_recording(recording, settings.output)
    return SimulateOutput(
        (path, metadata_path(path)),
        scenario.name,
        scenario.seed,
        samples=len(recording),
        visible=int(recording.visible.sum()),
        motion_time_s=simulation.plan.motion_time_s,
        messages=list(simulation.plan.messages),
        gate=gate,
    )


@dataclass(frozen=True)
class VerifySettings:
    """``spacecal verify``: the paper's verification experiment (§5.2) in simulation.

    Attributes
    ----------
    calibration : str
        Calibration JSON.
    scenario : str or None
        The simulated world to verify in; default: the one the calibration's data came from.
    points : int
        Needle poses (the paper: 15).
    output, figure : str or None
        Verification JSON and Fig. 7-style PNG to write.
    """

    calibration: str
    scenario: str | None = None
    points: int = 15
    output: str | None = None
    figure: str | None = None
    force: bool = False


@dataclass(frozen=True)
class VerifyOutput:
    """The verification and which simulated world it ran in."""

    result: VerificationResult
    scenario: str
    world_source: str
    paths: tuple[Path, ...] = ()
    notes: list[str] = field(default_factory=list)


def scenario_of_calibration(calibration: CalibrationResult) -> tuple[Scenario | None, str]:
    """The simulated scenario a calibration's data came from, and where that was found."""
    if calibration.provenance.scenario is not None:
        return scenario_from_dict(calibration.provenance.scenario), "the calibration's provenance"
    recording = calibration.provenance.recording
    meta = metadata_path(recording) if recording else None
    if meta is not None and meta.is_file():
        data = read_json_object(meta, "recording metadata")
        if isinstance(data.get("scenario"), dict):
            return scenario_from_dict(data["scenario"]), f"the recording metadata {meta}"
    return None, ""


def verify(settings: VerifySettings) -> VerifyOutput:
    """Run the verification experiment for a calibration in its simulated world."""
    if not 1 <= settings.points <= 1000:
        raise InvalidInputError(f"--points must be 1..1000, got {settings.points}")
    guard_outputs(
        [settings.output, settings.figure],
        [settings.calibration, settings.scenario],
        settings.force,
        any_file=True,
    )
    calibration, notes = open_calibration(settings.calibration, "verify")
    if settings.scenario is not None:
        scenario = load_scenario(settings.scenario)
        source = "given"
        if calibration.provenance.simulated is False:
            notes.append(
                "this calibration came from real devices: it is scored against the simulated world "
                f"{scenario.name!r}, which is unrelated to the real set-up"
            )
    else:
        found, source = scenario_of_calibration(calibration)
        if found is None:
            raise InvalidInputError(
                "no simulated world for this calibration (real or imported data?): verify runs only in "
                "simulation; pass --scenario to score it against a simulated world anyway"
            )
        scenario = found
    result = verify_in_simulation(calibration, scenario, settings.points)
    result = dataclasses.replace(result, simulated=True, scenario=scenario.name)
    paths = []
    if settings.output:
        paths.append(write_json(result.to_dict(), settings.output))
    if settings.figure:
        with atomic_path(settings.figure) as temporary:
            plot_verification_errors(result.position_error_mm, result.posture_error_deg, temporary)
        paths.append(Path(settings.figure))
    return VerifyOutput(result, scenario.name, source, tuple(paths), notes)


@dataclass(frozen=True)
class DemoSettings:
    """``spacecal demo``: simulate, calibrate (paper and ML) and verify on one scenario."""

    scenario: str = DEFAULT_SCENARIO
    out: str | None = None
    force: bool = False


@dataclass(frozen=True)
class DemoOutput:
    result: DemoResult
    paths: tuple[Path, ...] = ()


def demo(settings: DemoSettings) -> DemoOutput:
    """The whole chain on the simulated system, with a table beside the paper's figures."""
    names = (
        "recording.csv",
        "recording.meta.json",
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
        recording_path = write_recording(result.simulation.recording, out / "recording.csv")
        calibration = result.calibration.replace(
            provenance=dataclasses.replace(
                result.calibration.provenance,
                recording=str(recording_path.resolve()),
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
    return DemoOutput(result, tuple(paths))


@dataclass(frozen=True)
class PhantomCommandSettings:
    """``spacecal phantom``: the paper's phantom needle biopsy (§5.3) in simulation."""

    scenario: str = DEFAULT_SCENARIO
    method: str = "paper"
    cases: int = PhantomSettings.cases
    output: str | None = None
    figure: str | None = None
    force: bool = False


def phantom(settings: PhantomCommandSettings) -> tuple[PhantomResult, tuple[Path, ...]]:
    """Run the phantom experiment; returns its result and the files written."""
    if not 1 <= settings.cases <= 100:
        raise InvalidInputError(f"--cases must be 1..100, got {settings.cases}")
    guard_outputs([settings.output, settings.figure], [settings.scenario], settings.force, any_file=True)
    result = run_phantom_experiment(
        load_scenario(settings.scenario), settings.method, PhantomSettings(cases=settings.cases)
    )
    paths = []
    if settings.output:
        paths.append(write_json(result.to_dict(), settings.output))
    if settings.figure:
        with atomic_path(settings.figure) as temporary:
            plot_phantom_errors(
                result.entry_error_mm, result.target_error_mm, result.direction_error_deg, temporary
            )
        paths.append(Path(settings.figure))
    return result, tuple(paths)


def scenario(preset: str = DEFAULT_SCENARIO) -> dict[str, Any]:
    """A scenario as JSON-ready values, to copy and edit (``spacecal scenario``)."""
    return load_scenario(preset).to_dict()
