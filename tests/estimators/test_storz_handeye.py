"""Real data: UCL's Storz laparoscope hand-eye set (10 views, optically tracked), against the
authors' SmartLiver result and the OpenCV pose solvers' spread (../shared/realdata/handeye_storz_sksurgery).

The set maps onto spacecal's chain ``tracker_from_marker_i = tracker_from_base @ base_from_tcp_i
@ tcp_from_marker`` with: tracker = the camera, base = the laparoscope's marker ("device"),
tcp = the board's marker, marker = the board pattern. So ``base_from_tcp_i = inv(T_dev_i) @ T_obj_i``,
``tracker_from_marker_i = E_i`` (pattern -> camera, from the images) and the estimated
``tracker_from_base`` is the hand-eye H (device marker -> camera); the README's closure
``E_i ~= H inv(T_dev_i) T_obj_i P`` is exactly the chain.
"""

from __future__ import annotations

import numpy as np
import pytest

from spacecal.estimators import calibrate
from spacecal.geometry.rotations import rotation_angle
from spacecal.geometry.transforms import invert_transform
from spacecal.records import Recording

from ..conftest import shared_realdata

VIEWS = 10


@pytest.fixture(scope="module")
def storz():
    folder = shared_realdata("handeye_storz_sksurgery")

    def load(name: str) -> np.ndarray:
        return np.loadtxt(folder / name).reshape(4, 4)

    device = np.array([load(f"tracking/calib.device_tracking.{i}.txt") for i in range(VIEWS)])
    board = np.array([load(f"tracking/calib.calib_obj_tracking.{i}.txt") for i in range(VIEWS)])
    camera = np.array(
        [load(f"derived_sksurgerycalibration_1.2.6/camera/calib.extrinsics.{i}.txt") for i in range(VIEWS)]
    )
    recording = Recording(
        time_s=np.arange(float(VIEWS)),
        segment=np.array(["view"] * VIEWS),
        joints_rad=np.full((VIEWS, 6), np.nan),
        base_from_tcp_stack=invert_transform(device) @ board,
        tracker_from_marker_stack=camera,
        marker_rms_mm=np.full(VIEWS, np.nan),
        metadata={"source": "Storz hand-eye set"},
    )
    smartliver = load("authors_reference/calib.left.handeye.txt")
    return recording, smartliver


def _solve(recording: Recording, method: str):
    # the images give no per-view noise figure: ML takes an assumed 0.5 mm per axis (it
    # scales the covariance, not the estimate)
    return (
        calibrate(recording, method, sigma_mm=0.5)
        if method == "ml"
        else calibrate(recording, method, uncertainty=False)
    )


def _closure(recording: Recording, result) -> tuple[float, float]:
    """Mean rotation (deg) and translation (mm) disagreement of E_i with the chain."""
    predicted = result.tracker_from_base @ recording.base_from_tcp_stack @ result.tcp_from_marker
    measured = recording.tracker_from_marker_stack
    rotation = np.degrees([rotation_angle(p[:3, :3] @ m[:3, :3].T) for p, m in zip(predicted, measured)])
    translation = np.linalg.norm(predicted[:, :3, 3] - measured[:, :3, 3], axis=1)
    return float(rotation.mean()), float(translation.mean())


@pytest.mark.parametrize("method", ["shah", "dornaika", "park", "ml"])
def test_the_hand_eye_lands_where_the_authors_software_does(storz, method):
    """OpenCV's pose solvers land 0.29-0.90 deg and 2.8-5.9 mm from SmartLiver's H on these views
    (README table); the AX = YB forms and ML must do at least as well as that spread."""
    recording, smartliver = storz
    hand_eye = _solve(recording, method).tracker_from_base
    angle = np.degrees(rotation_angle(hand_eye[:3, :3] @ smartliver[:3, :3].T))
    distance = np.linalg.norm(hand_eye[:3, 3] - smartliver[:3, 3])
    assert angle < 0.9 and distance < 5.9


#: The worst mean closure of the OpenCV pose solvers on these views (README table: ANDREFF's
#: translation, TSAI's rotation).
REFERENCE_WORST_DEG, REFERENCE_WORST_MM = 0.401, 1.124


@pytest.mark.parametrize("method", ["shah", "dornaika", "park"])
def test_the_closed_forms_explain_the_views_as_well_as_the_reference_solvers(storz, method):
    """SmartLiver's H explains the views to 0.36 deg / 0.82 mm mean, the OpenCV pose solvers to
    0.35-0.40 deg / 0.62-1.12 mm; these closed forms must be no worse than the worst of those."""
    recording, _ = storz
    rotation_deg, translation_mm = _closure(recording, _solve(recording, method))
    assert rotation_deg < REFERENCE_WORST_DEG and translation_mm < REFERENCE_WORST_MM


def test_ml_explains_the_positions_as_well_as_the_reference_solvers(storz):
    """ML weighs positions (mm) against its assumed noise, not rotations: its mean position
    closure must be no worse than the reference solvers'; its rotation closure is measured at
    0.41 deg, at the edge of theirs, and held within 25 % of it."""
    recording, _ = storz
    rotation_deg, translation_mm = _closure(recording, _solve(recording, "ml"))
    assert translation_mm < REFERENCE_WORST_MM and rotation_deg < 1.25 * REFERENCE_WORST_DEG


@pytest.mark.parametrize("method", ["li", "tsai", "daniilidis"])
def test_the_remaining_forms_explain_the_views(storz, method):
    """Known weakness: with 10 views, our Li, Tsai and Daniilidis (motions between consecutive
    views) explain the rotations less well than OpenCV's (0.55-0.61 deg mean against 0.35-0.40)
    and land 2-3 deg from SmartLiver; positions stay within the reference spread. Held at that."""
    recording, _ = storz
    rotation_deg, translation_mm = _closure(recording, _solve(recording, method))
    assert translation_mm < REFERENCE_WORST_MM and rotation_deg < 0.7
