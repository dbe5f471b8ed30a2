import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from spacecal.core.errors import DegenerateDataError
from spacecal.geometry.metrics import cube_grid, position_error, posture_error_rad, summary_statistics
from spacecal.geometry.rotations import mean_rotation, nearest_rotation, rotation_angle, wahba_rotation
from spacecal.geometry.transforms import axis_angle_transform, make_transform

seeds = st.integers(min_value=0, max_value=2**32 - 1)


@given(seeds)
def test_nearest_rotation_is_identity_on_rotations_and_proper_otherwise(seed):
    rotation = Rotation.random(random_state=seed).as_matrix()
    assert np.allclose(nearest_rotation(rotation), rotation, atol=1e-12)
    perturbed = rotation + np.random.default_rng(seed).normal(scale=0.05, size=(3, 3))
    projected = nearest_rotation(perturbed)
    assert np.allclose(projected.T @ projected, np.eye(3), atol=1e-12)
    assert np.linalg.det(projected) == pytest.approx(1.0)


def test_nearest_rotation_never_returns_a_reflection():
    assert np.linalg.det(nearest_rotation(np.diag([1.0, 1.0, -1.0]))) == pytest.approx(1.0)


@given(seeds)
def test_wahba_recovers_rotation(seed):
    rotation = Rotation.random(random_state=seed).as_matrix()
    directions_in_b = np.random.default_rng(seed).normal(size=(3, 3))
    assert np.allclose(
        wahba_rotation(
            directions_in_source=directions_in_b, directions_in_target=directions_in_b @ rotation.T
        ),
        rotation,
        atol=1e-9,
    )


def test_wahba_equals_paper_form_for_axes():
    # Fitted axes (columns) A, commanded directions = TCP axes R_bt: Wahba = nearest(A) R_bt^T.
    rng = np.random.default_rng(1)
    a = Rotation.random(random_state=2).as_matrix() + rng.normal(scale=0.01, size=(3, 3))
    r_bt = Rotation.random(random_state=3).as_matrix()
    wahba = wahba_rotation(
        directions_in_source=r_bt.T, directions_in_target=a.T / np.linalg.norm(a.T, axis=1, keepdims=True)
    )
    paper = nearest_rotation(a / np.linalg.norm(a, axis=0)) @ r_bt.T
    assert np.allclose(wahba, paper, atol=1e-9)


def test_wahba_rejects_parallel_directions():
    with pytest.raises(DegenerateDataError):
        wahba_rotation(
            directions_in_source=[[0, 1, 0], [0, 2, 0]], directions_in_target=[[1, 0, 0], [2, 0, 0]]
        )


def test_posture_error_is_the_angle_of_rd_rr_inverse():
    desired = axis_angle_transform([0, 0, 1], np.radians(30))
    reached = axis_angle_transform([0, 0, 1], np.radians(28.5))
    assert np.degrees(posture_error_rad(desired, reached)) == pytest.approx(1.5)
    assert position_error(make_transform(np.eye(3), [3, 4, 0]), np.eye(4)) == pytest.approx(5.0)


def test_small_angles_keep_precision():
    tiny = axis_angle_transform([1, 0, 0], 1e-9)[:3, :3]
    assert rotation_angle(tiny) == pytest.approx(1e-9, rel=1e-6)


def test_mean_rotation_of_symmetric_pair():
    a = axis_angle_transform([0, 1, 0], 0.2)[:3, :3]
    b = axis_angle_transform([0, 1, 0], -0.2)[:3, :3]
    assert np.allclose(mean_rotation([a, b]), np.eye(3), atol=1e-12)


def test_cube_grid_and_summary():
    grid = cube_grid([0, 0, 0], 200, 5)
    assert grid.shape == (125, 3) and grid.max() == 100 and grid.min() == -100
    stats = summary_statistics([3.0, 4.0])
    assert stats == {"min": 3.0, "mean": 3.5, "max": 4.0, "rms": pytest.approx(np.sqrt(12.5))}
