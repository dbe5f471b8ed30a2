"""``spacecal doctor``: read-only checks of a robot and a tracker before a run.

Each device is opened read-only (the robot gets no program uploaded, nothing moves), asked
for its own findings (:class:`spacecal.core.ports.Preflight`) and, for the robot, checked
against spacecal's settings (model, tool), exactly as ``spacecal acquire --dry-run`` does.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from spacecal.app.devices import (
    DeviceSettings,
    close_device,
    finding_line,
    open_robot,
    open_tracker,
    robot_findings,
    tracker_findings,
)
from spacecal.app.result import NOTE_CHARS, CommandResult, Quality
from spacecal.core.errors import DeviceError, InvalidInputError
from spacecal.core.ports import FINDING_PROBLEM, DeviceFinding
from spacecal.core.text import exception_line, sanitize_for_terminal


@dataclass(frozen=True)
class DoctorSettings:
    """``spacecal doctor``.

    Attributes
    ----------
    devices : DeviceSettings
        The devices to check, as ``acquire`` names them; a robot or tracker left None is not
        checked (``robot_model`` None: the model the controller names; ``tool`` None: the
        controller's TCP).
    """

    devices: DeviceSettings = field(default_factory=lambda: DeviceSettings(robot=None, tracker=None))


@dataclass
class DoctorOutput:
    """Every finding, as ``(device, finding)`` in the order checked."""

    findings: list[tuple[str, DeviceFinding]] = field(default_factory=list)

    @property
    def problems(self) -> list[tuple[str, DeviceFinding]]:
        return [(device, f) for device, f in self.findings if f.level == FINDING_PROBLEM]


def _connection_problem(exc: Exception) -> DeviceFinding:
    return DeviceFinding(FINDING_PROBLEM, "connection", exception_line(exc))


def doctor(settings: DoctorSettings) -> CommandResult[DoctorOutput]:
    """Open each named device read-only, collect its findings, close it again.

    Returns
    -------
    CommandResult of DoctorOutput
        Every finding; the quality passes when none is a problem.
    """
    devices = settings.devices
    if not devices.robot and not devices.tracker:
        raise InvalidInputError("name a device to check: --robot ur://HOST and/or --tracker URL")
    output = DoctorOutput()
    if devices.robot:
        try:
            robot = open_robot(devices.robot, devices.robot_model, control=False)
        except DeviceError as exc:
            output.findings.append(("robot", _connection_problem(exc)))
        else:
            try:
                _, found = robot_findings(robot, devices.robot_model, devices.tool)
                output.findings += [("robot", f) for f in found]
            except DeviceError as exc:  # it stopped answering (a call passed its deadline)
                output.findings.append(("robot", _connection_problem(exc)))
            finally:
                close_device(robot)
    if devices.tracker:
        try:
            tracker = open_tracker(devices.tracker, devices.rom, devices.tracker_rate_hz)
        except DeviceError as exc:
            output.findings.append(("tracker", _connection_problem(exc)))
        except InvalidInputError as exc:
            # a missing or unreadable tool definition (a camera's board or intrinsics) is the
            # tracker's finding: the robot's findings, already collected, are still reported beside it
            subject = "configuration" if devices.tracker.startswith("camera:") else "tool definition"
            output.findings.append(("tracker", DeviceFinding(FINDING_PROBLEM, subject, str(exc))))
        else:
            try:
                output.findings += [("tracker", f) for f in tracker_findings(tracker)]
            except DeviceError as exc:  # it stopped answering (a call passed its deadline)
                output.findings.append(("tracker", _connection_problem(exc)))
            finally:
                close_device(tracker)
    return doctor_result(output.findings)


def doctor_result(findings: list[tuple[str, DeviceFinding]]) -> CommandResult[DoctorOutput]:
    """The result of ``doctor`` from its findings, as ``(device, finding)`` in the order checked:
    one line per finding, and a quality that fails on any problem."""
    output = DoctorOutput(list(findings))
    # devices name things: every line is escaped and cut for a terminal
    lines = [sanitize_for_terminal(finding_line(device, f), NOTE_CHARS) for device, f in output.findings]
    count = len(output.problems)
    if count:
        quality = Quality(
            False,
            f"{count} problem{'s' if count > 1 else ''} found",
            f"{count} problem{'s' if count > 1 else ''} found (marked PROBLEM above); fix "
            f"{'them' if count > 1 else 'it'} before running spacecal acquire",
        )
    else:
        lines.append("every check passed: spacecal acquire can start")
        quality = Quality(True, "every check passed")
    return CommandResult(output, lines=tuple(lines), quality=quality)
