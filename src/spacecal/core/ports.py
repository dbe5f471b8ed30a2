"""Device interfaces: what workflows need from a robot, a tracker and a reference instrument.

Simulated devices (:mod:`spacecal.sim.devices`) and hardware adapters
(:mod:`spacecal.adapters`) implement these; workflows talk to devices only through them.
Units at this boundary are spacecal's: mm, rad, seconds.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from spacecal.core.errors import DeviceError

#: Robot safety states, as the workflows understand them. Anything but ``normal`` ends a run;
#: the workflow names it as ``"robot " + state.replace("_", " ")``, so each value reads as the
#: end of that sentence ("robot safeguard stop", "robot program stopped on the teach pendant").
SAFETY_NORMAL = "normal"
SAFETY_PROTECTIVE_STOP = "protective_stop"
SAFETY_EMERGENCY_STOP = "emergency_stop"
SAFETY_SAFEGUARD_STOP = "safeguard_stop"
SAFETY_VIOLATION = "safety_violation"
SAFETY_FAULT = "safety_system_fault"
SAFETY_RECOVERY = "in_safety_recovery_mode"
SAFETY_STOPPED_BY_SAFETY = "stopped_by_the_safety_system"
#: Not safety states strictly, but the same for a run: the arm cannot follow its commands.
SAFETY_POWERED_OFF = "powered_off"
SAFETY_NOT_RUNNING = "not_running"
SAFETY_PROGRAM_STOPPED = "program_stopped_on_the_teach_pendant"
SAFETY_PROGRAM_PAUSED = "program_paused_on_the_teach_pendant"

#: Tracker frame status values. Only ``ok`` frames are a plainly seen marker; a pose reported
#: with any other status is recorded with its status and left out of estimation by default.
FRAME_OK = "ok"
FRAME_MISSING = "missing"
FRAME_OUT_OF_VOLUME = "out_of_volume"
FRAME_PARTIALLY_OUT_OF_VOLUME = "partially_out_of_volume"
#: The tool is not enabled on the tracker (NDI handle status 0x04): no pose.
FRAME_DISABLED = "disabled"
#: The tracker flagged its own computation of this frame (NDI port status: processing
#: exception, algorithm limitation, fell behind): a reported pose is doubtful.
FRAME_PROCESSING_EXCEPTION = "processing_exception"
#: Too much infrared light (NDI port status IR interference, or the system status bit).
FRAME_INTERFERENCE = "interference"
#: The sender marked the pose invalid but still sent one (OpenIGTLink ``TransformStatus``
#: other than OK with a real pose); placeholders (identity, zeros, NaN) are never kept.
FRAME_INVALID = "invalid"
#: Every status a frame may carry (``ok`` first).
FRAME_STATUSES = (
    FRAME_OK,
    FRAME_MISSING,
    FRAME_OUT_OF_VOLUME,
    FRAME_PARTIALLY_OUT_OF_VOLUME,
    FRAME_DISABLED,
    FRAME_PROCESSING_EXCEPTION,
    FRAME_INTERFERENCE,
    FRAME_INVALID,
)

#: Preflight finding levels, from fine to blocking.
FINDING_OK, FINDING_WARNING, FINDING_PROBLEM = "ok", "warning", "problem"


@dataclass(frozen=True)
class DeviceFinding:
    """One thing a read-only preflight found out about a device.

    Attributes
    ----------
    level : str
        ``ok`` (information), ``warning`` (the run can go on) or ``problem`` (it cannot).
    subject : str
        What was checked, e.g. ``controller version``, ``remote control``, ``tool status``.
    text : str
        What was found and, for a problem, what to do, in a robot operator's words.
    """

    level: str
    subject: str
    text: str


#: Longest identity text kept from a device (a model name, a firmware tag).
MAX_IDENTITY_CHARS = 64
#: What a serial number may look like: a device's other answers ("could not understand: ...",
#: an error code) are not one.
_SERIAL = re.compile(r"[0-9A-Za-z][0-9A-Za-z._-]{2,39}")


def _identity_text(value: str | None) -> str | None:
    """A device's own text as it may be recorded: printable, one line, at most
    :data:`MAX_IDENTITY_CHARS` characters; None when nothing of it is left."""
    if value is None:
        return None
    text = "".join(c for c in str(value) if c.isprintable()).strip()[:MAX_IDENTITY_CHARS].strip()
    return text or None


@dataclass(frozen=True)
class DeviceIdentity:
    """What a device says it is: the one robot or tracker a calibration belongs to.

    Every field is the device's own answer, kept only when it is plain text (device replies are
    untrusted: they reach recordings, calibrations and generated files); None where the device
    does not say.

    Attributes
    ----------
    model : str or None
        The model it names (``UR10e``, ``Polaris Vega``).
    serial : str or None
        Its serial number (UR dashboard ``get serial number``; NDI ``VER 4``'s ``S/N`` line).
    firmware : str or None
        Its software version (PolyScope version; NDI freeze tag).
    """

    model: str | None = None
    serial: str | None = None
    firmware: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "model", _identity_text(self.model))
        object.__setattr__(self, "firmware", _identity_text(self.firmware))
        serial = _identity_text(self.serial)
        object.__setattr__(self, "serial", serial if serial and _SERIAL.fullmatch(serial) else None)

    def as_metadata(self) -> dict[str, str]:
        """The fields the device answered, for a recording's metadata."""
        fields = {"model": self.model, "serial": self.serial, "firmware": self.firmware}
        return {key: value for key, value in fields.items() if value is not None}


@dataclass(frozen=True)
class RobotState:
    """One controller state.

    Attributes
    ----------
    time_s : float
        Controller timestamp, s (its own clock).
    joints_rad : numpy.ndarray, shape (J,)
        Joint angles, rad: 6 on a UR arm, 7 on a Franka arm.
    base_from_tcp : numpy.ndarray, shape (4, 4)
        TCP pose from the controller's own kinematics, mm.
    safety : str
        ``normal`` or what stops the arm: one of the ``SAFETY_*`` values (protective,
        emergency and safeguard stops, safety faults, the arm not running, the control
        program stopped or paused on the teach pendant).
    moving : bool
        A motion command is still executing.
    """

    time_s: float
    joints_rad: np.ndarray
    base_from_tcp: np.ndarray
    safety: str = SAFETY_NORMAL
    moving: bool = False

    def __post_init__(self) -> None:
        # the device boundary: a controller's values are checked before anything uses them
        joints = np.asarray(self.joints_rad, dtype=float)
        pose = np.asarray(self.base_from_tcp, dtype=float)
        if not np.isfinite(self.time_s):
            raise DeviceError(f"the robot sent a state time that is not a number ({self.time_s})")
        if (
            joints.shape not in ((6,), (7,))
            or not np.all(np.isfinite(joints))
            or np.max(np.abs(joints)) > MAX_JOINT_RAD
        ):
            raise DeviceError(
                f"the robot sent joint angles that are not an arm's: {np.round(joints, 3).tolist()}"
            )
        if (
            pose.shape != (4, 4)
            or not np.all(np.isfinite(pose))
            or np.max(np.abs(pose[:3, 3])) > MAX_ROBOT_REACH_MM
        ):
            raise DeviceError("the robot sent a TCP pose that is not finite or not within its reach")


@dataclass(frozen=True)
class TrackerFrame:
    """One tracker frame for one tool.

    Attributes
    ----------
    time_s : float
        Tracker timestamp, s (its own clock).
    frame_number : int
    status : str
        One of :data:`FRAME_STATUSES`.
    tracker_from_marker : numpy.ndarray, shape (4, 4), or None
        None when the device reported no pose; a pose reported with a status other than
        ``ok`` (e.g. partially out of volume) is kept, and its status says it is doubtful.
    rms_mm : float
        The tracker's RMS fit error, NaN when not ``ok``.
    spheres_in_tracker : numpy.ndarray, shape (K, 3), or None
        Raw sphere centres where the device reports them, mm.
    tools : mapping of str to numpy.ndarray (4, 4) or None
        Further tools the tracker follows in the same frame, by the name the user gave them
        (an NDI tool definition's, an OpenIGTLink device's): ``tracker_from_<tool>``, mm, or
        None when the tool was not plainly seen (missing, or any status but ``ok``). Empty
        when the tracker follows the marker only. A pose that is not one
        (:func:`plausible_tracked_pose`) is None here and its name is in ``refused_tools``.
    tool_statuses : mapping of str to str
        The status (one of :data:`FRAME_STATUSES`) of each tool of ``tools``: why a tool has
        no pose. Filled in from the poses (``ok`` or ``missing``) where the device gives none.
    refused_tools : tuple of str
        The tools whose pose the device sent was not one (set here, never by the device).
    """

    time_s: float
    frame_number: int
    status: str
    tracker_from_marker: np.ndarray | None
    rms_mm: float = float("nan")
    spheres_in_tracker: np.ndarray | None = None
    #: True when the device sent a pose that is not one (set here, never by the device).
    refused_pose: bool = False
    tools: Mapping[str, np.ndarray | None] = field(default_factory=dict)
    tool_statuses: Mapping[str, str] = field(default_factory=dict)
    refused_tools: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        self._check_tools()
        # the device boundary: a pose that is not a rigid transform within the tracker's reach
        # (NaN, 1e30 mm, a scaled matrix) is kept as an invalid frame without a pose, a gap in
        # the run, never a sample
        if not np.isfinite(self.time_s):
            raise DeviceError(f"the tracker sent a frame time that is not a number ({self.time_s})")
        if self.tracker_from_marker is not None and not plausible_tracked_pose(self.tracker_from_marker):
            object.__setattr__(self, "tracker_from_marker", None)
            object.__setattr__(self, "status", FRAME_INVALID)
            object.__setattr__(self, "refused_pose", True)
            object.__setattr__(self, "rms_mm", float("nan"))
            object.__setattr__(self, "spheres_in_tracker", None)
        if self.spheres_in_tracker is not None and not np.all(np.isfinite(self.spheres_in_tracker)):
            object.__setattr__(self, "spheres_in_tracker", None)
        if not (np.isnan(self.rms_mm) or 0.0 <= self.rms_mm <= MAX_FIT_RMS_MM):
            object.__setattr__(self, "rms_mm", float("nan"))

    def _check_tools(self) -> None:
        """The further tools at the device boundary, as the marker's pose: a pose that is not
        a rigid transform within a tracker's reach is no pose (None, status ``invalid``), a
        doubtful one (any status but ``ok``) is not a plainly seen tool; copied (poses read-only)."""
        poses: dict[str, np.ndarray | None] = {}
        statuses: dict[str, str] = {}
        refused = list(self.refused_tools)
        for name, pose in dict(self.tools).items():
            if not isinstance(name, str) or not name.strip():
                raise DeviceError(f"a tracked tool needs a name, got {name!r}")
            status = str(dict(self.tool_statuses).get(name, FRAME_OK if pose is not None else FRAME_MISSING))
            if status not in FRAME_STATUSES:
                raise DeviceError(f"tool {name!r}: unknown frame status {status!r}")
            if pose is not None and not plausible_tracked_pose(pose):
                pose, status = None, FRAME_INVALID
                if name not in refused:
                    refused.append(name)
            elif pose is not None:
                pose = np.array(pose, dtype=float)
                pose.flags.writeable = False
            if status != FRAME_OK:
                pose = None
            elif pose is None:
                status = FRAME_MISSING
            poses[name], statuses[name] = pose, status
        object.__setattr__(self, "tools", poses)
        object.__setattr__(self, "tool_statuses", statuses)
        object.__setattr__(self, "refused_tools", tuple(refused))

    def tool(self, name: str) -> np.ndarray | None:
        """``tracker_from_<name>`` (4, 4), mm, or None when the tool was not plainly seen.

        Raises
        ------
        InvalidInputError
            The tracker does not follow a tool of that name (one line naming the ones it does).
        """
        if name not in self.tools:
            from spacecal.core.errors import InvalidInputError

            known = ", ".join(sorted(self.tools)) or "none but the marker"
            raise InvalidInputError(f"the tracker follows no tool {name!r} (its tools: {known})")
        return self.tools[name]


#: Joint angles beyond this (rad) are not a UR's (its joints turn +-2 pi; a margin for wrap).
MAX_JOINT_RAD = 4.0 * np.pi
#: A TCP farther than this from the base (mm) is not within any arm's reach.
MAX_ROBOT_REACH_MM = 10_000.0
#: A marker farther than this from the tracker (mm) is not within any optical tracker's or
#: camera's working volume (a Polaris Vega reaches 3 m).
MAX_TRACKED_DISTANCE_MM = 20_000.0
#: A fit RMS above this (mm) is not a tracker's figure for a seen marker.
MAX_FIT_RMS_MM = 100.0


def plausible_tracked_pose(pose: np.ndarray) -> bool:
    """True for a finite rigid transform (4, 4) whose translation is within
    :data:`MAX_TRACKED_DISTANCE_MM`: rotation orthonormal to 1e-3, last row 0 0 0 1."""
    pose = np.asarray(pose, dtype=float)
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        return False
    if np.max(np.abs(pose[:3, 3])) > MAX_TRACKED_DISTANCE_MM:
        return False
    rotation = pose[:3, :3]
    return bool(
        np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-3)
        and np.linalg.det(rotation) > 0
        and np.allclose(pose[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9)
    )


def refused_poses_finding(refused: int, frames: int) -> DeviceFinding | None:
    """A preflight's problem when the tracker sent poses that are not one (NaN, a marker
    beyond any tracker's reach, a scaled matrix: :func:`plausible_tracked_pose`), else None.

    A run keeps such frames as gaps; a tracker that sends them at all is broken or
    misconfigured (wrong units, a transform that is not the marker's), so ``doctor`` does not
    pass it."""
    if refused == 0:
        return None
    return DeviceFinding(
        FINDING_PROBLEM,
        "marker poses",
        f"{refused} of {frames} marker pose(s) were not a pose (not finite, beyond "
        f"{MAX_TRACKED_DISTANCE_MM / 1000:g} m, or not a rigid transform): check the tracker's "
        "output, its units and which transform it sends",
    )


@runtime_checkable
class Robot(Protocol):
    """A position-controlled 6-joint arm."""

    def state(self) -> RobotState:
        """The newest controller state."""

    def move_joints(self, joints_rad: np.ndarray, speed_rad_s: float, accel_rad_s2: float) -> None:
        """Move to joint angles (6,) and return when there."""

    def move_linear(
        self, base_from_tcp: np.ndarray, speed_mm_s: float, accel_mm_s2: float, asynchronous: bool = False
    ) -> None:
        """Straight-line TCP move to a pose (4, 4), mm; return at once when ``asynchronous``."""

    def stop(self) -> None:
        """Decelerate and stop any motion now."""


# Optional robot capabilities: a workflow asks ``isinstance(robot, StreamingRobot)``, never
# probes for a method's name. A UR controller (spacecal.adapters.ur) has all of them; the
# simulated arm streams its states; a robot that has none of them is still a Robot.


@runtime_checkable
class StreamingRobot(Protocol):
    """A robot that keeps every controller state it receives, for the raw robot stream."""

    def drain_states(self) -> list[RobotState]:
        """The states received since the last call, oldest first (each once)."""


@runtime_checkable
class ModelledRobot(Protocol):
    """A robot whose controller names its model and publishes the kinematics it runs.

    Attributes
    ----------
    nominal : spacecal.models.RobotModel
        The nominal model (the one the controller names, or the one the user gave).
    kinematics : object or None
        What the controller published of its calibrated kinematics (None: nothing).
    """

    nominal: Any
    kinematics: Any

    def controller_model(self) -> tuple[Any, str]:
        """(the RobotModel the controller runs: its DH and TCP, where it came from in words)."""


@runtime_checkable
class ControlledRobot(Protocol):
    """A robot opened read-only whose control interface is connected (its program uploaded)
    only after every check has passed and motion is confirmed."""

    def connect_control(self) -> None:
        """Connect the control interface; nothing moves."""


@runtime_checkable
class Closable(Protocol):
    """A device holding a connection, closed on every way out."""

    def close(self) -> None:
        """Release the device; never raises for a device already gone."""


@runtime_checkable
class Tracker(Protocol):
    """An optical tracker following the calibrated marker (and any further tools it was
    given, in :attr:`TrackerFrame.tools`)."""

    def next_frame(self, timeout_s: float) -> TrackerFrame:
        """Block until a frame newer than the last one returned, at most ``timeout_s``.

        Raises
        ------
        spacecal.core.errors.DeviceError
            When no new frame arrives in time (unplugged, stalled stream).
        """


@runtime_checkable
class Preflight(Protocol):
    """A device that can report on itself without moving anything (``spacecal doctor``)."""

    def preflight(self) -> list[DeviceFinding]:
        """Read-only checks: version, modes, configuration, what the device sees now."""


@runtime_checkable
class Identified(Protocol):
    """A device that can say which one it is (model, serial number, firmware)."""

    def identity(self) -> DeviceIdentity:
        """Ask the device; fields it does not answer are None. Never raises for a device that
        does not answer: that is an identity of Nones."""


@runtime_checkable
class PoseReference(Protocol):
    """An instrument measuring the needle pose independently (the paper's laser tracker).

    It reports in the tracker frame: the paper gives its targets and measures the reached
    poses in one "surgical space".
    """

    def measure_tracker_from_needle(self) -> np.ndarray:
        """The needle pose (4, 4) in the tracker frame, mm."""
