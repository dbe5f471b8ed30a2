"""Small helpers the app functions share: outputs that must not overwrite inputs or results
(what a recording file is, :func:`~spacecal.io.recording_files.is_recording` decides),
provenance, and reading a calibration whose content hash is checked."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from spacecal.adapters import canonical_url
from spacecal.app.devices import DeviceSettings
from spacecal.app.motion_settings import MotionSettings, WorkspaceBox
from spacecal.core.errors import DegenerateDataError, InvalidInputError
from spacecal.io.digest import file_sha256, spacecal_schema_of
from spacecal.io.recordings import is_recording, metadata_path
from spacecal.io.results_json import read_calibration, read_json_object
from spacecal.records import CalibrationResult, Provenance, Recording, RecordingSource
from spacecal.sim.scenario import DEFAULT_SCENARIO, Scenario, load_scenario, scenario_from_dict

#: What an existing spacecal file is, by its ``schema``, for the line that refuses to replace it.
RESULT_KINDS = {
    "spacecal.calibration": "calibration",
    "spacecal.verification": "verification result",
    "spacecal.check": "check history",
    "spacecal.phantom": "phantom result",
    "spacecal.landmark_registration": "landmark registration",
    "spacecal.pivot": "pivot result",
    "spacecal.plan": "plan",
    "spacecal.acquisition_progress": "acquisition progress file",
}


def refuse_overwriting_inputs(
    output: str | Path | None,
    *inputs: str | Path | None,
    force: bool = False,
    recordings: bool = True,
    any_file: bool = False,
) -> None:
    """Raise if ``output`` names one of the command's own input files, an existing recording
    or an existing spacecal result (a calibration, a check history, ...), unless ``force``
    (outputs are written atomically, after the inputs are read).

    ``any_file``: the command writes a result file, and replaces no existing file of any kind
    without ``force`` (a calibration, a verification, a plan: each is evidence of its own).
    """
    if output is None or force:
        return
    target = Path(output).resolve()
    for item in inputs:
        if item is not None and Path(item).resolve() == target:
            raise InvalidInputError(
                f"{output}: the output would overwrite an input of this command; choose another file "
                "or pass --force"
            )
    if recordings and is_recording(target):
        raise InvalidInputError(
            f"{output}: an existing recording; choose another file or pass --force to replace it"
        )
    schema = spacecal_schema_of(target)
    if schema is not None or (any_file and target.exists()):
        kind = RESULT_KINDS.get(schema or "", "spacecal file" if schema else "file")
        raise InvalidInputError(
            f"{output}: an existing {kind}; choose another file or pass --force to replace it"
        )


def guard_outputs(
    outputs: list[str | Path | None], inputs: list[str | Path | None], force: bool, any_file: bool = False
) -> None:
    """:func:`refuse_overwriting_inputs` for each of several outputs."""
    for output in outputs:
        refuse_overwriting_inputs(output, *inputs, force=force, any_file=any_file)


#: How to let an edited calibration through, in the commands that allow it.
ACCEPT_EDITED = "--accept-edited"


def open_calibration(
    path: str | Path, command: str, accept_edited: bool | None = None
) -> tuple[CalibrationResult, list[str]]:
    """Read a calibration and check its content hash; returns it and the notes to show.

    Parameters
    ----------
    path : str or Path
    command : str
        The command reading it (named when an edited file is refused).
    accept_edited : bool or None
        False: refuse an edited file, naming ``--accept-edited``; True: use it with a note;
        None: the command takes no edited calibration at all (``verify``, ``bound``,
        ``acquire --prior``), and the refusal says so.

    Raises
    ------
    InvalidInputError
        The file is not a calibration this spacecal reads (a future version is refused,
        naming the versions it reads), or it has been edited and that is not accepted.
    """
    calibration = read_calibration(path)
    integrity = calibration.integrity
    if integrity is None or integrity.unverifiable:
        return calibration, [
            f"{path} is a version {calibration.schema_version} calibration, written before calibrations "
            "carried a content hash: it cannot be verified (calibrating again writes one)"
        ]
    if not integrity.edited:
        return calibration, []
    why = "content hash missing" if integrity.recorded_sha256 is None else "content hash differs"
    edited = f"{path} has been edited since it was written ({why})"
    if accept_edited is None:
        raise InvalidInputError(
            f"{edited}; {command} does not use an edited calibration (calibrate again, or restore the "
            "file as calibrate wrote it)"
        )
    if not accept_edited:
        raise InvalidInputError(f"{edited}; pass {ACCEPT_EDITED} to use it anyway")
    return calibration, [f"{edited}; used as {ACCEPT_EDITED} asks"]


def other_devices(
    calibration: CalibrationResult,
    robot_url: str,
    tracker_url: str,
    robot_model: str,
    accept: bool,
    robot_identity: Mapping[str, str] | None = None,
    tracker_identity: Mapping[str, str] | None = None,
) -> list[str]:
    """Compare the real devices connected with those the calibration records; returns notes.

    A device is compared by its serial number where the calibration records one and the device
    connected says its own (``robot_identity`` / ``tracker_identity``, from
    :func:`~spacecal.app.devices.device_identity`): the same serial at a new address is the same
    device. Otherwise by URL. The robot's model is compared where recorded; a calibration of
    simulated data on real devices is a mismatch too.

    Raises
    ------
    InvalidInputError
        On a mismatch, unless ``accept`` (``--accept-other-devices``): then it is a note.
    """
    provenance = calibration.provenance
    recorded_robot = provenance.devices.get("robot") or {}
    recorded_tracker = provenance.devices.get("tracker") or {}
    differences = []
    if provenance.simulated is True:
        differences.append("it was calibrated on simulated devices")
    for what, recorded, url, identity in (
        ("robot", recorded_robot, robot_url, robot_identity or {}),
        ("tracker", recorded_tracker, tracker_url, tracker_identity or {}),
    ):
        recorded_serial, connected_serial = recorded.get("serial"), identity.get("serial")
        if isinstance(recorded_serial, str) and connected_serial is not None:
            if recorded_serial != connected_serial:
                differences.append(
                    f"{what} serial number {recorded_serial} recorded, {connected_serial} connected"
                )
            continue
        recorded_url = recorded.get("url")
        if isinstance(recorded_url, str) and canonical_url(recorded_url) != canonical_url(url):
            differences.append(f"{what} {recorded_url} recorded, {url} connected")
    model = recorded_robot.get("model")
    if isinstance(model, str) and model.upper() != robot_model.upper():
        differences.append(f"a {model} recorded, a {robot_model} connected")
    if not differences:
        if not (recorded_robot.get("url") or recorded_tracker.get("url")):
            return ["the calibration records no device URLs: the devices connected were not compared"]
        return []
    text = "; ".join(differences)
    if not accept:
        raise InvalidInputError(
            f"the calibration belongs to other devices ({text}); connect those, or pass "
            "--accept-other-devices to check it on these"
        )
    return [f"checked on other devices than the calibration's ({text}), as --accept-other-devices asks"]


#: Device identity keys kept from the recording's metadata (``serial_number`` is read as ``serial``).
DEVICE_KEYS = ("station_name", "model", "url", "name", "serial", "firmware", "rate_hz")


def provenance_of(
    recording: Recording,
    source: RecordingSource | None,
    recording_path: str | Path | None = None,
    tracker_kind: str | None = None,
) -> Provenance:
    """Where a recording came from: its ``source`` (its files and their sha256, how it was
    paired: :func:`~spacecal.io.recording_source.open_path`), what its metadata says (simulated,
    the scenario, the devices), the marker's tool definition it names
    (``marker.tool_definition``, relative to ``recording_path``) with its sha256 taken now, and
    the ``tracker_kind`` it was calibrated as."""
    metadata: dict[str, Any] = recording.metadata or {}
    scenario = metadata.get("scenario")
    simulated: bool | None = metadata.get("simulated")
    if simulated is None and metadata.get("source") == "spacecal simulator":
        simulated = True
    if simulated is None and metadata.get("source") == "spacecal acquire":
        simulated = False
    devices = {}
    for role in ("robot", "tracker"):
        entry = metadata.get(role)
        if isinstance(entry, dict):
            known = {**entry}
            if "serial" not in known and "serial_number" in known:
                known["serial"] = known["serial_number"]
            devices[role] = {k: v for k, v in known.items() if k in DEVICE_KEYS}
    marker = metadata.get("marker")
    tool_definition = marker.get("tool_definition") if isinstance(marker, dict) else None
    tool_definition = tool_definition if isinstance(tool_definition, str) and tool_definition else None
    if tool_definition is not None and recording_path is not None:
        # a relative path is the recording's neighbour (acquire writes an absolute one)
        tool_definition = str(Path(recording_path).resolve().parent / tool_definition)
    return Provenance(
        source=source,
        simulated=simulated if isinstance(simulated, bool) else None,
        scenario=scenario if isinstance(scenario, dict) else None,
        devices=devices,
        tracker_kind=tracker_kind,
        tool_definition=None if tool_definition is None else str(Path(tool_definition).resolve()),
        tool_definition_sha256=(
            file_sha256(tool_definition)
            if tool_definition is not None and Path(tool_definition).is_file()
            else None
        ),
    )


def check_consistent(recording: Recording, what: str) -> None:
    """Refuse a recording that another reading of its conventions explains clearly better
    (quaternion order, inverted or conjugated poses, metres, swapped columns), naming it.

    No fixed residual limit: a distant camera leaves several mm and is sound
    (:mod:`spacecal.estimators.methods.conventions`).
    """
    from spacecal.estimators.methods.conventions import find_better_convention

    finding = find_better_convention(recording)
    if finding is not None:
        raise DegenerateDataError(finding.message(what))


def check_belongs(recording: Recording, tracker_from_base, tcp_from_marker, what: str) -> None:
    """Refuse a calibration that does not belong to ``recording`` (it explains it far worse than
    the recording's own closed-form fit), after :func:`check_consistent`."""
    from spacecal.estimators.methods.conventions import calibration_mismatch

    check_consistent(recording, what)
    reason = calibration_mismatch(recording, tracker_from_base, tcp_from_marker)
    if reason is not None:
        raise DegenerateDataError(f"{what}: {reason}")


def scenario_of_calibration(calibration: CalibrationResult) -> tuple[Scenario | None, str]:
    """The simulated scenario a calibration's data came from, and where that was found."""
    if calibration.provenance.scenario is not None:
        return scenario_from_dict(calibration.provenance.scenario), "the calibration's provenance"
    source = calibration.provenance.source
    meta = None if source is None else metadata_path(source.recording)
    if meta is not None and meta.is_file():
        data = read_json_object(meta, "recording metadata")
        if isinstance(data.get("scenario"), dict):
            return scenario_from_dict(data["scenario"]), f"the recording metadata {meta}"
    return None, ""


def simulated_scenario(calibration: CalibrationResult, scenario: str | None) -> Scenario:
    """The world simulated devices run in for a calibration: ``scenario`` (a preset or file)
    when given, else the one its data came from (:func:`scenario_of_calibration`).

    Raises
    ------
    InvalidInputError
        None given and none found with the calibration.
    """
    found = load_scenario(scenario) if scenario is not None else scenario_of_calibration(calibration)[0]
    if found is None:
        raise InvalidInputError("no scenario given and none found with the calibration; pass --scenario")
    return found


def calibration_motion(
    calibration: CalibrationResult,
    devices: DeviceSettings,
    scenario: str | None,
    dry_run: bool,
    confirm_robot_motion: bool,
    workspace_box: WorkspaceBox | None,
    simulated_speed: float | None,
) -> MotionSettings:
    """The motion of a command that moves a calibrated robot (``check``, ``verify``, ``guide``):
    the acquisition's speeds on ``devices``; simulated devices run in the calibration's world
    (:func:`simulated_scenario`), real ones need none."""
    return MotionSettings(
        devices=devices,
        scenario=simulated_scenario(calibration, scenario) if devices.simulated else DEFAULT_SCENARIO,
        dry_run=dry_run,
        confirm_robot_motion=confirm_robot_motion,
        workspace_box=workspace_box,
        simulated_speed=simulated_speed,
    )
