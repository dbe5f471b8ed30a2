"""One calibration at the station: a robot and a tracker, a folder for its files, and the steps
of the workflow, each one call of a :mod:`spacecal.app` function."""

from __future__ import annotations

import datetime
import hashlib
import json
import re
import secrets
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from spacecal import app
from spacecal.app._common import open_calibration
from spacecal.app.devices import SIMULATED
from spacecal.core.errors import InvalidInputError, SpacecalError
from spacecal.core.ports import FINDING_OK, FINDING_PROBLEM, FINDING_WARNING
from spacecal.core.text import exception_line
from spacecal.io.check_history import history_path, read_history
from spacecal.io.recordings import changed_file, open_calibrated_recording, recording_in
from spacecal.models.kinematics import N_JOINTS
from spacecal.models.tracker_kinds import tracker_kind_of
from spacecal.records import CalibrationResult
from spacecal.station.guide_step import INSERTIONS, LOCATED_NAME, GuideStep
from spacecal.station.scene import setup_scene
from spacecal.station.verify_step import VerifyStep

#: The finding levels in an operator's words.
#: Simulated devices move in real time at the station: training shows the motion as long as the
#: robot takes, and STOP or a closed page acts mid-motion as it would on the robot.
SIMULATED_SPEED = 1.0

LEVEL_WORDS = {
    FINDING_OK: "fine",
    FINDING_WARNING: "check this before you start",
    FINDING_PROBLEM: "must be fixed before the robot can move",
}

#: The report's file in a calibration's folder.
REPORT_NAME = "report.html"

#: The export targets the station offers: label, file name.
EXPORTS = {
    "slicer": ("3D Slicer transform", "tracker_from_base.tfm"),
    "plus": ("PLUS configuration", "plus_config.xml"),
    "ros2_launch": ("ROS 2 launch file", "tracker.launch.py"),
    "ur_calibration": ("UR ROS driver calibration", "ur_calibration.yaml"),
}


@dataclass
class Workspace:
    """A calibration in progress at the station.

    Attributes
    ----------
    id : int
    robot, tracker : dict
        The record's rows of the robot and tracker (name, url, ...).
    folder : Path
        Where its plan, recording, calibration, report and exports are written.
    """

    id: int
    robot: dict[str, Any]
    tracker: dict[str, Any]
    folder: Path
    rom: str | None = None
    tool_id: int | None = None
    error_thresholds: app.ErrorThresholds | None = None
    findings: list[tuple[str, str, str]] | None = None
    plan_summary: str | None = None
    dry_run_lines: list[str] = field(default_factory=list)
    dry_run_ok: bool = False
    dry_run_basis: str | None = None
    moves: int = 0
    motion_time_s: float = 0.0
    acquired: bool = False
    run_id: int | None = None
    verify_run_id: int | None = None
    guide_run_id: int | None = None
    calibration: app.CommandResult[CalibrationResult] | None = None
    calibration_record_id: int | None = None
    checks: list[app.CheckOutput] = field(default_factory=list)
    report: Path | None = None
    exported: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    #: What a new acquisition retired, in the operator's words (shown until the next calibration).
    superseded: str | None = None
    verification: VerifyStep = field(init=False)
    guide: GuideStep = field(init=False)

    def __post_init__(self) -> None:
        self.verification = VerifyStep(self.calibration_path)
        self.guide = GuideStep(self.folder, self.calibration_path)

    @property
    def simulated(self) -> bool:
        return self.robot["url"] == SIMULATED and self.tracker["url"] == SIMULATED

    @property
    def devices(self) -> app.DeviceSettings:
        rate = self.tracker.get("rate_hz") or 20.0
        return app.DeviceSettings(
            self.robot["url"],
            self.tracker["url"],
            rom=(self.rom,) if self.rom else (),
            tracker_rate_hz=float(rate),
            robot_model=self.robot.get("model") or None,
            robot_name=self.robot.get("name") or None,
            tracker_name=self.tracker.get("name") or None,
        )

    @property
    def plan_path(self) -> Path:
        return self.folder / "plan.json"

    @property
    def recording_path(self) -> Path:
        return recording_in(self.folder)

    @property
    def calibration_path(self) -> Path:
        return self.folder / "calibration.json"

    def doctor(self) -> list[tuple[str, str, str]]:
        """The devices' read-only findings as ``(device, level in words, text)`` (asked again)."""
        if self.simulated:
            self.findings = [("robot and tracker", "fine", "simulated devices (training and demonstrations)")]
            return self.findings
        devices = self.devices
        named = app.DeviceSettings(
            None if devices.robot == SIMULATED else devices.robot,
            None if devices.tracker == SIMULATED else devices.tracker,
            rom=devices.rom,
            tracker_rate_hz=devices.tracker_rate_hz,
            robot_model=devices.robot_model,
        )
        out = app.doctor(app.DoctorSettings(named))
        self.findings = [
            (device, LEVEL_WORDS[f.level], f"{f.subject}: {f.text}") for device, f in out.record.findings
        ]
        return self.findings

    def devices_sha256(self) -> str:
        """A digest of the robot's and tracker's record rows as this calibration uses them
        (name, address, model, frame rate): a confirmation is bound to it."""
        rows = [
            {k: row.get(k) for k in ("id", "name", "url", "model", "rate_hz")}
            for row in (self.robot, self.tracker)
        ]
        return hashlib.sha256(json.dumps(rows, sort_keys=True).encode("utf-8")).hexdigest()[:16]

    def device_edited(self, kind: str, row: dict[str, Any]) -> None:
        """The record's robot or tracker (``kind``) was edited: this calibration uses its new
        values, and everything checked on the old ones is gone (the findings, the dry runs of
        the acquisition, the verification and the guidance; the confirmations they allowed).
        What was recorded stays (the recording, the calibration and its checks)."""
        setattr(self, kind, dict(row))
        self.findings = None
        self.dry_run_ok, self.dry_run_basis, self.dry_run_lines = False, None, []
        self.verification.basis, self.verification.dry_run_lines = None, []
        self.guide.forget_motions()

    # -- the steps ---------------------------------------------------------------------------

    def plan(self) -> None:
        """The calibration motion: the paper's sweeps, as a plan file for simulated devices; a
        real robot plans them from where it stands (at the dry run). A new plan needs a new
        dry run."""
        self.dry_run_ok, self.dry_run_basis = False, None
        if not self.simulated:
            self.plan_summary = "the paper's sweeps, planned from where the robot stands (see the dry run)"
            return
        record = app.plan(app.PlanSettings(paper_sweeps=True, output=str(self.plan_path), force=True)).record
        self.plan_summary = (
            f"the paper's sweeps: {len(record.moves)} moves, {record.motion_time_s:.1f} s of motion, "
            f"predicted tip error at the site {record.predicted_error_mm:.3f} mm"
        )

    def acquire_settings(self, dry_run: bool) -> app.AcquireSettings:
        return app.AcquireSettings(
            str(self.recording_path),
            devices=self.devices,
            dry_run=dry_run,
            confirm_robot_motion=not dry_run,  # the station's confirmation page was answered
            plan=str(self.plan_path) if self.plan_path.is_file() else None,
            simulated_speed=None if dry_run else SIMULATED_SPEED,
        )

    def set_aside_earlier_recording(self, run_id: int | None = None) -> Path | None:
        """Before a new acquisition: the files of an earlier one (a run that was stopped, or one
        acquired before) go to ``earlier-N/`` beside them, kept whole, so the new run starts
        over on fresh files. Everything that followed from that recording goes with it (the
        calibration, its check history, report, exports, verifications, guidance results and
        the located plan) and the page forgets it: what the page shows belongs to the files on
        disk, and a report can never pair the old calibration with the new recording. The
        plan and the guide's uploads stay (they do not follow from the recording).

        Parameters
        ----------
        run_id : int or None
            The new acquisition's run, named in :attr:`superseded`.

        Returns
        -------
        Path or None
            The ``earlier-N`` folder, or None when there was nothing to keep.
        """
        earlier = [
            *sorted(self.folder.glob(self.recording_path.stem + ".*")),
            *(p for p in self._files_that_follow_the_recording() if p.is_file()),
        ]
        if not earlier:
            return None
        n = 1
        while (self.folder / f"earlier-{n}").exists():
            n += 1
        kept = self.folder / f"earlier-{n}"
        kept.mkdir()
        for path in earlier:
            path.rename(kept / path.name)
        if self.calibration is not None:
            verdict = self.calibration.record.verdict
            grade = f" ({verdict.headline})" if verdict is not None else ""
            by = f"run {run_id}" if run_id is not None else "a new acquisition"
            self.superseded = (
                f"the calibration{grade} of the earlier recording is superseded by {by}; its files are "
                f"kept in {kept.name}/"
            )
        self._forget_what_followed()
        return kept

    def _files_that_follow_the_recording(self) -> list[Path]:
        """The files in the folder made from the recording, directly or through the calibration."""
        named = [
            self.calibration_path,
            history_path(self.calibration_path),
            self.folder / REPORT_NAME,
            self.folder / LOCATED_NAME,
            *(self.folder / name for _, name in EXPORTS.values()),
        ]
        made = [*self.folder.glob("verification-*.json"), *self.folder.glob("verification-*.png")]
        return [*named, *sorted(made), *sorted(self.folder.glob("guidance-*.json"))]

    def plan_contents(self) -> dict[str, Any] | None:
        """The plan file's contents as on disk; None without one, or one that is not a JSON
        object (the dry run says why; the pages that draw from it draw nothing)."""
        if not self.plan_path.is_file():
            return None
        try:
            plan = json.loads(self.plan_path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        return plan if isinstance(plan, dict) else None

    def scene(self, motion: str | None = None) -> dict[str, Any] | None:
        """The set-up in 3-D (:func:`spacecal.station.scene.setup_scene`) from the files on
        disk: the plan, and once calibrated the calibration and its recording in the tracker's
        frame; None before a plan. The volume is the tracker kind's (the simulated tracker is a
        Polaris Vicra); a kind that states none draws none.

        For a run's page (``motion``): an acquisition's scene is the robot base frame (its
        samples are drawn live, where the TCP was, coloured by whether the marker was seen);
        a check, verification or guidance is drawn in the tracker frame through the
        calibration, without the recording's samples."""
        plan = self.plan_contents()
        if plan is None:
            return None
        calibration = self.calibration.record if self.calibration is not None else None
        if motion == "acquire":
            calibration = None  # a new recording: nothing links it to the tracker yet
        recording = None
        if calibration is not None and motion is None:
            try:
                opened = open_calibrated_recording(calibration)
                recording = opened.recording if opened is not None else None
            except (SpacecalError, OSError):
                recording = None  # the page says why elsewhere (check_files)
        model = "Polaris Vicra" if self.tracker["url"] == SIMULATED else self.tracker.get("model")
        kind = tracker_kind_of(model)
        return setup_scene(
            plan,
            calibration,
            recording,
            kind.volume if kind is not None else None,
            str(self.tracker.get("name") or "tracker"),
        )

    def check_files(self) -> None:
        """Stop showing the calibration and what followed it once its recording on disk is no
        longer the one it was made from (edited, replaced, or gone): the page shows a result
        only while its files are the ones on disk. The files themselves are left as they are."""
        if self.calibration is None:
            return
        source = self.calibration.record.provenance.source
        if source is None:
            return
        headline = self.calibration.record.verdict.headline if self.calibration.record.verdict else "made"
        gone = [Path(f.path).name for f in source.files if not Path(f.path).is_file()]
        changed = changed_file(source)
        if changed is None and not gone:
            return
        what = f"{Path(changed[0].path).name} changed on disk" if changed else f"{', '.join(gone)} is gone"
        self._forget_what_followed()
        self.acquired = self.recording_path.is_file()
        self.superseded = (
            f"{what} after the calibration ({headline}) was made from it: that calibration no longer "
            f"describes the recording, so its verdict, check, report and exports are not shown; "
            f"calibrate again, or acquire again (the files are left as they are)"
        )

    def _forget_what_followed(self) -> None:
        """The page's memory of the calibration and everything after it, gone with its files."""
        self.acquired = False
        self.calibration, self.calibration_record_id = None, None
        self.checks, self.report, self.exported = [], None, []
        self.verification = VerifyStep(self.calibration_path)
        self.guide.results, self.guide.located, self.guide.located_lines = [], None, []
        self.guide.forget_motions()

    def dry_run(self) -> None:
        """Check the plan without moving (reach, limits, visibility, workspace). The earlier
        dry run's verdict is gone first: a dry run that fails, or raises, leaves none standing,
        and a confirmation issued for an earlier one is no longer accepted
        (:meth:`motion_basis`)."""
        self.dry_run_ok, self.dry_run_basis, self.dry_run_lines = False, None, []
        plan_before = self.plan_sha256()
        done = app.acquire(self.acquire_settings(dry_run=True))
        out = done.record
        self.moves, self.motion_time_s = out.moves, out.motion_time_s
        gate = [out.gate.summary(), *out.gate.lines()] if out.gate is not None else []
        self.dry_run_lines = [*gate, *done.notes, "dry run: nothing moved"]
        passed = out.gate is None or out.gate.passed
        if passed and self.plan_sha256() == plan_before:
            # this dry run, of this plan: a confirmation names it, and the plan file must not
            # change between the two
            self.dry_run_basis = f"dry-run {secrets.token_hex(8)} plan {plan_before}"
        self.dry_run_ok = self.dry_run_basis is not None

    def plan_sha256(self) -> str:
        """The plan file's sha256 (``none`` while there is none: a real robot plans the sweeps
        from where it stands)."""
        if not self.plan_path.is_file():
            return "none"
        return hashlib.sha256(self.plan_path.read_bytes()).hexdigest()

    def motion_basis(self, motion: str) -> str | None:
        """What a confirmation of ``motion`` confirms, while it still holds: the dry run that
        passed of the plan now on disk (``acquire``), or the calibration file now on disk
        (``check``), or the verification's dry run of the calibration now on disk (``verify``);
        None when there is nothing to confirm."""
        if motion == "verify":
            return self.verification.motion_basis() if self.calibration is not None else None
        if motion == "acquire":
            basis = self.dry_run_basis
            if basis is None or not basis.endswith(f"plan {self.plan_sha256()}"):
                return None
            return basis
        if self.calibration is None or not self.calibration_path.is_file():
            return None
        return f"calibration {hashlib.sha256(self.calibration_path.read_bytes()).hexdigest()}"

    def motion_words(self, motion: str, insertion: str | None = None) -> str:
        """The motion a confirmation names."""
        if motion == "verify":
            return self.verification.words()
        if motion == "standoff":
            name = self.guide.given_names.get("plan", "the plan")
            return (
                f"the guidance to the standoff of {name}: {self.guide.standoff_mm:g} mm before the entry, "
                "on the planned axis (the needle does not enter)"
            )
        if motion == "insert":
            name = self.guide.given_names.get("plan", "the plan")
            how = (
                "along the planned axis from the standoff to the target (the needle enters)"
                if insertion == "advance"
                else "to the entry, holding the guide there for a manual insertion"
            )
            return f"the insertion of {name} ({INSERTIONS.get(insertion or '', '')}): {how}"
        if motion == "acquire":
            return (
                f"the calibration motion: {self.moves} moves, about {self.motion_time_s:.0f} s "
                "of motion (the paper's sweeps)"
            )
        poses = self.check_settings().poses
        return (
            f"the check: {check_moves(poses)} moves, holding the TCP at {poses} poses near where the robot "
            "stands (the first where it stands, the others 40 mm away and tilted 10 deg) and back"
        )

    def calibrate(self, method: str = "ml") -> app.CommandResult[CalibrationResult]:
        out = app.calibrate(
            app.CalibrateSettings(
                str(self.recording_path),
                str(self.calibration_path),
                method,
                force=True,
                error_thresholds=self.error_thresholds,
            )
        )
        self.calibration, self.superseded = out, None
        return out

    def check_settings(self) -> app.CheckSettings:
        """The check's settings: its motion was confirmed on the station's confirmation page."""
        return app.CheckSettings(
            str(self.calibration_path),
            devices=self.devices,
            confirm_robot_motion=True,
            simulated_speed=SIMULATED_SPEED,
        )

    def verify_dry_run(self, poses: int) -> None:
        """The verification's dry run (nothing moves): the needle poses through the gate."""
        if self.calibration is None:
            raise InvalidInputError("calibrate first: the verification reaches poses through the calibration")
        self.verification.dry_run(self.devices, poses)

    def verify_settings(self) -> app.VerifySettings:
        """The verification's settings: its motion was confirmed on the confirmation page."""
        return self.verification.settings(self.devices, dry_run=False, simulated_speed=SIMULATED_SPEED)

    def guide_dry_run(self) -> None:
        """The guidance's dry run (nothing moves): where the plan lands, the standoff's motion
        through the gate."""
        if self.calibration is None:
            raise InvalidInputError("calibrate first: the plan reaches the robot through the calibration")
        self.guide.dry_run(self.devices)

    def guide_settings(self, stage: str, insertion: str = "advance") -> Any:
        """A guidance stage's settings: its motion confirmed on the station's page (twice for
        an insertion)."""
        return self.guide.settings(
            self.devices,
            stage,
            insertion=insertion,
            confirm_robot_motion=True,
            confirm_insertion=stage != "standoff",
            simulated_speed=SIMULATED_SPEED,
        )

    def make_report(self) -> Path:
        out = app.report(
            app.ReportSettings(str(self.calibration_path), str(self.folder / REPORT_NAME), force=True)
        )
        self.report = out.files_written[0]
        return out.files_written[0]

    def located(self) -> dict[str, Any] | None:
        """Where the calibration puts the robot, for its page: ``tracker_from_base`` (4x4, mm),
        the robot base's distance from the tracker (mm) and, with a plan, the home TCP's (the
        working distance the measurement volume must hold); None before a calibration."""
        if self.calibration is None:
            return None
        tracker_from_base = np.asarray(self.calibration.record.tracker_from_base, dtype=float)
        home_mm = None  # without a plan that says where home is: the base's distance alone
        try:
            home = np.asarray((self.plan_contents() or {}).get("home_base_from_tcp"), dtype=float)
        except (ValueError, TypeError):
            home = np.empty(0)
        if home.shape == (4, 4) and np.all(np.isfinite(home)):
            home_mm = float(np.linalg.norm((tracker_from_base @ home)[:3, 3]))
        return {
            "tracker_from_base": tracker_from_base.tolist(),
            "base_mm": float(np.linalg.norm(tracker_from_base[:3, 3])),
            "home_mm": home_mm,
        }

    def ur_export_blocked(self) -> str | None:
        """Why the UR ROS driver's calibration cannot be written from this calibration, in an
        operator's words; None when it can (a calibration of the kinematic method, of a six-joint
        UR arm: the driver's file holds the identified joints)."""
        if self.calibration is None:
            return "calibrate first"
        model = self.calibration.record.robot_model
        if model is None:
            return (
                "the UR ROS driver's calibration needs the robot's kinematics: calibrate with the "
                "method kinematic to write it"
            )
        if model.n_joints != N_JOINTS:
            return (
                f"the UR ROS driver's calibration is of a UR arm's six joints; the {model.name} "
                f"has {model.n_joints}"
            )
        return None

    def export(self, targets: list[str]) -> ExportOutcome:
        """Export to each target chosen (keys of :data:`EXPORTS`), one at a time, so that one
        that fails leaves the others written; what was written and what failed, and why."""
        outcome = ExportOutcome(chosen=[key for key in EXPORTS if key in targets])
        for key in outcome.chosen:
            name = EXPORTS[key][1]
            blocked = self.ur_export_blocked() if key == "ur_calibration" else None
            if blocked is not None:
                outcome.failed[key] = blocked
                continue
            path, calibration = str(self.folder / name), str(self.calibration_path)
            try:
                if key in ("slicer", "plus"):
                    app.export(
                        app.ExportSettings(
                            calibration,
                            slicer=path if key == "slicer" else None,
                            plus=path if key == "plus" else None,
                            force=True,
                        )
                    )
                else:
                    app.export_ros(
                        app.RosExportSettings(
                            calibration,
                            ros2_launch=path if key == "ros2_launch" else None,
                            ur_calibration=path if key == "ur_calibration" else None,
                            force=True,
                        )
                    )
            except (SpacecalError, OSError) as exc:
                # the system's reason without its number and paths (the file is named already)
                system = isinstance(exc, OSError) and not isinstance(exc, SpacecalError)
                why = (
                    exc.strerror
                    if system and isinstance(exc, OSError) and exc.strerror
                    else exception_line(exc)
                )
                outcome.failed[key] = f"{EXPORTS[key][0]} ({name}) was not written: {why}"
                continue
            outcome.written.append(name)
            self.exported = sorted({*self.exported, name})
        return outcome


@dataclass
class ExportOutcome:
    """An export as the page shows it: the targets ticked, the files written, and for each
    target that failed, why (an operator's line).

    Attributes
    ----------
    chosen : list of str
        Keys of :data:`EXPORTS` ticked, kept ticked when the form is shown again.
    written : list of str
        File names written, in the calibration's folder.
    failed : dict of str to str
    message : str or None
        A line about the form as a whole (nothing ticked).
    """

    chosen: list[str] = field(default_factory=list)
    written: list[str] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)
    message: str | None = None


def check_moves(poses: int) -> int:
    """The moves of a check at ``poses`` poses, as :func:`spacecal.planning.check_poses.check_plan`
    plans them: a hold at each pose, the first where the robot stands, a transit to each other
    pose and one back (``tests/station/test_stepper.py`` holds the two together).

    Parameters
    ----------
    poses : int
        Check poses (1 to 3).

    Returns
    -------
    int
        Holds and transits, the run page's move total.
    """
    return 1 if poses <= 1 else 2 * poses


#: The steps of a calibration's page, in order: key and heading.
STEPS = (
    ("devices", "Devices"),
    ("plan", "Plan"),
    ("dry-run", "Dry run"),
    ("acquire", "Acquire"),
    ("calibrate", "Calibrate"),
    ("check", "Check"),
    ("verify", "Verify on the robot"),
    ("guide", "Guide a needle"),
    ("report", "Report"),
    ("export", "Export"),
)
#: Steps the next step skips until every other one is done (the paper's §5.2 and §5.3).
OPTIONAL_STEPS = ("verify", "guide")
#: A step's states: finished, can be done now, or refused by the station until an earlier step.
DONE, CURRENT, LOCKED = "done", "current", "locked"
#: The devices' finding words and the grade a display colours them with.
FINDING_GRADES = {"fine": "good", "check this before you start": "acceptable"}


@dataclass(frozen=True)
class StepState:
    """One step of a calibration as its page shows it.

    Attributes
    ----------
    key : str
        The step (a key of :data:`STEPS`).
    title : str
    state : str
        :data:`DONE`, :data:`CURRENT` or :data:`LOCKED`.
    words : str
        What it came to (done), what it waits for (current), or why it is locked, in the
        operator's words.
    grade : str or None
        The grade of its result for the display's colour (``good``, ``acceptable``, ``poor``,
        ``unusable``: a calibration's verdict grades, also for findings, dry runs and checks);
        None when the step's result has no grade.
    next : bool
        The step to do next (at most one step).
    """

    key: str
    title: str
    state: str
    words: str = ""
    grade: str | None = None
    next: bool = False


def step_states(work: Workspace, running: str | None = None) -> list[StepState]:
    """What each step of ``work`` is now, in :data:`STEPS`' order, from the workspace's state
    and its files: a step is locked exactly when the station would refuse it (the motions'
    confirmations, :meth:`Workspace.motion_basis`; the calibration's steps need a recording,
    the rest a calibration). The next step is the first one neither done nor locked, leaving
    out the plan once a dry run passed (it plans for itself) and :data:`OPTIONAL_STEPS` while
    any other step is still to do.

    Parameters
    ----------
    work : Workspace
    running : str or None
        The motion of this workspace's run still moving the robot (``acquire``, ``check``,
        ``verify``, ``standoff``, ``insert``), if any.

    Returns
    -------
    list of StepState
    """
    calibrated = work.calibration is not None
    after_calibration = "calibrate first: it is made from the calibration"
    states: dict[str, tuple[str, str, str | None]] = {}

    levels = [level for _, level, _ in work.findings or []]
    if work.findings is None:
        states["devices"] = (CURRENT, "asking the devices", None)
    elif LEVEL_WORDS[FINDING_PROBLEM] in levels:
        states["devices"] = (CURRENT, LEVEL_WORDS[FINDING_PROBLEM], "poor")
    else:
        worst = LEVEL_WORDS[FINDING_WARNING] if LEVEL_WORDS[FINDING_WARNING] in levels else "fine"
        states["devices"] = (DONE, worst, FINDING_GRADES[worst])

    states["plan"] = (DONE, "planned", None) if work.plan_summary else (CURRENT, "", None)

    if work.motion_basis("acquire") is not None:
        states["dry-run"] = (DONE, "passed", "good")
    elif work.dry_run_ok:
        states["dry-run"] = (CURRENT, "the plan changed since it passed: run it again", None)
    elif work.dry_run_lines:
        states["dry-run"] = (CURRENT, "did not pass: see its findings", "poor")
    else:
        states["dry-run"] = (CURRENT, "", None)

    recorded = work.recording_path.is_file()
    if running == "acquire":
        states["acquire"] = (CURRENT, "the robot is moving", None)
    elif recorded:
        states["acquire"] = (DONE, "recorded", None)
    elif work.motion_basis("acquire") is None:
        if work.dry_run_ok:
            why = "the plan changed since the dry run: run it again"
        else:
            why = "the dry run did not pass" if work.dry_run_lines else "run the dry run first"
        states["acquire"] = (LOCKED, f"{why}: the robot moves only after it passed", None)
    else:
        states["acquire"] = (CURRENT, "", None)

    if calibrated:
        assert work.calibration is not None
        verdict = work.calibration.record.verdict
        grade = verdict.grade if verdict is not None else None
        states["calibrate"] = (DONE, verdict.headline if verdict is not None else "calibrated", grade)
    elif recorded and running != "acquire":
        states["calibrate"] = (CURRENT, "", None)
    else:
        states["calibrate"] = (LOCKED, "acquire first: the calibration is computed from the recording", None)

    checked = [c.result for c in work.checks if c.result is not None]
    if running == "check":
        states["check"] = (CURRENT, "the robot is moving", None)
    elif work.motion_basis("check") is None:
        states["check"] = (LOCKED, "calibrate first: the check compares the robot with it", None)
    elif checked:
        passed = checked[-1].passed
        states["check"] = (DONE, "PASS" if passed else "FAIL", "good" if passed else "poor")
    else:
        states["check"] = (CURRENT, "", None)

    if running == "verify":
        states["verify"] = (CURRENT, "the robot is moving", None)
    elif not calibrated:
        states["verify"] = (LOCKED, "calibrate first: the verification reaches its poses through it", None)
    elif work.verification.done is not None:
        states["verify"] = (DONE, "verified", None)
    else:
        states["verify"] = (CURRENT, "", None)

    if running in ("standoff", "insert"):
        states["guide"] = (CURRENT, "the robot is moving", None)
    elif not calibrated:
        states["guide"] = (LOCKED, "calibrate first: the plan reaches the robot through it", None)
    elif work.guide.results:
        states["guide"] = (DONE, "guided", None)
    else:
        states["guide"] = (CURRENT, "", None)

    if not calibrated:
        states["report"] = (LOCKED, after_calibration, None)
        states["export"] = (LOCKED, after_calibration, None)
    else:
        states["report"] = (DONE, "written", None) if work.report else (CURRENT, "", None)
        count = len(work.exported)
        files = f"{count} file{'s' if count != 1 else ''}"
        states["export"] = (DONE, files, None) if count else (CURRENT, "", None)

    # the next step: the first one that can be done, past the plan once a dry run planned for
    # itself, and the paper's needle steps (verify, guide) only once every other step is done
    can = [key for key, _ in STEPS if states[key][0] == CURRENT]
    can = [key for key in can if not (key == "plan" and states["dry-run"][0] == DONE)]
    upcoming = next((key for key in can if key not in OPTIONAL_STEPS), can[0] if can else None)
    if running is not None:
        upcoming = None  # while the robot moves there is nothing to do next but watch it (or STOP)
    return [StepState(key, title, *states[key], next=key == upcoming) for key, title in STEPS]


def reopened_workspace(
    row: dict[str, Any],
    robot: dict[str, Any],
    tracker: dict[str, Any],
    error_thresholds: app.ErrorThresholds | None = None,
) -> Workspace:
    """A workspace of the record as its folder now stands (the station restarted).

    What is shown comes from the files on disk, never from memory: the plan, whether there is a
    recording, the calibration (read and its content hash checked, as every command reads it),
    its checks (its check history, the lines bound to its content hash), the report and the
    exports. A dry run is never carried over a restart (the robot may stand
    elsewhere; it is run again before any motion), nor are confirmations. A calibration file that
    is unreadable or edited is not shown as done; the reason is kept in :attr:`Workspace.errors`.

    Parameters
    ----------
    row : dict
        The record's row (:meth:`spacecal.ledger.Ledger.workspaces`).
    robot, tracker : dict
        The record's rows of its robot and tracker.
    """
    work = Workspace(
        int(row["id"]),
        robot,
        tracker,
        Path(row["folder"]),
        row.get("rom"),
        row.get("tool_id"),
        error_thresholds=error_thresholds,
    )
    if not work.folder.is_dir():
        work.errors.append(f"its folder {work.folder} is gone: start a new calibration")
        return work
    if work.plan_path.is_file():
        work.plan_summary = "the plan written before the station restarted (plan.json): dry-run it again"
    work.acquired = work.recording_path.is_file()
    if work.calibration_path.is_file():
        try:
            calibration, notes = open_calibration(work.calibration_path, "station", accept_edited=False)
        except (SpacecalError, OSError) as exc:
            work.errors.append(f"{work.calibration_path.name} is not shown: {exc}")
        else:
            work.calibration = app.CommandResult(calibration, (work.calibration_path,), tuple(notes))
            history = read_history(work.calibration_path).checks
            work.checks = [app.CheckOutput(check, "the calibration's check history") for check in history]
    if work.calibration is not None and (work.folder / REPORT_NAME).is_file():
        work.report = work.folder / REPORT_NAME
    if work.calibration is not None:
        work.exported = sorted(name for _, name in EXPORTS.values() if (work.folder / name).is_file())
    return work


def new_folder(data: Path, robot_name: str) -> Path:
    """A fresh folder for a calibration of ``robot_name``: ``DATA/<robot>-<UTC time>``."""
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y%m%dT%H%M%S%f")
    safe = re.sub(r"[^A-Za-z0-9_.-]+", "-", robot_name).strip("-.")[:40] or "robot"
    folder = data / f"{safe}-{stamp}"
    folder.mkdir(parents=True, exist_ok=False)
    return folder
