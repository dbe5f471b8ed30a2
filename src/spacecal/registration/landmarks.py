"""Detecting landmark touches in a tracked-stylus stream (PLUS-style, streaming).

A landmark is touched by holding the stylus tip still in a divot while pivoting the shaft.
Frames are grouped in filter windows of ``round(rate x 0.2 s)`` frames. After each window
the window's mean tip position and the current position of a point 100 mm up the shaft
extend two bounding boxes. If the tip's box grows beyond 1.5 mm (diagonal) the tip moved:
everything collected is dropped and detection starts again. Once at least one second of
windows is collected and the shaft point's box diagonal reaches 30 mm (the stylus pivoted
rather than rested), a landmark is accepted — unless one was already found within a third
of the smallest landmark spacing — and detection starts again.

This follows the landmark detection of the PLUS toolkit (vtkPlusLandmarkDetectionAlgo,
default parameters). The landmark position is the mean tip position over the detection
period after its first window. PLUS itself averages only frames 1–4 of the period (its
window-size variable is overwritten by the number of windows to skip); ``plus_compatible``
reproduces that, to compare with PLUS's results.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spacecal.core.errors import DegenerateDataError
from spacecal.geometry.arrays import ArrayLike, FloatArray


@dataclass(frozen=True)
class LandmarkDetectionSettings:
    """Parameters of :func:`detect_landmarks` (PLUS defaults).

    Attributes
    ----------
    acquisition_rate_hz : float
    filter_window_s, detection_s : float
    tip_max_motion_mm : float
        Largest diagonal of the filtered tip's bounding box while still.
    shaft_min_motion_mm : float
        Smallest diagonal of the shaft point's bounding box for a pivot.
    shaft_point_in_tip_mm : tuple
        The shaft point, in the stylus-tip frame.
    min_landmark_spacing_mm : float
        Landmarks closer than a third of this are the same landmark.
    skip_fraction : float
        Share of the detection windows not averaged (the stylus settles).
    plus_compatible : bool
        Average as PLUS does (frames 1 to 4 of the detection period).
    """

    acquisition_rate_hz: float = 20.0
    filter_window_s: float = 0.2
    detection_s: float = 1.0
    tip_max_motion_mm: float = 1.5
    shaft_min_motion_mm: float = 30.0
    shaft_point_in_tip_mm: tuple[float, float, float] = (100.0, 0.0, 0.0)
    min_landmark_spacing_mm: float = 15.0
    skip_fraction: float = 0.1
    plus_compatible: bool = False


class _Box:
    """An axis-aligned bounding box that can be empty."""

    def __init__(self) -> None:
        self.low: FloatArray | None = None
        self.high: FloatArray | None = None

    def add(self, point: ArrayLike) -> None:
        p = np.asarray(point, dtype=np.float64)
        self.low = p.copy() if self.low is None else np.minimum(self.low, p)
        self.high = p.copy() if self.high is None else np.maximum(self.high, p)

    def diagonal(self) -> float:
        if self.low is None or self.high is None:
            return 0.0
        return float(np.linalg.norm(self.high - self.low))

    def reset(self) -> None:
        self.low = self.high = None


def _round_half_up(value: float) -> int:
    return int(np.floor(value + 0.5))


def detect_landmarks(
    reference_from_tip_stack: ArrayLike,
    settings: LandmarkDetectionSettings | None = None,
    expected: int | None = None,
) -> tuple[np.ndarray, list[int]]:
    """Landmark positions touched by a pivoting stylus, in the reference frame.

    Parameters
    ----------
    reference_from_tip_stack : array_like, shape (N, 4, 4)
        The stylus tip frame in the reference (phantom/patient marker) frame, per frame in
        time order, mm. NaN frames are skipped.
    settings : LandmarkDetectionSettings, optional
    expected : int, optional
        Stop after this many landmarks.

    Returns
    -------
    landmarks_in_reference : numpy.ndarray, shape (M, 3), mm
    end_frames : list of int
        The frame at which each landmark was accepted.
    """
    s = settings or LandmarkDetectionSettings()
    window = max(_round_half_up(s.acquisition_rate_hz * s.filter_window_s), 1)
    windows_needed = int(s.detection_s / s.filter_window_s + 1e-9)
    if windows_needed < 2:
        raise DegenerateDataError(
            "landmark detection: the detection time must span at least two filter windows"
        )
    skip = max(_round_half_up(windows_needed * s.skip_fraction), 1)
    if s.plus_compatible:
        first, last = skip, windows_needed  # frames, as PLUS indexes them
    else:
        first, last = skip * window, windows_needed * window
    shaft_point = np.append(np.asarray(s.shaft_point_in_tip_mm, dtype=float), 1.0)
    tips: list[np.ndarray] = []
    tip_box, shaft_box = _Box(), _Box()
    landmarks: list[np.ndarray] = []
    ends: list[int] = []
    for index, pose in enumerate(np.asarray(reference_from_tip_stack, dtype=float)):
        if expected is not None and len(landmarks) >= expected:
            break
        if not np.all(np.isfinite(pose)):
            continue
        tips.append(pose[:3, 3].copy())
        if len(tips) % window:
            continue
        tip_box.add(np.mean(tips[-window:], axis=0))
        shaft_box.add((pose @ shaft_point)[:3])
        if tip_box.diagonal() > s.tip_max_motion_mm:  # the tip moved: start again
            tips.clear()
            tip_box.reset()
            shaft_box.reset()
            continue
        if len(tips) // window < windows_needed or shaft_box.diagonal() < s.shaft_min_motion_mm:
            continue  # not long enough, or not pivoted enough yet
        candidate = np.mean(tips[first:last], axis=0)
        if all(np.linalg.norm(candidate - known) >= s.min_landmark_spacing_mm / 3 for known in landmarks):
            landmarks.append(candidate)
            ends.append(index)
        tips.clear()
        tip_box.reset()
        shaft_box.reset()
    return np.array(landmarks).reshape(-1, 3), ends
