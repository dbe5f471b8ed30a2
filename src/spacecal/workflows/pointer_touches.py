"""Touching fiducials with a tracked pointer: the tip's position in the tracker frame, held still.

For each fiducial in turn the operator is asked to touch it (``before_touch(label)``: the CLI
prints "touch fiducial F-3 and hold still"), then the tracker's frames are read until the
pointer has been seen and held still for :attr:`TouchSettings.frames` frames in a row, and the
tip's positions over those frames are averaged::

    tip_in_tracker = (tracker_from_pointer @ pointer_from_tip)[:3, 3]

A window of frames is accepted only when the pointer is seen in every one of them, its tip's
positions scatter from frame to frame no more than :attr:`TouchSettings.max_scatter_mm` (the
RMS 3-D difference of successive positions over sqrt 2: the noise of one position, which a
slow drift hardly enters), its tip did not move (the means of the window's first and second
quarters are within :attr:`TouchSettings.max_motion_mm`), and it is not where an earlier
fiducial was touched (the operator has not moved on yet). Scatter is judged first: noisy
positions also move the quarters' means apart. Frames are read until one is
accepted or :attr:`TouchSettings.wait_s` has passed, then the touch is refused with one line
saying why the last window failed. Every frame is waited for at most
:attr:`TouchSettings.frame_timeout_s` (a tracker that stops answering is the tracker's
:class:`~spacecal.core.errors.DeviceError`).

The touches are written in the touched-points format (:mod:`spacecal.io.touched_points`,
``write_touched_points``) and registered with
:func:`spacecal.registration.image_fiducials.register_image_fiducials`.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from spacecal.core.errors import DeviceError, InvalidInputError
from spacecal.core.ports import Tracker
from spacecal.core.text import quoted
from spacecal.geometry.arrays import ArrayLike
from spacecal.geometry.transforms import check_transform

#: Kinds of refusal (:attr:`TouchRejectedError.reason`).
NOT_SEEN, MOVING, SCATTERED, NOT_MOVED_ON = "not seen", "moving", "scattered", "not moved on"


class TouchRejectedError(DeviceError):
    """A touch that was not held: the pointer not seen, moving, its frames scattered, or still
    at an earlier fiducial, until the wait ran out. ``reason`` is one of :data:`NOT_SEEN`,
    :data:`MOVING`, :data:`SCATTERED`, :data:`NOT_MOVED_ON`; the message is one line."""

    def __init__(self, message: str, reason: str):
        super().__init__(message)
        self.reason = reason
        #: The touches taken before this one (set by :func:`collect_touches`).
        self.touches: dict[str, PointerTouch] = {}


@dataclass(frozen=True)
class TouchSettings:
    """How a touch is taken and judged.

    Attributes
    ----------
    frames : int
        Frames in a row the pointer must be seen and still (at 20 Hz, 20 frames are 1 s).
    max_motion_mm : float
        Largest distance between the mean tip positions of the window's quarters: a tip that
        travels more is moving, not held.
    max_scatter_mm : float
        Largest frame-to-frame scatter of the tip (RMS 3-D difference of successive positions
        over sqrt 2). A held pointer scatters by the tracker's noise at the tip (0.3 to 0.5 mm
        with a 0.25 mm sphere noise and a tip 190 mm from the spheres' centre); more is a
        trembling hand or a pointer seen badly.
    min_separation_mm : float
        A touch closer than this to an earlier fiducial's is the pointer still there.
    wait_s : float
        How long a touch may take, from its first frame (on the tracker's clock and the
        computer's, whichever passes first).
    frame_timeout_s : float
        Deadline of each tracker frame.
    """

    frames: int = 20
    max_motion_mm: float = 1.0
    max_scatter_mm: float = 1.0
    min_separation_mm: float = 5.0
    wait_s: float = 30.0
    frame_timeout_s: float = 1.0

    def __post_init__(self) -> None:
        if not (isinstance(self.frames, int) and self.frames >= 2):
            raise InvalidInputError(f"a touch needs at least 2 frames, got {self.frames!r}")
        for name in ("max_motion_mm", "max_scatter_mm", "wait_s", "frame_timeout_s"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise InvalidInputError(f"touch setting {name} must be a positive number, got {value!r}")
        if not (np.isfinite(self.min_separation_mm) and self.min_separation_mm >= 0):
            raise InvalidInputError(
                f"touch setting min_separation_mm must be 0 or more, got {self.min_separation_mm!r}"
            )


@dataclass(frozen=True)
class PointerTouch:
    """One fiducial touched with the pointer.

    Attributes
    ----------
    label : str
    tip_in_tracker : numpy.ndarray, shape (3,)
        The mean tip position over the accepted frames, tracker frame, mm.
    scatter_rms_mm : float
        The frames' frame-to-frame scatter of the tip (:attr:`TouchSettings.max_scatter_mm`).
    motion_mm : float
        Largest distance between the mean tip positions of the window's quarters.
    frames : int
        Frames averaged.
    time_s : tuple of float
        Tracker times of the first and last frame averaged, s.
    """

    label: str
    tip_in_tracker: np.ndarray
    scatter_rms_mm: float
    motion_mm: float
    frames: int
    time_s: tuple[float, float]


def _scatter_mm(tips: np.ndarray) -> float:
    """The frame-to-frame scatter (mm) of positions (N, 3): RMS 3-D successive difference / sqrt 2."""
    return float(np.sqrt(np.mean(np.sum(np.diff(tips, axis=0) ** 2, axis=1)) / 2.0))


def _motion_mm(tips: np.ndarray) -> float:
    """How far (mm) the mean of positions (N, 3) moved: the largest distance between the means
    of the window's quarters (halves would miss a sway of the window's own period)."""
    blocks = np.array([block.mean(axis=0) for block in np.array_split(tips, min(4, len(tips)))])
    return float(np.max(np.linalg.norm(blocks[:, None] - blocks[None], axis=2)))


def _window_problem(
    label: str, tips: np.ndarray, settings: TouchSettings, earlier: dict[str, PointerTouch]
) -> tuple[str, str] | None:
    """Why a full window of tip positions (N, 3) is not a touch, as (reason, one line), or None."""
    scatter, motion = _scatter_mm(tips), _motion_mm(tips)
    if scatter > settings.max_scatter_mm:
        return SCATTERED, (
            f"the pointer's tip positions on {quoted(label)} scatter {scatter:.2f} mm RMS from frame to "
            f"frame over {len(tips)} frames (at most {settings.max_scatter_mm:g} mm): steady the hand, or "
            "bring the pointer nearer the middle of the tracker's view"
        )
    if motion > settings.max_motion_mm:
        return MOVING, (
            f"the pointer did not hold still on {quoted(label)}: its tip moved {motion:.1f} mm within "
            f"{len(tips)} frames (at most {settings.max_motion_mm:g} mm); hold it still on the fiducial"
        )
    mean = tips.mean(axis=0)
    for other, touch in earlier.items():
        distance = float(np.linalg.norm(mean - touch.tip_in_tracker))
        if distance < settings.min_separation_mm:
            return NOT_MOVED_ON, (
                f"the pointer is still where {quoted(other)} was touched ({distance:.1f} mm from it): "
                f"touch {quoted(label)}"
            )
    return None


def collect_touch(
    tracker: Tracker,
    tool: str,
    pointer_from_tip: ArrayLike,
    label: str,
    settings: TouchSettings | None = None,
    earlier: dict[str, PointerTouch] | None = None,
) -> PointerTouch:
    """Wait until the pointer is held still on a fiducial and return its mean tip position.

    Parameters
    ----------
    tracker : Tracker
        Following the pointer as a further tool (:attr:`~spacecal.core.ports.TrackerFrame.tools`).
    tool : str
        The pointer's name among the tracker's tools.
    pointer_from_tip : array_like, shape (4, 4)
        The pointer's pivot-calibrated tip in its marker frame, mm (only its translation is used).
    label : str
        The fiducial being touched (for the messages and the result).
    settings : TouchSettings, optional
    earlier : dict of str to PointerTouch, optional
        Touches already taken: a window where one of them was taken is not this touch.

    Returns
    -------
    PointerTouch

    Raises
    ------
    TouchRejectedError
        No accepted window within ``settings.wait_s``: one line saying why the last failed.
    InvalidInputError
        The tracker follows no tool of that name, or ``pointer_from_tip`` is no transform.
    DeviceError
        The tracker sent no frame within ``settings.frame_timeout_s``.
    """
    settings = settings or TouchSettings()
    earlier = earlier or {}
    tip_in_pointer = check_transform(pointer_from_tip, "pointer_from_tip")[:3, 3]
    window: deque[tuple[float, np.ndarray]] = deque(maxlen=settings.frames)
    started = time.monotonic()
    first_time_s: float | None = None
    problem: tuple[str, str] = (NOT_SEEN, f"the pointer {quoted(tool)} was not seen")
    unseen_since: float | None = None
    unseen_frames = 0
    window_judged = False  # a full window was judged: its problem outweighs a dropout or two
    while True:
        frame = tracker.next_frame(settings.frame_timeout_s)
        first_time_s = frame.time_s if first_time_s is None else first_time_s
        pose = frame.tool(tool)
        if pose is None:
            window.clear()
            unseen_since = frame.time_s if unseen_since is None else unseen_since
            unseen_frames += 1
            status = frame.tool_statuses.get(tool, "missing").replace("_", " ")
            if not window_judged or unseen_frames >= settings.frames:
                problem = (
                    NOT_SEEN,
                    f"the pointer {quoted(tool)} was not seen ({status}) for the last "
                    f"{frame.time_s - unseen_since:.1f} s: bring it into the tracker's view "
                    f"on {quoted(label)}",
                )
        else:
            unseen_since, unseen_frames = None, 0
            window.append((frame.time_s, pose[:3, :3] @ tip_in_pointer + pose[:3, 3]))
            if len(window) == settings.frames:
                tips = np.array([tip for _, tip in window])
                found = _window_problem(label, tips, settings, earlier)
                if found is None:
                    return PointerTouch(
                        label=label,
                        tip_in_tracker=tips.mean(axis=0),
                        scatter_rms_mm=_scatter_mm(tips),
                        motion_mm=_motion_mm(tips),
                        frames=len(tips),
                        time_s=(window[0][0], window[-1][0]),
                    )
                problem, window_judged = found, True
        elapsed_s = max(time.monotonic() - started, frame.time_s - first_time_s)
        if elapsed_s > settings.wait_s:
            reason, line = problem
            raise TouchRejectedError(
                f"no touch of {quoted(label)} within {settings.wait_s:g} s: {line}", reason
            )


def collect_touches(
    tracker: Tracker,
    tool: str,
    pointer_from_tip: ArrayLike,
    labels: Sequence[str],
    before_touch: Callable[[str], None] | None = None,
    settings: TouchSettings | None = None,
) -> dict[str, PointerTouch]:
    """Touch fiducials in order; ``before_touch(label)`` runs before each (prompt the operator).

    Parameters
    ----------
    tracker, tool, pointer_from_tip, settings
        As :func:`collect_touch`.
    labels : sequence of str
        The fiducials, in the order they are touched; each once.
    before_touch : callable, optional
        Called with each label before its touch is waited for.

    Returns
    -------
    dict of str to PointerTouch
        In the order touched.

    Raises
    ------
    InvalidInputError
        No labels, an empty label, or one label twice.
    TouchRejectedError, DeviceError
        As :func:`collect_touch`; a :class:`TouchRejectedError` carries the touches taken
        before it in its ``touches`` (a dict like the return value).
    """
    labels = [str(label) for label in labels]
    if not labels:
        raise InvalidInputError("no fiducials to touch")
    for label in labels:
        if not label.strip():
            raise InvalidInputError("a fiducial to touch has an empty label")
        if labels.count(label) > 1:
            raise InvalidInputError(f"fiducial {quoted(label)} is to be touched twice")
    touches: dict[str, PointerTouch] = {}
    for label in labels:
        if before_touch is not None:
            before_touch(label)
        try:
            touches[label] = collect_touch(tracker, tool, pointer_from_tip, label, settings, touches)
        except TouchRejectedError as error:
            error.touches = dict(touches)
            raise
    return touches


def touched_points(touches: dict[str, PointerTouch]) -> dict[str, np.ndarray]:
    """The tip positions (3,), tracker frame, mm, by label: what a touched-points file holds and
    :func:`~spacecal.registration.image_fiducials.register_image_fiducials` pairs."""
    return {label: touch.tip_in_tracker for label, touch in touches.items()}
