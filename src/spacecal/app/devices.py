"""The devices ``acquire``, ``check`` and ``doctor`` open, and what spacecal asks of them.

One set of settings names them (:class:`DeviceSettings`: the URLs, the tracker's tool
definitions and frame rate, the robot's model and tool); device URLs go through the adapters'
one table (:data:`spacecal.adapters.DEVICE_SCHEMES`). The robot's read-only findings and the
kinematic model spacecal plans with are worked out here, before anything is uploaded or moved.
"""

from __future__ import annotations

import contextlib
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.core.ports import (
    FINDING_OK,
    FINDING_PROBLEM,
    FINDING_WARNING,
    Closable,
    ControlledRobot,
    DeviceFinding,
    Identified,
    ModelledRobot,
    Preflight,
    Robot,
    Tracker,
)
from spacecal.core.text import check_printable_token, quoted
from spacecal.geometry.rotations import rotation_angle
from spacecal.geometry.transforms import make_transform, matrix_to_rotvec, rotvec_to_matrix
from spacecal.io.ndi_rom import read_rom_marker
from spacecal.models.kinematics import RobotModel, forward_kinematics
from spacecal.models.robot_kinds import robot_kind
from spacecal.planning.motion import MotionLimits

#: The simulated robot and tracker (of a scenario), instead of a device URL.
SIMULATED = "sim"
#: Accepted tracker frame rates, Hz.
TRACKER_RATE_RANGE_HZ = (1.0, 1000.0)


@dataclass(frozen=True)
class DeviceSettings:
    """The robot and tracker of ``acquire``, ``check`` and ``doctor``.

    Attributes
    ----------
    robot, tracker : str or None
        ``sim`` (the simulated system) or device URLs (``ur://HOST``; ``ndi://...``,
        ``igtl://HOST:PORT``, ``natnet://HOST?body=RIGID_BODY``). None: not named (``doctor``
        checks only what is named).
    rom : tuple of str
        NDI tool definitions: the marker first.
    tracker_rate_hz : float
        The tracker's frame rate (Vicra 20, Vega 60), Hz.
    robot_model : str or None
        Robot kind for planning checks; None: the one the controller names (simulated devices:
        the scenario's).
    tool : (x, y, z, rx, ry, rz) or None
        The TCP in the flange frame as the teach pendant shows it: mm and a rotation vector in
        rad. None (the default) takes the TCP set on the controller; a value must match it.
    tools : tuple of (str, str)
        Further tools the tracker is opened with, as :attr:`spacecal.adapters.DeviceOptions.tools`
        takes them: (the name they are reported by, the NDI ROM file or OpenIGTLink device name).
        Further ``rom`` files are tools too, named after their files.
    """

    robot: str | None = SIMULATED
    tracker: str | None = SIMULATED
    rom: tuple[str, ...] = ()
    tracker_rate_hz: float = 20.0
    robot_model: str | None = None
    tool: tuple[float, float, float, float, float, float] | None = None
    tools: tuple[tuple[str, str], ...] = ()

    def __post_init__(self) -> None:
        check_tracker_rate_hz(self.tracker_rate_hz)
        # the command line gives None for a field no option fills (its default is ())
        object.__setattr__(self, "tools", tuple(self.tools or ()))
        if self.tool is not None:
            tool = np.asarray(self.tool, dtype=float)
            if (
                tool.shape != (6,)
                or not np.all(np.isfinite(tool))
                or np.any(np.abs(tool[:3]) > 2000)
                or np.linalg.norm(tool[3:]) > 2 * np.pi
            ):
                raise InvalidInputError(
                    "--tool takes X,Y,Z,RX,RY,RZ: mm within +-2000 and a rotation vector in rad "
                    "(at most 2 pi)"
                )

    @property
    def simulated(self) -> bool:
        """Both devices are the simulated ones."""
        return self.robot == SIMULATED and self.tracker == SIMULATED


def check_tracker_rate_hz(rate_hz: object, what: str = "--tracker-rate-hz") -> float:
    """``rate_hz`` if it is a tracker frame rate spacecal accepts (a finite number in
    :data:`TRACKER_RATE_RANGE_HZ`), as a float; else one line naming ``what``.

    Raises
    ------
    InvalidInputError
    """
    low, high = TRACKER_RATE_RANGE_HZ
    if isinstance(rate_hz, bool) or not isinstance(rate_hz, (int, float)):
        raise InvalidInputError(
            f"{what} must be a positive number in {low:g}..{high:g}, got {quoted(rate_hz)}"
        )
    if not (math.isfinite(rate_hz) and low <= rate_hz <= high):
        raise InvalidInputError(f"{what} must be a positive number in {low:g}..{high:g}, got {rate_hz}")
    return float(rate_hz)


#: Longest device URL accepted (what the record keeps).
MAX_DEVICE_URL_CHARS = 500


def validate_device_url(kind: str, url: object) -> str:
    """``url`` if it names a ``kind`` device (``"robot"`` or ``"tracker"``) the way ``--robot``
    and ``--tracker`` take it: ``sim``, or a URL of the adapters' table (``ur://HOST``;
    ``ndi://SERIAL_PORT_OR_HOST[:PORT]``, ``igtl://HOST[:PORT]``,
    ``natnet://HOST[:PORT]?body=RIGID_BODY``), parsed by the same parser
    that opens the device (:func:`spacecal.adapters.device_address`). Nothing is opened.

    The URL is first held to :func:`spacecal.core.text.check_printable_token` (at most
    :data:`MAX_DEVICE_URL_CHARS` printable characters, no space, no line break): the URL
    parser would drop a tab or a line break silently, and its message quotes the URL.

    Returns
    -------
    str
        ``url`` as given.

    Raises
    ------
    InvalidInputError
        One line: not a URL of that kind of device, no host, a bad port, too long, a
        character that does not print as itself; or ``kind`` is neither.
    """
    from spacecal.adapters import ROBOT, TRACKER, device_address

    if kind not in (ROBOT, TRACKER):
        raise InvalidInputError(f"a device is a {ROBOT} or a {TRACKER}, not {quoted(kind)}")
    text = check_printable_token(url, f"the {kind}'s URL", MAX_DEVICE_URL_CHARS)
    if text != SIMULATED:
        device_address(text, kind)
    return text


#: Largest distance (mm) between where our model puts the TCP and where the controller reports it.
TCP_MISMATCH_MM = 1.0


def open_tracker(
    url: str, rom: Sequence[str], rate_hz: float, tools: Sequence[tuple[str, str]] = ()
) -> Tracker:
    """Open the tracker a URL names (``ndi://...`` with the marker's ROM first, ``igtl://...``,
    ``natnet://HOST?body=RIGID_BODY``; the URL table is :data:`spacecal.adapters.DEVICE_SCHEMES`),
    following the further ``tools`` too (:attr:`DeviceSettings.tools`)."""
    from spacecal.adapters import TRACKER, DeviceOptions, open_device

    return open_device(
        url, TRACKER, DeviceOptions(rom=tuple(rom), tracker_rate_hz=rate_hz, tools=tuple(tools))
    )


def open_robot(url: str, robot_model: str | None, control: bool, limits: MotionLimits | None = None) -> Robot:
    """Open the robot a URL names (``ur://HOST``); ``control=False`` is read-only (nothing is
    uploaded to the controller)."""
    from spacecal.adapters import ROBOT, DeviceOptions, open_device

    return open_device(url, ROBOT, DeviceOptions(robot_model=robot_model, control=control, limits=limits))


def open_hardware(devices: DeviceSettings, limits: MotionLimits | None = None) -> tuple[Robot, Tracker]:
    """Open the robot and tracker named by the settings' URLs (this is where hardware is chosen).

    The robot first: a controller that refuses us (local control, registers in use, not
    running) ends the command before the tracker is touched."""
    from spacecal.adapters import ROBOT, TRACKER, device_address

    if devices.robot in (SIMULATED, None) or devices.tracker in (SIMULATED, None):
        raise InvalidInputError("use --robot sim with --tracker sim, or real devices for both")
    device_address(devices.robot, ROBOT)  # both URLs are checked before either device is opened
    device_address(devices.tracker, TRACKER)
    # read-only until every check has passed and motion is confirmed (see acquire)
    robot = open_robot(devices.robot, devices.robot_model, False, limits)
    try:
        tracker = open_tracker(devices.tracker, devices.rom, devices.tracker_rate_hz, devices.tools)
    except BaseException:
        close_device(robot)
        raise
    return robot, tracker


def close_device(device: object) -> None:
    """Close a device that holds a connection; an error closing it is not raised (it must not
    mask the error that ended the command)."""
    if isinstance(device, Closable):
        with contextlib.suppress(OSError):
            device.close()


#: The user's --tool and the controller's TCP agree within these (mm, rad).
TOOL_MATCH_MM, TOOL_MATCH_RAD = 0.5, np.radians(0.05)


def tool_transform(tool: Sequence[float]) -> np.ndarray:
    """``flange_from_tcp`` (4, 4, mm) of a pendant-style TCP ``X, Y, Z`` (mm), ``RX, RY, RZ`` (rad)."""
    values = np.asarray(tool, dtype=float)
    return make_transform(rotvec_to_matrix(values[3:6]), values[:3])


@dataclass
class HardwareModel:
    """The robot model spacecal plans, solves IK and records with, and how it was found."""

    model: RobotModel
    source: str
    findings: list[DeviceFinding] = field(default_factory=list)
    #: The controller published its kinematics (else the DH parameters are nominal and the
    #: recording's pairs of joints and reported poses identify them afterwards).
    published: bool = False

    def problems(self) -> list[DeviceFinding]:
        return [f for f in self.findings if f.level == FINDING_PROBLEM]


def hardware_model(
    robot: Robot, robot_model: str | None, tool: Sequence[float] | None = None
) -> HardwareModel:
    """The controller's kinematic model (its calibrated DH and pendant TCP where it publishes
    them) checked against what it reports and against ``--robot-model`` (None: the model the
    robot names) / ``--tool`` (None: the controller's TCP)."""
    modelled = robot if isinstance(robot, ModelledRobot) else None
    if robot_model is not None:
        nominal = robot_kind(robot_model).model()
    elif modelled is not None and isinstance(modelled.nominal, RobotModel):
        nominal = modelled.nominal
    else:
        raise InvalidInputError("this robot does not name its model: pass --robot-model")
    if modelled is not None:
        model, source = modelled.controller_model()
    else:  # a robot that cannot say: the nominal model with the user's tool
        model = nominal.with_tcp(tool_transform(tool if tool is not None else (0.0,) * 6))
        source = f"the nominal {nominal.name} model"
    findings = []
    if tool is not None:
        wanted = tool_transform(tool)
        offset_mm = float(np.linalg.norm(wanted[:3, 3] - model.flange_from_tcp[:3, 3]))
        angle = float(rotation_angle(wanted[:3, :3].T @ model.flange_from_tcp[:3, :3]))
        if offset_mm > TOOL_MATCH_MM or angle > TOOL_MATCH_RAD:
            findings.append(
                DeviceFinding(
                    FINDING_PROBLEM,
                    "tool (TCP)",
                    f"--tool is {offset_mm:.1f} mm and {np.degrees(angle):.2f} deg from the TCP set on the "
                    "teach "
                    f"pendant ({tcp_text(model.flange_from_tcp)}): change --tool to match it, pass --tool "
                    "controller to use the pendant's, or set the right TCP on the pendant",
                )
            )
        else:
            findings.append(
                DeviceFinding(FINDING_OK, "tool (TCP)", "--tool matches the TCP set on the pendant")
            )
    state = robot.state()
    predicted = forward_kinematics(model, state.joints_rad)
    mismatch = float(np.linalg.norm(predicted[:3, 3] - state.base_from_tcp[:3, 3]))
    if mismatch > TCP_MISMATCH_MM:
        findings.append(
            DeviceFinding(
                FINDING_PROBLEM,
                "kinematics",
                f"{source} puts the TCP {mismatch:.1f} mm from where the controller reports it",
            )
        )
    return HardwareModel(model, source, findings, modelled is not None and modelled.kinematics is not None)


def tcp_text(flange_from_tcp: np.ndarray) -> str:
    values = [*flange_from_tcp[:3, 3], *matrix_to_rotvec(flange_from_tcp[:3, :3])]
    return "{:.1f},{:.1f},{:.1f} mm, {:.4f},{:.4f},{:.4f} rad".format(*values)


def marker_in_use(rom: Sequence[str]) -> dict[str, Any]:
    """The recording's ``marker`` entry: the geometry of the tool definition the tracker was
    given (the first ``--rom``), or, for a tracker that sends poses only (OpenIGTLink), a
    statement that the geometry is not known (the likelihood then places a stand-in layout by
    the measured pose to weight position against rotation, and learns the noise from the
    residuals; see :func:`spacecal.estimators.methods.observations.marker_geometry_of`)."""
    if not rom:
        return {"name": "unknown (the tracker sends poses only)", "geometry_known": False}
    marker = read_rom_marker(rom[0])
    return {**marker.to_dict(), "tool_definition": str(Path(rom[0]).resolve()), "geometry_known": True}


def device_identity(device: object) -> dict[str, str]:
    """What a device says it is (model, serial number, firmware) as recording metadata; empty
    for a device that cannot say (:class:`~spacecal.core.ports.Identified`)."""
    return device.identity().as_metadata() if isinstance(device, Identified) else {}


def robot_findings(
    robot: Robot, robot_model: str | None, tool: Sequence[float] | None = None
) -> tuple[HardwareModel, list[DeviceFinding]]:
    """The robot's own read-only checks and spacecal's (model, tool), in that order."""
    found = list(robot.preflight()) if isinstance(robot, Preflight) else []
    hardware = hardware_model(robot, robot_model, tool)
    return hardware, found + hardware.findings


def refuse_when_not_ready(findings: list[DeviceFinding]) -> None:
    """Raise with the first blocking finding, before anything is uploaded or moved."""
    blocking = [f for f in findings if f.level == FINDING_PROBLEM]
    if blocking:
        raise InvalidInputError(
            f"the robot is not ready ({blocking[0].subject}): {blocking[0].text}; nothing moved"
        )


def upload_control_program(robot: Robot) -> None:
    """Connect the robot's control interface (its program is uploaded only now, after every
    read-only check has passed and motion is confirmed); a robot without one has nothing to do."""
    if isinstance(robot, ControlledRobot):
        robot.connect_control()


def finding_line(device: str, finding: DeviceFinding) -> str:
    """One line an operator reads: ``robot: remote control: PROBLEM: ...``."""
    level = {FINDING_OK: "ok", FINDING_WARNING: "warning", FINDING_PROBLEM: "PROBLEM"}[finding.level]
    return f"{device}: {finding.subject}: {level}: {finding.text}"


def tracker_findings(tracker: Tracker) -> list[DeviceFinding]:
    return list(tracker.preflight()) if isinstance(tracker, Preflight) else []


def device_url_forms(role: str) -> str:
    """The URL forms a ``robot`` or ``tracker`` device takes, e.g. ``ur://HOST`` (for help texts)."""
    from spacecal.adapters import DEVICE_SCHEMES

    return " or ".join(row.form for row in DEVICE_SCHEMES.values() if row.role == role)


def end_programs_left_running() -> bool:
    """After a dropped robot connection the robot library's own threads may still be
    reconnecting (and may upload their program to the controller again): stop the program once
    more. True when such threads were left, and so the process should end at once, without the
    interpreter's teardown, which would destroy the library's objects under those threads (a
    crash instead of the command's exit code)."""
    # only a robot adapter that was imported can have left anything running
    ur = sys.modules.get("spacecal.adapters.ur")
    if ur is None or not ur.interfaces_left_running():
        return False
    ur.end_programs_left_running()
    return True
