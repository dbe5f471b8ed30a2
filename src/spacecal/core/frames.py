"""The coordinate frames spacecal knows, each defined once.

Transforms are named ``<to>_from_<from>`` (``p_tracker = tracker_from_base @ p_base``);
see docs/conventions.md. Code that needs a new frame adds it here.
"""

from __future__ import annotations

FRAMES: dict[str, str] = {
    "tracker": "the optical tracker's measurement frame (paper: M); NDI Polaris, volume along -z",
    "base": "the robot base frame (paper: J), as in the robot's kinematic model",
    "flange": "the robot's tool flange (last DH frame)",
    "tcp": "the robot's tool centre point = flange @ configured tool offset (paper: O); "
    "for the needle guide it is the needle tip",
    "marker": "the passive 4-sphere marker fixed to the tool (paper: B, 'digital reference frame')",
    "needle": "the needle tip frame, z along the needle; coincides with tcp in the paper's setup",
    "image": "CT image space",
    "image_lps": "CT image space in the image's LPS patient coordinates (DICOM, ITK, Slicer's files): "
    "x to the patient's left, y posterior, z superior; a needle plan is held in it",
    "image_ras": "CT image space in RAS coordinates (3D Slicer's world): image_lps with x and y negated",
    "reference": "a reference marker that is not the calibrated one, with its own tool definition: "
    "fixed to the patient or phantom, or rigidly on the needle guide (the simulated world's), where "
    "it measures the reached needle independently of the calibration",
    "pointer": "a hand-held tracked pointer's marker frame",
    "tip": "a pointer's (or needle's) pivot-calibrated tip; pointer_from_tip places it",
    "camera": "a camera on the robot's tool (eye-in-hand); it plays the marker's role",
    "target": "a calibration target fixed in the robot's world, seen by an eye-in-hand camera; "
    "it plays the tracker's role",
}


def check_frame(name: str) -> str:
    """Return ``name`` if it is a known frame, else raise ``ValueError`` listing them."""
    if name not in FRAMES:
        from spacecal.core.errors import InvalidInputError

        raise InvalidInputError(f"unknown frame {name!r}; known frames: {', '.join(sorted(FRAMES))}")
    return name


def transform_name(to_frame: str, from_frame: str) -> str:
    """The canonical name of the transform mapping ``from_frame`` into ``to_frame``."""
    return f"{check_frame(to_frame)}_from_{check_frame(from_frame)}"
