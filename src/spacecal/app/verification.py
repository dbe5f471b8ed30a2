"""``spacecal verify``: the paper's verification experiment (§5.2), on the robot or in simulation.

Needle poses X_d = [P_d, phi_d] given in the tracker frame (the paper's 15 around the site, or
from a file) are mapped through the calibration into the robot base, reached by inverse
kinematics (on the kinematic model the calibration identified, where it has one), held while
the tracker measures them, and compared with what was reached: the position error ``|P_d - P_r|``
and the posture error, the angle of R_d R_r^-1.

What measures the reached pose is said with every figure:

* the calibrated marker (default): the marker measures its own pose, carried to the needle by
  this calibration's ``tcp_from_marker``. It is not independent of the calibration: it sees the
  robot's positioning and the base side of the calibration, not an error in marker_from_tcp.
* a reference tool (``--reference-tool NAME``): a tracked tool on the needle guide, with its
  own definition of where the needle is (``reference_from_needle``), independent of this
  calibration.

The reference tool is a further tool the tracker follows: on the simulated devices the world's
``reference`` tool; on an NDI tracker a further tool definition (``--rom``), named after its
file; on OpenIGTLink the device of that name (:func:`reference_devices`).

Every motion runs through the motion session (:mod:`spacecal.app.motion_session`): gated
before anything moves, confirmed on real devices, stopped on a fault. A verification stopped
after some poses were held (Ctrl-C, a stop request, a device fault) keeps them: the poses
measured so far are written to ``-o`` marked ``interrupted``, and the command ends with one line
(:class:`VerificationInterrupted`, exit code 1); the robot was stopped and is not moved again.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, NoReturn

import numpy as np

from spacecal.app._common import calibration_motion, guard_outputs, open_calibration, scenario_of_calibration
from spacecal.app.devices import DeviceSettings
from spacecal.app.motion_session import MotionSession, motion_session
from spacecal.app.motion_settings import MotionSettings, WorkspaceBox
from spacecal.app.result import CommandResult, note_lines
from spacecal.core.errors import DegenerateDataError, DeviceError, InvalidInputError, UnreachableError
from spacecal.core.strict_numbers import integer
from spacecal.experiments.verification import verify_in_simulation
from spacecal.geometry.metrics import position_error, posture_error_rad
from spacecal.geometry.transforms import (
    axis_angle_transform,
    invert_transform,
    make_transform,
    mean_transform,
)
from spacecal.io.atomic import atomic_path
from spacecal.io.recordings import refuse_changed
from spacecal.io.results_json import read_json_object, write_json
from spacecal.models.kinematics import forward_kinematics, inverse_kinematics
from spacecal.planning.held_poses import hold_plan
from spacecal.planning.motion_gate import MotionGateReport
from spacecal.records import CalibrationResult, VerificationResult
from spacecal.records.fields import as_transform
from spacecal.report.figures import plot_verification_errors
from spacecal.sim.scenario import Scenario, load_scenario
from spacecal.workflows.acquisition import SampleCallback
from spacecal.workflows.held_poses import HeldPose, HoldsStopped

#: What the calibrated marker's measurement is, in every figure that shows it.
MEASURED_BY_MARKER = (
    "the calibrated marker (it measures its own pose through this calibration's tcp_from_marker: "
    "not independent of the calibration)"
)
#: Label of the hold at needle pose k (1-based).
POSE_LABEL = "pose-{}"
#: Largest number of needle poses.
MAX_POSES = 100
#: The default poses: positions in a cube of this side (mm) around where the needle stands,
#: tilted by up to this much (deg), as the simulated scenarios draw them (paper §5.2: "around
#: the surgical site").
TARGET_CUBE_MM = Scenario.target_cube_mm
TARGET_TILT_DEG = Scenario.target_tilt_deg


@dataclass(frozen=True)
class VerifySettings:
    """``spacecal verify``: the paper's verification experiment (§5.2).

    With ``--robot`` and ``--tracker`` (``sim`` for the simulated devices, or device URLs) the
    poses are reached on the devices; without, in the calibration's simulated world by the
    simulator's own path, measured by its laser tracker.

    Attributes
    ----------
    calibration : str
        Calibration JSON.
    devices : DeviceSettings
        The robot and tracker; neither named: the simulated world, without devices.
    scenario : str or None
        The simulated world (default: the one the calibration's data came from).
    points : int
        Needle poses around where the needle stands (the paper: 15), unless ``targets``.
    targets : str or None
        A JSON file of needle poses in the tracker frame: ``{"tracker_from_needle": [4x4, ...]}``.
    seed : int
        Seeds the default poses.
    reference_tool : str or None
        A further tool the tracker sees on the needle guide that measures the reached pose
        independently; needs ``reference_from_needle``.
    reference_from_needle : str or None
        JSON file ``{"reference_from_needle": 4x4}``: the needle in the reference tool's frame.
    frames_per_pose : int
        Tracker frames averaged at each pose.
    dry_run, confirm_robot_motion, workspace_box, simulated_speed
        As for ``acquire``.
    accept_edited, accept_other_devices : bool
    output, figure : str or None
        Verification JSON and Fig. 7-style PNG to write.
    force : bool
    """

    calibration: str
    devices: DeviceSettings = field(default_factory=lambda: DeviceSettings(robot=None, tracker=None))
    scenario: str | None = None
    points: int = 15
    targets: str | None = None
    seed: int = 0
    reference_tool: str | None = None
    reference_from_needle: str | None = None
    frames_per_pose: int = 10
    dry_run: bool = False
    confirm_robot_motion: bool = False
    workspace_box: WorkspaceBox | None = None
    simulated_speed: float | None = None
    accept_edited: bool = False
    accept_other_devices: bool = False
    output: str | None = None
    figure: str | None = None
    force: bool = False

    #: The command line's flag and argparse options of the fields only this command has.
    FLAGS: ClassVar[dict[str, tuple[str, dict[str, Any]]]] = {
        "targets": (
            "--targets",
            dict(metavar="POSES.json", help="needle poses in the tracker frame to reach"),
        ),
        "points": ("--points", dict(type=integer, help="number of needle poses")),
        "seed": ("--seed", dict(type=integer, help="seeds the default needle poses")),
        "reference_tool": (
            "--reference-tool",
            dict(metavar="NAME", help="a tracked tool on the needle guide: measures the pose independently"),
        ),
        "reference_from_needle": (
            "--reference-from-needle",
            dict(metavar="TOOL.json", help="the needle in the reference tool's frame"),
        ),
        "frames_per_pose": (
            "--frames-per-pose",
            dict(type=integer, help="tracker frames averaged at each pose"),
        ),
        "dry_run": ("--dry-run", dict(action="store_true", help="plan the needle poses without moving")),
    }

    @property
    def on_devices(self) -> bool:
        """The poses are reached on devices (a robot or tracker is named)."""
        return self.devices.robot is not None or self.devices.tracker is not None

    def __post_init__(self) -> None:
        if not 1 <= self.points <= MAX_POSES:
            raise InvalidInputError(f"--points must be 1..{MAX_POSES}, got {self.points}")
        if not 3 <= self.frames_per_pose <= 1000:
            raise InvalidInputError(f"--frames-per-pose must be 3..1000, got {self.frames_per_pose}")
        if (self.reference_tool is None) != (self.reference_from_needle is None):
            raise InvalidInputError("--reference-tool and --reference-from-needle go together")


class VerificationInterrupted(DeviceError):
    """A verification on devices stopped after ``measured`` of ``planned`` poses; the robot was
    stopped. ``result`` holds the poses measured (None when none was), already written to the
    files in ``files``."""

    def __init__(
        self, message: str, result: VerificationResult | None, planned: int, files: tuple[Path, ...]
    ) -> None:
        super().__init__(message)
        self.result, self.planned, self.files = result, planned, files
        self.measured = 0 if result is None else len(result.position_error_mm)


@dataclass(frozen=True)
class RobotVerifyOutput:
    """The verification (None after a dry run) and what the motion gate checked."""

    result: VerificationResult | None
    gate: MotionGateReport
    poses: int


def read_needle_poses(path: str | Path) -> np.ndarray:
    """Needle poses (N, 4, 4), tracker frame, mm, from ``{"tracker_from_needle": [...]}``."""
    data = read_json_object(path, "needle poses")
    poses = data.get("tracker_from_needle")
    if not isinstance(poses, list) or not 1 <= len(poses) <= MAX_POSES:
        raise InvalidInputError(f"{path}: 'tracker_from_needle' must be a list of 1..{MAX_POSES} 4x4 poses")
    return np.array([as_transform(p, f"tracker_from_needle[{k}]", str(path)) for k, p in enumerate(poses)])


def needle_poses_around(tracker_from_needle: np.ndarray, count: int, seed: int) -> np.ndarray:
    """``count`` needle poses (count, 4, 4, tracker frame, mm) around the needle's pose
    ``tracker_from_needle``: positions uniform in a cube of :data:`TARGET_CUBE_MM`, each tilted
    by up to :data:`TARGET_TILT_DEG` about a random axis."""
    rng = np.random.default_rng([seed, 2])
    poses = []
    for _ in range(count):
        offset = rng.uniform(-0.5, 0.5, 3) * TARGET_CUBE_MM
        tilt = axis_angle_transform(rng.normal(size=3), np.radians(rng.uniform(0, TARGET_TILT_DEG)))
        orientation = tracker_from_needle[:3, :3] @ tilt[:3, :3]
        poses.append(make_transform(orientation, tracker_from_needle[:3, 3] + offset))
    return np.array(poses)


def commanded_tcp_poses(
    session: MotionSession, calibration: CalibrationResult, desired: np.ndarray, tcp_from_needle: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Where to command the TCP (controller base frame) so that the needle reaches each desired
    pose: IK on the calibration's model (its identified DH where it has them) from where the
    robot stands, then the controller's own forward kinematics of those joints (the controller
    solves its straight moves with its model).

    Returns
    -------
    commanded : numpy.ndarray, shape (N, 4, 4)
    joints_rad : numpy.ndarray, shape (N, 6)
    """
    base_from_tracker = invert_transform(calibration.tracker_from_base)
    needle_from_tcp = invert_transform(tcp_from_needle)
    model, controller = session.ik_model(calibration), session.model
    start = session.robot.state().joints_rad
    commanded, joints = [], []
    for k, target in enumerate(desired):
        try:
            q = inverse_kinematics(model, base_from_tracker @ target @ needle_from_tcp, start)
        except UnreachableError as exc:
            raise UnreachableError(f"needle pose {k + 1}: {exc}; nothing moved") from None
        joints.append(q)
        commanded.append(forward_kinematics(controller, q))
    return np.array(commanded), np.array(joints)


def reached_needle_poses(
    held: list[HeldPose],
    calibration: CalibrationResult,
    tcp_from_needle: np.ndarray,
    reference: tuple[str, np.ndarray] | None,
) -> np.ndarray:
    """The reached needle pose (N, 4, 4, tracker frame) at each hold, as its source measured it."""
    reached = []
    for pose in held:
        if reference is None:
            marker = mean_transform(pose.tracker_from_marker_stack)
            reached.append(marker @ invert_transform(calibration.tcp_from_marker) @ tcp_from_needle)
            continue
        name, reference_from_needle = reference
        seen = pose.tools.get(name)
        if seen is None or len(seen) < 3:
            raise DegenerateDataError(
                f"verification {pose.label}: the reference tool {name!r} was seen in "
                f"{0 if seen is None else len(seen)} frames; make sure the tracker sees it"
            )
        reached.append(mean_transform(seen) @ reference_from_needle)
    return np.array(reached)


def verify_on_devices(
    settings: VerifySettings,
    on_sample: SampleCallback | None = None,
    on_plan: Callable[[int], None] | None = None,
) -> CommandResult[RobotVerifyOutput]:
    """Reach the needle poses on the robot through the calibration and measure them.

    Returns
    -------
    CommandResult of RobotVerifyOutput
        The errors at the needle poses (none after a dry run); the JSON and figure written.
    """
    guard_outputs(
        [settings.output, settings.figure],
        [settings.calibration, settings.targets, settings.reference_from_needle],
        settings.force,
        any_file=True,
    )
    calibration, notes = open_calibration(settings.calibration, "verify", settings.accept_edited)
    if calibration.provenance.source is not None:
        refuse_changed(calibration.provenance.source, settings.accept_edited)
    reference = None
    if settings.reference_tool is not None:
        assert settings.reference_from_needle is not None
        data = read_json_object(settings.reference_from_needle, "reference tool")
        reference = (
            settings.reference_tool,
            as_transform(
                data.get("reference_from_needle"), "reference_from_needle", settings.reference_from_needle
            ),
        )
    desired_given = read_needle_poses(settings.targets) if settings.targets else None
    tcp_from_needle = calibration.tcp_from_needle if calibration.tcp_from_needle is not None else np.eye(4)
    with motion_session(_motion(settings, calibration)) as session:
        notes += session.calibration_notes(calibration, settings.accept_other_devices)
        where = calibration.tracker_from_base @ session.robot.state().base_from_tcp @ tcp_from_needle
        desired = (
            desired_given
            if desired_given is not None
            else needle_poses_around(where, settings.points, settings.seed)
        )
        commanded, _ = commanded_tcp_poses(session, calibration, desired, tcp_from_needle)
        labels = [POSE_LABEL.format(k + 1) for k in range(len(desired))]
        plan = hold_plan(
            session.model,
            session.robot.state().joints_rad,
            commanded,
            labels,
            session.settings.limits(),
            session.frame_period_s,
            settings.frames_per_pose,
            via_home=True,  # the paper reaches each pose "from another place"
            summary={"verification_poses": len(desired)},
        )
        gate = session.gate(plan)
        if settings.dry_run:
            lines = (
                f"{len(desired)} needle poses planned, {plan.motion_time_s:.1f} s of motion; nothing moved",
            )
            return CommandResult(RobotVerifyOutput(None, gate, len(desired)), (), tuple(notes), lines)
        session.begin_motion()
        if on_plan is not None:
            on_plan(len(plan.moves))
        try:
            held = session.hold(plan, settings.frames_per_pose, on_sample=on_sample, what="verification")
        except HoldsStopped as stopped:
            # the robot was stopped (hold_poses); what was measured is kept, and nothing moves again
            keep_interrupted(
                stopped, labels, desired, calibration, tcp_from_needle, reference, session, settings
            )
        result = verification_of(held, labels, desired, calibration, tcp_from_needle, reference, session)
    files = write_verification(result, settings)
    return robot_verify_result(RobotVerifyOutput(result, gate, len(desired)), files, tuple(notes))


def verification_of(
    held: list[HeldPose],
    labels: list[str],
    desired: np.ndarray,
    calibration: CalibrationResult,
    tcp_from_needle: np.ndarray,
    reference: tuple[str, np.ndarray] | None,
    session: MotionSession,
    interrupted: str = "",
) -> VerificationResult:
    """The verification of the holds ``held`` (all, or those measured before a stop: then
    ``interrupted`` says why), each compared with its desired pose (by its label)."""
    index = [labels.index(pose.label) for pose in held]
    wanted = desired[index]
    reached = reached_needle_poses(held, calibration, tcp_from_needle, reference)
    return VerificationResult(
        desired_tracker_from_needle=wanted,
        reached_tracker_from_needle=reached,
        joints_rad=np.array([pose.at_rest.joints_rad for pose in held]),
        position_error_mm=position_error(wanted, reached),
        posture_error_deg=np.degrees(posture_error_rad(wanted, reached)),
        simulated=session.simulated,
        scenario=session.world.scenario.name if session.world is not None else "",
        measured_by=MEASURED_BY_MARKER if reference is None else f"reference tool {reference[0]}",
        devices=session.identity(),
        interrupted=interrupted,
        poses_planned=len(desired) if interrupted else None,
    )


def keep_interrupted(
    stopped: HoldsStopped,
    labels: list[str],
    desired: np.ndarray,
    calibration: CalibrationResult,
    tcp_from_needle: np.ndarray,
    reference: tuple[str, np.ndarray] | None,
    session: MotionSession,
    settings: VerifySettings,
) -> NoReturn:
    """Write the poses measured before the stop (``-o``, marked interrupted; the figure) and
    end the command with one line.

    Raises
    ------
    VerificationInterrupted
        Always: "verification interrupted after K of N poses (why); ...".
    """
    result: VerificationResult | None = None
    files: tuple[Path, ...] = ()
    try:
        if stopped.held:
            result = verification_of(
                stopped.held,
                labels,
                desired,
                calibration,
                tcp_from_needle,
                reference,
                session,
                stopped.reason,
            )
            files = write_verification(result, settings)
    except DegenerateDataError as exc:  # a hold without its reference tool: nothing to score
        kept = f"nothing written ({exc})"
    else:
        kept = (
            "; ".join(f"wrote {path}" for path in files)
            if files
            else ("nothing measured" if result is None else "no -o given: nothing written")
        )
    measured = 0 if result is None else len(result.position_error_mm)
    raise VerificationInterrupted(
        f"verification interrupted after {measured} of {len(desired)} poses ({stopped.reason}); "
        f"the robot was stopped; {kept}",
        result,
        len(desired),
        files,
    ) from None


def write_verification(result: VerificationResult, settings: VerifySettings) -> tuple[Path, ...]:
    """Write the verification JSON (``-o``) and its Fig. 7 (``--figure``), each atomically."""
    files = []
    if settings.output:
        files.append(write_json(result.to_dict(), settings.output))
    if settings.figure:
        with atomic_path(settings.figure) as temporary:
            plot_verification_errors(result.position_error_mm, result.posture_error_deg, temporary)
        files.append(Path(settings.figure))
    return tuple(files)


def _motion(settings: VerifySettings, calibration: CalibrationResult) -> MotionSettings:
    return calibration_motion(
        calibration,
        reference_devices(settings.devices, settings.reference_tool),
        settings.scenario,
        settings.dry_run,
        settings.confirm_robot_motion,
        settings.workspace_box,
        settings.simulated_speed,
    )


def reference_devices(devices: DeviceSettings, name: str | None) -> DeviceSettings:
    """The devices with the tracker following the reference tool ``name`` as well (None: as they
    are). The simulated tracker follows the world's tools (``reference``) already; an NDI
    tracker names its further tools after their ROM files, so one of ``--rom`` must be
    ``NAME.rom``; an OpenIGTLink tracker is asked for the device ``NAME``.

    Raises
    ------
    InvalidInputError
        An NDI tracker without a further tool definition of that name.
    """
    if name is None or devices.simulated or devices.tracker is None:
        return devices
    if any(tool == name for tool, _ in devices.tools):
        return devices
    if devices.tracker.startswith("ndi://"):
        if not any(Path(rom).stem == name for rom in devices.rom[1:]):
            raise InvalidInputError(
                f"--reference-tool {name}: no further tool definition {name}.rom among --rom (an NDI "
                "tracker names its further tools after their ROM files; the marker's comes first)"
            )
        return devices
    return dataclasses.replace(devices, tools=(*devices.tools, (name, name)))


def robot_verify_result(
    out: RobotVerifyOutput,
    files: tuple[Path, ...] = (),
    notes: tuple[str, ...] = (),
) -> CommandResult[RobotVerifyOutput]:
    """The lines of a verification on devices: per pose, then min / mean / max and the source."""
    result = out.result
    assert result is not None
    where = "simulated robot and tracker" if result.simulated else "the robot"
    lines = [
        *(f"wrote {path}" for path in files),
        *note_lines(notes),
        out.gate.summary(),
        f"verification on {where}: {len(result.position_error_mm)} needle poses, measured by "
        f"{result.measured_by}",
    ]
    for k, (p, a) in enumerate(zip(result.position_error_mm, result.posture_error_deg)):
        lines.append(f"  pose {k + 1:>3}: position {p:.3f} mm, posture {a:.3f} deg")
    return CommandResult(out, files, notes, (*lines, *error_statistics_lines(result)))


def error_statistics_lines(result: VerificationResult) -> list[str]:
    """min / mean / max / RMS of the position and posture errors, beside the paper's (§5.2)."""
    s = result.statistics()
    pos, ang = s["position_mm"], s["posture_deg"]
    return [
        f"  position error min / mean / max / RMS: {pos['min']:.3f} / {pos['mean']:.3f} / "
        f"{pos['max']:.3f} / {pos['rms']:.3f} mm   (paper: min 0.87, mean < 1.05 mm)",
        f"  posture error  min / mean / max / RMS: {ang['min']:.3f} / {ang['mean']:.3f} / "
        f"{ang['max']:.3f} / {ang['rms']:.3f} deg  (paper: min 0.83, mean about 1.1 deg)",
    ]


def verify(settings: VerifySettings, on_sample: SampleCallback | None = None) -> CommandResult[Any]:
    """The verification experiment: on the devices named (:func:`verify_on_devices`), or in
    the calibration's simulated world without devices (:func:`verify_in_simulated_world`)."""
    if settings.on_devices:
        return verify_on_devices(settings, on_sample)
    return verify_in_simulated_world(settings)


def verify_in_simulated_world(settings: VerifySettings) -> CommandResult[VerificationResult]:
    """Run the verification experiment for a calibration in its simulated world (no devices:
    the simulator's own path, measured by its laser tracker).

    Returns
    -------
    CommandResult of VerificationResult
        The errors at the needle poses; the verification JSON and figure written, if asked.
    """
    guard_outputs(
        [settings.output, settings.figure],
        [settings.calibration, settings.scenario],
        settings.force,
        any_file=True,
    )
    calibration, notes = open_calibration(settings.calibration, "verify")
    if calibration.provenance.source is not None:
        # a calibration whose recording changed is not the one verified (files gone: nothing to compare)
        refuse_changed(calibration.provenance.source, settings.accept_edited)
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
    return verify_result(result, source, write_verification(result, settings), tuple(notes))


def verify_result(
    result: VerificationResult, world_source: str, files: tuple[Path, ...] = (), notes: tuple[str, ...] = ()
) -> CommandResult[VerificationResult]:
    """The result of ``verify`` from its verification and where its simulated world came from."""
    lines = [
        *(f"wrote {path}" for path in files),
        *note_lines(notes),
        f"verification in simulation on {len(result.position_error_mm)} needle poses "
        f"(scenario {result.scenario}, from {world_source}):",
        *error_statistics_lines(result),
    ]
    return CommandResult(result, files, notes, tuple(lines))


@dataclass(frozen=True)
class DemoSettings:
    """``spacecal demo``: simulate, calibrate (paper and ML) and verify on one scenario."""
