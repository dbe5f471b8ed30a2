"""The station's "guide a needle" step: a 3D Slicer plan brought to the robot (paper §5.3).

The operator uploads the plan (``.mrk.json``) and the image registration (a Slicer ``.tfm``, or
the image fiducials and the pointer's touches of them) into the calibration's folder, under
names the station chooses (the names given are kept only to be shown, as text). The station
shows where the plan lands (:func:`spacecal.app.plan_from_slicer`: entry and target in the
tracker and the robot base, the predicted error at the target) without moving, then the two
motions of :func:`spacecal.app.guidance.guide`, each behind a confirmation of its own:

* ``standoff``: to the plan's standoff on its axis, after a dry run of it passed;
* ``insert``: along the axis to the target ("advance") or holding the guide at the entry
  ("hold"), confirmed a second time, only while the robot stands where the standoff left it.

Every confirmation is bound to the files it names (their sha256) and the calibration's.
"""

from __future__ import annotations

import hashlib
import math
import secrets
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from spacecal import app
from spacecal.core.errors import InvalidInputError
from spacecal.io.results_json import read_json_object
from spacecal.io.slicer_registration import ROLES, role_from_name
from spacecal.records.guidance import GuidanceResult

#: The paper's guidance errors (§5.3): at the entry and the target, mm, and in direction, deg.
PAPER_ENTRY_MM = 0.87
PAPER_TARGET_MM = 0.83
PAPER_DIRECTION_DEG = 0.89
#: What the operator may upload: the form field, the station's name for it, the endings allowed.
UPLOADS = {
    "plan": ("guide-plan.mrk.json", (".mrk.json",)),
    "registration": ("guide-registration.tfm", (".tfm", ".txt")),
    "fiducials": ("guide-fiducials.mrk.json", (".mrk.json",)),
    "touched": ("guide-touched.csv", (".csv",)),
}
#: Longest upload name shown, characters.
NAME_LIMIT = 100
#: The insertion modes, in the operator's words.
INSERTIONS = {"advance": "advance to the target", "hold": "hold the guide at the entry"}
#: The located plan's JSON in the calibration's folder.
LOCATED_NAME = "guide-plan-located.json"


def stage_output(standoff_output: str | None, stage: str) -> str | None:
    """The guidance JSON of ``stage`` beside the standoff's (``guidance-standoff.json``)."""
    if standoff_output is None:
        return None
    return str(Path(standoff_output).with_name(f"guidance-{stage}.json"))


def standoff_from_form(text: str) -> float:
    """The standoff from the form, mm before the entry (empty: 20 mm, the command line's).

    Raises
    ------
    InvalidInputError
        Not a number in the range the guidance takes.
    """
    from spacecal.app.guidance import STANDOFF_RANGE_MM

    if not text:
        return 20.0
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    low, high = STANDOFF_RANGE_MM
    if not low <= value <= high:
        raise InvalidInputError(
            f"the standoff must be {low:g}..{high:g} mm before the entry, not {text[:20]!r}"
        )
    return value


def sha256_of(path: Path) -> str:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return "none"


def shown_name(name: str) -> str:
    """An uploaded file's name as given, bounded (the page escapes it)."""
    name = name.replace("\\", "/").rsplit("/", 1)[-1]
    return name if len(name) <= NAME_LIMIT else name[: NAME_LIMIT - 3] + "..."


def check_upload(kind: str, name: str, data: bytes) -> None:
    """Refuse an upload that is not what its field names, in one line.

    Raises
    ------
    InvalidInputError
    """
    _, endings = UPLOADS[kind]
    if not name.lower().endswith(endings):
        raise InvalidInputError(
            f"the {kind} file must end in {' or '.join(endings)}, not {shown_name(name)!r}"
        )
    if not data:
        raise InvalidInputError(f"the {kind} file {shown_name(name)!r} is empty")
    try:
        data.decode("utf-8")
    except UnicodeDecodeError:
        raise InvalidInputError(f"the {kind} file {shown_name(name)!r} is not text (UTF-8)") from None


@dataclass
class GuideStep:
    """The guidance step of one calibration at the station.

    Attributes
    ----------
    folder : Path
        The calibration's folder (the uploads and the guidance's files go there).
    calibration_path : Path
    given_names : dict of str to str
        The names the uploads were given (shown as text only).
    registration_maps : str or None
        The registration's role, or None to read it from the name given.
    located_lines : list of str
        Where the plan lands (the command line's lines of ``plan-from-slicer``).
    located : Any
        :class:`~spacecal.workflows.plan_frames.LocatedPlan`, or None.
    dry_run_lines : list of str
    basis : str or None
        What the standoff's confirmation confirms: its dry run that passed, of these files.
    standoff_run : int or None
        The run that brought the robot to the standoff, once it finished there.
    results : list of (str, GuidanceResult)
        The guidance JSON files written by the stages that ran to their end, read back.
    """

    folder: Path
    calibration_path: Path
    given_names: dict[str, str] = field(default_factory=dict)
    registration_maps: str | None = None
    standoff_mm: float = 20.0
    located_lines: list[str] = field(default_factory=list)
    located: Any = None
    dry_run_lines: list[str] = field(default_factory=list)
    basis: str | None = None
    standoff_run: int | None = None
    standoff_basis: str | None = None
    live_run: int | None = None
    live_basis: str | None = None
    results: list[Any] = field(default_factory=list)

    def path(self, kind: str) -> Path:
        return self.folder / UPLOADS[kind][0]

    def has(self, kind: str) -> bool:
        return self.path(kind).is_file()

    def forget_motions(self) -> None:
        """New inputs: no confirmation issued before holds, and the standoff is not this plan's."""
        self.basis, self.standoff_run, self.standoff_basis = None, None, None
        self.live_run, self.live_basis = None, None
        self.dry_run_lines = []

    def store(self, kind: str, name: str, data: bytes) -> None:
        """Keep an upload under the station's name for it (replacing the earlier one).

        Raises
        ------
        InvalidInputError
        """
        check_upload(kind, name, data)
        self.forget_motions()
        self.located, self.located_lines = None, []
        self.path(kind).write_bytes(data)
        self.given_names[kind] = shown_name(name)

    def set_maps(self, maps: str) -> None:
        """The registration's role from the form ("" to read it from the name given).

        Raises
        ------
        InvalidInputError
        """
        if maps and maps not in ROLES:
            raise InvalidInputError(f"the registration's role must be one of {', '.join(ROLES)}")
        if (maps or None) != self.registration_maps:
            self.forget_motions()
        self.registration_maps = maps or None

    def registration_inputs(self) -> dict[str, Any]:
        """The registration's arguments of ``plan-from-slicer`` and ``guide``: the ``.tfm`` with
        its role, else the fiducials and the touched points."""
        if self.has("registration"):
            maps = self.registration_maps or role_from_name(self.given_names.get("registration", ""))
            if maps is None:
                raise InvalidInputError(
                    "say which way the registration maps: its file name does not (e.g. TrackerToRAS.tfm)"
                )
            return {"registration": str(self.path("registration")), "registration_maps": maps}
        if self.has("fiducials") and self.has("touched"):
            return {"fiducials": str(self.path("fiducials")), "touched": str(self.path("touched"))}
        raise InvalidInputError(
            "upload the registration: a Slicer transform (.tfm), or the fiducials (.mrk.json) and "
            "the touched points (.csv)"
        )

    def inputs_sha256(self) -> str:
        """One digest of the plan, the registration files and role, and the calibration."""
        parts = [f"{kind} {sha256_of(self.path(kind))}" for kind in UPLOADS]
        parts += [f"maps {self.registration_maps}", f"calibration {sha256_of(self.calibration_path)}"]
        return hashlib.sha256("\n".join(parts).encode()).hexdigest()

    def locate(self) -> None:
        """Where the plan lands, in the tracker and the base, without moving.

        Raises
        ------
        InvalidInputError
        """
        self.located, self.located_lines = None, []
        if not self.has("plan"):
            raise InvalidInputError("upload the plan (.mrk.json) first")
        out = app.plan_from_slicer(
            app.PlanFromSlicerSettings(
                plan=str(self.path("plan")),
                calibration=str(self.calibration_path),
                output=str(self.folder / LOCATED_NAME),
                force=True,
                **self.registration_inputs(),
            )
        )
        self.located = out.record
        # the lines name the station's own file names, not the operator's
        self.located_lines = list(out.lines)

    def settings(self, devices: app.DeviceSettings, stage: str, **more: Any) -> app.GuideSettings:
        """The guidance's settings for ``stage``; its motion confirmed on the station's page."""
        return app.GuideSettings(
            plan=str(self.path("plan")),
            calibration=str(self.calibration_path),
            devices=devices,
            stage=stage,
            standoff_mm=self.standoff_mm,
            output=stage_output(str(self.folder / "guidance-standoff.json"), stage),
            force=True,
            **self.registration_inputs(),
            **more,
        )

    def dry_run(self, devices: app.DeviceSettings) -> None:
        """The standoff's dry run (nothing moves): its motion through the gate."""
        self.forget_motions()
        before = self.inputs_sha256()
        if self.located is None:
            self.locate()
        out = app.guide(self.settings(devices, "standoff", dry_run=True))
        gate = out.record.gate
        self.dry_run_lines = [*(gate.lines() if gate is not None else []), *out.lines]
        if (gate is None or gate.passed) and self.inputs_sha256() == before:
            self.basis = f"standoff-dry-run {secrets.token_hex(8)} inputs {before}"

    def motion_basis(
        self, motion: str, insertion: str | None, last_run: int | None, awaiting_run: int | None
    ) -> str | None:
        """What a confirmation of ``standoff`` or ``insert`` (with ``insertion``) confirms, while
        it holds: the standoff's dry run of the files now on disk; for the insertion, the
        standoff that finished there with no motion since (``last_run``: the station's latest
        run), or the standoff run still in its session at the standoff, waiting for this
        confirmation (``awaiting_run``, simulated devices)."""
        inputs = self.inputs_sha256()
        if motion == "standoff":
            if self.basis is None or not self.basis.endswith(f"inputs {inputs}"):
                return None
            return self.basis
        if insertion not in INSERTIONS:
            return None
        if awaiting_run is not None and awaiting_run == self.live_run and self.live_basis is not None:
            return f"standoff-live-run {awaiting_run} {self.live_basis} insertion {insertion}"
        if self.standoff_run is None or last_run != self.standoff_run:
            return None
        if self.standoff_basis is None or not self.standoff_basis.endswith(f"inputs {inputs}"):
            return None
        return f"{self.standoff_basis} insertion {insertion}"

    def read_result(self, stage: str) -> Any:
        """The guidance JSON a ``stage`` wrote, read back: what the page shows is the file's.
        Kept as ``(file name, GuidanceResult)``."""
        name = f"guidance-{stage}.json"
        result = GuidanceResult.from_dict(read_json_object(self.folder / name, "guidance"), what=name)
        self.results.append((name, result))
        return result

    def standoff_reached(self, run_id: int) -> None:
        """The standoff run ``run_id`` finished at the standoff: the insertion may be confirmed."""
        self.standoff_run = run_id
        self.standoff_basis = f"standoff-run {run_id} {secrets.token_hex(8)} inputs {self.inputs_sha256()}"


def guidance_line(output: app.GuideOutput) -> str:
    """How a guidance stage that ran to its end ended: its last stage's entry, target and
    direction errors."""
    stage = None if output.result is None else output.result.last
    if stage is None:
        return "nothing was run"
    return (
        f"{stage.stage}: entry error {stage.entry_error_mm:.3f} mm, target error "
        f"{stage.target_error_mm:.3f} mm, direction error {stage.direction_error_deg:.3f} deg"
    )
