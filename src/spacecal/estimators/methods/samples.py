"""What every method reports of its own fit: the frames it used, their residuals, the motion's spread.

These are facts of one solution on one recording, not a judgement of it (the judgement is
:mod:`spacecal.estimators.assessment`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from spacecal.geometry.arrays import ArrayLike, FloatArray, IndexArray, IntArray, as_float_array
from spacecal.geometry.rotations import mean_rotation, rotation_angle
from spacecal.geometry.transforms import invert_transform, matrix_to_rotvec, mean_transform
from spacecal.records import Recording


def sample_counts(
    recording: Recording,
    used: ArrayLike,
    considered: ArrayLike | None = None,
    extra_rejections: dict[str, int] | None = None,
    per_segment: Sequence[str] = (),
) -> dict[str, Any]:
    """How many samples a method used and why the others were left out (every method's
    ``sample_counts``).

    Parameters
    ----------
    recording : Recording
    used : array_like of bool, shape (N,), or of int, shape (U,)
        The samples used (mask or row indices).
    considered : array_like of bool, shape (N,), optional
        The samples the method looks at (e.g. the paper's six sweeps); invisible ones among
        them count as ``rejected_not_visible``. All samples when omitted.
    extra_rejections : dict, optional
        Further ``rejected_<reason>`` counts, e.g. ``{"outlier": 12}``.
    per_segment : sequence of str
        Segment labels to count the used samples of.
    """
    mask = np.zeros(len(recording), dtype=bool)
    used_array = np.asarray(used)
    if used_array.dtype == bool:
        mask[:] = used_array
    else:
        mask[used_array.astype(int)] = True
    looked_at = (
        np.ones(len(recording), dtype=bool) if considered is None else np.asarray(considered, dtype=bool)
    )
    counts: dict[str, Any] = {
        "total": int(len(recording)),
        "used": int(mask.sum()),
        "rejected": int(len(recording) - mask.sum()),
        "rejected_not_visible": int((looked_at & ~recording.visible).sum()),
    }
    for reason, count in (extra_rejections or {}).items():
        counts[f"rejected_{reason}"] = int(count)
    if per_segment:
        counts["per_segment"] = {
            label: int((mask & (recording.segment == label)).sum()) for label in per_segment
        }
    return counts


def sample_residuals(
    recording: Recording,
    tracker_from_base: FloatArray,
    tcp_from_marker: FloatArray,
    rms_rows: IndexArray | None = None,
) -> dict[str, Any]:
    """Residuals of every visible frame: measured vs predicted ``tracker_from_marker``.

    Parameters
    ----------
    rms_rows : array_like of int, optional
        The frames the RMS figures summarise (e.g. without flagged outliers); default all.

    Returns
    -------
    dict
        ``rows`` (indices), ``position_mm`` (marker origin distance), ``rotation_deg``,
        and their RMS over ``rms_rows``.
    """
    rows = np.flatnonzero(recording.visible)
    predicted = tracker_from_base @ recording.base_from_tcp_stack[rows] @ tcp_from_marker
    measured = recording.tracker_from_marker_stack[rows]
    position = np.linalg.norm(predicted[:, :3, 3] - measured[:, :3, 3], axis=1)
    rotation = np.degrees(rotation_angle(predicted[:, :3, :3] @ np.swapaxes(measured[:, :3, :3], 1, 2)))
    summarised = np.ones(len(rows), bool) if rms_rows is None else np.isin(rows, rms_rows)
    return {
        "rows": rows,
        "position_mm": position,
        "rotation_deg": rotation,
        "position_rms_mm": float(np.sqrt(np.mean(position[summarised] ** 2))),
        "rotation_rms_deg": float(np.sqrt(np.mean(rotation[summarised] ** 2))),
    }


def motion_spread(base_from_tcp_stack: ArrayLike) -> dict[str, Any]:
    """How much the tool rotated and moved: principal spreads of orientation and position.

    Small second or third rotation spreads mean the tool turned about (nearly) one axis:
    the marker offset along that axis is then poorly determined.
    """
    stack = np.asarray(base_from_tcp_stack)
    reference = mean_rotation(stack[:, :3, :3])
    rotvecs = matrix_to_rotvec(stack[:, :3, :3] @ reference.T)
    rot_spread = np.sqrt(np.clip(np.linalg.eigvalsh(np.cov(rotvecs.T)), 0, None))[::-1]
    positions = stack[:, :3, 3]
    pos_spread = np.sqrt(np.clip(np.linalg.eigvalsh(np.cov(positions.T)), 0, None))[::-1]
    return {"rotation_sd_deg": np.degrees(rot_spread).tolist(), "position_sd_mm": pos_spread.tolist()}


def residual_table(
    recording: Recording, residuals: dict[str, Any], outlier_rows: Sequence[int] | IntArray = ()
) -> list[dict[str, Any]]:
    """Per-sample residual rows for result files (time, segment, position, rotation, outlier)."""
    outliers = set(int(r) for r in outlier_rows)
    return [
        {
            "row": int(r),
            "time_s": float(recording.time_s[r]),
            "segment": str(recording.segment[r]),
            "position_mm": float(p),
            "rotation_deg": float(a),
            "outlier": int(r) in outliers,
        }
        for r, p, a in zip(residuals["rows"], residuals["position_mm"], residuals["rotation_deg"])
    ]


def site_in_base(recording: Recording, rows: IndexArray | None = None) -> FloatArray:
    """The surgical site proxy: centroid of the TCP positions of the used samples (3,), mm."""
    used = np.flatnonzero(recording.visible) if rows is None else rows
    return as_float_array(recording.base_from_tcp_stack[used, :3, 3].mean(axis=0))


def tracker_from_base_from_samples(
    recording: Recording, tcp_from_marker: FloatArray, rows: IndexArray
) -> FloatArray:
    """Mean of tracker_from_marker_i @ marker_from_tcp @ tcp_from_base_i over rows."""
    each = (
        recording.tracker_from_marker_stack[rows]
        @ invert_transform(tcp_from_marker)
        @ invert_transform(recording.base_from_tcp_stack[rows])
    )
    return mean_transform(each)
