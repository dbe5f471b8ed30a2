"""App function ``plan-from-slicer``: check a needle plan drawn in 3D Slicer before guidance.

The plan (a Slicer markups file, or a plan JSON this command wrote) is brought into the
tracker with a registration, either a Slicer transform file or one made here from fiducials
touched with a tracked pointer, and, with a calibration, into the robot base. Nothing moves:
the command prints where the entry and target are in each frame, the needle's direction and
length, and the predicted TRE at the target for a pointer-made registration.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from spacecal.app._common import open_calibration, refuse_overwriting_inputs
from spacecal.app.result import CommandResult, note_lines, paths
from spacecal.core.errors import InvalidInputError
from spacecal.core.strict_numbers import decimal
from spacecal.core.text import sanitize_for_terminal
from spacecal.io.results_json import read_json_object, write_json
from spacecal.io.slicer_markups import fiducials_from_markups, plan_from_markups
from spacecal.io.slicer_registration import ROLES, read_slicer_registration
from spacecal.io.touched_points import read_touched_file
from spacecal.records.fields import plain
from spacecal.records.needle_plan import NEEDLE_PLAN_SCHEMA, ImageRegistration, NeedlePlan
from spacecal.registration.image_fiducials import DEFAULT_MAX_FRE_MM, register_image_fiducials
from spacecal.workflows.plan_frames import LocatedPlan, locate_plan

#: Longest name from a file shown on a line.
_NAME_CHARS = 80


@dataclass(frozen=True)
class PlanFromSlicerSettings:
    """``spacecal plan-from-slicer``: a Slicer needle plan in the image, tracker and robot frames.

    Attributes
    ----------
    plan : str
        Slicer markups file (``.mrk.json``: a Line, or a point list with entry and target), or a
        plan JSON written by this command.
    registration : str or None
        Slicer transform file (``.tfm``, ``.txt``, ``.h5``) of the image registration.
    registration_maps : str or None
        Its role (``image-to-tracker``, ``tracker-to-image``, ...; default: from the file's name).
    fiducials, touched : str or None
        Instead of ``registration``: the image fiducials (a markups point list) and the pointer's
        touches of them (touched-points CSV), paired by label.
    calibration : str or None
        Calibration JSON, for robot-base coordinates.
    accept_edited : bool
        Use a calibration edited since it was written.
    entry_label, target_label : str or None
        Labels of the entry and target points (default ``entry`` and ``target``; a Line's first
        and second point).
    markup : str or None
        The markup to read when the plan file holds several.
    coordinate_system : {"LPS", "RAS"} or None
        For a markups file that does not state its system.
    max_fre_mm : float
        Largest RMS FRE of a pointer-made registration accepted.
    accept_high_fre : bool
        Use a pointer-made registration above ``max_fre_mm``.
    output : str or None
        Plan JSON to write (the plan with its points in every frame).
    force : bool
        Replace an existing output.
    """

    plan: str
    registration: str | None = None
    registration_maps: str | None = None
    fiducials: str | None = None
    touched: str | None = None
    calibration: str | None = None
    accept_edited: bool = False
    entry_label: str | None = None
    target_label: str | None = None
    markup: str | None = None
    coordinate_system: str | None = None
    max_fre_mm: float = DEFAULT_MAX_FRE_MM
    accept_high_fre: bool = False
    output: str | None = None
    force: bool = False

    #: The command line's flag (space-separated forms) and argparse options of each field.
    FLAGS: ClassVar[dict[str, tuple[str, dict[str, Any]]]] = {
        "plan": (
            "plan",
            dict(help="Slicer markups file (.mrk.json: a Line, or points labelled entry and target)"),
        ),
        "registration": (
            "--registration",
            dict(help="Slicer transform file (.tfm, .txt, .h5) of the registration"),
        ),
        "registration_maps": (
            "--registration-maps",
            dict(
                choices=tuple(ROLES),
                help="which way it maps (default: from its name: TrackerToRAS, ImageToTracker)",
            ),
        ),
        "fiducials": ("--fiducials", dict(help="instead of --registration: the image fiducials (.mrk.json)")),
        "touched": (
            "--touched",
            dict(help="with --fiducials: CSV label,x_in_tracker_mm,y_in_tracker_mm,z_in_tracker_mm"),
        ),
        "calibration": ("--calibration", dict(help="calibration JSON: also show the plan in the robot base")),
        "entry_label": ("--entry-label", dict(help="label of the entry point (default: entry)")),
        "target_label": ("--target-label", dict(help="label of the target point (default: target)")),
        "markup": ("--markup", dict(help="name of the markup holding the plan, when the file has several")),
        "coordinate_system": (
            "--coordinate-system",
            dict(choices=("LPS", "RAS"), help="for a markups file that does not state its own"),
        ),
        "max_fre_mm": (
            "--max-fre-mm",
            dict(
                type=decimal,
                help=f"largest RMS FRE of a pointer registration, mm (default {DEFAULT_MAX_FRE_MM:g})",
            ),
        ),
        "accept_high_fre": (
            "--accept-high-fre",
            dict(action="store_true", help="use a pointer registration above it"),
        ),
        "output": ("-o --output", dict(help="plan JSON to write (the plan in every frame)")),
    }

    def __post_init__(self) -> None:
        by_file = self.registration is not None
        by_pointer = self.fiducials is not None or self.touched is not None
        if by_file == by_pointer:
            raise InvalidInputError(
                "give the registration as --registration FILE, or as --fiducials FIDUCIALS.mrk.json "
                "with --touched TOUCHED.csv (one of the two)"
            )
        if by_pointer and (self.fiducials is None or self.touched is None):
            raise InvalidInputError("a pointer registration needs both --fiducials and --touched")
        if self.registration_maps is not None and self.registration_maps not in ROLES:
            raise InvalidInputError(
                f"--registration-maps takes {', '.join(ROLES)}, got {self.registration_maps!r}"
            )


def read_plan(
    path: str,
    entry_label: str | None = None,
    target_label: str | None = None,
    markup: str | None = None,
    coordinate_system: str | None = None,
) -> NeedlePlan:
    """The plan of a Slicer markups file, or of a plan JSON ``plan-from-slicer`` wrote (the
    arguments are :class:`PlanFromSlicerSettings`' fields of the same names)."""
    if not path.lower().endswith(".mrk.json") and path.lower().endswith(".json"):
        data = read_json_object(path, "needle plan")
        if data.get("schema") == NEEDLE_PLAN_SCHEMA:
            return NeedlePlan.from_dict(data, f"{path}")
    return plan_from_markups(
        path,
        entry_label=entry_label,
        target_label=target_label,
        markup_name=markup,
        coordinate_system=coordinate_system,
    )


def read_registration(
    registration: str | None,
    registration_maps: str | None = None,
    fiducials: str | None = None,
    touched: str | None = None,
    coordinate_system: str | None = None,
    max_fre_mm: float = DEFAULT_MAX_FRE_MM,
    accept_high_fre: bool = False,
) -> ImageRegistration:
    """The image registration: a Slicer transform file, or one made from image fiducials and
    the pointer's touches of them (refused above ``max_fre_mm`` unless ``accept_high_fre``); the
    arguments are :class:`PlanFromSlicerSettings`' fields of the same names."""
    if registration is not None:
        return read_slicer_registration(registration, registration_maps)
    if fiducials is None or touched is None:
        raise InvalidInputError("a pointer registration needs both --fiducials and --touched")
    points = fiducials_from_markups(fiducials, coordinate_system=coordinate_system)
    touches = read_touched_file(touched)
    return register_image_fiducials(
        points,
        touches.points,
        image_frame="image_lps",
        tracker_frame=touches.frame,
        max_fre_mm=max_fre_mm,
        accept_high_fre=accept_high_fre,
        tip_accuracy_mm=touches.tip_accuracy_mm,
    )


def _read_plan(settings: PlanFromSlicerSettings) -> NeedlePlan:
    return read_plan(
        settings.plan,
        settings.entry_label,
        settings.target_label,
        settings.markup,
        settings.coordinate_system,
    )


def _registration(settings: PlanFromSlicerSettings) -> ImageRegistration:
    return read_registration(
        settings.registration,
        settings.registration_maps,
        settings.fiducials,
        settings.touched,
        settings.coordinate_system,
        settings.max_fre_mm,
        settings.accept_high_fre,
    )


def _xyz(point: np.ndarray) -> str:
    return " ".join(f"{v:9.2f}" for v in point)


def _direction(vector: np.ndarray) -> str:
    return " ".join(f"{v:+.4f}" for v in vector)


def located_dict(located: LocatedPlan) -> dict[str, Any]:
    """The plan JSON: the plan record's fields, then its points in every frame it was brought to."""
    registration = located.registration
    data = located.plan.to_dict()
    data["registration"] = {
        "name": registration.name,
        "source": registration.source,
        registration.name: registration.tracker_from_image,
    }
    if registration.pointer is not None:
        data["registration"].update(
            fiducial_labels=list(registration.pointer.labels),
            fre_rms_mm=registration.pointer.fre_rms_mm,
            fle_rms_mm=registration.pointer.fle_rms_mm,
            max_fre_mm=registration.pointer.max_fre_mm,
            accepted_above_limit=registration.pointer.accepted_above_limit,
            pointer_tip_accuracy_mm=registration.pointer.tip_accuracy_mm,
            predicted_tre_at_target_mm=located.predicted_tre_at_target_mm,
        )
    frame = registration.tracker_frame
    data[f"entry_in_{frame}_mm"] = located.entry_in_tracker
    data[f"target_in_{frame}_mm"] = located.target_in_tracker
    if located.entry_in_base is not None:
        data["entry_in_base_mm"] = located.entry_in_base
        data["target_in_base_mm"] = located.target_in_base
    data["length_mm"] = located.plan.length_mm
    return plain(data)


def plan_lines(located: LocatedPlan, plan_path: str) -> list[str]:
    """What the command line prints for a located plan."""
    plan, registration = located.plan, located.registration

    def shown(text: str) -> str:
        return sanitize_for_terminal(text, _NAME_CHARS)

    title = f"plan {shown(plan.name)!r}" if plan.name else "plan"
    labels = f"entry {shown(plan.entry_label)!r}, target {shown(plan.target_label)!r}"
    lines = [f"{title} from {shown(plan_path)}: {labels}"]
    pointer = registration.pointer
    if pointer is None:
        lines.append(f"registration: {registration.name} from {shown(registration.source)}")
    else:
        above = " (above the limit: accepted on request)" if pointer.accepted_above_limit else ""
        lines.append(
            f"registration: {registration.name} from {len(pointer.labels)} touched fiducials, FRE "
            f"{pointer.fre_rms_mm:.2f} mm RMS (limit {pointer.max_fre_mm:g} mm){above}; per fiducial "
            + ", ".join(f"{shown(k)} {v:.2f}" for k, v in zip(pointer.labels, pointer.residuals_mm))
        )
    lines.append(f"{'frame':12s} {'entry x, y, z (mm)':>29s}   {'target x, y, z (mm)':>29s}")
    rows = [(plan.image_frame, plan.entry_in_image, plan.target_in_image)]
    rows.append((registration.tracker_frame, located.entry_in_tracker, located.target_in_tracker))
    if located.entry_in_base is not None and located.target_in_base is not None:
        rows.append(("base", located.entry_in_base, located.target_in_base))
    lines += [f"{frame:12s} {_xyz(entry)}   {_xyz(target)}" for frame, entry, target in rows]
    lines.append(f"needle length: {plan.length_mm:.2f} mm")
    lines.append(f"needle direction in {plan.image_frame}: {_direction(plan.direction_in_image)}")
    lines.append(
        f"needle direction in {registration.tracker_frame}: {_direction(located.direction_in_tracker)}"
    )
    if located.entry_in_base is not None and located.target_in_base is not None:
        in_base = (located.target_in_base - located.entry_in_base) / plan.length_mm
        lines.append(f"needle direction in base: {_direction(in_base)}")
    if located.predicted_tre_at_target_mm is not None:
        lines.append(
            f"predicted TRE at the target: {located.predicted_tre_at_target_mm:.2f} mm RMS "
            "(the registration's alone, Fitzpatrick-West-Maurer)"
        )
    return lines


def plan_from_slicer(settings: PlanFromSlicerSettings) -> CommandResult[LocatedPlan]:
    """Read the plan and the registration, bring the plan into the tracker (and the base).

    Returns
    -------
    CommandResult of LocatedPlan
        The plan in every frame; the plan JSON written, if asked.

    Raises
    ------
    InvalidInputError
        Any input that is malformed or disagrees with another (frames, units, a registration
        that is not rigid or whose FRE is above its limit), in one line.
    """
    inputs = [
        settings.plan,
        settings.registration,
        settings.fiducials,
        settings.touched,
        settings.calibration,
    ]
    refuse_overwriting_inputs(settings.output, *inputs, force=settings.force, any_file=True)
    plan = _read_plan(settings)
    registration = _registration(settings)
    notes: list[str] = []
    tracker_from_base = None
    if settings.calibration is not None:
        calibration, notes = open_calibration(
            settings.calibration, "plan-from-slicer", settings.accept_edited
        )
        tracker_from_base = calibration.tracker_from_base
    located = locate_plan(plan, registration, tracker_from_base)
    if registration.pointer is not None and registration.pointer.accepted_above_limit:
        notes.append(
            f"the registration's FRE {registration.pointer.fre_rms_mm:.2f} mm is above its limit "
            f"{registration.pointer.max_fre_mm:g} mm and was used on request"
        )
    written = write_json(located_dict(located), settings.output) if settings.output else None
    files = paths(written)
    lines = [*(f"wrote {path}" for path in files), *plan_lines(located, settings.plan), *note_lines(notes)]
    return CommandResult(located, files, notes=tuple(notes), lines=tuple(lines))


__all__ = [
    "PlanFromSlicerSettings",
    "located_dict",
    "plan_from_slicer",
    "plan_lines",
    "read_plan",
    "read_registration",
]
