"""Recordings spoilt the way real ones get spoilt, for testing that no verdict hides it.

Each is built from a good simulated recording of the same world, so the truth (and the
verification experiment) still applies: a calibration from a spoilt recording is judged by
how far off it really is, against the expected error it states.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from spacecal.core.errors import SpacecalError, UnreachableError
from spacecal.estimators import calibrate
from spacecal.estimators.time_offset import pair_streams
from spacecal.experiments.simulation import simulate, simulate_raw
from spacecal.experiments.verification import verify_in_simulation
from spacecal.geometry.transforms import axis_angle_transform, invert_transform
from spacecal.records import Recording
from spacecal.sim.scenario import Scenario

#: A verdict may call a calibration good or acceptable only if its true mean error at the
#: targets is at most this factor times the stated expected error ...
HONEST_FACTOR = 2.0
#: ... plus this margin (mm).
HONEST_MARGIN_MM = 0.2


def _scaled_tcp(recording: Recording, factor: float) -> Recording:
    stack = recording.base_from_tcp_stack.copy()
    stack[:, :3, 3] *= factor
    return dataclasses.replace(recording, base_from_tcp_stack=stack)


def _duplicated(recording: Recording) -> Recording:
    return recording.select(np.repeat(np.arange(len(recording)), 2))


def _few_frames(recording: Recording, keep: int = 8) -> Recording:
    visible = np.flatnonzero(recording.visible)
    hidden = np.setdiff1d(visible, visible[np.linspace(0, len(visible) - 1, keep).round().astype(int)])
    stack = recording.tracker_from_marker_stack.copy()
    stack[hidden] = np.nan
    rms = recording.marker_rms_mm.copy()
    rms[hidden] = np.nan
    return dataclasses.replace(recording, tracker_from_marker_stack=stack, marker_rms_mm=rms)


def _bumped(recording: Recording, angle_deg: float = 2.0, shift_mm: float = 2.0) -> Recording:
    """The marker knocked on the tool halfway through: its pose on the tool changes."""
    bump = axis_angle_transform([0.3, 1.0, 0.2], np.radians(angle_deg))
    bump[:3, 3] = [shift_mm, 0.0, -shift_mm]
    stack = recording.tracker_from_marker_stack.copy()
    later = np.arange(len(recording)) >= len(recording) // 2
    stack[later] = stack[later] @ bump
    return dataclasses.replace(recording, tracker_from_marker_stack=stack)


def _mislabelled(recording: Recording) -> Recording:
    """The rotation about z labelled as the translation along z."""
    segment = recording.segment.copy()
    segment[segment == "rot_z"] = "lin_z"
    return dataclasses.replace(recording, segment=segment)


def _swapped_labels(recording: Recording) -> Recording:
    """The labels of the rotation about x and the translation along x swapped."""
    segment = recording.segment.copy()
    rotation, translation = segment == "rot_x", segment == "lin_x"
    segment[rotation], segment[translation] = "lin_x", "rot_x"
    return dataclasses.replace(recording, segment=segment)


def _tracker_scaled(recording: Recording, factor: float) -> Recording:
    """Marker positions (and the tracker's RMS) in another length unit than the robot's mm."""
    stack = recording.tracker_from_marker_stack.copy()
    stack[:, :3, 3] *= factor
    return dataclasses.replace(
        recording, tracker_from_marker_stack=stack, marker_rms_mm=recording.marker_rms_mm * factor
    )


def _tracker_inverted(recording: Recording) -> Recording:
    """``marker_from_tracker`` written where ``tracker_from_marker`` belongs."""
    stack = recording.tracker_from_marker_stack.copy()
    seen = recording.has_pose
    stack[seen] = invert_transform(stack[seen])
    return dataclasses.replace(recording, tracker_from_marker_stack=stack)


def _rotation_transposed(recording: Recording) -> Recording:
    """The marker's rotation transposed (a quaternion's sign or order convention mixed up),
    its position right."""
    stack = recording.tracker_from_marker_stack.copy()
    stack[:, :3, :3] = np.swapaxes(stack[:, :3, :3], 1, 2)
    return dataclasses.replace(recording, tracker_from_marker_stack=stack)


def _loose(recording: Recording, angle_deg: float = 1.5, shift_mm: float = 1.0) -> Recording:
    """The marker loose on the tool from halfway: it creeps, growing to ``angle_deg`` and
    ``shift_mm`` by the end of the run."""
    stack = recording.tracker_from_marker_stack.copy()
    n = len(recording)
    start = n // 2
    for i in range(start, n):
        fraction = (i - start + 1) / (n - start)
        creep = axis_angle_transform([1.0, -0.4, 0.5], np.radians(angle_deg * fraction))
        creep[:3, 3] = fraction * shift_mm * np.array([0.0, 0.6, 0.8])
        stack[i] = stack[i] @ creep
    return dataclasses.replace(recording, tracker_from_marker_stack=stack)


def _one_segment_seen(recording: Recording, label: str = "rot_x") -> Recording:
    """The marker seen during one sweep only (occluded in the others)."""
    hidden = recording.segment != label
    stack = recording.tracker_from_marker_stack.copy()
    stack[hidden] = np.nan
    rms = recording.marker_rms_mm.copy()
    rms[hidden] = np.nan
    return dataclasses.replace(recording, tracker_from_marker_stack=stack, marker_rms_mm=rms)


def _rows_shifted(recording: Recording, rows: int = 3) -> Recording:
    """The tracker's column paired ``rows`` samples late (an off-by-rows join of two logs)."""
    keep = np.arange(len(recording) - rows)
    shifted = recording.select(keep)
    return dataclasses.replace(
        shifted,
        tracker_from_marker_stack=recording.tracker_from_marker_stack[rows:],
        marker_rms_mm=recording.marker_rms_mm[rows:],
        marker_status=None if recording.marker_status is None else recording.marker_status[rows:],
    )


def bad_recordings(scenario: Scenario, recording: Recording | None = None) -> dict[str, Recording]:
    """The scenario's recording spoilt in each way (name -> recording).

    ``recording`` is the scenario's simulated recording when already at hand.

    * ``robot in cm``, ``robot in inches``: TCP positions in another length unit than the
      tracker's millimetres;
    * ``duplicated rows``: every sample written twice;
    * ``marker in 8 frames``: the marker seen in only a handful of frames;
    * ``100 ms offset, naive pairs``: raw streams with the robot clock 100 ms ahead, paired as
      if the clocks agreed;
    * ``marker bumped halfway``: the marker moved on the tool (2 deg, 2.8 mm) halfway through;
    * ``segment mislabelled``: the rotation about z labelled as the translation along z;
    * ``robot in m``: TCP positions in metres;
    * ``tracker in m``: marker positions (and the tracker's RMS) in metres, the robot in mm;
    * ``tracker poses inverted``: ``marker_from_tracker`` written as ``tracker_from_marker``;
    * ``tracker rotation transposed``: the marker's rotation transposed, its position right;
    * ``marker loose from halfway``: the marker creeping on the tool in the second half, to
      1.5 deg and 1 mm by the end;
    * ``marker seen in one sweep``: occluded during every sweep but the rotation about x;
    * ``two labels swapped``: the rotation about x and the translation along x swapped;
    * ``tracker rows 3 late``: the tracker's column joined to the robot's three rows late;
    * ``30 ms offset, naive pairs``: raw streams with the robot clock 30 ms ahead, paired as if
      the clocks agreed.
    """
    recording = simulate(scenario).recording if recording is None else recording
    raw, _ = simulate_raw(scenario, clock_offset_s=0.100)
    raw_30ms, _ = simulate_raw(scenario, clock_offset_s=0.030)
    return {
        "robot in cm": _scaled_tcp(recording, 0.1),
        "robot in inches": _scaled_tcp(recording, 1.0 / 25.4),
        "duplicated rows": _duplicated(recording),
        "marker in 8 frames": _few_frames(recording),
        "100 ms offset, naive pairs": dataclasses.replace(
            pair_streams(raw, 0.0), metadata={**recording.metadata}
        ),
        "marker bumped halfway": _bumped(recording),
        "segment mislabelled": _mislabelled(recording),
        "robot in m": _scaled_tcp(recording, 0.001),
        "tracker in m": _tracker_scaled(recording, 0.001),
        "tracker poses inverted": _tracker_inverted(recording),
        "tracker rotation transposed": _rotation_transposed(recording),
        "marker loose from halfway": _loose(recording),
        "marker seen in one sweep": _one_segment_seen(recording),
        "two labels swapped": _swapped_labels(recording),
        "tracker rows 3 late": _rows_shifted(recording),
        "30 ms offset, naive pairs": dataclasses.replace(
            pair_streams(raw_30ms, 0.0), metadata={**recording.metadata}
        ),
    }


def judge(recording: Recording, method: str, scenario: Scenario) -> dict:
    """Calibrate a (spoilt) recording and compare the verdict with the truth.

    Returns
    -------
    dict
        ``outcome`` (``"refused"`` with the message, or the verdict's grade), and for a result
        ``expected_mm`` (stated), ``true_mm`` (mean verification error; infinite when the targets
        are out of reach) and ``honest``: False
        only for a good or acceptable grade with a true error above
        ``HONEST_FACTOR * expected + HONEST_MARGIN_MM``.
    """
    try:
        result = calibrate(recording, method)
    except SpacecalError as exc:
        return {"outcome": "refused", "message": str(exc), "honest": True}
    grade = result.verdict.grade if result.verdict is not None else "none"
    stated = result.expected_error
    expected = float("nan") if stated is None or stated.position_mm is None else stated.position_mm
    try:
        true = float(verify_in_simulation(result, scenario).statistics()["position_mm"]["mean"])
    except UnreachableError:  # the calibration sends the robot out of its workspace
        true = float("inf")
    passing = grade in ("good", "acceptable")
    honest = not passing or true <= HONEST_FACTOR * expected + HONEST_MARGIN_MM
    return {"outcome": grade, "expected_mm": expected, "true_mm": true, "honest": bool(honest)}
