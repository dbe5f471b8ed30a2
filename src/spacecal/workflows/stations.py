"""Averaging the frames taken at each station of a stop-and-go run into one sample."""

from __future__ import annotations

import numpy as np

from spacecal.geometry.transforms import mean_transform
from spacecal.planning.stop_and_go import TRANSIT
from spacecal.records import Recording

#: A gap longer than this many frame periods between two samples starts a new station.
STATION_GAP_PERIODS = 2.5


def average_stations(recording: Recording, frame_period_s: float) -> Recording:
    """One sample per station: the frames with the marker seen at each rest, averaged.

    Stations are the runs of samples of one segment with no gap longer than
    ``STATION_GAP_PERIODS`` frame periods. Samples paired with a robot state of a transit
    (a frame captured while the arm was still moving, delivered as it stopped) are not at a
    station and are left out.
    The marker pose, the robot's TCP pose and joints, the RMS and the spheres are averaged
    over the frames where the marker was seen; a station where it never was is kept as one
    unseen sample.

    Parameters
    ----------
    recording : Recording
        Paired samples of a stop-and-go run.
    frame_period_s : float
        Tracker frame period, s.

    Returns
    -------
    Recording
        Time of each station: its first frame's; metadata with ``stations_averaged``.
    """
    recording = recording.select(recording.segment != TRANSIT)
    if len(recording) == 0:
        return recording
    new_station = np.concatenate(
        [
            [True],
            (np.diff(recording.time_s) > STATION_GAP_PERIODS * frame_period_s)
            | (recording.segment[1:] != recording.segment[:-1]),
        ]
    )
    starts = np.flatnonzero(new_station)
    ends = np.append(starts[1:], len(recording))
    seen = recording.visible
    rows = []
    for start, end in zip(starts, ends):
        members = np.arange(start, end)
        used = members[seen[members]] if seen[members].any() else members[:1]
        marker = (
            mean_transform(recording.tracker_from_marker_stack[used])
            if seen[members].any()
            else np.full((4, 4), np.nan)
        )
        spheres = None
        if recording.spheres_in_tracker is not None:
            with np.errstate(invalid="ignore"):
                spheres = (
                    np.nanmean(recording.spheres_in_tracker[used], axis=0)
                    if seen[members].any()
                    else (np.full(recording.spheres_in_tracker.shape[1:], np.nan))
                )
        rows.append(
            (
                recording.time_s[start],
                recording.segment[start],
                recording.joints_rad[used].mean(axis=0),
                mean_transform(recording.base_from_tcp_stack[used]),
                marker,
                float(np.nanmean(recording.marker_rms_mm[used])) if seen[members].any() else np.nan,
                spheres,
            )
        )
    times, labels, joints, tcp, markers, rms, spheres_rows = zip(*rows)
    return Recording(
        time_s=np.array(times),
        segment=np.array(labels),
        joints_rad=np.array(joints),
        base_from_tcp_stack=np.array(tcp),
        tracker_from_marker_stack=np.array(markers),
        marker_rms_mm=np.array(rms, dtype=float),
        metadata={**recording.metadata, "stations_averaged": len(rows)},
        spheres_in_tracker=None if recording.spheres_in_tracker is None else np.array(spheres_rows),
    )  # statuses follow the poses: ok where a plainly seen frame was averaged, missing elsewhere
