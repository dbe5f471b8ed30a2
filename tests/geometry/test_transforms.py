import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from spacecal.geometry.transforms import (
    apply_transform,
    invert_transform,
    is_rigid_transform,
    make_transform,
    matrix_to_quaternion_wxyz,
    quaternion_wxyz_to_matrix,
    transform_from_position_quaternion,
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
