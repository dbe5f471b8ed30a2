"""App functions for ROS users: ``import-bag``, ``import-easy-handeye``, and ROS exports
(easy_handeye2 ``.calib``, ROS 2 static transform command and launch file, URDF joint, UR
driver kinematics file). None needs ROS installed; reading bags needs ``spacecal[ros]``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from spacecal.app._common import guard_outputs, open_calibration, refuse_overwriting_inputs
from spacecal.app.files import ExportSettings, export
from spacecal.app.result import NOTE_CHARS as LINE_CHARS
from spacecal.app.result import CommandResult
from spacecal.core.errors import InvalidInputError
from spacecal.core.text import sanitize_for_terminal
from spacecal.io.atomic import write_text_atomic
from spacecal.io.easy_handeye import easy_handeye2_calibration_text, read_easy_handeye_samples
from spacecal.io.names import check_calibration_name, check_ros_frame_name
from spacecal.io.recordings import metadata_path, stream_paths, write_raw_recording, write_recording
from spacecal.io.ros_bag import BagContents, list_bag_contents, read_ros_bag
from spacecal.io.ros_exports import (
    calibration_static_transform,
    ros2_launch_text,
    static_transform_publisher_command,
    urdf_joint_text,
)
from spacecal.io.ur_driver_calibration import (
    folds_last_link,
    tool_offset_text,
    ur_calibration_text,
    ur_flange_from_tcp,
)
from spacecal.models.kinematics import N_JOINTS
from spacecal.records import CalibrationResult, RawRecording, Recording

#: Longest note line printed (a note quotes topic names from the bag).
NOTE_CHARS = 400


@dataclass(frozen=True)
class ImportBagSettings:
    """``spacecal import-bag``: a ROS 1 or ROS 2 bag as a raw two-stream recording.

    Attributes
    ----------
    bag : str
        ROS 1 ``.bag``, ROS 2 bag folder, or a bare ``.db3`` / ``.mcap`` file.
    output : str or None
        Stem of ``STEM.robot.csv`` and ``STEM.tracker.csv`` (None with ``list_only``).
    list_only : bool
        Only describe the topics and tf frames found.
    base_frame, tool_frame, tracker_frame, marker_frame : str or None
        tf frames of the robot pose (base -> tool) and the marker pose (tracker -> marker).
    joint_states, marker_topic : str or None
        ``sensor_msgs/JointState`` topic (with ``robot_model``) and a ``PoseStamped`` /
        ``TransformStamped`` topic for the marker.
    robot_model : str
        Robot kind whose kinematics turn joint states into TCP poses.
    """

    bag: str
    output: str | None = None
    list_only: bool = False
    base_frame: str | None = None
    tool_frame: str | None = None
    tracker_frame: str | None = None
    marker_frame: str | None = None
    joint_states: str | None = None
    marker_topic: str | None = None
    robot_model: str = "UR10"
    force: bool = False


#: The ``import-bag`` flags, by the argument of :func:`~spacecal.io.ros_bag.read_ros_bag` they set.
IMPORT_BAG_FLAGS = {
    "base_frame": "--base-frame",
    "tool_frame": "--tool-frame",
    "tracker_frame": "--tracker-frame",
    "marker_frame": "--marker-frame",
    "joint_state_topic": "--joint-states",
    "marker_topic": "--marker-topic",
    "robot_model": "--robot-model",
}


def import_bag(settings: ImportBagSettings) -> CommandResult[RawRecording | BagContents]:
    """Describe the bag (``list_only``) or convert it.

    Returns
    -------
    CommandResult of RawRecording or BagContents
        The two streams read and written, or (``list_only``) what the bag holds. Its notes say,
        per stream, which messages were skipped (invalid, out of time order, repeated stamps;
        also in the streams' metadata, ``ros_bag.notes``); its lines say what was written, then
        one ``note: ...`` line per such note.
    """
    if settings.list_only:
        contents = list_bag_contents(settings.bag)
        return CommandResult(contents, lines=tuple(contents.describe().split("\n")))
    if not settings.output:
        raise InvalidInputError("say where to write the streams: -o STEM (or --list to look inside the bag)")
    stem = settings.output[:-4] if settings.output.endswith(".csv") else settings.output
    guard_outputs(list(stream_paths(stem)), [settings.bag], settings.force)
    raw = read_ros_bag(
        settings.bag,
        base_frame=settings.base_frame,
        tool_frame=settings.tool_frame,
        tracker_frame=settings.tracker_frame,
        marker_frame=settings.marker_frame,
        joint_state_topic=settings.joint_states,
        marker_topic=settings.marker_topic,
        robot_model=settings.robot_model if settings.joint_states else None,
        option_names=IMPORT_BAG_FLAGS | {"list": f"spacecal import-bag {settings.bag} --list"},
    )
    robot_path, tracker_path = write_raw_recording(raw, stem)
    # what was skipped of a damaged stream; names in it come from the bag
    skipped = tuple(raw.metadata["ros_bag"]["notes"])
    notes = [f"note: {sanitize_for_terminal(n, NOTE_CHARS)}" for n in skipped]
    picked = raw.metadata["ros_bag"].get("picked")
    if picked:
        notes.insert(0, sanitize_for_terminal(picked, NOTE_CHARS))  # frame names come from the bag
    line = (
        f"wrote {robot_path} ({len(raw.robot_time_s)} robot poses) and {tracker_path} "
        f"({len(raw.tracker_time_s)} tracker poses); calibrate with: spacecal calibrate {robot_path} "
        f"--tracker-stream {tracker_path} --method ml (the clock offset is estimated)"
    )
    written = (robot_path, tracker_path, *stream_paths(stem)[2:])
    return CommandResult(raw, written, ((picked,) if picked else ()) + skipped, (line, *notes))


@dataclass(frozen=True)
class ImportEasyHandeyeSettings:
    """``spacecal import-easy-handeye``: easy_handeye2 saved samples as a recording CSV.

    Attributes
    ----------
    samples : str
        The easy_handeye2 ``.samples`` file.
    output : str
        Recording CSV to write.
    force : bool
        Replace an existing recording, or the samples file itself.
    """

    samples: str
    output: str
    force: bool = False


def import_easy_handeye(settings: ImportEasyHandeyeSettings) -> CommandResult[Recording]:
    """easy_handeye2 saved samples as a recording CSV, to re-solve with spacecal's estimators;
    an existing recording or the samples file itself is replaced only with ``force``.

    Returns
    -------
    CommandResult of Recording
        The recording; its CSV and metadata written.
    """
    guard_outputs([settings.output, metadata_path(settings.output)], [settings.samples], settings.force)
    recording = read_easy_handeye_samples(settings.samples)
    path = write_recording(recording, settings.output)
    line = f"wrote {path}: {len(recording)} samples (re-solve with: spacecal calibrate {path} --method ml)"
    return CommandResult(recording, (path, metadata_path(path)), lines=(line,))


@dataclass(frozen=True)
class RosExportSettings:
    """ROS exports of a calibration (``spacecal export --easy-handeye2/--ros2-launch/...``).

    The frame names are the user's: ``base_frame`` is the robot base link the tracker is
    attached to (the tf parent), ``tracker_frame`` the tracker's (the child).
    """

    calibration: str
    easy_handeye2: str | None = None
    ros2_launch: str | None = None
    urdf: str | None = None
    static_tf: bool = False
    ur_calibration: str | None = None
    base_frame: str = "base"
    tool_frame: str = "tool0"
    tracker_frame: str = "tracker"
    marker_frame: str = "marker"
    force: bool = False
    accept_edited: bool = False


def _check_names(settings: RosExportSettings) -> None:
    """Refuse, before anything is read or written, a frame name that is not a ROS frame name
    (docs/formats.md, "Names"), naming the option that gave it."""
    frames = [("--base-frame", settings.base_frame), ("--tracker-frame", settings.tracker_frame)]
    if settings.easy_handeye2:
        frames += [("--tool-frame", settings.tool_frame), ("--marker-frame", settings.marker_frame)]
    for flag, value in frames:
        check_ros_frame_name(value, flag)
    if settings.easy_handeye2:
        check_calibration_name(
            Path(settings.easy_handeye2).stem, "--easy-handeye2: the calibration name (the file's stem)"
        )


def export_ros(settings: RosExportSettings, write: bool = True) -> CommandResult[CalibrationResult]:
    """Write each ROS export named: a result whose lines say one export each, after a
    ``note: ...`` line for a calibration that cannot be verified or was accepted edited.

    Every file's text is made, and so every name and the calibration checked, before any is
    written: a refused export leaves no other written. ``write=False`` only checks (the
    command line does so before it writes the other exports of the same command).
    """
    for output in (settings.easy_handeye2, settings.ros2_launch, settings.urdf, settings.ur_calibration):
        refuse_overwriting_inputs(output, settings.calibration, force=settings.force)
    _check_names(settings)
    calibration, notes = open_calibration(settings.calibration, "export", settings.accept_edited)
    edge = calibration_static_transform(
        calibration.tracker_from_base, base_frame=settings.base_frame, tracker_frame=settings.tracker_frame
    )
    done = [f"note: {note}" for note in notes]
    files: list[tuple[Path, str, str]] = []  # (path, text, what it is)
    if settings.easy_handeye2:
        files.append(
            (
                Path(settings.easy_handeye2),
                easy_handeye2_calibration_text(
                    calibration.tracker_from_base,
                    name=Path(settings.easy_handeye2).stem,
                    robot_base_frame=settings.base_frame,
                    robot_effector_frame=settings.tool_frame,
                    tracking_base_frame=settings.tracker_frame,
                    tracking_marker_frame=settings.marker_frame,
                ),
                f"easy_handeye2 eye-on-base: {settings.base_frame} -> {settings.tracker_frame}",
            )
        )
    if settings.ros2_launch:
        files.append(
            (
                Path(settings.ros2_launch),
                ros2_launch_text(edge),
                f"ROS 2 launch file: static transform parent {settings.base_frame}, "
                f"child {settings.tracker_frame}",
            )
        )
    if settings.urdf:
        files.append(
            (
                Path(settings.urdf),
                urdf_joint_text(edge),
                f"URDF fixed joint {settings.base_frame} -> {settings.tracker_frame}",
            )
        )
    if settings.ur_calibration:
        if calibration.robot_model is None:
            raise InvalidInputError(
                "this calibration holds no identified robot model: calibrate with --method kinematic first"
            )
        model = calibration.robot_model
        if model.n_joints != N_JOINTS:
            raise InvalidInputError(
                f"--ur-calibration writes a UR arm's six joints; this calibration's robot, the "
                f"{model.name}, has {model.n_joints}"
            )
        tool = tool_offset_text(ur_flange_from_tcp(model))
        if folds_last_link(model):
            fold = (
                f"its a_6 = {float(model.a_mm[5]):.4g} mm and alpha_6 = {float(model.alpha_rad[5]):.4g} rad "
                f"are folded into the tool offset written beside them (set it as the TCP): {tool}"
            )
        else:
            fold = f"tool offset to set as the TCP with it: {tool}"
        files.append(
            (
                Path(settings.ur_calibration),
                ur_calibration_text(model),
                f"UR ROS driver kinematics of the identified {model.name}; {fold}",
            )
        )
    if not write:
        return CommandResult(calibration, notes=tuple(notes), provenance=calibration.provenance)
    for path, text, what in files:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(text, path)
        done.append(f"wrote {path} ({what})")
    if settings.static_tf:
        done.append(static_transform_publisher_command(edge))
    return CommandResult(
        calibration,
        tuple(path for path, _, _ in files),
        tuple(notes),
        tuple(sanitize_for_terminal(line, LINE_CHARS) for line in done),  # names from the calibration
        provenance=calibration.provenance,
    )


def export_calibration(settings: ExportSettings, ros: RosExportSettings) -> CommandResult[CalibrationResult]:
    """``spacecal export``: every export named in ``settings`` and ``ros`` (without any, the
    error of :func:`~spacecal.app.files.export` naming every target).

    Every ROS file is checked before anything is written: a refused name or model leaves no
    Slicer or PLUS file behind either.
    """
    named = (ros.easy_handeye2, ros.ros2_launch, ros.urdf, ros.static_tf, ros.ur_calibration)
    if any(named):
        export_ros(ros, write=False)
    done: list[CommandResult[CalibrationResult]] = []
    if settings.slicer or settings.plus or settings.igtl or not any(named):
        done.append(export(settings))
    if any(named):
        done.append(export_ros(ros))
    return CommandResult(
        done[0].record,
        tuple(path for out in done for path in out.files_written),
        tuple(dict.fromkeys(note for out in done for note in out.notes)),
        # a note on the calibration is made by both exports: shown once
        tuple(dict.fromkeys(line for out in done for line in out.lines)),
        provenance=done[0].provenance,
    )
