"""The oracle of a fixed prediction, and the expected error against fresh noise in one world."""

import numpy as np
import pytest
from scipy import stats

from spacecal.experiments.prediction_oracle import best_fixed_share, noise_draws, share_within
from spacecal.sim.scenario import PRESETS


def test_best_fixed_share_is_exact_on_small_sets_and_half_for_a_3d_gaussian_length():
    # 1.0 and 1.8 fit one window (any c in [1.8 * 0.7, 1.0 * 1.3] = [1.26, 1.3]); 3.0 does not
    share, best = best_fixed_share([1.0, 1.8, 3.0])
    assert share == pytest.approx(2 / 3) and best == pytest.approx(1.28)
    assert share_within(best, [1.0, 1.8, 3.0]) == pytest.approx(2 / 3)
    # the length of a 3-D Gaussian vector: chi with 3 dof, best share 0.523 (numerical optimum
    # of cdf(c / 0.7) - cdf(c / 1.3)); 20000 draws give it to about 3 s.e. = 0.011
    lengths = np.linalg.norm(np.random.default_rng(3).normal(size=(20000, 3)), axis=1)
    chi = stats.chi(3)
    grid = np.linspace(0.5, 3.0, 5001)
    exact = float(np.max(chi.cdf(grid / 0.7) - chi.cdf(grid / 1.3)))
    assert exact == pytest.approx(0.523, abs=0.001)
    assert best_fixed_share(lengths)[0] == pytest.approx(exact, abs=0.011 + 0.005)  # + in-sample optimism
    with pytest.raises(ValueError):
        best_fixed_share([1.0, -1.0])


def test_white_noise_expected_error_is_the_mean_of_fresh_noise_draws(white_simulation):
    # one world, fresh tracker noise: the stated expected error must match the mean of the
    # measured verification means; their relative s.d. is that of a 3-D Gaussian length
    # (0.42), so the mean of 30 draws is known to 3 * 0.42 / sqrt(30) = 23 %
    draws = noise_draws(PRESETS["paper-white"], 30, simulation=white_simulation)
    measured, expected = draws[:, 0], draws[:, 1]
    assert np.mean(expected) == pytest.approx(np.mean(measured), rel=3 * 0.42 / np.sqrt(30))
    # the stated number hardly moves between draws (it cannot follow the draw), except where
    # the noise's misfit happens to exceed its two standard errors and is read as systematic
    assert np.mean(np.abs(expected / np.median(expected) - 1) < 0.1) >= 0.8
    spread = np.std(measured) / np.mean(measured)
    assert 0.25 < spread < 0.6
