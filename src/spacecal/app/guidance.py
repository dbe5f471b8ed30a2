"""``spacecal guide``: put the needle where a 3D Slicer plan says, on the robot (paper §5.3).

A needle path planned on CT (entry, target; a Slicer markups file, or sent live by Slicer over
OpenIGTLink) is registered to the tracker (a Slicer transform file, or fiducials touched with
the pointer), mapped through the calibration into the robot base, and the robot places the
needle in stages:

* ``standoff``: the tip on the planned axis ``standoff_mm`` before the entry, along entry to
  target;
* ``insert``: from the standoff straight along the axis, to the target (``advance``: the robot
  inserts) or to the entry (``hold``: the guide holds on the axis for a manual insertion).

At each stage's end the robot holds, the tracker measures the needle (through the calibrated
marker, as ``verify`` does: not independent of the calibration), and the entry, target and
direction errors (:mod:`spacecal.workflows.guidance`) are printed beside the predicted error
(:func:`spacecal.planning.needle.plan_needle`: the calibration's stated error, the
registration's TRE and the robot's repeatability, in quadrature).

Every motion runs through the motion session (:mod:`spacecal.app.motion_session`): the whole
motion is gated before anything moves; a real robot needs ``--confirm-robot-motion``, and its
insertion ``--confirm-insertion`` too; an interrupted guidance writes what it measured, says so,
and never moves the robot again.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from spacecal.adapters.slicer_link import SLICER_LINK_DEFAULT_PORT, SlicerLink
from spacecal.app._common import calibration_motion, guard_outputs, open_calibration
from spacecal.app.devices import DeviceSettings
from spacecal.app.motion_session import MotionSession, motion_session
from spacecal.app.motion_settings import MotionSettings, WorkspaceBox
from spacecal.app.result import CommandResult, note_lines
from spacecal.app.slicer_plan import PlanFromSlicerSettings, read_plan, read_registration
from spacecal.app.verification import MEASURED_BY_MARKER, commanded_tcp_poses
from spacecal.core.errors import DeviceError, InvalidInputError, SpacecalError, UnreachableError
from spacecal.core.strict_numbers import decimal, integer
from spacecal.core.text import sanitize_for_terminal
from spacecal.geometry.transforms import apply_transform, invert_transform, mean_transform
from spacecal.io.results_json import write_json
from spacecal.models.robot_errors import REPEATABILITY_TO_AXIS_SD
from spacecal.planning.motion import MotionPlan
from spacecal.planning.motion_gate import MotionGateReport
from spacecal.planning.needle import plan_needle
from spacecal.records import CalibrationResult
from spacecal.records.guidance import GuidanceResult, StageMeasurement
from spacecal.records.needle_plan import ImageRegistration, NeedlePlan
from spacecal.registration.image_fiducials import DEFAULT_MAX_FRE_MM, pointer_predicted_tre
from spacecal.sim.devices import SimulatedTracker
from spacecal.workflows.acquisition import SampleCallback
from spacecal.workflows.guidance import (
    AT_STANDOFF_DEG,
    AT_STANDOFF_MM,
    INSERTIONS,
    NeedleAxis,
    at_pose,
    needle_errors,
    stage_place_mm,
    stage_plan,
    stage_pose,
)
from spacecal.workflows.held_poses import HeldPose
from spacecal.workflows.plan_frames import LocatedPlan, locate_plan

#: The stages ``--stage`` takes, and what each runs.
STAGE_CHOICES = {"standoff": ("standoff",), "insert": ("insert",), "all": ("standoff", "insert")}
#: Accepted standoff distances, mm (on the axis before the entry: above the skin, within reach).
STANDOFF_RANGE_MM = (1.0, 200.0)
#: A real robot's positioning repeatability when the devices do not state it, mm (UR5e and
#: UR10e data sheets: +-0.03 mm; CB3 arms +-0.1 mm: the larger, to predict no better than is
#: known).
ROBOT_REPEATABILITY_MM = 0.1
#: How a hold's stop ends its line; guidance keeps what earlier stages measured, so says so.
HOLD_STOPPED = "; the robot was stopped and nothing was logged"
#: How long to wait for Slicer's plan by default, s.
SLICER_TIMEOUT_S = 120.0


@dataclass(frozen=True)
class GuideSettings:
    """``spacecal guide``: place the needle on a planned path with the robot (paper §5.3).

    Attributes
    ----------
    plan : str or None
        Slicer markups file (``.mrk.json``) or plan JSON (``plan-from-slicer -o``); None with
        ``slicer_live`` (the plan comes from Slicer).
    calibration : str
        Calibration JSON.
    registration, registration_maps, fiducials, touched, max_fre_mm, accept_high_fre
        The image registration, as for ``plan-from-slicer``.
    coordinate_system, entry_label, target_label, markup
        Reading the markups file, as for ``plan-from-slicer``.
    devices : DeviceSettings
        The robot and tracker (``sim``: the simulated ones of the calibration's world).
    scenario : str or None
        The simulated world (default: the calibration's).
    stage : {"standoff", "insert", "all"}
        ``insert`` alone needs the robot at this plan's standoff already.
    insertion : {"advance", "hold"}
    standoff_mm : float
    confirm_robot_motion, confirm_insertion : bool
        A real robot moves only with the first; its insertion also needs the second.
    dry_run : bool
        Gate the motion and predict the error; nothing moves.
    workspace_box, simulated_speed
        As for ``acquire``.
    frames_per_pose : int
        Tracker frames averaged at each stage's end.
    slicer_live : int or None
        Serve OpenIGTLink for Slicer on this port (0: any free one): the plan comes from Slicer
        and the needle's pose streams back.
    slicer_timeout_s : float
        How long to wait for Slicer's plan, s.
    accept_edited, accept_other_devices : bool
    output : str or None
        Guidance JSON to write.
    force : bool
    """

    plan: str | None
    calibration: str
    registration: str | None = None
    registration_maps: str | None = None
    fiducials: str | None = None
    touched: str | None = None
    max_fre_mm: float = DEFAULT_MAX_FRE_MM
    accept_high_fre: bool = False
    coordinate_system: str | None = None
    entry_label: str | None = None
    target_label: str | None = None
    markup: str | None = None
    devices: DeviceSettings = field(default_factory=DeviceSettings)
    scenario: str | None = None
    stage: str = "all"
    insertion: str = "advance"
    standoff_mm: float = 20.0
    confirm_robot_motion: bool = False
    confirm_insertion: bool = False
    dry_run: bool = False
    workspace_box: WorkspaceBox | None = None
    simulated_speed: float | None = None
    frames_per_pose: int = 10
    slicer_live: int | None = None
    slicer_timeout_s: float = SLICER_TIMEOUT_S
    accept_edited: bool = False
    accept_other_devices: bool = False
    output: str | None = None
    force: bool = False

    #: The command line's flag and argparse options of the fields only this command has (the
    #: registration's and the markups' are ``plan-from-slicer``'s).
    FLAGS: ClassVar[dict[str, tuple[str, dict[str, Any]]]] = {
        **{
            k: v
            for k, v in PlanFromSlicerSettings.FLAGS.items()
            if k not in ("plan", "calibration", "output")
        },
        "plan": ("plan", dict(nargs="?", help="Slicer markups file (.mrk.json); none with --slicer-live")),
        "calibration": ("calibration", dict(help="calibration JSON")),
        "scenario": ("--scenario", dict(help="simulated world (default: the calibration's)")),
        "stage": (
            "--stage",
            dict(choices=tuple(STAGE_CHOICES), help="standoff, insert (from the standoff) or all (default)"),
        ),
        "insertion": (
            "--insertion",
            dict(
                choices=INSERTIONS,
                help="advance: the robot inserts to the target (default); hold: the guide holds at the entry",
            ),
        ),
        "standoff_mm": ("--standoff-mm", dict(type=decimal, help="standoff before the entry, mm (20)")),
        "confirm_insertion": (
            "--confirm-insertion",
            dict(action="store_true", help="required for a real robot's insertion along the needle"),
        ),
        "dry_run": (
            "--dry-run",
            dict(action="store_true", help="gate the motion and predict; nothing moves"),
        ),
        "frames_per_pose": (
            "--frames-per-pose",
            dict(type=integer, help="tracker frames averaged at each stage (10)"),
        ),
        "slicer_live": (
            "--slicer-live",
            dict(
                type=integer,
                metavar="PORT",
                help=f"serve OpenIGTLink for Slicer (e.g. {SLICER_LINK_DEFAULT_PORT}): the plan from "
                "Slicer, the needle's pose back to it",
            ),
        ),
        "slicer_timeout_s": (
            "--slicer-timeout-s",
            dict(type=decimal, help=f"wait this long for Slicer's plan, s ({SLICER_TIMEOUT_S:g})"),
        ),
        "simulated_speed": (
            "--simulated-speed",
            dict(type=decimal, help="simulated devices: times real time (default: as fast as they compute)"),
        ),
        "output": ("-o --output", dict(help="guidance JSON to write")),
    }

    def __post_init__(self) -> None:
        if self.stage not in STAGE_CHOICES:
            raise InvalidInputError(f"--stage must be one of {', '.join(STAGE_CHOICES)}, got {self.stage!r}")
        if self.insertion not in INSERTIONS:
            raise InvalidInputError(
                f"--insertion must be one of {', '.join(INSERTIONS)}, got {self.insertion!r}"
            )
        low, high = STANDOFF_RANGE_MM
        if not (isinstance(self.standoff_mm, (int, float)) and low <= self.standoff_mm <= high):
            raise InvalidInputError(f"--standoff-mm must be {low:g}..{high:g} mm, got {self.standoff_mm}")
        if not 3 <= self.frames_per_pose <= 1000:
            raise InvalidInputError(f"--frames-per-pose must be 3..1000, got {self.frames_per_pose}")
        if (self.plan is None) == (self.slicer_live is None):
            raise InvalidInputError(
                "give the plan as PLAN (a markups file) or --slicer-live PORT (one of the two)"
            )
        if self.slicer_live is not None and not 0 <= self.slicer_live <= 65535:
            raise InvalidInputError(f"--slicer-live must be a port 0..65535, got {self.slicer_live}")
        if not (math.isfinite(self.slicer_timeout_s) and 0 < self.slicer_timeout_s <= 3600):
            raise InvalidInputError(f"--slicer-timeout-s must be 0..3600 s, got {self.slicer_timeout_s}")
        by_file = self.registration is not None
        if by_file == (self.fiducials is not None or self.touched is not None):
            raise InvalidInputError(
                "give the registration as --registration FILE, or as --fiducials FIDUCIALS.mrk.json "
                "with --touched TOUCHED.csv (one of the two)"
            )
        if not by_file and (self.fiducials is None or self.touched is None):
            raise InvalidInputError("a pointer registration needs both --fiducials and --touched")

    @property
    def stages(self) -> tuple[str, ...]:
        """The stages this guidance runs, in order."""
        return STAGE_CHOICES[self.stage]


class GuidanceInterrupted(DeviceError):
    """A guidance stopped before its last stage ended (a fault, a stop, Ctrl-C); ``result`` is
    what was measured before, ``interrupted`` set (also written to the guidance JSON, if asked)."""

    def __init__(self, result: GuidanceResult, message: str):
        super().__init__(message)
        self.result = result


@dataclass(frozen=True)
class GuideOutput:
    """The guidance (None after a dry run), what the motion gate checked, and the stage asked."""

    result: GuidanceResult | None
    gate: MotionGateReport
    stage: str


@dataclass(frozen=True)
class _Prediction:
    entry_mm: float
    target_mm: float
    direction_deg: float
    contributions: dict[str, Any]


#: What a guidance's next stage, in the same session, may differ in from its first.
SAME_SESSION_FIELDS = ("stage", "insertion", "confirm_insertion", "output")
#: Asked, in the session, once a standoff finished there: the insertion's settings (the
#: standoff's with :data:`SAME_SESSION_FIELDS` changed), or None to end at the standoff.
ThenInsert = Callable[[CommandResult["GuideOutput"]], "GuideSettings | None"]


def guide(
    settings: GuideSettings, on_sample: SampleCallback | None = None, then: ThenInsert | None = None
) -> CommandResult[GuideOutput]:
    """Place the needle on the plan in stages and measure it (module docstring).

    With ``then`` (a standoff, ``stage="standoff"``), the insertion runs in the same session
    once the standoff finished there: ``then`` is called with the standoff's result and may
    wait (for an operator's second confirmation) while the robot holds still at the standoff;
    the insertion it returns (``stage="insert"``) then checks, as always, that the robot
    stands at the standoff. On simulated devices this is how an insertion follows its
    standoff: a new session starts a fresh simulated world with the robot at home.

    Returns
    -------
    CommandResult of GuideOutput
        The measured stages and their errors (none after a dry run); the guidance JSON written.

    Raises
    ------
    InvalidInputError, UnreachableError, MotionRefusedError
        Bad input or a motion the gate refuses, one line; nothing has moved.
    DeviceError
        A device fault or an interruption during the motion: the robot was stopped, the
        guidance JSON keeps what was measured (``interrupted``), and the line says so.
    """
    inputs: list[str | Path | None] = [
        settings.plan,
        settings.calibration,
        settings.registration,
        settings.fiducials,
        settings.touched,
    ]
    guard_outputs([settings.output], inputs, settings.force, any_file=True)
    calibration, notes = open_calibration(settings.calibration, "guide", settings.accept_edited)
    registration = read_registration(
        settings.registration,
        settings.registration_maps,
        settings.fiducials,
        settings.touched,
        settings.coordinate_system,
        settings.max_fre_mm,
        settings.accept_high_fre,
    )
    if registration.pointer is not None and registration.pointer.accepted_above_limit:
        notes.append(
            f"the registration's FRE {registration.pointer.fre_rms_mm:.2f} mm is above its limit "
            f"{registration.pointer.max_fre_mm:g} mm and was used on request"
        )
    file_plan = None
    if settings.plan is not None:
        file_plan = read_plan(
            settings.plan,
            settings.entry_label,
            settings.target_label,
            settings.markup,
            settings.coordinate_system,
        )
        locate_plan(file_plan, registration, calibration.tracker_from_base)  # frames agree: before any device
    with contextlib.ExitStack() as stack:
        session = stack.enter_context(motion_session(_motion(settings, calibration)))
        notes += session.calibration_notes(calibration, settings.accept_other_devices)
        link = None if settings.slicer_live is None else stack.enter_context(_served(settings.slicer_live))
        plan, revision = file_plan, 0
        if link is not None:
            link.set_registration(registration)
            received = link.wait_for_plan(settings.slicer_timeout_s)
            plan, revision = received.plan, received.revision
        assert plan is not None  # the file's or Slicer's
        first = _guide(settings, session, calibration, plan, registration, (link, revision), notes, on_sample)
        if then is None or settings.dry_run:
            return first
        if settings.stage != "standoff":
            raise InvalidInputError("only a standoff is followed by an insertion in its session")
        following = then(first)
        if following is None:
            return first
        asked, started = dataclasses.asdict(following), dataclasses.asdict(settings)
        changed = [name for name in asked if name not in SAME_SESSION_FIELDS and asked[name] != started[name]]
        if following.stage != "insert" or changed:
            raise InvalidInputError(
                "the insertion in the standoff's session must be of the same plan, registration, "
                f"calibration and devices (it differs in {', '.join(changed) or 'its stage'}); "
                "the robot stays at the standoff"
            )
        return _guide(following, session, calibration, plan, registration, (link, revision), notes, on_sample)
    raise AssertionError("unreachable")  # pragma: no cover (the with block returns or raises)


@contextlib.contextmanager
def _served(port: int) -> Iterator[SlicerLink]:
    link = SlicerLink.serve(port)
    try:
        yield link
    finally:
        link.close()


def _guide(
    settings: GuideSettings,
    session: MotionSession,
    calibration: CalibrationResult,
    plan: NeedlePlan,
    registration: ImageRegistration,
    slicer: tuple[SlicerLink | None, int],
    notes: list[str],
    on_sample: SampleCallback | None,
) -> CommandResult[GuideOutput]:
    link, revision = slicer
    located = locate_plan(plan, registration, calibration.tracker_from_base)
    axis = NeedleAxis(located.entry_in_tracker, located.target_in_tracker)
    tcp_from_needle = calibration.tcp_from_needle if calibration.tcp_from_needle is not None else np.eye(4)
    needle_from_marker = invert_transform(tcp_from_needle) @ calibration.tcp_from_marker
    state = session.robot.state()
    where = calibration.tracker_from_base @ state.base_from_tcp @ tcp_from_needle
    prediction, prediction_notes = _predict(
        session, calibration, located, tcp_from_needle, settings.standoff_mm
    )
    notes += prediction_notes
    stages = settings.stages
    planned = np.array(
        [stage_pose(s, axis, settings.insertion, settings.standoff_mm, where[:3, 0]) for s in stages]
    )
    if stages[0] == "insert":
        # the insertion runs from this plan's standoff: the robot must stand there (its own
        # reading, through the calibration)
        standoff = stage_pose("standoff", axis, settings.insertion, settings.standoff_mm, where[:3, 0])
        at, distance, angle = at_pose(where, standoff)
        if not at:
            raise InvalidInputError(
                f"--stage insert needs the robot at this plan's standoff (within {AT_STANDOFF_MM:g} mm and "
                f"{AT_STANDOFF_DEG:g} deg); its needle is {distance:.1f} mm and {angle:.1f} deg from it: "
                "run --stage standoff first; nothing moved"
            )
    commanded, _ = commanded_tcp_poses(session, calibration, planned, tcp_from_needle)
    motion = stage_plan(
        session.model,
        state.joints_rad,
        commanded,
        stages,
        session.settings.limits(),
        session.frame_period_s,
        settings.frames_per_pose,
    )
    gate = session.gate(motion)
    if settings.dry_run:
        lines = (
            *note_lines(notes),
            gate.summary(),
            f"guidance {' then '.join(stages)} planned ({settings.insertion}), "
            f"{motion.motion_time_s:.1f} s of motion; predicted error at the target "
            f"{prediction.target_mm:.2f} mm; nothing moved",
        )
        return CommandResult(GuideOutput(None, gate, settings.stage), (), tuple(notes), lines)
    session.require_confirmation()
    if "insert" in stages and not session.simulated and not settings.confirm_insertion:
        raise InvalidInputError(
            "inserting the needle along its axis on a real robot needs --confirm-insertion as well "
            "(check the path is clear); nothing moved"
        )
    session.begin_motion()
    observer = None if link is None else _streamer(link, needle_from_marker)
    truth = _SimulatorTruth(session, observer) if session.simulated else None
    observer = truth if truth is not None else observer
    if link is not None:
        link.update_needle(where)  # the needle where it stands, until the first frame
    measured: list[StageMeasurement] = []
    interruption = ""
    # one stage at a time, so that a stage's measurement is kept before the next moves
    for k, stage in enumerate(stages):
        part = _one_stage(motion, stage)
        try:
            held = session.hold(
                part, settings.frames_per_pose, on_sample=on_sample, what="guidance", observer=observer
            )
        except (SpacecalError, KeyboardInterrupt) as exc:
            interruption = (
                "interrupted by the user (Ctrl-C)"
                if isinstance(exc, KeyboardInterrupt)
                else str(exc).removesuffix(HOLD_STOPPED)
            )
            with contextlib.suppress(SpacecalError):  # the hold stopped it; again, whatever ended it
                session.robot.stop()
            break
        true_needle = None if truth is None else truth.take()
        measured.append(
            _measurement(stage, planned[k], held[0], needle_from_marker, axis, settings, true_needle)
        )
    result = GuidanceResult(
        plan_name=plan.name,
        image_frame=plan.image_frame,
        entry_in_image=plan.entry_in_image,
        target_in_image=plan.target_in_image,
        tracker_frame=registration.tracker_frame,
        entry_in_tracker=located.entry_in_tracker,
        target_in_tracker=located.target_in_tracker,
        registration=f"{registration.name} from {registration.source}",
        insertion=settings.insertion,
        standoff_mm=settings.standoff_mm,
        stages=tuple(measured),
        predicted_entry_error_mm=prediction.entry_mm,
        predicted_target_error_mm=prediction.target_mm,
        predicted_direction_error_deg=prediction.direction_deg,
        predicted_contributions=prediction.contributions,
        measured_by=MEASURED_BY_MARKER,
        devices=session.identity(),
        simulated=session.simulated,
        interrupted=bool(interruption),
        interruption=interruption,
        plan_source=str(settings.plan) if link is None else "3D Slicer (OpenIGTLink)",
    )
    files = (write_json(result.to_dict(), settings.output),) if settings.output else ()
    if link is not None:
        notes += _link_notes(link, revision)
    if interruption:
        kept = ", ".join(m.stage for m in measured) or "nothing"
        where_written = (
            f"; wrote {files[0]} with what was measured ({kept})"
            if files
            else f"; measured: {kept} (not written: no -o)"
        )
        raise GuidanceInterrupted(
            result,
            f"guidance interrupted at stage {stages[len(measured)]}: "
            f"{sanitize_for_terminal(interruption, 200)}; "
            f"the robot was stopped and will not move again by itself{where_written}",
        )
    return guide_result(GuideOutput(result, gate, settings.stage), tuple(files), tuple(notes))


def _link_notes(link: SlicerLink, revision: int) -> list[str]:
    """What the link to Slicer did: the needle frames sent and dropped, and whether Slicer's
    plan changed after the guidance took it (the guidance keeps the plan it started with)."""
    status = link.status()
    sent, dropped = status.frames_sent, status.frames_dropped
    notes = [f"Slicer: {sent} needle frames sent, {dropped} dropped ({status.url})"]
    try:
        newest = link.latest_plan()
    except InvalidInputError as exc:
        newest, notes = None, [*notes, f"Slicer's newest plan message was refused: {exc}"]
    if newest is not None and newest.revision > revision:
        notes.append("Slicer's plan changed during the guidance: the guidance ran the plan it started with")
    return notes


def _motion(settings: GuideSettings, calibration: CalibrationResult) -> MotionSettings:
    return calibration_motion(
        calibration,
        settings.devices,
        settings.scenario,
        settings.dry_run,
        settings.confirm_robot_motion,
        settings.workspace_box,
        settings.simulated_speed,
    )


def _predict(
    session: MotionSession,
    calibration: CalibrationResult,
    located: LocatedPlan,
    tcp_from_needle: np.ndarray,
    standoff_mm: float,
) -> tuple[_Prediction, list[str]]:
    """The predicted RMS errors at the entry and the target (:func:`plan_needle`, which also
    refuses a path the robot cannot reach) and the notes on what they leave out."""
    notes = []
    registration = located.registration
    if registration.pointer is not None:
        pointer = registration.pointer
        image_from_tracker = invert_transform(registration.tracker_from_image)
        points = apply_transform(
            image_from_tracker, np.array([located.entry_in_tracker, located.target_in_tracker])
        )
        tre = tuple(float(v) for v in pointer_predicted_tre(pointer, points))
        if pointer.tip_accuracy_mm is None:
            notes.append(
                "the touches state no pointer tip accuracy: the predicted error leaves out the tip's "
                "calibration error (spacecal touch --pointer-tip-accuracy-mm)"
            )
    else:
        tre = (0.0, 0.0)
        notes.append("the registration file states no error of its own: the predicted error leaves it out")
    stated = calibration.assessment.position_mm if calibration.assessment is not None else None
    if stated is None:
        stated = (calibration.predicted_tre_mm or {}).get("site")
    if stated is None:
        stated = 0.0
        notes.append("the calibration states no expected error: the predicted error leaves it out")
    if session.world is not None:
        repeatability = session.world.scenario.repeatability_mm
    else:
        repeatability = ROBOT_REPEATABILITY_MM
    try:
        needle = plan_needle(
            located.entry_in_tracker,
            located.target_in_tracker,
            np.eye(4),  # the points are given in the tracker frame already
            calibration.tracker_from_base,
            session.ik_model(calibration),
            session.robot.state().joints_rad,
            standoff_mm=standoff_mm,
            tcp_from_needle=tcp_from_needle,
            registration_tre_mm=tre,
            calibration_tre_mm=(float(stated), float(stated)),
            robot_position_sd_mm=repeatability * REPEATABILITY_TO_AXIS_SD,
        )
    except UnreachableError as exc:
        raise UnreachableError(f"{exc}; nothing moved") from None
    p = needle.predicted_error
    prediction = _Prediction(p["entry_mm"], p["target_mm"], p["direction_deg"], p["contributions"])
    return prediction, notes


def _one_stage(motion: MotionPlan, stage: str) -> MotionPlan:
    """The part of the stages' motion that ends with ``stage``'s hold (from the hold before)."""
    moves, part = list(motion.moves), []
    start = 0
    for index, move in enumerate(moves):
        if move.label == stage and move.sample_period_s > 0:
            part = moves[start : index + 1]
            break
        if move.sample_period_s > 0:
            start = index + 1
    home = part[0].start
    return MotionPlan(motion.home_joints_rad, home, part, motion.extents, [])


def _streamer(link: SlicerLink, needle_from_marker: np.ndarray) -> Callable[..., None]:
    """The frame observer that gives every frame's needle pose to Slicer."""
    marker_to_needle = invert_transform(needle_from_marker)

    def observe(
        time_s: float, segment: str, tracker_from_marker: Any, base_from_tcp: Any, recorded: bool
    ) -> None:
        if tracker_from_marker is not None:
            link.update_needle(np.asarray(tracker_from_marker) @ marker_to_needle)

    return observe


class _SimulatorTruth:
    """On the simulated devices: the frames each hold recorded (chained before ``observer``),
    to read the simulator's truth of where the needle was while it was measured (the
    simulated tracker keeps the true marker pose of every frame it delivered). The needle of
    the simulated world is its TCP. Documented as the simulator's truth, as a verification's
    simulated laser tracker is; nothing like it exists on real devices."""

    def __init__(self, session: MotionSession, observer: Callable[..., None] | None):
        self.session, self.observer = session, observer
        self.times: list[float] = []

    def __call__(
        self, time_s: float, segment: str, tracker_from_marker: Any, base_from_tcp: Any, recorded: bool
    ) -> None:
        if self.observer is not None:
            self.observer(time_s, segment, tracker_from_marker, base_from_tcp, recorded)
        if recorded and tracker_from_marker is not None:
            self.times.append(time_s)

    def take(self) -> np.ndarray | None:
        """The mean true ``tracker_from_needle`` (4, 4), mm, over the frames recorded since the
        last call (None without any), and forget them."""
        tracker = self.session.tracker
        world, truth = self.session.world, tracker.truth if isinstance(tracker, SimulatedTracker) else {}
        poses = [truth[t][0] for t in self.times if t in truth]
        self.times = []
        if world is None or not poses:
            return None
        return mean_transform(np.array(poses)) @ invert_transform(world.tcp_from_marker)


def _measurement(
    stage: str,
    planned: np.ndarray,
    held: HeldPose,
    needle_from_marker: np.ndarray,
    axis: NeedleAxis,
    settings: GuideSettings,
    true_needle: np.ndarray | None = None,
) -> StageMeasurement:
    measured = mean_transform(held.tracker_from_marker_stack) @ invert_transform(needle_from_marker)
    errors = needle_errors(
        measured, axis, stage_place_mm(stage, axis, settings.insertion, settings.standoff_mm)
    )
    return StageMeasurement(
        stage=stage,
        planned_tracker_from_needle=planned,
        measured_tracker_from_needle=measured,
        joints_rad=held.at_rest.joints_rad,
        tip_error_mm=errors.tip_error_mm,
        entry_error_mm=errors.entry_error_mm,
        target_error_mm=errors.target_error_mm,
        direction_error_deg=errors.direction_error_deg,
        simulated_true_tracker_from_needle=true_needle,
    )


def guide_result(
    out: GuideOutput, files: tuple[Path, ...] = (), notes: tuple[str, ...] = ()
) -> CommandResult[GuideOutput]:
    """The lines of a guidance: per stage the errors beside the predicted ones, and the source."""
    result = out.result
    assert result is not None
    where = "simulated robot and tracker" if result.simulated else "the robot"
    lines = [
        *(f"wrote {path}" for path in files),
        *note_lines(notes),
        out.gate.summary(),
        f"guidance on {where} ({result.insertion}), measured by {result.measured_by}",
    ]
    for stage in result.stages:
        lines.append(
            f"  {stage.stage:>8}: tip {stage.tip_error_mm:.3f} mm, entry {stage.entry_error_mm:.3f} mm, "
            f"target {stage.target_error_mm:.3f} mm, direction {stage.direction_error_deg:.3f} deg"
        )
    lines.append(
        f"  predicted (RMS): entry {result.predicted_entry_error_mm:.3f} mm, target "
        f"{result.predicted_target_error_mm:.3f} mm, direction "
        f"{result.predicted_direction_error_deg:.3f} deg "
        "(paper: entry 0.87 mm, target 0.83 mm, direction 0.89 deg minimum)"
    )
    return CommandResult(out, files, notes, tuple(lines))


__all__ = ["GuidanceInterrupted", "GuideOutput", "GuideSettings", "guide", "guide_result"]
