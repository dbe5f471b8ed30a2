"""TUM trajectory files: one pose per line, ``timestamp tx ty tz qx qy qz qw``.

The format of the TUM RGB-D benchmark (Sturm et al., IROS 2012, doi:10.1109/IROS.2012.6385773),
written and read by evo and most SLAM and hand-eye tools:

* columns separated by spaces or tabs; lines starting with ``#`` are comments (a ``#`` after
  the numbers starts a comment too); blank lines are skipped;
* ``timestamp``: seconds, strictly increasing;
* ``tx ty tz``: the body's origin in the world frame, metres (``units="mm"`` for files in mm);
* ``qx qy qz qw``: the body's orientation in the world frame, a Hamilton unit quaternion,
  scalar last.

Each line is the pose of the body in the world, i.e. our ``world_from_body`` (it maps body
coordinates into the world). Which frames "world" and "body" are is the caller's to say (a
robot's base and TCP, a tracker and its marker, a target and a camera); this module converts
exactly the numbers: metres to mm and ``x, y, z, w`` to a 4x4 matrix, and back.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.geometry.transforms import (
    MEASURED_TRANSFORM_ATOL,
    check_transform,
    make_transform,
    matrix_to_quaternion_wxyz,
    quaternion_wxyz_to_matrix,
)
from spacecal.io.atomic import write_text_atomic
from spacecal.io.csv_core import MAX_ABS_POSITION_MM, MAX_ABS_TIME_S
from spacecal.io.text import read_text_file
from spacecal.records import RawRecording

#: Length units a TUM file may be in, and millimetres per unit.
MM_PER_UNIT = {"m": 1000.0, "mm": 1.0}

#: Largest TUM file read (bytes): 3.5 million poses at full double precision (150 bytes a
#: line); an hour of a 500 Hz robot is 1.8 million.
MAX_TUM_BYTES = 512 * 1024**2

#: Most poses in one file.
MAX_POSES = 5_000_000

#: Largest translation component accepted, metres: beyond it a number is not a position.
MAX_ABS_TRANSLATION_M = 1e6

#: Largest deviation of a quaternion's norm from 1 that is normalised away. Files written with
#: four decimals (the TUM RGB-D ground truth) deviate by up to about 2e-4; a quaternion off by
#: more is not a rotation (or its columns are not ``qx qy qz qw``).
QUATERNION_NORM_TOLERANCE = 1e-3

#: Positions all below this (mm) are metres read as mm (as :func:`spacecal.core.units.check_lengths_in_mm`).
SMALLEST_EXTENT_MM = 5.0

#: Segment label of every robot state of an import.
ROBOT_SEGMENT = "tum"

#: The header line written above the poses.
COLUMNS_LINE = "# timestamp tx ty tz qx qy qz qw"

# a plain decimal number: no ``_`` separators, no hex, no nan or inf
_NUMBER = r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"
_POSE_LINE = re.compile(r"\s*" + r"\s+".join([f"({_NUMBER})"] * 8) + r"\s*")
_NUMBER_TOKEN = re.compile(_NUMBER)
_NAMES = ("timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw")


@dataclass(frozen=True)
class TumTrajectory:
    """The poses of one TUM file, in spacecal's units.

    Attributes
    ----------
    time_s : numpy.ndarray, shape (N,)
        The file's timestamps, seconds, strictly increasing.
    world_from_body_stack : numpy.ndarray, shape (N, 4, 4)
        Each line's pose, translations in mm.
    lines : numpy.ndarray of int, shape (N,)
        The line number of each pose in the file (for messages).
    path : Path or None
        The file read.
    units : str
        Length unit of the file (``"m"`` or ``"mm"``).
    normalised : int
        Quaternions whose norm differed from 1 by more than 1e-9 (and at most
        ``QUATERNION_NORM_TOLERANCE``) and were normalised.
    """

    time_s: np.ndarray
    world_from_body_stack: np.ndarray
    lines: np.ndarray
    path: Path | None = None
    units: str = "m"
    normalised: int = 0

    def __len__(self) -> int:
        return len(self.time_s)


def _check_units(units: str) -> float:
    if units not in MM_PER_UNIT:
        raise InvalidInputError(f"TUM units must be one of {', '.join(MM_PER_UNIT)}, got {units!r}")
    return MM_PER_UNIT[units]


def _bad_line(path: Path, number: int, line: str) -> InvalidInputError:
    """The one-line error for a data line that is not eight plain numbers."""
    where = f"{path}: line {number}"
    if "," in line:
        return InvalidInputError(
            f"{where}: commas; a TUM file separates its columns with spaces: timestamp tx ty tz qx qy qz qw"
        )
    tokens = line.split()
    if len(tokens) != 8:
        return InvalidInputError(
            f"{where}: {len(tokens)} columns; a TUM line has 8: timestamp tx ty tz qx qy qz qw"
        )
    for name, token in zip(_NAMES, tokens):
        if _NUMBER_TOKEN.fullmatch(token):
            continue
        if token.lower().lstrip("+-") in ("nan", "inf", "infinity"):
            return InvalidInputError(f"{where}: {name} {token!r} is not a finite number")
        hint = " (a header line must start with #)" if name == "timestamp" and token.isalpha() else ""
        return InvalidInputError(f"{where}: {name} {token[:40]!r} is not a plain number{hint}")
    return InvalidInputError(f"{where}: not a TUM pose line")  # pragma: no cover - the regex matches then


def read_tum(path: str | Path, units: str = "m", what: str = "TUM trajectory") -> TumTrajectory:
    """Read and check a TUM trajectory file.

    Parameters
    ----------
    path : str or Path
    units : {"m", "mm"}
        Length unit of ``tx ty tz`` in the file.
    what : str
        What the file is, for the messages (e.g. "robot TUM trajectory").

    Returns
    -------
    TumTrajectory
        Timestamps (s) and ``world_from_body`` poses in mm.

    Raises
    ------
    InvalidInputError
        One line naming the file and line: a missing, binary or oversized file; no poses; a
        line without exactly 8 plain numbers (``1_000``, ``nan``, ``inf``, ``0x1p3`` and
        commas are refused); a non-finite or absurd number (a timestamp beyond 1e10 s, a
        translation beyond 1e6 m); a quaternion whose norm is off 1 by more than
        ``QUATERNION_NORM_TOLERANCE`` (smaller deviations are normalised); a timestamp not
        after the one before it.
    """
    scale = _check_units(units)
    path = Path(path)
    if path.is_file() and path.stat().st_size > MAX_TUM_BYTES:
        raise InvalidInputError(
            f"{path}: {path.stat().st_size / 1024**2:.0f} MB is too large for a {what} "
            f"(at most {MAX_TUM_BYTES // 1024**2} MB)"
        )
    text = read_text_file(path, what)
    rows: list[tuple[str, ...]] = []
    numbers: list[int] = []
    for number, line in enumerate(text.splitlines(), start=1):
        data = line.split("#", 1)[0]
        if not data.strip():
            continue
        match = _POSE_LINE.fullmatch(data)
        if match is None:
            raise _bad_line(path, number, data)
        rows.append(match.groups())
        numbers.append(number)
        if len(rows) > MAX_POSES:
            raise InvalidInputError(f"{path}: more than {MAX_POSES} poses; too many for a {what}")
    if not rows:
        raise InvalidInputError(f"{path}: no poses (only comments or blank lines); expected a {what}")
    values = np.array(rows, dtype=float)
    lines = np.array(numbers)

    bad = ~np.isfinite(values)
    if bad.any():
        k, column = np.argwhere(bad)[0]
        token = rows[k][column][:40]
        raise InvalidInputError(
            f"{path}: line {lines[k]}: {_NAMES[column]} {token} overflows (not a finite number)"
        )
    time_s, translation, quaternion_xyzw = values[:, 0], values[:, 1:4], values[:, 4:8]
    absurd = np.flatnonzero(np.abs(time_s) > MAX_ABS_TIME_S)
    if len(absurd):
        k = absurd[0]
        raise InvalidInputError(
            f"{path}: line {lines[k]}: timestamp {time_s[k]:.6g} is beyond +-{MAX_ABS_TIME_S:g} s "
            "(TUM timestamps are seconds, not nanoseconds)"
        )
    limit = MAX_ABS_TRANSLATION_M * MM_PER_UNIT["m"] / scale
    absurd = np.flatnonzero(np.any(np.abs(translation) > limit, axis=1))
    if len(absurd):
        k = absurd[0]
        value = translation[k][np.abs(translation[k]) > limit][0]
        raise InvalidInputError(
            f"{path}: line {lines[k]}: translation {value:.6g} {units} is beyond +-{limit:g} {units}; "
            "not a position"
        )
    norms = np.linalg.norm(quaternion_xyzw, axis=1)
    off = np.flatnonzero(np.abs(norms - 1.0) > QUATERNION_NORM_TOLERANCE)
    if len(off):
        k = off[0]
        raise InvalidInputError(
            f"{path}: line {lines[k]}: quaternion qx qy qz qw has norm {norms[k]:.6g}; expected a unit "
            f"quaternion ({len(off)} line(s) affected)"
        )
    not_after = np.flatnonzero(np.diff(time_s) <= 0)
    if len(not_after):
        k = not_after[0] + 1
        kind = "repeats" if time_s[k] == time_s[k - 1] else "is before"
        raise InvalidInputError(
            f"{path}: line {lines[k]}: timestamp {rows[k][0]} {kind} the previous pose's "
            f"({rows[k - 1][0]}, line {lines[k - 1]}); timestamps must strictly increase"
        )
    quaternion_wxyz = np.roll(quaternion_xyzw / norms[:, None], 1, axis=1)
    return TumTrajectory(
        time_s=time_s,
        world_from_body_stack=make_transform(quaternion_wxyz_to_matrix(quaternion_wxyz), translation * scale),
        lines=lines,
        path=path,
        units=units,
        normalised=int(np.sum(np.abs(norms - 1.0) > 1e-9)),
    )


def tum_text(time_s, world_from_body_stack, units: str = "m", comments: tuple[str, ...] = ()) -> str:
    """The text of a TUM file of these poses (numbers written so that they read back exactly).

    Parameters
    ----------
    time_s : array_like, shape (N,)
        Strictly increasing timestamps, seconds.
    world_from_body_stack : array_like, shape (N, 4, 4)
        Rigid poses, translations in mm.
    units : {"m", "mm"}
        Length unit to write ``tx ty tz`` in.
    comments : tuple of str
        Lines written first, each after ``#`` and a space.
    """
    scale = _check_units(units)
    time_s = np.asarray(time_s, dtype=float)
    stack = check_transform(
        world_from_body_stack, "world_from_body_stack", stack=True, atol=MEASURED_TRANSFORM_ATOL
    )
    if time_s.shape != (len(stack),):
        raise InvalidInputError(f"time_s must have shape ({len(stack)},), got {time_s.shape}")
    if not np.all(np.isfinite(time_s)) or np.any(np.diff(time_s) <= 0):
        raise InvalidInputError("time_s must be finite and strictly increasing")
    quaternion_xyzw = np.roll(matrix_to_quaternion_wxyz(stack[:, :3, :3]), -1, axis=1)
    translation = stack[:, :3, 3] / scale
    out = [f"# {line}" for comment in comments for line in comment.splitlines()]
    out.append(f"{COLUMNS_LINE}  (s, {units}, Hamilton quaternion, world_from_body)")
    for k in range(len(stack)):
        out.append(" ".join(_number(v) for v in (time_s[k], *translation[k], *quaternion_xyzw[k])))
    return "\n".join(out) + "\n"


def write_tum(
    path: str | Path, time_s, world_from_body_stack, units: str = "m", comments: tuple[str, ...] = ()
) -> Path:
    """Write a TUM trajectory file atomically (see :func:`tum_text`); returns the path."""
    return write_text_atomic(tum_text(time_s, world_from_body_stack, units, comments), path)


def _number(value: float) -> str:
    # the shortest text that reads back as the same double (-0.0 as 0.0); finite, checked above
    return repr(float(value) + 0.0)


#: Frame names of the two TUM files of an import, by set-up (``world`` and ``body`` of each file).
IMPORT_FRAMES = {
    False: {
        "robot": "base_from_tcp (TUM world: robot base, body: TCP, or the flange/gripper a robot reports)",
        "tracker": "tracker_from_marker (TUM world: tracker, body: marker)",
    },
    True: {
        "robot": "base_from_tcp (TUM world: robot base, body: TCP, or the flange/gripper a robot reports)",
        "tracker": "target_from_camera (TUM world: the fixed target, body: the camera on the tool), "
        "stored as tracker_from_marker with tracker = target, marker = camera",
    },
}


def raw_recording_from_tum(
    robot: TumTrajectory, tracker: TumTrajectory, eye_in_hand: bool = False
) -> RawRecording:
    """The raw two-stream recording of a robot and a tracker TUM trajectory, each on its own clock.

    The streams are not paired: ``spacecal calibrate ROBOT --tracker-stream TRACKER`` estimates
    the clock offset (or takes ``--time-offset-ms``) and pairs them. Both keep their own
    timestamps, counted from the earlier of the two first ones (``time_origin_s`` in the
    metadata), so the offset between the clocks is kept as it is.

    Frames. The robot file holds ``base_from_tcp`` (a robot that reports its flange or gripper
    makes that the TCP, and ``tcp_from_marker`` is then ``flange_from_marker``).

    * Eye-on-base (default), a tracker fixed beside the robot and a marker on the tool: the
      tracker file holds ``tracker_from_marker`` and
      ``tracker_from_marker_i = tracker_from_base @ base_from_tcp_i @ tcp_from_marker``.
    * Eye-in-hand (``eye_in_hand=True``), a camera on the tool and a target fixed in the
      robot's world: the tracker file is the camera's trajectory in the target's frame,
      ``target_from_camera`` (TUM's ``world_from_body`` with the target as world), and
      ``target_from_camera_i = target_from_base @ base_from_tcp_i @ tcp_from_camera``. That is
      spacecal's model with the roles swapped by the hand-eye duality: the fixed target plays
      the tracker (fixed to the base), the camera plays the marker (fixed to the TCP). The
      poses go in unchanged; the calibration's ``tracker_from_base`` is then
      ``target_from_base`` and its ``tcp_from_marker`` is ``tcp_from_camera`` (the hand-eye
      transform). A file of the target's pose in the camera (``camera_from_target``, what
      solvePnP returns) is the inverse and is not this: invert it first.

    Parameters
    ----------
    robot, tracker : TumTrajectory
        As :func:`read_tum` returns them (mm); each needs at least 10 poses.
    eye_in_hand : bool
        The tracker file is a camera on the tool looking at a fixed target (see above).

    Returns
    -------
    RawRecording
        Joints unrecorded (NaN), one segment ``tum``, ``marker_rms_mm`` NaN (pose-only: a TUM
        file carries no fit RMS); metadata: ``source`` "TUM import" and the ``tum`` entry
        (files, units, set-up, frames, time origin).

    Raises
    ------
    InvalidInputError
        Fewer than 10 poses in a file, or positions a recording cannot hold (beyond +-1e5 mm:
        a file in mm read as metres) or that look like metres read as mm.
    """
    for label, trajectory in (("robot", robot), ("tracker", tracker)):
        where = trajectory.path or f"{label} trajectory"
        if len(trajectory) < 10:
            raise InvalidInputError(f"{where}: {len(trajectory)} poses; at least 10 are needed")
        positions = trajectory.world_from_body_stack[:, :3, 3]
        beyond = np.flatnonzero(np.any(np.abs(positions) > MAX_ABS_POSITION_MM, axis=1))
        if len(beyond):
            k = beyond[0]
            value = (
                positions[k][np.abs(positions[k]) > MAX_ABS_POSITION_MM][0] / MM_PER_UNIT[trajectory.units]
            )
            hint = "; is the file in mm? (--units mm)" if trajectory.units == "m" else ""
            raise InvalidInputError(
                f"{where}: line {trajectory.lines[k]}: translation {value:.6g} {trajectory.units} is "
                f"beyond the +-{MAX_ABS_POSITION_MM / 1000:g} m a recording holds{hint}"
            )
        largest = float(np.max(np.abs(positions)))
        if largest < SMALLEST_EXTENT_MM:
            hint = " (TUM files are in metres: leave out --units mm)" if trajectory.units == "mm" else ""
            raise InvalidInputError(
                f"{where}: every translation is below {SMALLEST_EXTENT_MM:g} mm (largest {largest:.3g} "
                f"{trajectory.units}); these look like metres read as mm{hint}"
            )
    origin = float(min(robot.time_s[0], tracker.time_s[0]))
    count = len(robot)
    # Eye-in-hand: target_from_camera is tracker_from_marker with tracker = target and
    # marker = camera (the duality above), so the poses go in as they are, either way.
    tracker_from_marker = tracker.world_from_body_stack
    metadata = {
        "source": "TUM import",
        "tum": {
            "robot_file": None if robot.path is None else str(robot.path),
            "tracker_file": None if tracker.path is None else str(tracker.path),
            "units": {"robot": robot.units, "tracker": tracker.units},
            "eye_in_hand": bool(eye_in_hand),
            "time_origin_s": origin,
            "time": "seconds since time_origin_s, each file on its own clock (not paired)",
            "robot_poses": IMPORT_FRAMES[bool(eye_in_hand)]["robot"],
            "tracker_poses": IMPORT_FRAMES[bool(eye_in_hand)]["tracker"],
            "normalised_quaternions": {"robot": robot.normalised, "tracker": tracker.normalised},
        },
        "robot": {"name": f"poses from {_name(robot)} (TUM), no joints"},
        "tracker": {"name": f"poses from {_name(tracker)} (TUM), pose-only: no fit RMS", "pose_only": True},
        "units": {"length": "mm", "angle": "rad", "time": "s"},
    }
    if eye_in_hand:
        metadata["frames"] = {
            "tracker": "target: the calibration target, fixed in the robot's world",
            "marker": "camera: on the robot's tool",
        }
    return RawRecording(
        robot_time_s=robot.time_s - origin,
        robot_segment=np.full(count, ROBOT_SEGMENT),
        joints_rad=np.full((count, 6), np.nan),
        base_from_tcp_stack=robot.world_from_body_stack,
        tracker_time_s=tracker.time_s - origin,
        tracker_from_marker_stack=tracker_from_marker,
        marker_rms_mm=np.full(len(tracker), np.nan),
        metadata=metadata,
    )


def _name(trajectory: TumTrajectory) -> str:
    return "a trajectory" if trajectory.path is None else trajectory.path.name
