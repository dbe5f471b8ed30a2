"""A needle plan made in image space, and the registration that brings it to the tracker.

Two records, each with the frames it is in stated beside its numbers (CONVENTIONS §2, frames
travel with the matrix at boundaries):

* :class:`NeedlePlan`: the entry and target points of a planned needle path, in a named image
  frame (``image_lps`` for a plan read from 3D Slicer: LPS, as DICOM and ITK give it).
* :class:`ImageRegistration`: ``tracker_from_image``, the rigid map of that image frame into the
  tracker (or a reference marker's) frame, with the fiducial errors when it was made with a
  tracked pointer.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.core.frames import FRAMES
from spacecal.core.text import quoted
from spacecal.records.fields import as_array, as_transform, check_schema, get_str, plain

#: The image frames a plan or a registration may be in (each defined in ``core/frames.py``).
IMAGE_FRAMES = ("image", "image_lps", "image_ras")
#: The frames a registration may map an image into.
REGISTERED_FRAMES = ("tracker", "reference")
#: Shortest needle path accepted, mm: shorter, the direction is not determined by the points.
MIN_PATH_MM = 1.0

NEEDLE_PLAN_SCHEMA = "spacecal.needle_plan"


def _frame(name: object, allowed: tuple[str, ...], what: str, role: str) -> str:
    if not isinstance(name, str) or name not in allowed or name not in FRAMES:
        raise InvalidInputError(
            f"{what}: {role} frame {quoted(str(name))} is not one of {', '.join(allowed)}"
        )
    return name


@dataclass(frozen=True)
class NeedlePlan:
    """A planned needle path: entry and target in an image frame.

    Attributes
    ----------
    entry_in_image, target_in_image : numpy.ndarray, shape (3,)
        Where the needle enters and where its tip must end, mm, in ``image_frame``.
    image_frame : str
        The frame of both points: ``image_lps`` (read from Slicer), ``image_ras`` or ``image``.
    name : str
        The plan's name (the markup's name in Slicer), for display.
    entry_label, target_label : str
        The labels of the two control points the plan was read from.
    """

    entry_in_image: np.ndarray
    target_in_image: np.ndarray
    image_frame: str = "image_lps"
    name: str = ""
    entry_label: str = "entry"
    target_label: str = "target"

    def __post_init__(self) -> None:
        what = "needle plan"
        entry = as_array(self.entry_in_image, (3,), "entry_in_image", what)
        target = as_array(self.target_in_image, (3,), "target_in_image", what)
        entry.setflags(write=False)
        target.setflags(write=False)
        object.__setattr__(self, "entry_in_image", entry)
        object.__setattr__(self, "target_in_image", target)
        _frame(self.image_frame, IMAGE_FRAMES, what, "image")
        if float(np.linalg.norm(target - entry)) < MIN_PATH_MM:
            raise InvalidInputError(
                f"{what}: entry and target are {np.linalg.norm(target - entry):.3g} mm apart (at least "
                f"{MIN_PATH_MM:g} mm needed for a needle direction)"
            )

    @property
    def length_mm(self) -> float:
        """The path length, entry to target, mm."""
        return float(np.linalg.norm(self.target_in_image - self.entry_in_image))

    @property
    def direction_in_image(self) -> np.ndarray:
        """Unit vector (3,) from entry to target, in ``image_frame``."""
        return (self.target_in_image - self.entry_in_image) / self.length_mm

    def to_dict(self) -> dict[str, Any]:
        return plain(
            {
                "schema": NEEDLE_PLAN_SCHEMA,
                "schema_version": 1,
                "units": {"length": "mm"},
                "name": self.name,
                "image_frame": self.image_frame,
                "entry_label": self.entry_label,
                "target_label": self.target_label,
                "entry_in_image_mm": self.entry_in_image,
                "target_in_image_mm": self.target_in_image,
            }
        )

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], what: str = "needle plan") -> NeedlePlan:
        check_schema(data, NEEDLE_PLAN_SCHEMA, (1,), what)
        return cls(
            entry_in_image=as_array(data.get("entry_in_image_mm"), (3,), "entry_in_image_mm", what),
            target_in_image=as_array(data.get("target_in_image_mm"), (3,), "target_in_image_mm", what),
            image_frame=get_str(data, "image_frame", what),
            name=get_str(data, "name", what, ""),
            entry_label=get_str(data, "entry_label", what, "entry"),
            target_label=get_str(data, "target_label", what, "target"),
        )


#: Largest stated pointer tip accuracy taken, mm: beyond it the pointer is not calibrated.
MAX_TIP_ACCURACY_MM = 10.0


@dataclass(frozen=True)
class PointerFiducials:
    """What a pointer-made registration was computed from, and its errors.

    Attributes
    ----------
    labels : tuple of str
        The fiducials' labels, in the order of the arrays.
    fiducials_in_image : numpy.ndarray, shape (N, 3)
        The fiducials in the registration's image frame, mm (where predicted TRE is evaluated).
    residuals_mm : numpy.ndarray, shape (N,)
        Distance of each touched fiducial from its registered image position, mm.
    fre_rms_mm, fle_rms_mm : float
        Fiducial registration error (RMS) and the localisation error it implies, mm.
    max_fre_mm : float
        The largest FRE the registration was to be accepted with.
    accepted_above_limit : bool
        The FRE was above ``max_fre_mm`` and the registration was accepted anyway, on request.
    tip_accuracy_mm : float or None
        The stated RMS 3-D accuracy of the pointer's calibrated tip, mm (a Type-B term: the
        tip's pivot-calibration error is common to every touch made in one orientation, so the
        FRE cannot show it and it moves the whole registration); None where the touches state
        none.
    """

    labels: tuple[str, ...]
    fiducials_in_image: np.ndarray
    residuals_mm: np.ndarray
    fre_rms_mm: float
    fle_rms_mm: float
    max_fre_mm: float
    accepted_above_limit: bool = False
    tip_accuracy_mm: float | None = None

    def __post_init__(self) -> None:
        what = "pointer registration"
        if self.tip_accuracy_mm is not None and not (
            np.isfinite(self.tip_accuracy_mm) and 0.0 <= self.tip_accuracy_mm <= MAX_TIP_ACCURACY_MM
        ):
            raise InvalidInputError(
                f"{what}: the pointer tip's accuracy must be 0 to {MAX_TIP_ACCURACY_MM:g} mm, got "
                f"{self.tip_accuracy_mm}"
            )
        points = as_array(self.fiducials_in_image, (None, 3), "fiducials_in_image", what)
        residuals = as_array(self.residuals_mm, (len(points),), "residuals_mm", what)
        if len(self.labels) != len(points):
            raise InvalidInputError(f"{what}: {len(self.labels)} labels for {len(points)} fiducials")
        object.__setattr__(self, "labels", tuple(self.labels))
        object.__setattr__(self, "fiducials_in_image", points)
        object.__setattr__(self, "residuals_mm", residuals)


@dataclass(frozen=True)
class ImageRegistration:
    """``tracker_from_image``: a rigid map from an image frame into the tracker's.

    Attributes
    ----------
    tracker_from_image : numpy.ndarray, shape (4, 4)
        Maps points given in ``image_frame`` into ``tracker_frame``, mm.
    image_frame : str
        ``image_lps``, ``image_ras`` or ``image``.
    tracker_frame : str
        ``tracker``, or ``reference`` for a registration to a marker fixed to the patient.
    source : str
        Where it came from, for display (a file name, or ``pointer``).
    pointer : PointerFiducials or None
        The fiducials and errors, for a registration made with a tracked pointer.
    """

    tracker_from_image: np.ndarray
    image_frame: str
    tracker_frame: str = "tracker"
    source: str = ""
    pointer: PointerFiducials | None = field(default=None)

    def __post_init__(self) -> None:
        what = "image registration"
        matrix = as_transform(self.tracker_from_image, "tracker_from_image", what)
        matrix.setflags(write=False)
        object.__setattr__(self, "tracker_from_image", matrix)
        _frame(self.image_frame, IMAGE_FRAMES, what, "image")
        _frame(self.tracker_frame, REGISTERED_FRAMES, what, "registered")

    @property
    def name(self) -> str:
        """The transform's name in spacecal's ``<to>_from_<from>`` form, e.g. ``tracker_from_image_lps``."""
        return f"{self.tracker_frame}_from_{self.image_frame}"
