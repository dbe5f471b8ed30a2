"""The white noise's covariance from a fit's residuals, whatever its shape
(:mod:`spacecal.estimators.assessment.residual_noise`), on linear models whose truth is known."""

from __future__ import annotations

import numpy as np
import pytest

from spacecal.core.errors import DegenerateDataError
from spacecal.estimators.assessment.residual_noise import frame_noise_covariance, held_out_noise_power

SPHERES = 4
WIDTH = 3 * SPHERES
FRAMES = 40
#: Per-axis variances of the translation-like noise (mm^2): a camera's depth and lateral noise.
TRANSLATION_VARIANCES = np.array([9.0, 4.0, 1.0])
#: Per-coordinate variance of the small isotropic rest (mm^2).
REST_VARIANCE = 0.01


def translation_like_design(rng: np.random.Generator, columns: int) -> np.ndarray:
    """(FRAMES, WIDTH, columns): every column moves a frame's spheres alike (a translation),
    along a direction that turns from frame to frame as a DH error's does with the joints."""
    directions = rng.normal(size=(FRAMES, columns, 3))
    directions /= np.linalg.norm(directions, axis=2, keepdims=True)
    return np.tile(directions, SPHERES).transpose(0, 2, 1)


def concentrated_noise(rng: np.random.Generator) -> np.ndarray:
    """(FRAMES, WIDTH): one translation per frame shared by its spheres, plus a small rest."""
    shift = rng.normal(0.0, np.sqrt(TRANSLATION_VARIANCES), (FRAMES, 3))
    return np.tile(shift, SPHERES) + rng.normal(0.0, np.sqrt(REST_VARIANCE), (FRAMES, WIDTH))


TRUE_POWER = SPHERES * TRANSLATION_VARIANCES.sum() + WIDTH * REST_VARIANCE


def residuals_of(design: np.ndarray, noise: np.ndarray) -> np.ndarray:
    stacked = design.reshape(-1, design.shape[-1])
    coefficients, *_ = np.linalg.lstsq(stacked, noise.reshape(-1), rcond=None)
    return (noise.reshape(-1) - stacked @ coefficients).reshape(noise.shape)


@pytest.fixture(scope="module")
def trials() -> dict[str, np.ndarray]:
    """200 recordings of concentrated noise through 36 translation-like columns: the shaped
    estimate's power and degrees of freedom, and the count's power."""
    rng = np.random.default_rng(1)
    design = translation_like_design(rng, 36)
    assert np.linalg.matrix_rank(design.reshape(-1, 36)) == 36
    shaped, dof, counted = [], [], []
    for _ in range(200):
        residual = residuals_of(design, concentrated_noise(rng))
        estimate = frame_noise_covariance(design, residual)
        shaped.append(estimate["power_mm2"])
        dof.append(estimate["dof"])
        m = residual.size
        counted.append(np.sum(residual**2) / FRAMES * m / (m - 36))
    return {"shaped": np.array(shaped), "dof": np.array(dof), "counted": np.array(counted)}


def test_noise_along_few_coordinates_is_measured_where_a_count_of_degrees_of_freedom_is_not(trials):
    shaped, counted = trials["shaped"], trials["counted"]
    standard_error = shaped.std() / np.sqrt(len(shaped))
    # unbiased within three standard errors of the 200 trials' mean
    assert abs(shaped.mean() - TRUE_POWER) < 3.0 * standard_error
    # the count assumes every coordinate loses 36 / m of its power to the fit; the 36
    # translation-like columns take 36 / (3 FRAMES) of the translation's: biased low by far
    # more than the trials' scatter (a 30 % loss against 7.5 %)
    assert TRUE_POWER - counted.mean() > 10.0 * counted.std() / np.sqrt(len(counted))


def test_the_power_s_scatter_is_what_its_degrees_of_freedom_say(trials):
    powers = trials["shaped"]
    stated = np.sqrt(2.0 / np.median(trials["dof"]))
    # the relative s.d. of 200 estimates is itself known to about 5 %
    assert powers.std() / powers.mean() == pytest.approx(stated, rel=0.25)


def test_isotropic_noise_gives_the_count_of_degrees_of_freedom():
    rng = np.random.default_rng(3)
    design = rng.normal(size=(FRAMES, WIDTH, 20))
    residual = residuals_of(design, rng.normal(0.0, 2.0, (FRAMES, WIDTH)))
    m = residual.size
    estimate = frame_noise_covariance(design, residual)
    # the count is the right estimate for isotropic noise; the shaped one agrees with it
    counted = np.sum(residual**2) / FRAMES * m / (m - 20)
    assert estimate["power_mm2"] == pytest.approx(counted, rel=0.05)
    # the effective degrees of freedom never exceed the count (tr(A)^2 <= rank(A) tr(A^2))
    assert 0.5 * (m - 20) < estimate["dof"] <= m - 20


def test_a_design_that_explains_everything_leaves_no_noise_to_measure():
    rng = np.random.default_rng(4)
    design = rng.normal(size=(2, 3, 6))
    with pytest.raises(DegenerateDataError):
        frame_noise_covariance(design, rng.normal(size=(2, 3)))


def _misfit_of(jac: np.ndarray, blocks: list[np.ndarray]) -> dict:
    inverses = []
    for block in blocks:
        keep = np.ones(len(jac), dtype=bool)
        keep[block] = False
        train = jac[keep].reshape(-1, jac.shape[-1])
        inverses.append(np.linalg.inv(train.T @ train))
    return {
        "frame_sse_mm2": np.ones(len(jac)),
        "block_indices": blocks,
        "jacobian": jac,
        "block_normal_inverses": inverses,
    }


def test_held_out_noise_power_is_the_leverage_rule_for_isotropic_noise_and_simulation_for_any():
    rng = np.random.default_rng(5)
    jac = rng.normal(size=(30, WIDTH, 12))
    blocks = np.array_split(np.arange(30), 6)
    misfit = _misfit_of(jac, blocks)
    # isotropic: sigma^2 (D + leverage)
    leverage = np.concatenate(
        [
            np.einsum("nia,ab,nib->n", jac[b], inv, jac[b])
            for b, inv in zip(blocks, misfit["block_normal_inverses"])
        ]
    )
    assert held_out_noise_power(misfit, 4.0 * np.eye(WIDTH)) == pytest.approx(4.0 * (WIDTH + leverage.mean()))
    # concentrated: the mean held-out squared error of least-squares refits, simulated
    shape = np.zeros((WIDTH, WIDTH))
    shape[:3, :3] = np.diag(TRANSLATION_VARIANCES)
    factor = np.linalg.cholesky(shape + 1e-12 * np.eye(WIDTH))
    errors = []
    for _ in range(400):
        noise = rng.normal(size=(30, WIDTH)) @ factor.T
        sse = np.empty(30)
        for block in blocks:
            keep = np.ones(30, dtype=bool)
            keep[block] = False
            theta, *_ = np.linalg.lstsq(jac[keep].reshape(-1, 12), noise[keep].reshape(-1), rcond=None)
            sse[block] = np.sum((noise[block] - jac[block] @ theta) ** 2, axis=1)
        errors.append(sse.mean())
    errors = np.array(errors)
    assert held_out_noise_power(misfit, shape) == pytest.approx(
        errors.mean(), abs=3.0 * errors.std() / np.sqrt(len(errors))
    )
