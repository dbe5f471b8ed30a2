"""A needle plan brought from its image into the tracker and the robot base.

Chain (CONVENTIONS §2; the names meet in the middle)::

    tracker_from_image_lps = tracker_from_image_ras @ image_ras_from_image_lps
    entry_in_tracker = tracker_from_image @ entry_in_image
    entry_in_base = base_from_tracker @ entry_in_tracker

The plan and the registration must name the same image frame; the one conversion made is the
fixed reflection between ``image_lps`` and ``image_ras`` (the same image, two conventions). A
plan in ``image`` (convention unstated) with a registration in ``image_lps``, or the reverse,
is refused: which of the two the other means is not known. A registration into a reference
marker's frame gives no robot-base coordinates (that needs the reference's pose at guidance).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.geometry.anatomical import RAS_FROM_LPS
from spacecal.geometry.transforms import apply_transform, check_transform, invert_transform
from spacecal.records.needle_plan import ImageRegistration, NeedlePlan
from spacecal.registration.image_fiducials import pointer_predicted_tre

#: The anatomical conventions of one image, and the fixed map between them.
_CONVERSIONS = {("image_ras", "image_lps"): RAS_FROM_LPS, ("image_lps", "image_ras"): RAS_FROM_LPS}


@dataclass(frozen=True)
class LocatedPlan:
    """A plan's entry and target in the image, the tracker and (with a calibration) the base.

    Attributes
    ----------
    plan : spacecal.records.needle_plan.NeedlePlan
    registration : spacecal.records.needle_plan.ImageRegistration
    entry_in_tracker, target_in_tracker : numpy.ndarray, shape (3,)
        In the registration's tracker frame (``registration.tracker_frame``), mm.
    entry_in_base, target_in_base : numpy.ndarray, shape (3,) or None
        In the robot base, mm, when a calibration was given.
    predicted_tre_at_target_mm : float or None
        The registration's predicted RMS TRE at the target (Fitzpatrick–West–Maurer), for a
        pointer-made registration.
    """

    plan: NeedlePlan
    registration: ImageRegistration
    entry_in_tracker: np.ndarray
    target_in_tracker: np.ndarray
    entry_in_base: np.ndarray | None = None
    target_in_base: np.ndarray | None = None
    predicted_tre_at_target_mm: float | None = None

    @property
    def direction_in_tracker(self) -> np.ndarray:
        """Unit vector (3,), entry to target, in the tracker frame."""
        return (self.target_in_tracker - self.entry_in_tracker) / self.plan.length_mm


def tracker_from_plan_image(plan: NeedlePlan, registration: ImageRegistration) -> np.ndarray:
    """``tracker_from_image`` (4, 4) for the plan's own image frame.

    Raises
    ------
    InvalidInputError
        The plan's image frame and the registration's are not the same, nor the two conventions
        of one image.
    """
    if registration.image_frame == plan.image_frame:
        return np.array(registration.tracker_from_image)
    conversion = _CONVERSIONS.get((registration.image_frame, plan.image_frame))
    if conversion is None:
        raise InvalidInputError(
            f"the plan's points are in {plan.image_frame} but the registration is "
            f"{registration.name}: they must name the same image frame"
        )
    # e.g. tracker_from_image_lps = tracker_from_image_ras @ image_ras_from_image_lps
    return np.array(registration.tracker_from_image @ conversion)


def locate_plan(
    plan: NeedlePlan, registration: ImageRegistration, tracker_from_base: np.ndarray | None = None
) -> LocatedPlan:
    """The plan's entry and target in the tracker and, given ``tracker_from_base``, the base.

    Parameters
    ----------
    plan : spacecal.records.needle_plan.NeedlePlan
    registration : spacecal.records.needle_plan.ImageRegistration
    tracker_from_base : array_like, shape (4, 4), optional
        The robot calibration, mm.

    Raises
    ------
    InvalidInputError
        The frames disagree (see :func:`tracker_from_plan_image`), or a calibration is given with
        a registration into a reference marker's frame.
    """
    tracker_from_image = tracker_from_plan_image(plan, registration)
    entry_in_tracker = apply_transform(tracker_from_image, plan.entry_in_image)
    target_in_tracker = apply_transform(tracker_from_image, plan.target_in_image)
    entry_in_base = target_in_base = None
    if tracker_from_base is not None:
        if registration.tracker_frame != "tracker":
            raise InvalidInputError(
                f"the registration is {registration.name}: robot-base coordinates need it in the tracker "
                "frame (the reference marker's pose at guidance time), not a reference marker's"
            )
        base_from_tracker = invert_transform(check_transform(tracker_from_base, "tracker_from_base"))
        entry_in_base = apply_transform(base_from_tracker, entry_in_tracker)
        target_in_base = apply_transform(base_from_tracker, target_in_tracker)
    tre = None
    pointer = registration.pointer
    if pointer is not None:
        # the fiducials are in the registration's image frame: so must the target be
        target = apply_transform(invert_transform(registration.tracker_from_image), target_in_tracker)
        tre = float(pointer_predicted_tre(pointer, target)[0])
    return LocatedPlan(
        plan, registration, entry_in_tracker, target_in_tracker, entry_in_base, target_in_base, tre
    )
