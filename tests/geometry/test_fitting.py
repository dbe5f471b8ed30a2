import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from spacecal.core.errors import DegenerateDataError
from spacecal.geometry.fitting import fit_line, fit_rigid, fit_sphere, fit_sphere_algebraic

seeds = st.integers(min_value=0, max_value=2**32 - 1)


def points_on_sphere(rng, centre, radius, count, cap_deg=180.0):
    """Points on a spherical cap of half-angle cap_deg around +z."""
    polar = np.radians(rng.uniform(0, cap_deg, count))
    azimuth = rng.uniform(0, 2 * np.pi, count)
    unit = np.column_stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)])
    return centre + radius * unit


@given(seeds)
def test_sphere_fit_recovers_exact_sphere(seed):
    rng = np.random.default_rng(seed)
    centre = rng.uniform(-1000, 1000, 3)
    radius = rng.uniform(50, 300)
    fit = fit_sphere(points_on_sphere(rng, centre, radius, 30, cap_deg=60))
    assert np.allclose(fit.centre, centre, atol=1e-8)
    assert fit.radius == pytest.approx(radius, abs=1e-8)
    assert fit.rms < 1e-8


def test_sphere_fit_noise_matches_theory():
    # With N points over the whole sphere and per-axis noise s, the radial residual RMS is s
    # and the centre error per axis has s.d. about s * sqrt(3 / N).
    rng = np.random.default_rng(7)
    sigma, count, errors, rms = 0.1, 400, [], []
    for _ in range(200):
        unit = rng.normal(size=(count, 3))
        unit /= np.linalg.norm(unit, axis=1, keepdims=True)  # uniform over the whole sphere
        points = 150.0 * unit + rng.normal(scale=sigma, size=(count, 3))
        fit = fit_sphere(points)
        errors.append(fit.centre)
        rms.append(fit.rms)
    centre_sd = np.std(np.array(errors), axis=0)
    assert np.allclose(centre_sd, sigma * np.sqrt(3 / count), rtol=0.25)
    assert np.mean(rms) == pytest.approx(sigma, rel=0.05)


def test_geometric_fit_beats_algebraic_on_a_noisy_cap():
    rng = np.random.default_rng(3)
    truth = np.array([10.0, -20.0, -900.0])
    geometric, algebraic = [], []
    for _ in range(100):
        points = points_on_sphere(rng, truth, 160.0, 200, cap_deg=60) + rng.normal(scale=0.15, size=(200, 3))
        geometric.append(np.linalg.norm(fit_sphere(points).centre - truth))
        algebraic.append(np.linalg.norm(fit_sphere_algebraic(points)[0] - truth))
    assert np.mean(geometric) < np.mean(algebraic)


def test_sphere_fit_rejects_planar_points():
    rng = np.random.default_rng(0)
    angles = rng.uniform(0, 2 * np.pi, 50)
    circle = np.column_stack([100 * np.cos(angles), 100 * np.sin(angles), np.zeros(50)])
    with pytest.raises(DegenerateDataError, match="plane or a line"):
        fit_sphere(circle)


def test_sphere_fit_rejects_nan_and_too_few():
    with pytest.raises(DegenerateDataError, match="NaN"):
        fit_sphere(np.array([[0, 0, 1.0], [1, 0, 0], [0, 1, 0], [np.nan, 0, 0]]))
    with pytest.raises(DegenerateDataError, match="at least 4"):
        fit_sphere(np.eye(3))


@given(seeds)
def test_line_fit_recovers_direction_signed_by_travel(seed):
    rng = np.random.default_rng(seed)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    start = rng.uniform(-500, 500, 3)
    points = start + np.linspace(0, 400, 25)[:, None] * direction
    fit = fit_line(points)
    assert np.allclose(fit.direction, direction, atol=1e-10)
    assert fit.rms < 1e-9
    assert fit.length == pytest.approx(400.0)
    assert np.allclose(fit_line(points[::-1]).direction, -direction, atol=1e-10)


def test_line_rms_measures_straightness():
    t = np.linspace(-200, 200, 101)
    bent = np.column_stack([t, 3.0 * np.sin(t / 40.0), np.zeros_like(t)])
    assert fit_line(bent).rms > 1.5


@settings(max_examples=25)
@given(seeds)
def test_rigid_fit_recovers_pose(seed):
    rng = np.random.default_rng(seed)
    model = rng.uniform(-50, 50, (4, 3))
    rotation = Rotation.random(random_state=seed).as_matrix()
    translation = rng.uniform(-1000, 1000, 3)
    measured = model @ rotation.T + translation
    pose, rms = fit_rigid(points_in_source=model, points_in_target=measured)
    assert np.allclose(pose[:3, :3], rotation, atol=1e-9)
    assert np.allclose(pose[:3, 3], translation, atol=1e-8)
    assert rms < 1e-9
    stack, stack_rms = fit_rigid(points_in_source=model, points_in_target=np.stack([measured, measured]))
    assert np.allclose(stack[1], pose) and stack_rms.shape == (2,)
