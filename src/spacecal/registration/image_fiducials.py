"""Registering an image to the tracker from fiducials touched with a tracked pointer.

The fiducials are marked on the image (their positions in an image frame, by label) and touched
with the tip of a pivot-calibrated pointer (their positions in the tracker, by label). Pairing by
label, :func:`~spacecal.registration.points.register_points` gives ``tracker_from_image`` with
its FRE and the fiducial localisation error it implies, from which the predicted TRE at the
target follows (Fitzpatrick, West, Maurer 1998; see :mod:`spacecal.registration.points`).

A registration whose RMS FRE is above the limit is refused unless accepted on request: a large
FRE means a fiducial was touched in the wrong place or mislabelled, and every point of the plan
moves with it.

The FRE shows only the part of the touches' error that differs between fiducials. A pointer's
tip-calibration error touched in one orientation is common to every touch: it moves the whole
registration and the FRE cannot see it. Its stated accuracy is a Type-B term (GUM §4.3) that
:func:`pointer_predicted_tre` adds in quadrature to Fitzpatrick's TRE.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from spacecal.core.errors import DegenerateDataError, InvalidInputError
from spacecal.core.text import quoted
from spacecal.geometry.arrays import ArrayLike
from spacecal.records.needle_plan import ImageRegistration, PointerFiducials
from spacecal.registration.points import predicted_tre, register_points

#: Default largest RMS FRE accepted, mm: twice a good optical tracker's pointer FLE (~0.25 to
#: 0.5 mm on skin-free bone fiducials) with margin; larger is a touch in the wrong divot.
DEFAULT_MAX_FRE_MM = 2.0


def register_image_fiducials(
    fiducials_in_image: Mapping[str, ArrayLike],
    touched_in_tracker: Mapping[str, ArrayLike],
    *,
    image_frame: str,
    tracker_frame: str = "tracker",
    max_fre_mm: float = DEFAULT_MAX_FRE_MM,
    accept_high_fre: bool = False,
    tip_accuracy_mm: float | None = None,
) -> ImageRegistration:
    """``tracker_from_image`` from fiducials paired by label.

    Parameters
    ----------
    fiducials_in_image : mapping of str to array_like, shape (3,)
        Fiducial positions in ``image_frame``, mm, by label.
    touched_in_tracker : mapping of str to array_like, shape (3,)
        The pointer tip's position at each touched fiducial in ``tracker_frame``, mm, by label.
        Every touched label must be a fiducial of the image; fiducials not touched are left out.
    image_frame, tracker_frame : str
        The frames of the two sets (``image_lps`` for fiducials read from Slicer).
    max_fre_mm : float
        Largest RMS fiducial registration error accepted.
    accept_high_fre : bool
        Return a registration above ``max_fre_mm`` anyway (it records that it was).
    tip_accuracy_mm : float, optional
        The pointer tip's stated RMS 3-D accuracy, mm (kept in
        :attr:`~spacecal.records.needle_plan.PointerFiducials.tip_accuracy_mm`).

    Raises
    ------
    InvalidInputError
        A touched label that is not a fiducial of the image, or an FRE above the limit.
    DegenerateDataError
        Fewer than 3 pairs, or collinear fiducials.
    """
    if not np.isfinite(max_fre_mm) or max_fre_mm <= 0:
        raise InvalidInputError(f"the FRE limit must be a positive number of mm, got {max_fre_mm}")
    unknown = [label for label in touched_in_tracker if label not in fiducials_in_image]
    if unknown:
        raise InvalidInputError(
            f"touched point {quoted(unknown[0])} is not a fiducial of the image "
            f"(its fiducials: {', '.join(quoted(k) for k in fiducials_in_image)})"
        )
    labels = tuple(touched_in_tracker)
    if len(labels) < 3:
        raise DegenerateDataError(f"a registration needs at least 3 touched fiducials, got {len(labels)}")
    image = np.array([np.asarray(fiducials_in_image[k], dtype=float) for k in labels])
    tracker = np.array([np.asarray(touched_in_tracker[k], dtype=float) for k in labels])
    registration = register_points(points_in_source=image, points_in_target=tracker)
    fre = registration.fre_rms_mm
    if fre > max_fre_mm and not accept_high_fre:
        worst = int(np.argmax(registration.residuals_mm))
        raise InvalidInputError(
            f"the registration's FRE is {fre:.2f} mm RMS, above its limit {max_fre_mm:g} mm (worst: "
            f"{quoted(labels[worst])}, {registration.residuals_mm[worst]:.2f} mm); touch the fiducials "
            "again, or pass --accept-high-fre to use it anyway"
        )
    return ImageRegistration(
        tracker_from_image=registration.target_from_source,
        image_frame=image_frame,
        tracker_frame=tracker_frame,
        source="pointer",
        pointer=PointerFiducials(
            labels=labels,
            fiducials_in_image=image,
            residuals_mm=registration.residuals_mm,
            fre_rms_mm=fre,
            fle_rms_mm=registration.fle_rms_mm,
            max_fre_mm=max_fre_mm,
            accepted_above_limit=fre > max_fre_mm,
            tip_accuracy_mm=tip_accuracy_mm,
        ),
    )


def pointer_predicted_tre(pointer: PointerFiducials, targets_in_image: ArrayLike) -> np.ndarray:
    """The predicted RMS error (M,) of a pointer-made registration at targets (M, 3), mm.

    Fitzpatrick's TRE (Fitzpatrick, West, Maurer 1998) from the FLE the FRE implies, with the
    pointer tip's stated accuracy added in quadrature: a tip error common to all touches
    translates the registration by itself, so at every target it counts in full.

    Parameters
    ----------
    pointer : PointerFiducials
    targets_in_image : array_like, shape (M, 3) or (3,)
        Targets in the registration's image frame, mm.
    """
    tre = predicted_tre(pointer.fiducials_in_image, targets_in_image, pointer.fle_rms_mm)
    tip = pointer.tip_accuracy_mm or 0.0
    return np.sqrt(tre**2 + tip**2)
