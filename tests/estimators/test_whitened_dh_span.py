"""The DH-span test on rigid motions whitened by the noise's covariance: a camera's depth noise,
many times its lateral noise, no longer hides an arm error that moves the marker across it."""

from __future__ import annotations

import numpy as np
import pytest

from spacecal.estimators.assessment.dh_span import DETECTION_STANDARD_ERRORS, whitened_dh_span_test
from spacecal.estimators.assessment.rigid_motion import rigid_coordinates
from spacecal.estimators.assessment.unseen_kinematics import unit_dh_sd
from spacecal.estimators.assessment.white_noise import MINIMUM_WHITENING_DOF
from spacecal.geometry.transforms import axis_angle_transform
from spacecal.models.kinematics import dh_point_jacobian, forward_kinematics, pose_point_jacobian
from spacecal.models.robot_kinds import robot_kind

#: A camera's noise in a frame's rigid motion (tracker frame: z is the line of sight), s.d.
#: per coordinate: translation (mm) 0.1 across, 0.6 along the line of sight; rotation (rad)
#: 6e-3 about the lateral axes (the depth noise of spheres 60 mm apart), 1e-3 about it.
NOISE_SD = np.array([0.1, 0.1, 0.6, 6e-3, 6e-3, 1e-3])
FRAMES = 60


@pytest.fixture(scope="module")
def geometry():
    """A UR10's sphere shapes at 60 poses: predicted spheres, pose and unit DH Jacobians."""
    rng = np.random.default_rng(11)
    model = robot_kind("UR10").model()
    joints = np.radians([0.0, -90.0, 90.0, -90.0, -90.0, 0.0]) + rng.uniform(-0.5, 0.5, (FRAMES, 6))
    tracker_from_base = axis_angle_transform([0, 0, 1], 180.0, [0.0, 0.0, 1800.0])
    tcp_from_marker = np.eye(4)
    spheres = np.array([[0.0, 0.0, 0.0], [60.0, 0.0, 0.0], [0.0, 50.0, 0.0], [-40.0, -30.0, 0.0]])
    chain = tracker_from_base @ forward_kinematics(model, joints) @ tcp_from_marker
    seen = np.einsum("nij,kj->nki", chain[:, :3, :3], spheres) + chain[:, None, :3, 3]
    pose = pose_point_jacobian(forward_kinematics(model, joints), tracker_from_base, tcp_from_marker, spheres)
    dh = dh_point_jacobian(model, joints, tracker_from_base, tcp_from_marker, spheres) * unit_dh_sd(6)
    return seen, pose, dh


def rigid_noise(rng: np.random.Generator, seen: np.ndarray) -> np.ndarray:
    """Sphere displacements (N, K, 3) of a random rigid motion per frame with NOISE_SD."""
    motion = rng.normal(0.0, 1.0, (len(seen), 6)) * NOISE_SD
    centred = seen - seen.mean(axis=1, keepdims=True)
    return motion[:, None, :3] + np.cross(motion[:, None, 3:], centred)


def test_rigid_coordinates_recover_a_rigid_motion(geometry):
    seen = geometry[0]
    rng = np.random.default_rng(2)
    motion = rng.normal(0.0, 1.0, (len(seen), 6)) * NOISE_SD
    centred = seen - seen.mean(axis=1, keepdims=True)
    displacement = motion[:, None, :3] + np.cross(motion[:, None, 3:], centred)
    assert np.allclose(rigid_coordinates(displacement, seen)[..., 0], motion, atol=1e-12)


def test_on_noise_alone_the_whitened_excess_is_chi_square(geometry):
    """Residuals of anisotropic noise alone (depth six times lateral): over 300 draws the test
    fires no more often than a two-standard-error threshold on a chi-square allows (about 3 %,
    within four binomial standard errors)."""
    seen, pose, dh = geometry
    covariance = np.diag(NOISE_SD**2)
    rng = np.random.default_rng(5)
    fired = 0
    trials = 300
    for _ in range(trials):
        detected, unit_power = whitened_dh_span_test(rigid_noise(rng, seen), seen, pose, dh, covariance)
        assert unit_power > 0
        fired += detected > 0
    # a chi-square with ~20 dimensions exceeds its mean by two standard errors in about 3 % of draws
    rate = fired / trials
    assert rate < 0.03 + 4.0 * np.sqrt(0.03 * 0.97 / trials)


def test_an_arm_error_below_the_depth_noise_is_detected_and_scaled(geometry):
    """DH errors whose expected whitened power beyond the pose is six standard errors of the
    noise's chi-square (about a tenth of the unit scale, under a quarter of the 0.6 mm depth noise):
    detected in most draws, and the scale they give is that of the errors drawn (the mean
    estimate of its square over 100 draws within a third of it)."""
    seen, pose, dh = geometry
    covariance = np.diag(NOISE_SD**2)
    rng = np.random.default_rng(8)
    _, unit_power = whitened_dh_span_test(np.zeros_like(seen), seen, pose, dh, covariance)
    dimensions = dh.shape[-1]  # at most: the threshold below is then the stricter one
    scale = np.sqrt(6.0 * np.sqrt(2.0 * dimensions) / unit_power)
    assert scale < NOISE_SD[2] / 4  # DH lengths off by a quarter of the depth noise at most
    estimates = []
    for _ in range(100):
        delta = rng.normal(0.0, scale, dh.shape[-1])
        residual = rigid_noise(rng, seen) + dh @ delta
        detected, unit_power = whitened_dh_span_test(residual, seen, pose, dh, covariance)
        estimates.append(detected / unit_power)
    estimates = np.array(estimates)
    assert np.mean(estimates > 0) > 0.8
    # DETECTION_STANDARD_ERRORS (2) of the six are taken off: the mean estimate is about 2/3
    assert (1.0 - DETECTION_STANDARD_ERRORS / 6.0) * 0.67 * scale**2 < np.mean(estimates) < 1.33 * scale**2


def test_a_covariance_from_few_pairs_does_not_raise_false_alarms(geometry):
    """Whitened by a covariance estimated from 20 independent steps (a 10 Hz camera's short
    sweep), noise alone inflates the whitened statistic about 20 / 13 times on average, and more
    along the estimate's least directions: taken as known, the test fires on about half of the
    draws; told the covariance's degrees of freedom, about as rarely as with the true covariance
    (within four binomial standard errors of 3 %)."""
    seen, pose, dh = geometry
    rng = np.random.default_rng(17)
    steps = 20
    fired_known = fired_estimated = 0
    trials = 300
    for _ in range(trials):
        draws = rng.normal(0.0, 1.0, (steps, 6)) * NOISE_SD
        estimate = draws.T @ draws / steps
        residual = rigid_noise(rng, seen)
        fired_known += whitened_dh_span_test(residual, seen, pose, dh, estimate)[0] > 0
        fired_estimated += (
            whitened_dh_span_test(residual, seen, pose, dh, estimate, covariance_dof=steps)[0] > 0
        )
    assert fired_known / trials > 0.3
    assert fired_estimated / trials < 0.03 + 4.0 * np.sqrt(0.03 * 0.97 / trials)


def test_too_few_pairs_whiten_nothing(geometry):
    seen, pose, dh = geometry
    covariance = np.diag(NOISE_SD**2)
    residual = rigid_noise(np.random.default_rng(1), seen) + dh @ np.full(dh.shape[-1], 1.0)
    assert whitened_dh_span_test(residual, seen, pose, dh, covariance)[0] > 0
    detected, unit_power = whitened_dh_span_test(
        residual, seen, pose, dh, covariance, covariance_dof=MINIMUM_WHITENING_DOF - 1
    )
    assert detected == 0.0 and unit_power > 0
