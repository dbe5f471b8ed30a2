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

from spacecal.estimators import ESTIMATORS, Family, calibrate
from spacecal.estimators.methods.hand_eye import motion_pairs, relative_motions, solve_daniilidis, solve_park
from spacecal.estimators.methods.samples import tracker_from_base_from_samples
from spacecal.estimators.registry import estimators_of
from spacecal.geometry.rotations import rotation_angle
from spacecal.geometry.transforms import invert_transform, make_transform
from spacecal.records import Recording

from ..conftest import STORZ_VIEWS, storz_handeye

VIEWS = STORZ_VIEWS
CLOSED_FORMS = list(estimators_of(Family.ROBOT_WORLD, Family.HAND_EYE))


@pytest.fixture(scope="module")
def storz():
    return storz_handeye()


def _solve(recording: Recording, method: str):
    # the images give no per-view noise figure: a likelihood method takes an assumed 0.5 mm
    # per axis (it scales the covariance, not the estimate)
    return (
        calibrate(recording, method, sigma_mm=0.5)
        if ESTIMATORS[method].likelihood
        else calibrate(recording, method, uncertainty=False)
    )


def _closure(recording: Recording, result) -> tuple[float, float]:
    """Mean rotation (deg) and translation (mm) disagreement of E_i with the chain."""
    predicted = result.tracker_from_base @ recording.base_from_tcp_stack @ result.tcp_from_marker
    measured = recording.tracker_from_marker_stack
    rotation = np.degrees([rotation_angle(p[:3, :3] @ m[:3, :3].T) for p, m in zip(predicted, measured)])
    translation = np.linalg.norm(predicted[:, :3, 3] - measured[:, :3, 3], axis=1)
    return float(rotation.mean()), float(translation.mean())


@pytest.mark.parametrize("method", [*CLOSED_FORMS, "ml"])
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


@pytest.mark.parametrize("method", CLOSED_FORMS)
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


#: SmartLiver's H explains the views to 0.360 deg mean and 1.027 mm RMS (README table); over 10
#: views that noise moves a hand-eye by about its 1/sqrt(10), the margin by which spacecal may
#: trail OpenCV's same method in distance from SmartLiver's H.
MARGIN_DEG, MARGIN_MM = 0.360 / np.sqrt(VIEWS), 1.027 / np.sqrt(VIEWS)


def _opencv_hand_eye(recording: Recording, method: str) -> np.ndarray:
    """OpenCV's same-named method on the recording, returned as ``tracker_from_base``.

    AX = XB: calibrateHandEye with gripper2base = base_from_tcp_i and target2cam =
    inv(tracker_from_marker_i) returns X = tcp_from_marker, averaged into tracker_from_base as
    the registry does. AX = YB: calibrateRobotWorldHandEye with world2cam = marker_from_tracker_i
    and base2gripper = tcp_from_base_i returns base2world = tracker_from_base.
    """
    cv2 = pytest.importorskip("cv2")
    a, b = recording.base_from_tcp_stack, recording.tracker_from_marker_stack
    if ESTIMATORS[method].family is Family.ROBOT_WORLD:
        marker_from_tracker, tcp_from_base = invert_transform(b), invert_transform(a)
        rotation, translation, _, _ = cv2.calibrateRobotWorldHandEye(
            list(marker_from_tracker[:, :3, :3]),
            list(marker_from_tracker[:, :3, 3]),
            list(tcp_from_base[:, :3, :3]),
            list(tcp_from_base[:, :3, 3]),
            method=cv2.CALIB_ROBOT_WORLD_HAND_EYE_LI,
        )
        return make_transform(rotation, translation.ravel())
    b_inv = invert_transform(b)
    rotation, translation = cv2.calibrateHandEye(
        list(a[:, :3, :3]),
        list(a[:, :3, 3]),
        list(b_inv[:, :3, :3]),
        list(b_inv[:, :3, 3]),
        method=getattr(cv2, f"CALIB_HAND_EYE_{method.upper()}"),
    )
    x = make_transform(rotation, translation.ravel())
    return tracker_from_base_from_samples(recording, x, np.arange(VIEWS))


@pytest.mark.parametrize("method", ["li", "tsai", "park", "daniilidis"])
def test_the_hand_eye_lands_at_least_as_close_as_opencvs_same_method(storz, method):
    """Measured distance from SmartLiver's H (deg / mm), spacecal against OpenCV 4.14:
    li 0.27 / 2.1 against 0.61 / 43.8, tsai 0.29 / 2.1 against 2.05 / 11.0, park 0.29 / 2.1
    against 0.29 / 2.2, daniilidis 0.29 / 1.6 against 4.54 / 29.9. Before the closed forms used
    every motion pair (and Li its scaling), li, tsai and daniilidis landed 2-3 deg and 11-16 mm
    away."""
    recording, smartliver = storz
    ours = _solve(recording, method).tracker_from_base
    theirs = _opencv_hand_eye(recording, method)
    assert np.all(np.isfinite(ours))

    def distance(hand_eye: np.ndarray) -> tuple[float, float]:
        angle = float(np.degrees(rotation_angle(hand_eye[:3, :3] @ smartliver[:3, :3].T)))
        return angle, float(np.linalg.norm(hand_eye[:3, 3] - smartliver[:3, 3]))

    (ours_deg, ours_mm), (theirs_deg, theirs_mm) = distance(ours), distance(theirs)
    assert ours_deg <= theirs_deg + MARGIN_DEG and ours_mm <= theirs_mm + MARGIN_MM


@pytest.mark.parametrize("motions", ["consecutive", "all pairs"])
@pytest.mark.parametrize("side", ["board marker", "camera"])
def test_daniilidis_gives_a_finite_answer_on_the_views(storz, side, motions):
    """The published recipe can stop with "no real solution" (test_closed_form_kinhec) or land
    far off: on the board's side the previous implementation was 1.9 deg (consecutive motions)
    and 4.6 deg (all pairs) from Park's rotation. Solved for either unknown (X = the board's
    pattern -> marker, as the registry does, or the hand-eye itself, as OpenCV's
    calibrateHandEye is fed) and from either set of motions, Daniilidis must return a finite
    rigid transform within 1 deg and 10 mm of Park's rotation-first solve on the same motions
    (measured: 0.2-0.6 deg, 0.8-5.1 mm)."""
    recording, _ = storz
    a, b = recording.base_from_tcp_stack, recording.tracker_from_marker_stack
    if side == "camera":  # A_i = gripper2base, B_i = cam2target: X = the hand-eye's inverse
        a, b = invert_transform(a), invert_transform(b)
    pairs = motion_pairs(a) if motions == "all pairs" else None
    found = solve_daniilidis(*relative_motions(a, b, pairs))
    park = solve_park(*relative_motions(a, b, pairs))
    assert np.all(np.isfinite(found))
    assert np.allclose(found[:3, :3] @ found[:3, :3].T, np.eye(3), atol=1e-9)
    assert np.degrees(rotation_angle(found[:3, :3] @ park[:3, :3].T)) < 1.0
    assert np.linalg.norm(found[:3, 3] - park[:3, 3]) < 10.0
