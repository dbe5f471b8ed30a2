"""``spacecal touch``: register the image to the tracker by touching its fiducials with a tracked
pointer (the patient registration the paper's phantom experiment needs before a plan made on CT
can be reached, §5.3).

For each image fiducial, by its label, the operator is asked to touch it and hold still
(``before_touch``); the touch is taken when the pointer has been seen and held still
(:func:`spacecal.workflows.pointer_touches.collect_touches`). The touches are written as a
touched-points CSV (``-o``; what ``plan-from-slicer --fiducials --touched`` reads), then
registered (:func:`spacecal.registration.image_fiducials.register_image_fiducials`): the FRE, each
fiducial's residual and the predicted TRE at the fiducials' centroid (Fitzpatrick, West, Maurer
1998) are shown, and a registration above ``--max-fre-mm`` is refused in one line unless
``--accept-high-fre``. ``--registration-output`` also writes it as a Slicer transform file (the
image-to-tracker role: its to-parent matrix is ``tracker_from_image_ras``), which
``plan-from-slicer --registration`` reads.

With ``--tracker sim`` the simulated tracker follows the world's pointer, and the simulated hand
places it on each fiducial of the world's phantom before each touch. On real trackers the
pointer is a further tool: an NDI tool definition among ``--rom`` after the first (named after
its file), or the OpenIGTLink device of that name. Nothing moves the robot here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from spacecal.app._common import guard_outputs
from spacecal.app.devices import SIMULATED, check_tracker_rate_hz, close_device, open_tracker
from spacecal.app.result import CommandResult
from spacecal.core.errors import InvalidInputError
from spacecal.core.ports import Tracker
from spacecal.core.strict_numbers import decimal, integer
from spacecal.core.text import quoted, sanitize_for_terminal
from spacecal.geometry.anatomical import RAS_FROM_LPS
from spacecal.geometry.transforms import make_transform
from spacecal.io.results_json import read_json_object
from spacecal.io.slicer import write_slicer_transform
from spacecal.io.slicer_markups import fiducials_from_markups
from spacecal.io.touched_points import write_touched_points
from spacecal.records import PivotResult
from spacecal.records.needle_plan import MAX_TIP_ACCURACY_MM, ImageRegistration
from spacecal.registration.image_fiducials import (
    DEFAULT_MAX_FRE_MM,
    pointer_predicted_tre,
    register_image_fiducials,
)
from spacecal.sim.scenario import DEFAULT_SCENARIO
from spacecal.sim.tools import POINTER_TIP_ERROR_MM
from spacecal.sim.world import World
from spacecal.workflows.pointer_touches import (
    TouchRejectedError,
    TouchSettings,
    collect_touches,
    touched_points,
)

#: Suffix of the file the touches taken before a refused one are kept in (beside ``-o``).
INCOMPLETE_SUFFIX = ".incomplete.csv"


@dataclass(frozen=True)
class TouchCommandSettings:
    """``spacecal touch``: touch the image fiducials with a tracked pointer and register.

    Attributes
    ----------
    fiducials : str
        The image fiducials: a Slicer markups point list (``.mrk.json``), by label.
    output : str
        Touched-points CSV to write (label and tip position in the tracker frame, mm).
    tracker : str
        ``sim`` (the simulated tracker and its phantom) or a tracker URL.
    pointer_tool : str
        The pointer's name among the tracker's tools.
    pointer_tip : str or None
        Pivot result of the pointer (``spacecal pivot -o``): its tip in its marker frame. Needed
        on a real tracker; with ``sim``, the simulated pointer's pivot calibration by default.
    pointer_tip_accuracy_mm : float or None
        The stated RMS 3-D accuracy of the pointer's tip, mm (its maker's, or a pivot checked
        against a known point): a Type-B term of the registration's predicted error, written in
        the touched-points file. None: the pivot fit's own uncertainty (a lower bound), or with
        ``sim`` the simulated pointer's stated accuracy.
    rom : tuple of str
        NDI tool definitions: a first one (the marker's, or any), then the pointer's.
    tracker_rate_hz : float
    scenario : str or None
        The simulated world (``sim`` only; default the default scenario).
    coordinate_system : {"LPS", "RAS"} or None
        For a markups file that does not state its system.
    frames : int
        Frames in a row the pointer must be held still for a touch.
    wait_s : float
        How long each touch may take, s.
    max_fre_mm : float
        Largest RMS FRE accepted.
    accept_high_fre : bool
    registration_output : str or None
        Slicer transform file (``.tfm``) of the registration to write.
    force : bool
    """

    fiducials: str
    output: str
    tracker: str = SIMULATED
    pointer_tool: str = "pointer"
    pointer_tip: str | None = None
    pointer_tip_accuracy_mm: float | None = None
    rom: tuple[str, ...] = ()
    tracker_rate_hz: float = 20.0
    scenario: str | None = None
    coordinate_system: str | None = None
    frames: int = 20
    wait_s: float = 30.0
    max_fre_mm: float = DEFAULT_MAX_FRE_MM
    accept_high_fre: bool = False
    registration_output: str | None = None
    force: bool = False

    #: The command line's flag and argparse options of each field.
    FLAGS: ClassVar[dict[str, tuple[str, dict[str, Any]]]] = {
        "tracker": ("--tracker", dict(help="sim (default) or a tracker URL (ndi://..., igtl://...)")),
        "pointer_tool": (
            "--pointer-tool",
            dict(metavar="NAME", help="the pointer's tool name (default pointer)"),
        ),
        "pointer_tip": (
            "--pointer-tip",
            dict(metavar="PIVOT.json", help="the pointer's pivot (spacecal pivot -o)"),
        ),
        "pointer_tip_accuracy_mm": (
            "--pointer-tip-accuracy-mm",
            dict(type=decimal, metavar="MM", help="the pointer tip's stated RMS accuracy, mm"),
        ),
        "fiducials": (
            "--fiducials",
            dict(required=True, metavar="FIDUCIALS.mrk.json", help="image fiducials"),
        ),
        "output": ("-o --output", dict(required=True, metavar="TOUCHED.csv", help="touched points to write")),
        "registration_output": (
            "--registration-output",
            dict(metavar="ImageToTracker.tfm", help="the registration as a Slicer transform file"),
        ),
        "rom": ("--rom", dict(action="append", help="NDI tool definitions: a first one, then the pointer's")),
        "tracker_rate_hz": ("--tracker-rate-hz", dict(type=decimal, help="tracker frame rate")),
        "scenario": ("--scenario", dict(help="with --tracker sim: the simulated world")),
        "coordinate_system": (
            "--coordinate-system",
            dict(choices=("LPS", "RAS"), help="for a markups file that does not state its own"),
        ),
        "max_fre_mm": (
            "--max-fre-mm",
            dict(type=decimal, help=f"largest RMS FRE accepted, mm (default {DEFAULT_MAX_FRE_MM:g})"),
        ),
        "accept_high_fre": (
            "--accept-high-fre",
            dict(action="store_true", help="use a registration above it"),
        ),
        "frames": ("--frames", dict(type=integer, help="frames held still for a touch (default 20)")),
        "wait_s": ("--wait-s", dict(type=decimal, help="longest wait for each touch, s (default 30)")),
    }

    def __post_init__(self) -> None:
        object.__setattr__(self, "rom", tuple(self.rom or ()))
        check_tracker_rate_hz(self.tracker_rate_hz)
        if not self.pointer_tool or not self.pointer_tool.strip():
            raise InvalidInputError("--pointer-tool needs the pointer's tool name")
        if self.tracker != SIMULATED and self.pointer_tip is None:
            raise InvalidInputError(
                "--pointer-tip PIVOT.json is needed on a real tracker (spacecal pivot -o)"
            )
        if self.tracker != SIMULATED and self.scenario is not None:
            raise InvalidInputError("--scenario is for --tracker sim")
        accuracy = self.pointer_tip_accuracy_mm
        if accuracy is not None and not (np.isfinite(accuracy) and 0.0 <= accuracy <= MAX_TIP_ACCURACY_MM):
            raise InvalidInputError(
                f"--pointer-tip-accuracy-mm must be 0 to {MAX_TIP_ACCURACY_MM:g} mm, got {accuracy:g}"
            )
        if self.registration_output is not None and Path(self.registration_output).suffix not in (
            ".tfm",
            ".txt",
        ):
            raise InvalidInputError("--registration-output writes a Slicer transform file: name it .tfm")


@dataclass(frozen=True)
class TouchOutput:
    """The touches and the registration made from them.

    Attributes
    ----------
    touched_in_tracker : dict of str to numpy.ndarray, shape (3,)
        The pointer tip at each fiducial, tracker frame, mm, in the order touched.
    registration : ImageRegistration
        ``tracker_from_image_lps`` with its fiducials and errors.
    predicted_tre_mm : float
        Fitzpatrick's predicted RMS TRE at the fiducials' centroid, mm.
    world : World or None
        The simulated world touched in (its truth), None on a real tracker.
    """

    touched_in_tracker: dict[str, np.ndarray]
    registration: ImageRegistration
    predicted_tre_mm: float
    world: World | None = None


def touch_prompt(label: str) -> str:
    """What the operator is asked before the touch of fiducial ``label`` (from a file: escaped)."""
    return f"touch fiducial {sanitize_for_terminal(label, 100)} and hold still"


def touch(
    settings: TouchCommandSettings,
    before_touch: Callable[[str], None] | None = None,
    on_line: Callable[[str], None] | None = None,
) -> CommandResult[TouchOutput]:
    """Touch each image fiducial with the pointer, write the touches and register.

    Parameters
    ----------
    settings : TouchCommandSettings
    before_touch : callable, optional
        Called with each fiducial's label before its touch is waited for (after the simulated
        hand has placed the pointer there).
    on_line : callable, optional
        Called with the prompt of each touch (:func:`touch_prompt`): the command line prints it.

    Raises
    ------
    InvalidInputError
        An unreadable fiducials or pivot file, fewer than 3 fiducials, a pointer the tracker
        does not follow, or an FRE above the limit (the touches are written first).
    TouchRejectedError
        A touch not taken in time (the pointer not seen, moving); the touches before it are
        kept in ``OUTPUT.incomplete.csv``.
    """
    guard_outputs(
        [settings.output, settings.registration_output],
        [settings.fiducials, settings.pointer_tip, *settings.rom],
        settings.force,
        any_file=True,
    )
    fiducials = fiducials_from_markups(settings.fiducials, coordinate_system=settings.coordinate_system)
    if len(fiducials) < 3:
        raise InvalidInputError(
            f"{settings.fiducials}: a registration needs at least 3 fiducials with positions, it has "
            f"{len(fiducials)}"
        )
    world, tracker = _open(settings)
    try:
        pointer_from_tip, tip_accuracy, accuracy_source = _pointer_tip(settings, world)

        def prompt(label: str) -> None:
            if world is not None:
                world.place_pointer(label)  # the simulated hand: a fiducial it lacks is one line
            if on_line is not None:
                on_line(touch_prompt(label))
            if before_touch is not None:
                before_touch(label)

        try:
            touches = collect_touches(
                tracker,
                settings.pointer_tool,
                pointer_from_tip,
                list(fiducials),
                prompt,
                TouchSettings(frames=settings.frames, wait_s=settings.wait_s),
            )
        except TouchRejectedError as error:
            if error.touches:  # recorded data is kept
                kept = _incomplete_path(settings.output)
                write_touched_points(
                    kept,
                    touched_points(error.touches),
                    comments=_comments(settings, True),
                    tip_accuracy_mm=tip_accuracy,
                )
                raise TouchRejectedError(
                    f"{error}; the {len(error.touches)} touches before it kept in {kept}", error.reason
                ) from None
            raise
    finally:
        close_device(tracker)
    points = touched_points(touches)
    files = [
        write_touched_points(
            settings.output, points, comments=_comments(settings, False), tip_accuracy_mm=tip_accuracy
        )
    ]
    registration = register_image_fiducials(
        fiducials,
        points,
        image_frame="image_lps",
        max_fre_mm=settings.max_fre_mm,
        accept_high_fre=settings.accept_high_fre,
        tip_accuracy_mm=tip_accuracy,
    )
    pointer = registration.pointer
    assert pointer is not None  # a pointer registration
    centroid = pointer.fiducials_in_image.mean(axis=0)
    tre = float(pointer_predicted_tre(pointer, centroid[None])[0])
    if settings.registration_output is not None:
        # Slicer's image-to-tracker transform: to-parent tracker_from_image_ras
        tracker_from_ras = registration.tracker_from_image @ np.linalg.inv(RAS_FROM_LPS)
        files.append(write_slicer_transform(tracker_from_ras, settings.registration_output))
    above = "; ACCEPTED ABOVE IT on request" if pointer.accepted_above_limit else ""
    lines = [
        *(f"wrote {path}" for path in files),
        f"{len(points)} fiducials touched with {quoted(settings.pointer_tool)}"
        + (" (simulated tracker)" if world is not None else ""),
        *(
            f"  {label}: residual {residual:.3f} mm (held still {touches[label].scatter_rms_mm:.2f} mm "
            f"scatter, {touches[label].frames} frames)"
            for label, residual in zip(pointer.labels, pointer.residuals_mm)
        ),
        f"registration {registration.name}: FRE {pointer.fre_rms_mm:.3f} mm RMS (limit "
        f"{settings.max_fre_mm:g} mm{above}), predicted TRE at the fiducials' centroid {tre:.3f} mm "
        f"(with the pointer tip's accuracy {tip_accuracy:.3f} mm RMS: {accuracy_source})",
        "use it: spacecal plan-from-slicer PLAN.mrk.json --fiducials "
        f"{sanitize_for_terminal(settings.fiducials, 300)} "
        f"--touched {sanitize_for_terminal(settings.output, 300)}",
    ]
    return CommandResult(TouchOutput(points, registration, tre, world), tuple(files), (), tuple(lines))


def _open(settings: TouchCommandSettings) -> tuple[World | None, Tracker]:
    """The simulated world and its tracker following the pointer, or the real tracker opened
    with the pointer as a further tool."""
    if settings.tracker == SIMULATED:
        from spacecal.app.motion_session import simulated_devices

        world, _, tracker = simulated_devices(settings.scenario or DEFAULT_SCENARIO)
        if settings.pointer_tool not in tracker.tools:
            raise InvalidInputError(
                f"the simulated tracker follows {', '.join(quoted(t) for t in tracker.tools)}, not "
                f"{quoted(settings.pointer_tool)}"
            )
        return world, tracker
    name = settings.pointer_tool
    tools: tuple[tuple[str, str], ...] = ()
    if settings.tracker.startswith("ndi://"):
        if not any(Path(rom).stem == name for rom in settings.rom[1:]):
            raise InvalidInputError(
                f"--pointer-tool {name}: no tool definition {name}.rom among --rom after the first (an NDI "
                "tracker names its further tools after their ROM files)"
            )
    else:
        tools = ((name, name),)  # an OpenIGTLink device of that name
    return None, open_tracker(settings.tracker, settings.rom, settings.tracker_rate_hz, tools)


def _pointer_tip(settings: TouchCommandSettings, world: World | None) -> tuple[np.ndarray, float, str]:
    """The pointer's tip (4, 4, in its marker frame, mm), its RMS 3-D accuracy (mm) and where
    that accuracy comes from.

    The tip is the pivot result file's, or the simulated pointer's own pivot calibration. The
    accuracy is ``--pointer-tip-accuracy-mm`` where given; else, with a pivot file, the fit's
    own uncertainty (the square root of the trace of its tip covariance: a lower bound, as a
    pivot's divot and bending errors are not in it; said so); else the simulated pointer's
    stated accuracy (:data:`spacecal.sim.tools.POINTER_TIP_ERROR_MM`)."""
    stated = settings.pointer_tip_accuracy_mm
    if settings.pointer_tip is None:
        assert world is not None  # __post_init__: a real tracker needs the file
        if stated is not None:
            return world.pointer_from_tip, stated, "stated with --pointer-tip-accuracy-mm"
        return world.pointer_from_tip, POINTER_TIP_ERROR_MM, "the simulated pointer's stated accuracy"
    pivot = PivotResult.from_dict(
        read_json_object(settings.pointer_tip, "pivot result"), settings.pointer_tip
    )
    tip = make_transform(np.eye(3), pivot.tip_in_marker)
    if stated is not None:
        return tip, stated, "stated with --pointer-tip-accuracy-mm"
    if pivot.tip_covariance_mm2 is not None:
        fit = float(np.sqrt(max(np.trace(pivot.tip_covariance_mm2), 0.0)))
        return tip, fit, "the pivot fit's own, a lower bound: state it with --pointer-tip-accuracy-mm"
    return tip, 0.0, "none stated and the pivot file has no covariance: --pointer-tip-accuracy-mm"


def _incomplete_path(output: str) -> Path:
    path = Path(output)
    return path.with_name(path.name.removesuffix(path.suffix) + INCOMPLETE_SUFFIX)


def _comments(settings: TouchCommandSettings, incomplete: bool) -> list[str]:
    return [
        "spacecal touch: pointer tip positions at the image fiducials"
        + ("; INCOMPLETE: a touch was refused" if incomplete else ""),
        f"fiducials: {Path(settings.fiducials).name}; "
        f"tracker: {'simulated' if settings.tracker == SIMULATED else 'real'}",
    ]
