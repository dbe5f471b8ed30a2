"""The recording is judged by what it says: another reading of its conventions must explain it
clearly better before it is refused, and a sound recording with camera-grade noise passes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from spacecal.estimators import calibrate
from spacecal.estimators.methods.conventions import (
    ALTERNATIVES,
    SWAPPED,
    calibration_mismatch,
    find_better_convention,
)
from spacecal.geometry.transforms import invert_transform, make_transform
from spacecal.records import Recording


def _on_visible(recording: Recording, change):
    def apply(stack):
        out = stack.copy()
        out[recording.visible] = change(stack[recording.visible])
        return out

    return apply


def _xyzw_read_as_wxyz(stack):
    """What a reader taking w,x,y,z makes of quaternions stored x,y,z,w."""
    out = stack.copy()
    x, y, z, w = Rotation.from_matrix(stack[:, :3, :3]).as_quat().T
    # stored (x, y, z, w), read as (w', x', y', z') = (x, y, z, w): scipy wants (x', y', z', w')
    out[:, :3, :3] = Rotation.from_quat(np.stack([y, z, w, x], axis=1)).as_matrix()
    return out


def _transposed(stack):
    out = stack.copy()
    out[:, :3, :3] = np.swapaxes(stack[:, :3, :3], 1, 2)
    return out


def _times(factor):
    def scale(stack):
        out = stack.copy()
        out[:, :3, 3] *= factor
        return out

    return scale


SPOILS = {
    "the tracker's quaternions are x,y,z,w": ("tracker", _xyzw_read_as_wxyz),
    "the robot's quaternions are x,y,z,w": ("robot", _xyzw_read_as_wxyz),
    "the tracker's rotations are conjugated (transposed)": ("tracker", _transposed),
    "the robot's rotations are conjugated (transposed)": ("robot", _transposed),
    "the tracker's poses are inverted (marker_from_tracker)": ("tracker", invert_transform),
    "the robot's poses are inverted (eye-in-hand / tcp_from_base)": ("robot", invert_transform),
    "the tracker's lengths are in metres": ("tracker", _times(0.001)),
    "the robot's lengths are in metres": ("robot", _times(0.001)),
    "the tracker's lengths were multiplied by 1000 twice": ("tracker", _times(1000.0)),
    "the robot's lengths were multiplied by 1000 twice": ("robot", _times(1000.0)),
}


def test_every_alternative_is_spoilt_and_named():
    assert set(SPOILS) == {words for words, *_ in ALTERNATIVES}


@pytest.mark.parametrize("words", sorted(SPOILS))
def test_a_spoilt_convention_is_named(white_simulation, words):
    recording = white_simulation.recording
    assert find_better_convention(recording) is None
    which, spoil = SPOILS[words]
    field = "tracker_from_marker_stack" if which == "tracker" else "base_from_tcp_stack"
    spoilt_stack = _on_visible(recording, spoil)(getattr(recording, field))
    spoilt = dataclasses.replace(recording, **{field: spoilt_stack})
    finding = find_better_convention(spoilt)
    assert finding is not None and finding.alternative == words
    # the alternative explains the spoilt data as well as the clean data is explained
    assert finding.alternative_mm < 3 * np.median(
        np.linalg.norm(recording.tracker_from_marker_stack[recording.visible, :3, 3], axis=1)
    )
    assert "far better if " + words in finding.message("rec.csv")


def test_swapped_robot_and_tracker_poses_are_named(white_simulation):
    recording = white_simulation.recording
    visible = recording.visible[:, None, None]
    robot, tracker = recording.base_from_tcp_stack, recording.tracker_from_marker_stack
    swapped = dataclasses.replace(
        recording,
        base_from_tcp_stack=np.where(visible, tracker, robot),
        tracker_from_marker_stack=np.where(visible, robot, np.nan),
    )
    finding = find_better_convention(swapped)
    assert finding is not None and finding.alternative == SWAPPED


@pytest.mark.parametrize("noise_mm", [1.0, 3.0, 10.0])
def test_a_distant_camera_with_mm_noise_is_not_refused(white_simulation, noise_mm):
    # a camera 0.4-2 m from its target leaves residuals of several mm: nothing is wrong with it
    recording = white_simulation.recording
    rng = np.random.default_rng(int(noise_mm))
    noisy = recording.tracker_from_marker_stack.copy()
    noisy[:, :3, 3] += rng.normal(0.0, noise_mm, (len(recording), 3))
    rotations = Rotation.from_rotvec(rng.normal(0.0, np.radians(0.3), (len(recording), 3))).as_matrix()
    noisy[:, :3, :3] = rotations @ noisy[:, :3, :3]
    assert find_better_convention(dataclasses.replace(recording, tracker_from_marker_stack=noisy)) is None


def test_a_calibration_of_another_recording_is_told_apart(white_simulation):
    recording = white_simulation.recording
    own = calibrate(recording, "shah", uncertainty=False)
    assert calibration_mismatch(recording, own.tracker_from_base, own.tcp_from_marker) is None
    moved = make_transform(np.eye(3), [11.0, 0.0, 0.0]) @ own.tracker_from_base
    reason = calibration_mismatch(recording, moved, own.tcp_from_marker)
    assert reason is not None and "does not explain this recording" in reason
