"""``spacecal doctor``: read-only checks of a robot and a tracker before a run.

Each device is opened read-only (the robot gets no program uploaded, nothing moves), asked
for its own findings (:class:`spacecal.core.ports.Preflight`) and, for the robot, checked
against spacecal's settings (model, tool), exactly as ``spacecal acquire --dry-run`` does.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from spacecal.app.acquisition import _close, open_robot, open_tracker, robot_findings, tracker_findings
from spacecal.core.errors import DeviceError, InvalidInputError
from spacecal.core.ports import FINDING_PROBLEM, DeviceFinding


@dataclass(frozen=True)
class DoctorSettings:
    """``spacecal doctor``.

    Attributes
    ----------
    robot : str or None
        ``ur://HOST``.
    tracker : str or None
        ``ndi://...`` or ``igtl://HOST:PORT``.
    rom : tuple of str
        NDI tool definitions (the marker first).
    tracker_rate_hz : float
    robot_model : str or None
        None: the model the controller names.
    tool : (x, y, z, rx, ry, rz) or None
        The TCP spacecal is told (mm, rotation vector in rad); None: the controller's.
    """

    robot: str | None = None
    tracker: str | None = None
    rom: tuple[str, ...] = ()
    tracker_rate_hz: float = 20.0
    robot_model: str | None = None
    tool: tuple[float, float, float, float, float, float] | None = None


@dataclass
class DoctorOutput:
    """Every finding, as ``(device, finding)`` in the order checked."""

    findings: list[tuple[str, DeviceFinding]] = field(default_factory=list)

    @property
    def problems(self) -> list[tuple[str, DeviceFinding]]:
        return [(device, f) for device, f in self.findings if f.level == FINDING_PROBLEM]


def _connection_problem(exc: Exception) -> DeviceFinding:
    return DeviceFinding(FINDING_PROBLEM, "connection", " ".join(str(exc).split()) or type(exc).__name__)


def doctor(settings: DoctorSettings) -> DoctorOutput:
    """Open each named device read-only, collect its findings, close it again."""
    if not settings.robot and not settings.tracker:
        raise InvalidInputError("name a device to check: --robot ur://HOST and/or --tracker URL")
    output = DoctorOutput()
    if settings.robot:
        try:
            robot = open_robot(settings.robot, settings.robot_model, control=False)
        except DeviceError as exc:
            output.findings.append(("robot", _connection_problem(exc)))
        else:
            try:
                _, found = robot_findings(robot, settings.robot_model, _tool(settings.tool))
                output.findings += [("robot", f) for f in found]
            except DeviceError as exc:  # it stopped answering (a call passed its deadline)
                output.findings.append(("robot", _connection_problem(exc)))
            finally:
                _close(robot)
    if settings.tracker:
        try:
            tracker = open_tracker(settings.tracker, settings.rom, settings.tracker_rate_hz)
        except DeviceError as exc:
            output.findings.append(("tracker", _connection_problem(exc)))
        except InvalidInputError as exc:
            # a missing or unreadable tool definition is the tracker's finding: the robot's
            # findings, already collected, are still reported beside it
            output.findings.append(("tracker", DeviceFinding(FINDING_PROBLEM, "tool definition", str(exc))))
        else:
            try:
                output.findings += [("tracker", f) for f in tracker_findings(tracker)]
            except DeviceError as exc:  # it stopped answering (a call passed its deadline)
                output.findings.append(("tracker", _connection_problem(exc)))
            finally:
                _close(tracker)
    return output


def _tool(tool: Sequence[float] | None) -> Sequence[float] | None:
    return None if tool is None else tuple(float(v) for v in tool)
