"""App function ``import-poses``: a robot and a tracker pose trajectory (TUM files) as a raw
two-stream recording, for the tools (evo, SLAM systems) and public hand-eye data sets that
write TUM trajectories."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from spacecal.app._common import guard_outputs
from spacecal.app.result import CommandResult, note_lines
from spacecal.core.errors import InvalidInputError
from spacecal.io.recordings import stream_paths, write_raw_recording
from spacecal.io.tum import MM_PER_UNIT, raw_recording_from_tum, read_tum
from spacecal.records import RawRecording


@dataclass(frozen=True)
class ImportPosesSettings:
    """``spacecal import-poses``: two TUM trajectories as ``STEM.robot.csv`` + ``STEM.tracker.csv``.

    Attributes
    ----------
    robot : str
        TUM file of the robot's poses, ``base_from_tcp`` (or base_from_flange / gripper).
    tracker : str
        TUM file of the tracker's poses: ``tracker_from_marker``, or with ``eye_in_hand`` the
        camera's trajectory in the target's frame, ``target_from_camera``.
    output : str
        Stem of the robot stream, the tracker stream and their metadata file
        (:func:`~spacecal.io.recording_files.stream_paths` names them).
    units : {"m", "mm"}
        Length unit of both files (TUM files are in metres).
    eye_in_hand : bool
        A camera on the tool looking at a fixed target (see
        :func:`spacecal.io.tum.raw_recording_from_tum` for the frames).
    force : bool
        Replace existing streams.
    """

    robot: str
    tracker: str
    output: str
    units: str = "m"
    eye_in_hand: bool = False
    force: bool = False

    def __post_init__(self) -> None:
        if self.units not in MM_PER_UNIT:
            raise InvalidInputError(f"--units must be one of {', '.join(MM_PER_UNIT)}, got {self.units!r}")


def import_poses(settings: ImportPosesSettings) -> CommandResult[RawRecording]:
    """Read both TUM files, check them, and write the raw two-stream recording (not paired:
    ``spacecal calibrate STEM.robot.csv --tracker-stream STEM.tracker.csv`` does that).

    Returns
    -------
    CommandResult of RawRecording
        The two streams; the robot CSV, the tracker CSV and the metadata written, in that order.
    """
    stem = settings.output[:-4] if settings.output.endswith(".csv") else settings.output
    paths = stream_paths(stem)
    guard_outputs(list(paths), [settings.robot, settings.tracker], settings.force)
    if Path(settings.robot).resolve() == Path(settings.tracker).resolve():
        raise InvalidInputError(f"{settings.robot}: given as both the robot and the tracker trajectory")
    robot = read_tum(settings.robot, settings.units, "robot TUM trajectory")
    tracker = read_tum(settings.tracker, settings.units, "tracker TUM trajectory")
    raw = raw_recording_from_tum(robot, tracker, settings.eye_in_hand)
    robot_path, tracker_path = write_raw_recording(raw, stem)
    notes = _clock_notes(raw)
    line = (
        f"wrote {robot_path} ({len(raw.robot_time_s)} robot poses) and {tracker_path} "
        f"({len(raw.tracker_time_s)} tracker poses{', eye-in-hand' if settings.eye_in_hand else ''}); "
        f"calibrate with: spacecal calibrate {robot_path} --tracker-stream {tracker_path} --method ml"
    )
    return CommandResult(raw, (robot_path, tracker_path, paths[2]), notes, (line, *note_lines(notes)))


def _clock_notes(raw: RawRecording) -> tuple[str, ...]:
    """A note when the two files' times do not overlap: their clocks are apart by more than the
    recording lasts, which the offset estimate (a search near zero) does not bridge."""
    robot, tracker = raw.robot_time_s, raw.tracker_time_s
    if tracker[-1] >= robot[0] and tracker[0] <= robot[-1]:
        return ()
    lead = robot[0] - tracker[0]
    return (
        f"the two files' timestamps do not overlap (the robot's start {abs(lead):.3f} s "
        f"{'after' if lead > 0 else 'before'} the tracker's): the clocks are apart; give calibrate "
        "--time-offset-ms (robot clock minus tracker clock)",
    )
