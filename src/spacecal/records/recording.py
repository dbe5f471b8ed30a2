"""Recordings: paired samples, and the two raw streams they are derived from.

They hold numbers and names only, checked for consistent shapes on construction; reading
and writing them is :mod:`spacecal.io` (:mod:`spacecal.io.recordings`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.core.ports import FRAME_MISSING, FRAME_OK, FRAME_STATUSES
from spacecal.models.kinematics import MAX_JOINTS
from spacecal.records.fields import has_shape, shape_text

#: Segment labels of the paper's sweeps (paper §4). Other labels are allowed in a recording.
ROTATION_SEGMENTS = ("rot_x", "rot_y", "rot_z")
TRANSLATION_SEGMENTS = ("lin_x", "lin_y", "lin_z")
PAPER_SEGMENTS = ROTATION_SEGMENTS + TRANSLATION_SEGMENTS


@dataclass
class Recording:
    """Paired robot and tracker samples, one per tracker frame.

    Attributes
    ----------
    time_s : numpy.ndarray, shape (N,)
        Tracker frame times, strictly increasing, s.
    segment : numpy.ndarray of str, shape (N,)
        Sweep label per sample (``rot_x`` ... ``lin_z``, or any other label).
    joints_rad : numpy.ndarray, shape (N, J)
        Joint angles reported by the robot, rad (J = 6 on a UR arm); NaN rows where not recorded.
    base_from_tcp_stack : numpy.ndarray, shape (N, 4, 4)
        TCP pose reported by the robot (its own forward kinematics), mm.
    tracker_from_marker_stack : numpy.ndarray, shape (N, 4, 4)
        Marker pose reported by the tracker, mm; NaN where the marker was not seen.
    marker_rms_mm : numpy.ndarray, shape (N,)
        The tracker's RMS fit error of the marker, mm; NaN where not seen.
    metadata : dict
        Robot model, TCP in flange, tracker, marker geometry, and for simulated data the
        scenario (see docs/formats.md).
    spheres_in_tracker : numpy.ndarray, shape (N, K, 3), optional
        Raw sphere centres when the tracker reports them, mm; NaN where not seen.
    marker_status : numpy.ndarray of str, shape (N,), optional
        The tracker's frame status per sample, one of
        :data:`spacecal.core.ports.FRAME_STATUSES`. By default ``ok`` where a pose is present
        and ``missing`` elsewhere. ``ok`` without a pose becomes ``missing``; ``missing`` has no
        pose; any other
        status (e.g. ``partially_out_of_volume``) may keep the pose the tracker reported, which
        is then doubtful: :attr:`visible` leaves it out.
    """

    time_s: np.ndarray
    segment: np.ndarray
    joints_rad: np.ndarray
    base_from_tcp_stack: np.ndarray
    tracker_from_marker_stack: np.ndarray
    marker_rms_mm: np.ndarray
    metadata: dict = field(default_factory=dict)
    spheres_in_tracker: np.ndarray | None = None
    marker_status: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(np.atleast_1d(self.time_s))
        self.time_s = _column(self.time_s, (n,), "time_s")
        self.segment = np.asarray(self.segment).astype(str)
        _check_shape(self.segment, (n,), "segment")
        self.joints_rad = _joint_column(self.joints_rad, n)
        self.base_from_tcp_stack = _column(self.base_from_tcp_stack, (n, 4, 4), "base_from_tcp_stack")
        self.tracker_from_marker_stack = _column(
            self.tracker_from_marker_stack, (n, 4, 4), "tracker_from_marker_stack"
        )
        self.marker_rms_mm = _column(self.marker_rms_mm, (n,), "marker_rms_mm")
        if self.spheres_in_tracker is not None:
            self.spheres_in_tracker = np.asarray(self.spheres_in_tracker, dtype=float)
            if self.spheres_in_tracker.ndim != 3 or self.spheres_in_tracker.shape[::2] != (n, 3):
                raise InvalidInputError(
                    f"recording: spheres_in_tracker must have shape ({n}, K, 3), "
                    f"got {self.spheres_in_tracker.shape}"
                )
        has_pose = self.has_pose
        if self.marker_status is None:
            self.marker_status = np.where(has_pose, FRAME_OK, FRAME_MISSING)
        self.marker_status = np.asarray(self.marker_status).astype("<U32")
        _check_shape(self.marker_status, (n,), "marker_status")
        unknown = sorted(set(self.marker_status.tolist()) - set(FRAME_STATUSES))
        if unknown:
            raise InvalidInputError(
                f"recording: unknown marker status {unknown[0]!r}; "
                f"expected one of {', '.join(FRAME_STATUSES)}"
            )
        # a pose removed later (e.g. a frame hidden on purpose) cannot stay ``ok``
        self.marker_status[(self.marker_status == FRAME_OK) & ~has_pose] = FRAME_MISSING
        bad = np.flatnonzero((self.marker_status == FRAME_MISSING) & has_pose)
        if len(bad):
            raise InvalidInputError(
                f"recording: sample {int(bad[0])} has status 'missing' but a marker pose "
                f"({len(bad)} sample(s))"
            )

    def __len__(self) -> int:
        return len(self.time_s)

    @property
    def has_pose(self) -> np.ndarray:
        """Boolean (N,): the tracker reported a marker pose, whatever its status."""
        return np.all(np.isfinite(self.tracker_from_marker_stack[:, :3, 3]), axis=1)

    @property
    def visible(self) -> np.ndarray:
        """Boolean (N,): the marker was plainly seen (a pose with status ``ok``); the mask every
        estimator uses."""
        return self.has_pose & (self.marker_status == FRAME_OK)

    @property
    def doubtful(self) -> np.ndarray:
        """Boolean (N,): a pose reported with a status other than ``ok`` (e.g. partially out of
        the measurement volume); left out of estimation unless trusted explicitly."""
        return self.has_pose & (self.marker_status != FRAME_OK)

    def trusting_doubtful_frames(self) -> Recording:
        """A copy whose doubtful poses count as seen (status ``ok``), to include them in
        estimation on purpose; the original statuses are noted in the metadata."""
        status = np.where(self.has_pose, FRAME_OK, np.asarray(self.marker_status))
        metadata = {**self.metadata, "doubtful_frames_included": int(self.doubtful.sum())}
        return replace(self, marker_status=status, metadata=metadata)

    def as_pose_only(self) -> Recording:
        """The same frames as a pose-only tracker reports them (PLUS over OpenIGTLink): marker
        poses, without sphere positions or fit RMS, so the tracker's noise is unknown to the
        estimators."""
        return replace(self, spheres_in_tracker=None, marker_rms_mm=np.full(len(self), np.nan))

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
            marker_status=None if self.marker_status is None else self.marker_status[mask],
        )


@dataclass
class RawRecording:
    """The two raw streams of an acquisition, each on its own clock.

    Attributes
    ----------
    robot_time_s : numpy.ndarray, shape (R,)
        Controller timestamps (its clock), increasing.
    robot_segment : numpy.ndarray of str, shape (R,)
    joints_rad : numpy.ndarray, shape (R, J)
    base_from_tcp_stack : numpy.ndarray, shape (R, 4, 4)
    tracker_time_s : numpy.ndarray, shape (T,)
        Tracker timestamps (its clock), increasing.
    tracker_from_marker_stack : numpy.ndarray, shape (T, 4, 4)
        NaN where the marker was not seen.
    marker_rms_mm : numpy.ndarray, shape (T,)
    metadata : dict
    spheres_in_tracker : numpy.ndarray, shape (T, K, 3), optional
        Raw sphere centres when the tracker reports them, mm; NaN where not seen.
    arrival_robot_time_s : numpy.ndarray, shape (T,), optional
        The newest robot timestamp (robot clock) when each frame arrived: a coarse link
        between the two clocks, which may count from unrelated epochs; NaN where unknown.
    marker_status : numpy.ndarray of str, shape (T,), optional
        The tracker's frame status (see :class:`Recording`); by default from the poses.
    """

    robot_time_s: np.ndarray
    robot_segment: np.ndarray
    joints_rad: np.ndarray
    base_from_tcp_stack: np.ndarray
    tracker_time_s: np.ndarray
    tracker_from_marker_stack: np.ndarray
    marker_rms_mm: np.ndarray
    metadata: dict = field(default_factory=dict)
    spheres_in_tracker: np.ndarray | None = None
    arrival_robot_time_s: np.ndarray | None = None
    marker_status: np.ndarray | None = None

    def __post_init__(self) -> None:
        r = len(np.atleast_1d(self.robot_time_s))
        t = len(np.atleast_1d(self.tracker_time_s))
        self.robot_time_s = _column(self.robot_time_s, (r,), "robot_time_s")
        self.robot_segment = np.asarray(self.robot_segment).astype(str)
        _check_shape(self.robot_segment, (r,), "robot_segment")
        self.joints_rad = _joint_column(self.joints_rad, r)
        self.base_from_tcp_stack = _column(self.base_from_tcp_stack, (r, 4, 4), "base_from_tcp_stack")
        self.tracker_time_s = _column(self.tracker_time_s, (t,), "tracker_time_s")
        self.tracker_from_marker_stack = _column(
            self.tracker_from_marker_stack, (t, 4, 4), "tracker_from_marker_stack"
        )
        self.marker_rms_mm = _column(self.marker_rms_mm, (t,), "marker_rms_mm")
        if self.spheres_in_tracker is not None:
            spheres = np.asarray(self.spheres_in_tracker, dtype=float)
            if spheres.ndim != 3 or spheres.shape[::2] != (t, 3):
                raise InvalidInputError(
                    f"recording: spheres_in_tracker must have shape ({t}, K, 3), got {spheres.shape}"
                )
            self.spheres_in_tracker = spheres
        if self.arrival_robot_time_s is not None:
            self.arrival_robot_time_s = _column(self.arrival_robot_time_s, (t,), "arrival_robot_time_s")
        if self.marker_status is not None:
            self.marker_status = np.asarray(self.marker_status).astype("<U32")
            _check_shape(self.marker_status, (t,), "marker_status")

    @classmethod
    def from_paired(cls, recording: Recording, metadata: dict | None = None) -> RawRecording:
        """A paired recording as its two streams on one clock: each row is one robot state and
        one tracker frame at the same time (s), poses in mm.

        Parameters
        ----------
        recording : Recording
        metadata : dict, optional
            The streams' metadata (default: the recording's).
        """
        return cls(
            recording.time_s,
            recording.segment,
            recording.joints_rad,
            recording.base_from_tcp_stack,
            recording.time_s,
            recording.tracker_from_marker_stack,
            recording.marker_rms_mm,
            recording.metadata if metadata is None else metadata,
        )


def _check_shape(array: np.ndarray, shape: tuple[int | None, ...], name: str) -> None:
    """Refuse ``array`` unless it has ``shape`` (None: any length along that axis)."""
    if not has_shape(array, shape):
        raise InvalidInputError(f"recording: {name} must have shape {shape_text(shape)}, got {array.shape}")


def _joint_column(values: object, rows: int) -> np.ndarray:
    """Joint angles (rows, J), the same J in every row: 1 to :data:`MAX_JOINTS` joints (a
    recording file carries no more)."""
    array = _column(values, (rows, None), "joints_rad")
    if not 1 <= array.shape[1] <= MAX_JOINTS:
        raise InvalidInputError(
            f"recording: joints_rad has {array.shape[1]} joints per row; 1 to {MAX_JOINTS} are held"
        )
    return array


def _column(values: object, shape: tuple[int | None, ...], name: str) -> np.ndarray:
    """A float array of the given shape (the length of ``time_s`` sets N)."""
    try:
        array = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise InvalidInputError(f"recording: {name} must be numbers") from None
    _check_shape(array, shape, name)
    return array
