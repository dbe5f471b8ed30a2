import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from spacecal.geometry.rotations import rotation_angle
from spacecal.geometry.transforms import (
    apply_transform,
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
