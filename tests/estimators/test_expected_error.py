"""The expected error at a target (held-out blocks + unseen kinematic error) and the verdict."""

import dataclasses

import numpy as np
import pytest

from spacecal.core.errors import InvalidInputError
from spacecal.estimators import calibrate
from spacecal.estimators.diagnostics import ErrorThresholds, grade
from spacecal.estimators.expected_error import (
    MEAN_OVER_RMS_3D,
    held_out_blocks,
    mean_gaussian_length,
    noise_level_relative_error,
)
from spacecal.estimators.registry import METHODS
from spacecal.experiments.verification import verify_in_simulation
from spacecal.sim.scenario import PRESETS

GRADES = ("good", "acceptable", "poor", "unusable")


def test_white_noise_expects_about_the_noise_only_error(white_simulation):
    # no systematic error: the held-out misfit is the noise's, and the expected error is the
    # mean length of the noise-only TRE
    result = calibrate(white_simulation.recording, "ml")
    expected = result.diagnostics["expected_error"]
    components = expected["components"]
    assert components["dh_error_scale_mm"] < 0.03
    assert expected["position_mm"] == pytest.approx(
        MEAN_OVER_RMS_3D * components["noise_tre_rms_mm"], rel=0.0, abs=0.05
    )
    assert components["blocks"] == 6 and components["blocks_refitted"] == 6
    assert "held-out" in expected["basis"] and result.verdict.grade == "good"


def test_realistic_expected_error_holds_the_unseen_kinematic_error(realistic_simulation):
    # the verification error here is dominated by DH errors that move the tip but not the
    # marker; the expected error must not be the (10x smaller) noise-only TRE
    result = calibrate(realistic_simulation.recording, "ml")
    expected = result.diagnostics["expected_error"]["position_mm"]
    measured = verify_in_simulation(result, PRESETS["paper-realistic"]).statistics()["position_mm"]["mean"]
    assert expected > 5 * result.predicted_tre_mm["site"]
    assert 0.5 * measured <= expected <= 3.0 * measured


@pytest.mark.parametrize("method", sorted(METHODS))
def test_every_method_gets_a_graded_verdict(white_simulation, method):
    result = calibrate(white_simulation.recording, method)
    assert result.verdict.grade in GRADES
    assert result.diagnostics["expected_error"]["position_mm"] > 0


def test_thresholds_grade_and_are_checked(white_simulation):
    thresholds = ErrorThresholds(0.001, 0.002, 0.003)
    result = calibrate(white_simulation.recording, "ml", error_thresholds=thresholds)
    assert result.verdict.grade == "unusable"
    assert result.diagnostics["thresholds_mm"] == dataclasses.asdict(thresholds)
    assert [grade(x, ErrorThresholds()) for x in (0.4, 0.9, 1.9, 2.1, np.nan)] == [
        "good",
        "acceptable",
        "poor",
        "unusable",
        "unusable",
    ]
    assert ErrorThresholds.parse("0.3,0.6,1.2") == ErrorThresholds(0.3, 0.6, 1.2)
    for bad in ("1,2", "2,1,3", "a,b,c", "0,1,2"):
        with pytest.raises(InvalidInputError):
            ErrorThresholds.parse(bad)


def test_blocks_are_segments_or_contiguous_time_blocks():
    segments = np.array(["a"] * 10 + ["b"] * 10 + ["c"] * 10 + ["d"] * 2)
    assert [len(b) for b in held_out_blocks(segments)] == [10, 10, 10]
    stations = held_out_blocks(np.array(["station"] * 60))
    assert len(stations) == 6 and np.array_equal(np.concatenate(stations), np.arange(60))


def test_mean_gaussian_length_matches_closed_forms_and_sampling():
    # isotropic: sqrt(8 / (3 pi)) * RMS; one direction: sqrt(2 / pi) * s.d.; two: sqrt(pi / 4) * RMS
    assert mean_gaussian_length(np.eye(3) * 4.0) == pytest.approx(MEAN_OVER_RMS_3D * np.sqrt(12.0), rel=1e-9)
    assert mean_gaussian_length(np.diag([9.0, 0.0, 0.0])) == pytest.approx(3.0 * np.sqrt(2 / np.pi), rel=1e-9)
    assert mean_gaussian_length(np.diag([1.0, 1.0, 0.0])) == pytest.approx(np.sqrt(np.pi / 2), rel=1e-9)
    assert mean_gaussian_length(np.zeros((3, 3))) == 0.0
    covariance = np.array([[4.0, 1.0, 0.0], [1.0, 1.0, 0.3], [0.0, 0.3, 0.2]])
    samples = np.random.default_rng(7).normal(size=(200_000, 3)) @ np.linalg.cholesky(covariance).T
    lengths = np.linalg.norm(samples, axis=1)
    # 200000 samples: the sample mean is known to 4 standard errors
    assert mean_gaussian_length(covariance) == pytest.approx(
        lengths.mean(), abs=4 * lengths.std() / np.sqrt(len(lengths))
    )


def test_noise_level_error_is_that_of_a_median_of_chi_square_values():
    # sigma^2 from the median of N chi-square(6) values: its relative scatter over many sets
    rng = np.random.default_rng(11)
    medians = np.median(rng.chisquare(6, size=(4000, 500)), axis=1)
    assert noise_level_relative_error(4, 500) == pytest.approx(np.std(medians) / np.mean(medians), rel=0.1)
