"""An image registration saved from 3D Slicer as a linear transform file.

A Slicer transform node's file holds its *to-parent* matrix (child coordinates into the
parent's, RAS) in ITK's resampling LPS form; :func:`spacecal.io.slicer.read_slicer_rigid_transform`
undoes that. Which side is the image is the transform's role, which the file does not store:

* the role is given as ``image-to-tracker`` (the child is the image: ``tracker_from_image_ras``),
  ``tracker-to-image`` (SlicerIGT's ``TrackerToRAS``: ``image_ras_from_tracker``), or the same
  with ``reference`` for a marker fixed to the patient;
* else it is read from the file's name when that is a Slicer/PLUS transform name ``<From>To<To>``
  with one side the image (``Image``, ``RAS``, ``CT``) and the other ``Tracker`` or
  ``Reference``: ``TrackerToRAS.tfm``, ``ImageToTracker.h5``;
* else the file is refused, naming the option: guessing would invert the registration.

The image side is ``image_ras`` (Slicer's world is RAS); tracker millimetres are Slicer's world
coordinates as they arrive over OpenIGTLink (as :mod:`spacecal.io.slicer` treats them).
"""

from __future__ import annotations

import re
from pathlib import Path

from spacecal.core.errors import InvalidInputError
from spacecal.core.text import quoted
from spacecal.geometry.transforms import invert_transform
from spacecal.io.slicer import read_slicer_rigid_transform
from spacecal.records.needle_plan import ImageRegistration

#: The roles a registration file may have: (child, parent) of Slicer's transform node.
ROLES = {
    "image-to-tracker": ("image", "tracker"),
    "tracker-to-image": ("tracker", "image"),
    "image-to-reference": ("image", "reference"),
    "reference-to-image": ("reference", "image"),
}
_WORDS = {"image": "image", "ras": "image", "ct": "image", "tracker": "tracker", "reference": "reference"}
_SLICER_NAME = re.compile(r"([A-Z][A-Za-z0-9]*?)To([A-Z][A-Za-z0-9]*)", re.ASCII)


def role_from_name(path: str | Path) -> str | None:
    """The role a file's name states (``TrackerToRAS.tfm``: ``tracker-to-image``), or None."""
    stem = Path(path).name.split(".")[0]
    match = _SLICER_NAME.fullmatch(stem)
    if match is None:
        return None
    child, parent = (_WORDS.get(word.lower()) for word in match.groups())
    role = f"{child}-to-{parent}"
    return role if role in ROLES else None


def read_slicer_registration(path: str | Path, role: str | None = None) -> ImageRegistration:
    """``tracker_from_image_ras`` from a Slicer transform file (``.tfm``, ``.txt``, ``.h5``).

    Parameters
    ----------
    path : str or Path
    role : str, optional
        One of :data:`ROLES`; by default read from the file's name.

    Raises
    ------
    InvalidInputError
        No role given or readable from the name, an unknown role, or a transform that is not
        rigid or not linear.
    """
    if role is None:
        role = role_from_name(path)
        if role is None:
            raise InvalidInputError(
                f"{path}: which side of this transform is the image? Name the file like Slicer's "
                "ImageToTracker or TrackerToRAS, or pass --registration-maps " + "|".join(ROLES)
            )
    elif role not in ROLES:
        raise InvalidInputError(f"--registration-maps takes {', '.join(ROLES)}, got {quoted(role)}")
    child, parent = ROLES[role]
    parent_from_child = read_slicer_rigid_transform(path)
    image_side_is_child = child == "image"
    tracker_from_image = parent_from_child if image_side_is_child else invert_transform(parent_from_child)
    return ImageRegistration(
        tracker_from_image=tracker_from_image,
        image_frame="image_ras",
        tracker_frame=parent if image_side_is_child else child,
        source=str(path),
    )
