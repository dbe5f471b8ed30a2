"""Plain data records passed between steps: recordings and calibration results.

They hold numbers and names only; reading and writing them is :mod:`spacecal.io`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Segment labels of the paper's sweeps (paper §4). Other labels are allowed in a recording.
ROTATION_SEGMENTS = ("rot_x", "rot_y", "rot_z")
TRANSLATION_SEGMENTS = ("lin_x", "lin_y", "lin_z")
PAPER_SEGMENTS = ROTATION_SEGMENTS + TRANSLATION_SEGMENTS

CALIBRATION_SCHEMA_VERSION = 1


@dataclass
class Recording:
    """Paired robot and tracker samples, one per tracker frame.

    Attributes
    ----------
    time_s : numpy.ndarray, shape (N,)
        Tracker frame times, strictly increasing, s.
    segment : numpy.ndarray of str, shape (N,)
        Sweep label per sample (``rot_x`` ... ``lin_z``, or any other label).
    joints_rad : numpy.ndarray, shape (N, 6)
        Joint angles reported by the robot, rad.
    base_from_tcp_stack : numpy.ndarray, shape (N, 4, 4)
        TCP pose reported by the robot (its own forward kinematics), mm.
    tracker_from_marker_stack : numpy.ndarray, shape (N, 4, 4)
        Marker pose reported by the tracker, mm; NaN where the marker was not seen.
    marker_rms_mm : numpy.ndarray, shape (N,)
        The tracker's RMS fit error of the marker, mm; NaN where not seen.
    metadata : dict
        Robot model, TCP in flange, tracker, marker geometry, and for simulated data the
        scenario (see the README's "Files" section).
    spheres_in_tracker : numpy.ndarray, shape (N, K, 3), optional
        Raw sphere centres when the tracker reports them, mm; NaN where not seen.
    """

    time_s: np.ndarray
    segment: np.ndarray
    joints_rad: np.ndarray
    base_from_tcp_stack: np.ndarray
    tracker_from_marker_stack: np.ndarray
    marker_rms_mm: np.ndarray
    metadata: dict = field(default_factory=dict)
    spheres_in_tracker: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.time_s)

    @property
    def visible(self) -> np.ndarray:
        """Boolean (N,): the marker was tracked in that frame."""
        return np.all(np.isfinite(self.tracker_from_marker_stack[:, :3, 3]), axis=1)

    def select(self, mask) -> Recording:
        """A new recording holding only the samples where ``mask`` (N,) is true."""
        mask = np.asarray(mask)
        return Recording(
            time_s=self.time_s[mask],
            segment=self.segment[mask],
            joints_rad=self.joints_rad[mask],
            base_from_tcp_stack=self.base_from_tcp_stack[mask],
            tracker_from_marker_stack=self.tracker_from_marker_stack[mask],
            marker_rms_mm=self.marker_rms_mm[mask],
            metadata=self.metadata,
            spheres_in_tracker=None if self.spheres_in_tracker is None else self.spheres_in_tracker[mask],
        )


@dataclass
class CalibrationResult:
    """The outcome of a calibration.

    Attributes
    ----------
    method : str
        Registry name of the estimator.
    tracker_from_base : numpy.ndarray, shape (4, 4)
        Maps base coordinates into the tracker frame, mm. What navigation needs.
    tcp_from_marker : numpy.ndarray, shape (4, 4)
        Pose of the marker on the tool, mm.
    sample_counts : dict
        ``{"total", "used", "rejected", "per_segment": {...}}``.
    diagnostics : dict
        Method-specific quality figures (see each estimator).
    source : dict
        Where the data came from (recording path, robot model).
    covariance : dict, optional
        ``{"parameters": [12 names], "matrix": 12x12}``: covariance of the perturbation
        parameters of both transforms (see :mod:`spacecal.estimators.ml`), mm and rad.
    predicted_tre_mm : dict, optional
        Predicted RMS target registration error at the surgical site, over a cube around
        it, and at user targets.
    """

    method: str
    tracker_from_base: np.ndarray
    tcp_from_marker: np.ndarray
    sample_counts: dict
    diagnostics: dict
    source: dict = field(default_factory=dict)
    covariance: dict | None = None
    predicted_tre_mm: dict | None = None
    schema_version: int = CALIBRATION_SCHEMA_VERSION


@dataclass
class RawRecording:
    """The two raw streams of an acquisition, each on its own clock.

    Attributes
    ----------
    robot_time_s : numpy.ndarray, shape (R,)
        Controller timestamps (its clock), increasing.
    robot_segment : numpy.ndarray of str, shape (R,)
    joints_rad : numpy.ndarray, shape (R, 6)
    base_from_tcp_stack : numpy.ndarray, shape (R, 4, 4)
    tracker_time_s : numpy.ndarray, shape (T,)
        Tracker timestamps (its clock), increasing.
    tracker_from_marker_stack : numpy.ndarray, shape (T, 4, 4)
        NaN where the marker was not seen.
    marker_rms_mm : numpy.ndarray, shape (T,)
    metadata : dict
    """

    robot_time_s: np.ndarray
    robot_segment: np.ndarray
    joints_rad: np.ndarray
    base_from_tcp_stack: np.ndarray
    tracker_time_s: np.ndarray
    tracker_from_marker_stack: np.ndarray
    marker_rms_mm: np.ndarray
    metadata: dict = field(default_factory=dict)
