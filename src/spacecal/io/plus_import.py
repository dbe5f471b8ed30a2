"""Turn a PLUS sequence file into a spacecal recording.

The sequence must hold the marker pose (``MarkerToTracker``, i.e. ``tracker_from_marker``)
and the robot's TCP pose (e.g. ``TCPToBase``, i.e. ``base_from_tcp``, as a PLUS robot device
or a tracked tool broadcasts it). Joint angles are not in PLUS sequences and stay empty.
Every frame gets the segment label given (sweep labels can be assigned afterwards).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.core.units import check_lengths_in_mm
from spacecal.geometry.transforms import orthonormalize_transforms
from spacecal.io.plus_sequence import read_plus_sequence
from spacecal.records import Recording


def recording_from_plus_sequence(
    path: str | Path, marker: str = "MarkerToTracker", tcp: str = "TCPToBase", segment: str = "static"
) -> Recording:
    """A recording from a PLUS sequence (frames where the TCP pose is invalid are dropped)."""
    sequence = read_plus_sequence(path)
    # frames are counted as in the file: each pose is checked before any frame is dropped
    tracker_from_marker = orthonormalize_transforms(sequence.transform(marker), f"{path}: {marker}")
    base_from_tcp = orthonormalize_transforms(sequence.transform(tcp), f"{path}: {tcp}")
    keep = np.all(np.isfinite(base_from_tcp.reshape(len(base_from_tcp), -1)), axis=1)
    keep &= np.concatenate([[True], np.diff(sequence.timestamps_s) > 0])
    if keep.sum() < 3:
        raise InvalidInputError(f"{path}: fewer than 3 frames with a valid {tcp}")

    tracker_from_marker = tracker_from_marker[keep]
    base_from_tcp = base_from_tcp[keep]
    check_lengths_in_mm(base_from_tcp[:, :3, 3], f"{path}: {tcp} translations")
    n = int(keep.sum())
    return Recording(
        time_s=sequence.timestamps_s[keep],
        segment=np.full(n, segment),
        joints_rad=np.full((n, 6), np.nan),
        base_from_tcp_stack=base_from_tcp,
        tracker_from_marker_stack=tracker_from_marker,
        marker_rms_mm=np.full(n, np.nan),
        metadata={
            "source": f"PLUS sequence {Path(path).name}",
            "plus_transforms": {"marker": marker, "tcp": tcp},
            "units": {"length": "mm", "angle": "rad", "time": "s"},
        },
    )
