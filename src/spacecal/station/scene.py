"""The set-up in 3-D, as a plotly figure: where the tracker, its measurement volume, the robot
base, the planned path, the site and the recorded samples are, in one named frame.

Before a calibration nothing links the robot to the tracker, so the plan is drawn in the robot
base frame alone. After it, ``tracker_from_base`` brings everything into the tracker's frame:
the base, the plan, the site, the measurement volume and the samples (seen: where the marker
was measured; unseen: where the TCP was, by the calibration). Every axis title names the frame.
Lengths are mm.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from spacecal.geometry.arrays import FloatArray
from spacecal.geometry.transforms import apply_transform
from spacecal.models.tracker import PyramidVolume
from spacecal.records import CalibrationResult
from spacecal.records.recording import Recording
from spacecal.station.trends import plotly_text

#: Length of the drawn frame axes, mm.
AXIS_MM = 100.0
#: Samples drawn at most per trace (a recording has thousands; the picture needs hundreds).
MAX_POINTS = 600
AXIS_COLOURS = ("#d62728", "#2ca02c", "#1f77b4")


def _line(points: list[FloatArray | None], name: str, colour: str, width: float = 3.0) -> dict[str, Any]:
    """One line trace; None in ``points`` breaks the line."""
    xyz = [[None if p is None else float(p[k]) for p in points] for k in range(3)]
    return {
        "type": "scatter3d",
        "mode": "lines",
        "name": name,
        "x": xyz[0],
        "y": xyz[1],
        "z": xyz[2],
        "line": {"color": colour, "width": width},
    }


def _points(points: FloatArray, name: str, colour: str, size: float = 2.0, symbol: str = "circle") -> dict:
    if len(points) > MAX_POINTS:
        points = points[np.linspace(0, len(points) - 1, MAX_POINTS).astype(int)]
    return {
        "type": "scatter3d",
        "mode": "markers",
        "name": f"{name} ({len(points)})" if len(points) > 1 else name,
        "x": points[:, 0].tolist(),
        "y": points[:, 1].tolist(),
        "z": points[:, 2].tolist(),
        "marker": {"size": size, "color": colour, "symbol": symbol},
    }


def _frame_axes(frame_pose: FloatArray, name: str) -> list[dict[str, Any]]:
    """A frame's origin and x, y, z axes (red, green, blue) as drawn in the scene's frame."""
    origin = frame_pose[:3, 3]
    axes = [
        _line([origin, origin + AXIS_MM * frame_pose[:3, k]], f"{name} {'xyz'[k]}", AXIS_COLOURS[k], 5.0)
        for k in range(3)
    ]
    for trace in axes:
        trace["showlegend"] = False
    return [*axes, _points(origin[None], name, "#222222", 6.0, "diamond")]


def volume_edges(volume: PyramidVolume) -> list[FloatArray | None]:
    """The twelve edges of a pyramid measurement volume in the tracker frame (along -z), as
    a broken line: (points, None separators)."""

    def face(depth: float) -> list[FloatArray]:
        w = 0.5 * volume.far_width_mm * depth / volume.far_mm
        h = 0.5 * volume.far_height_mm * depth / volume.far_mm
        return [np.array([sx * w, sy * h, -depth]) for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))]

    near, far = face(volume.near_mm), face(volume.far_mm)
    edges: list[FloatArray | None] = []
    for ring in (near, far):
        edges += [*ring, ring[0], None]
    for a, b in zip(near, far, strict=True):
        edges += [a, b, None]
    return edges


def _plan_positions(plan: dict[str, Any]) -> tuple[FloatArray, FloatArray | None]:
    """The plan's TCP path through its moves' ends, and its site (base frame, mm)."""
    path = []
    for move in plan.get("moves") or []:
        for key in ("start_base_from_tcp", "end_base_from_tcp"):
            pose = np.asarray(move.get(key, np.full((4, 4), np.nan)), dtype=float)
            if pose.shape == (4, 4) and np.all(np.isfinite(pose)):
                path.append(pose[:3, 3])
    site = plan.get("site_in_base_mm")
    site_point = np.asarray(site, dtype=float) if site is not None else None
    if site_point is not None and (site_point.shape != (3,) or not np.all(np.isfinite(site_point))):
        site_point = None
    return np.array(path).reshape(-1, 3), site_point


def setup_scene(
    plan: dict[str, Any] | None,
    calibration: CalibrationResult | None = None,
    recording: Recording | None = None,
    volume: PyramidVolume | None = None,
    tracker_name: str = "tracker",
) -> dict[str, Any]:
    """The plotly figure of the set-up.

    Parameters
    ----------
    plan : dict or None
        A plan file's contents (``spacecal plan``): its moves' TCP poses and site, base frame.
    calibration : CalibrationResult, optional
        Its ``tracker_from_base`` puts the scene in the tracker frame.
    recording : Recording, optional
        Samples drawn once calibrated: seen (the marker, tracker frame) and unseen (the TCP
        through the calibration).
    volume : PyramidVolume, optional
        The tracker's measurement volume (from its tracker kind); drawn in the tracker frame.
    tracker_name : str
        The tracker's name in the legend.

    Returns
    -------
    dict
        ``{"data": [...], "layout": {...}, "frame": "tracker" | "robot base", "scene_from_base":
        4x4}``: ``scene_from_base`` (mm) takes a robot base point into the scene's frame, for
        the live samples a run's page adds (the identity before a calibration,
        ``tracker_from_base`` after it).
    """
    tracker_name = plotly_text(tracker_name)  # an operator's text: plotly reads <a>, <b>, $..$
    in_tracker = calibration is not None
    to_scene = (
        np.asarray(calibration.tracker_from_base, dtype=float) if calibration is not None else np.eye(4)
    )
    frame = "tracker" if in_tracker else "robot base"
    data: list[dict[str, Any]] = []
    data += _frame_axes(to_scene, "robot base")
    if in_tracker:
        data += _frame_axes(np.eye(4), tracker_name)
        if volume is not None:
            data.append(_line(volume_edges(volume), "measurement volume", "#888888", 2.0))
    if plan is not None:
        path, site = _plan_positions(plan)
        if len(path):
            data.append(_line(list(apply_transform(to_scene, path)), "planned TCP path", "#ff7f0e", 2.0))
        if site is not None:
            data.append(_points(apply_transform(to_scene, site[None]), "site", "#9467bd", 7.0, "cross"))
    if in_tracker and recording is not None:
        seen = recording.visible
        marker = recording.tracker_from_marker_stack[seen][:, :3, 3]
        tcp_unseen = recording.base_from_tcp_stack[~seen][:, :3, 3]
        if len(marker):
            data.append(_points(marker, "samples seen (marker)", "#2ca02c"))
        if len(tcp_unseen):
            data.append(_points(apply_transform(to_scene, tcp_unseen), "samples unseen (TCP)", "#d62728"))
    axis = {f"{k}axis": {"title": {"text": f"{frame} {k} (mm)"}} for k in "xyz"}
    title = (
        f"in the {tracker_name}'s frame, through the calibration's tracker_from_base"
        if in_tracker
        else "in the robot base frame (the tracker is located by the calibration)"
    )
    layout = {
        "margin": {"l": 0, "r": 0, "t": 30, "b": 0},
        "title": {"text": title, "font": {"size": 13}},
        "scene": {"aspectmode": "data", **axis},
        "legend": {"itemsizing": "constant"},
    }
    return {"data": data, "layout": layout, "frame": frame, "scene_from_base": to_scene.tolist()}
