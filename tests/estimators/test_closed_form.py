"""Closed-form AX = YB and AX = XB solvers: exact on exact data, and checked against OpenCV 4.x."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from spacecal.core.errors import DegenerateDataError
from spacecal.estimators.methods.hand_eye import motion_pairs, relative_motions
from spacecal.estimators.registry import Family, estimators_of
from spacecal.geometry.rotations import rotation_angle
from spacecal.geometry.transforms import invert_transform, make_transform

ROBOT_WORLD_SOLVERS = {name: spec.closed_form for name, spec in estimators_of(Family.ROBOT_WORLD).items()}
HAND_EYE_SOLVERS = {name: spec.closed_form for name, spec in estimators_of(Family.HAND_EYE).items()}

ROTATION_NOISE_RAD = 0.002
TRANSLATION_NOISE_MM = 0.2


def problem(seed=0, count=20, noisy=False):
    """Random A_i = base_from_tcp, X = tcp_from_marker, Y = base_from_tracker, B_i = tracker_from_marker."""
    rng = np.random.default_rng(seed)
    x = make_transform(Rotation.random(random_state=seed + 1).as_matrix(), rng.normal(size=3) * 100)
    y = make_transform(Rotation.random(random_state=seed + 2).as_matrix(), rng.normal(size=3) * 1000)
    a = make_transform(
        Rotation.random(count, random_state=seed + 3).as_matrix(), rng.normal(size=(count, 3)) * 300
    )
    b = invert_transform(y) @ a @ x
    if noisy:
        b[:, :3, 3] += rng.normal(scale=TRANSLATION_NOISE_MM, size=(count, 3))
        tilt = Rotation.from_rotvec(rng.normal(scale=ROTATION_NOISE_RAD, size=(count, 3))).as_matrix()
        b[:, :3, :3] = tilt @ b[:, :3, :3]
    return a, b, x, y


def angle_deg(first, second):
    return float(np.degrees(rotation_angle(first[:3, :3] @ second[:3, :3].T)))


@pytest.mark.parametrize("name", sorted(ROBOT_WORLD_SOLVERS))
def test_robot_world_solvers_are_exact_on_exact_data(name):
    a, b, x, y = problem()
    x_est, y_est = ROBOT_WORLD_SOLVERS[name](a, b)
    assert np.allclose(x_est, x, atol=1e-9) and np.allclose(y_est, y, atol=1e-9)


@pytest.mark.parametrize("name", sorted(HAND_EYE_SOLVERS))
def test_hand_eye_solvers_are_exact_on_exact_data(name):
    a, b, x, _ = problem()
    # random orientations: a third of all pairs rotate beyond 150 deg (the sign-aligned ones)
    for pairs in (None, motion_pairs(a)):
        assert np.allclose(HAND_EYE_SOLVERS[name](*relative_motions(a, b, pairs)), x, atol=1e-9)


@pytest.mark.parametrize("name", sorted(ROBOT_WORLD_SOLVERS))
def test_robot_world_noise_stays_within_the_injected_noise(name):
    a, b, x, y = problem(noisy=True)
    x_est, y_est = ROBOT_WORLD_SOLVERS[name](a, b)
    # 20 poses of 0.002 rad noise: rotation error of order 0.002 / sqrt(20) rad, allow 5x
    limit_deg = np.degrees(5 * ROTATION_NOISE_RAD / np.sqrt(20))
    assert angle_deg(x_est, x) < limit_deg and angle_deg(y_est, y) < limit_deg


def test_too_few_poses_and_nan_are_refused():
    a, b, _, _ = problem(count=2)
    with pytest.raises(DegenerateDataError, match="at least 3 poses"):
        ROBOT_WORLD_SOLVERS["shah"](a, b)
    a, b, _, _ = problem()
    b[3] = np.nan
    with pytest.raises(DegenerateDataError, match="NaN"):
        ROBOT_WORLD_SOLVERS["li"](a, b)
    pure_translations = np.tile(np.eye(4), (5, 1, 1))
    pure_translations[:, :3, 3] = np.arange(15).reshape(5, 3)
    with pytest.raises(DegenerateDataError, match="at least two motions"):
        HAND_EYE_SOLVERS["park"](*relative_motions(pure_translations, pure_translations))


cv2 = pytest.importorskip("cv2")


def opencv_robot_world(a, b, flag):
    """OpenCV: cam_from_world = cam_from_gripper @ gripper_from_base @ base_from_world, with
    cam = marker, world = tracker, gripper = tcp. Returns (X, Y) in our names."""
    marker_from_tracker, tcp_from_base = invert_transform(b), invert_transform(a)
    r_base2world, t_base2world, r_gripper2cam, t_gripper2cam = cv2.calibrateRobotWorldHandEye(
        list(marker_from_tracker[:, :3, :3]),
        list(marker_from_tracker[:, :3, 3]),
        list(tcp_from_base[:, :3, :3]),
        list(tcp_from_base[:, :3, 3]),
        method=flag,
    )
    tracker_from_base = make_transform(r_base2world, t_base2world.ravel())
    marker_from_tcp = make_transform(r_gripper2cam, t_gripper2cam.ravel())
    return invert_transform(marker_from_tcp), invert_transform(tracker_from_base)


ROBOT_WORLD_FLAGS = {"shah": "CALIB_ROBOT_WORLD_HAND_EYE_SHAH", "li": "CALIB_ROBOT_WORLD_HAND_EYE_LI"}
HAND_EYE_FLAGS = {
    "tsai": "CALIB_HAND_EYE_TSAI",
    "park": "CALIB_HAND_EYE_PARK",
    "daniilidis": "CALIB_HAND_EYE_DANIILIDIS",
}


@pytest.mark.parametrize("name", sorted(ROBOT_WORLD_FLAGS))
def test_robot_world_matches_opencv(name):
    flag = getattr(cv2, ROBOT_WORLD_FLAGS[name])
    a, b, _, _ = problem()
    ours, theirs = ROBOT_WORLD_SOLVERS[name](a, b), opencv_robot_world(a, b, flag)
    assert np.allclose(ours[0], theirs[0], atol=1e-6) and np.allclose(ours[1], theirs[1], atol=1e-6)
    a, b, x, y = problem(noisy=True)
    ours, theirs = ROBOT_WORLD_SOLVERS[name](a, b), opencv_robot_world(a, b, flag)
    if name == "shah":  # the same Kronecker rotation step: identical rotations
        assert angle_deg(ours[0], theirs[0]) < 1e-9 and angle_deg(ours[1], theirs[1]) < 1e-9
    # our translation step (least squares in the base frame) is at least as good as OpenCV's here
    assert np.linalg.norm(ours[0][:3, 3] - x[:3, 3]) <= np.linalg.norm(theirs[0][:3, 3] - x[:3, 3])


@pytest.mark.parametrize("name", sorted(HAND_EYE_FLAGS))
def test_hand_eye_matches_opencv(name):
    """Eye-to-hand through OpenCV's eye-in-hand call: pass gripper_from_base as 'gripper2base'
    and tracker_from_marker as 'target2cam'; 'cam2gripper' is then base_from_tracker. Ours
    solves the same problem (tcp_from_base and marker_from_tracker stacks), like OpenCV over
    every pair of poses."""
    flag = getattr(cv2, HAND_EYE_FLAGS[name])
    for noisy in (False, True):
        a, b, _, y = problem(noisy=noisy)
        tcp_from_base = invert_transform(a)
        rotation, translation = cv2.calibrateHandEye(
            list(tcp_from_base[:, :3, :3]),
            list(tcp_from_base[:, :3, 3]),
            list(b[:, :3, :3]),
            list(b[:, :3, 3]),
            method=flag,
        )
        theirs = make_transform(rotation, translation.ravel())
        ours = HAND_EYE_SOLVERS[name](
            *relative_motions(tcp_from_base, invert_transform(b), motion_pairs(tcp_from_base))
        )
        if not noisy:
            assert np.allclose(ours, theirs, atol=1e-6) and np.allclose(ours, y, atol=1e-6)
        else:  # implementation details differ under noise: both stay within the noise's reach
            assert angle_deg(ours, theirs) < np.degrees(ROTATION_NOISE_RAD)


@pytest.mark.parametrize("name", sorted(ROBOT_WORLD_SOLVERS))
@pytest.mark.parametrize("axes", [0, 1])
def test_robot_world_solvers_refuse_a_robot_that_rotates_about_fewer_than_two_axes(name, axes):
    """A robot that never rotated (or about one axis only) leaves X's rotation about the free
    axis undetermined; every closed form still returned an X (graded 'good', 0.00 mm, for a
    robot that never moved)."""
    rng = np.random.default_rng(7)
    count = 12
    rotations = Rotation.from_rotvec(np.outer(rng.uniform(-0.5, 0.5, count), [0.0, 0.0, 1.0]) * axes)
    a = make_transform(rotations.as_matrix(), rng.normal(size=(count, 3)) * 200)
    _, _, x, y = problem()
    b = invert_transform(y) @ a @ x
    with pytest.raises(DegenerateDataError, match="fewer than|less than 2 deg about two independent axes"):
        ROBOT_WORLD_SOLVERS[name](a, b)


@pytest.mark.parametrize("name", sorted(ROBOT_WORLD_SOLVERS))
def test_robot_world_solvers_take_rotations_about_two_axes(name):
    rng = np.random.default_rng(8)
    count = 12
    vectors = np.zeros((count, 3))
    vectors[:, 0], vectors[:, 1] = rng.uniform(-0.3, 0.3, count), rng.uniform(-0.3, 0.3, count)
    a = make_transform(Rotation.from_rotvec(vectors).as_matrix(), rng.normal(size=(count, 3)) * 200)
    _, _, x, y = problem()
    x_est, y_est = ROBOT_WORLD_SOLVERS[name](a, invert_transform(y) @ a @ x)
    assert np.allclose(x_est, x, atol=1e-6) and np.allclose(y_est, y, atol=1e-6)
