import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from spacecal.core.errors import InvalidInputError
from spacecal.geometry.rotations import rotation_angle
from spacecal.geometry.transforms import (
    apply_transform,
    check_points,
    check_transform,
    interpolate_transforms,
    invert_transform,
    is_rigid_transform,
    make_transform,
    matrix_to_quaternion_wxyz,
    quaternion_wxyz_to_matrix,
    transform_from_position_quaternion,
    transform_points_by_stack,
    transform_to_position_quaternion,
)

seeds = st.integers(min_value=0, max_value=2**32 - 1)


def re_shape(shape):
    return re.escape(str(tuple(shape)))


def random_transforms(seed, count=5):
    rng = np.random.default_rng(seed)
    rotations = Rotation.random(count, random_state=seed).as_matrix()
    return make_transform(rotations, rng.uniform(-1000, 1000, (count, 3)))


@given(seeds)
def test_inverse_composes_to_identity(seed):
    a_from_b = random_transforms(seed)
    assert np.allclose(a_from_b @ invert_transform(a_from_b), np.eye(4), atol=1e-9)
    assert np.allclose(invert_transform(a_from_b) @ a_from_b, np.eye(4), atol=1e-9)


@given(seeds)
def test_apply_matches_homogeneous_product(seed):
    a_from_b = random_transforms(seed, 1)[0]
    points = np.random.default_rng(seed).normal(size=(7, 3)) * 100
    homogeneous = (a_from_b @ np.column_stack([points, np.ones(7)]).T).T[:, :3]
    assert np.allclose(apply_transform(a_from_b, points), homogeneous, atol=1e-9)


@given(seeds)
def test_quaternion_round_trip_is_scalar_first(seed):
    transforms = random_transforms(seed)
    position, quaternion = transform_to_position_quaternion(transforms)
    assert np.all(quaternion[:, 0] >= 0)
    assert np.allclose(np.linalg.norm(quaternion, axis=1), 1.0)
    assert np.allclose(transform_from_position_quaternion(position, quaternion), transforms, atol=1e-12)


def test_quaternion_order_is_wxyz():
    # 90 degrees about z: w = cos 45, z = sin 45.
    rotation = quaternion_wxyz_to_matrix([np.sqrt(0.5), 0, 0, np.sqrt(0.5)])
    assert np.allclose(rotation @ [1, 0, 0], [0, 1, 0])
    assert np.allclose(matrix_to_quaternion_wxyz(rotation), [np.sqrt(0.5), 0, 0, np.sqrt(0.5)])


@settings(max_examples=20)
@given(seeds)
def test_rigidity_check(seed):
    transforms = random_transforms(seed)
    assert is_rigid_transform(transforms)
    bent = transforms.copy()
    bent[0, 0, 0] += 0.01
    assert not is_rigid_transform(bent)
    mirrored = transforms[0].copy()
    mirrored[:3, 0] *= -1
    assert not is_rigid_transform(mirrored)


@given(seeds)
def test_points_by_stack_put_every_point_through_every_pose(seed):
    stack = random_transforms(seed, 4)
    points = np.random.default_rng(seed).normal(size=(3, 3)) * 100
    placed = transform_points_by_stack(stack, points)
    assert placed.shape == (4, 3, 3)
    for n in range(4):
        assert np.allclose(placed[n], apply_transform(stack[n], points), atol=1e-9)
    single = transform_points_by_stack(stack, points[0])
    assert single.shape == (4, 3) and np.allclose(single, placed[:, 0], atol=1e-12)


@given(seeds)
def test_interpolation_runs_the_geodesic_from_start_to_end(seed):
    start, end = random_transforms(seed, 2)
    fractions = np.linspace(0.0, 1.0, 5)
    path = interpolate_transforms(start, end, fractions)
    assert np.allclose(path[0], start, atol=1e-9) and np.allclose(path[-1], end, atol=1e-9)
    assert is_rigid_transform(path)
    # constant rate: equal fractions turn equal angles, and positions move on the straight line
    steps = rotation_angle(path[1:, :3, :3] @ np.swapaxes(path[:-1, :3, :3], 1, 2))
    assert np.allclose(steps, steps[0], atol=1e-9)
    assert np.allclose(path[2, :3, 3], (start[:3, 3] + end[:3, 3]) / 2, atol=1e-9)
    # stacks are interpolated pairwise
    pairwise = interpolate_transforms(np.stack([start, end]), np.stack([end, start]), np.array([0.25, 0.75]))
    assert np.allclose(pairwise[0], pairwise[1], atol=1e-9)


@given(seeds, st.integers(min_value=1, max_value=6))
def test_check_transform_returns_valid_transforms_as_float64(seed, count):
    stack = random_transforms(seed, count)
    checked = check_transform(stack, "base_from_tcp_stack", stack=True)
    assert checked.dtype == np.float64 and np.array_equal(checked, stack)
    assert np.array_equal(check_transform(stack[0], "tracker_from_base"), stack[0])
    assert check_transform(np.eye(4, dtype=int)).dtype == np.float64


@given(
    st.lists(st.integers(min_value=1, max_value=5), min_size=1, max_size=4).filter(
        lambda shape: tuple(shape) != (4, 4)
    )
)
def test_check_transform_names_the_shape_it_got(shape):
    with pytest.raises(InvalidInputError, match=r"^tracker_from_base: expected shape \(4, 4\), got"):
        check_transform(np.zeros(shape), "tracker_from_base")
    if len(shape) != 3 or tuple(shape[1:]) != (4, 4):
        with pytest.raises(InvalidInputError, match=r"expected shape \(N, 4, 4\), got " + re_shape(shape)):
            check_transform(np.zeros(shape), "stack", stack=True)


@given(seeds, st.integers(0, 2), st.integers(0, 2), st.floats(1e-4, 1.0), st.booleans())
def test_check_transform_refuses_a_non_orthonormal_rotation(seed, row, column, size, negative):
    bent = random_transforms(seed, 3)
    bent[1, row, column] += -size if negative else size
    with pytest.raises(
        InvalidInputError, match=r"^poses \(3, 4, 4\), matrix 1: rotation block is not orthonormal"
    ):
        check_transform(bent, "poses", stack=True)
    # within a looser tolerance, a slightly bent matrix passes
    if size < 1e-3:
        check_transform(bent, "poses", stack=True, atol=1e-2)


@given(seeds, st.integers(0, 2))
def test_check_transform_refuses_a_reflection(seed, axis):
    mirrored = random_transforms(seed, 1)[0]
    mirrored[:3, axis] *= -1
    with pytest.raises(InvalidInputError, match=r"^tcp_from_marker \(4, 4\): rotation has det -1"):
        check_transform(mirrored, "tcp_from_marker")


@given(seeds, st.integers(0, 3), st.floats(1e-3, 10.0))
def test_check_transform_refuses_a_wrong_bottom_row(seed, column, size):
    wrong = random_transforms(seed, 1)[0]
    wrong[3, column] += size
    with pytest.raises(InvalidInputError, match=r"bottom row is not 0 0 0 1"):
        check_transform(wrong, "tracker_from_base")
    with pytest.raises(InvalidInputError, match=r"bottom row"):
        check_transform(wrong.T.copy() if column == 3 else wrong, "transposed")


@given(seeds, st.integers(0, 3), st.integers(0, 3), st.sampled_from([np.nan, np.inf, -np.inf]))
def test_check_transform_refuses_non_finite_values(seed, row, column, value):
    stack = random_transforms(seed, 3)
    stack[2, row, column] = value
    with pytest.raises(InvalidInputError, match=r"^poses \(3, 4, 4\), matrix 2: non-finite"):
        check_transform(stack, "poses", stack=True)
    with pytest.raises(InvalidInputError, match="only whole rows may be NaN"):
        check_transform(stack, "poses", stack=True, allow_missing=True)
    stack[2] = np.nan  # a frame without the marker
    assert np.isnan(check_transform(stack, "poses", stack=True, allow_missing=True)[2]).all()
    with pytest.raises(InvalidInputError, match="non-finite"):
        check_transform(stack, "poses", stack=True)


def test_check_transform_refuses_what_is_not_numbers():
    with pytest.raises(InvalidInputError, match="^calibration: not an array of numbers"):
        check_transform([[1, 0], [0]], "calibration")
    with pytest.raises(InvalidInputError, match="^calibration: not an array of numbers"):
        check_transform("identity", "calibration")


@given(seeds, st.integers(1, 8))
def test_check_points(seed, count):
    points = np.random.default_rng(seed).normal(size=(count, 3))
    assert np.array_equal(check_points(points, "targets_in_base"), points)
    with pytest.raises(InvalidInputError, match=r"^targets_in_base: expected shape \(N, 3\), got \(3,\)"):
        check_points(points[0], "targets_in_base")
    with pytest.raises(InvalidInputError, match=rf"expected shape \(N, 3\), got \({count}, 2\)"):
        check_points(points[:, :2], "targets_in_base")
    points[-1, 1] = np.nan
    with pytest.raises(InvalidInputError, match=rf"row {count - 1}: non-finite coordinates"):
        check_points(points, "targets_in_base")
