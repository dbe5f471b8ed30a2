"""The expected error at a target (held-out blocks + unseen kinematic error) and the verdict."""

import dataclasses

import numpy as np
import pytest

from spacecal.core.errors import InvalidInputError
from spacecal.estimators import calibrate
from spacecal.estimators.diagnostics import ErrorThresholds, grade
from spacecal.estimators.expected_error import MEAN_OVER_RMS_3D, held_out_blocks
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
    assert "held-out" in expected["basis"] and result.diagnostics["verdict"].startswith("good:")


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
    assert result.diagnostics["verdict"].split(":")[0] in GRADES
    assert result.diagnostics["expected_error"]["position_mm"] > 0


def test_thresholds_grade_and_are_checked(white_simulation):
    thresholds = ErrorThresholds(0.001, 0.002, 0.003)
    result = calibrate(white_simulation.recording, "ml", error_thresholds=thresholds)
    assert result.diagnostics["verdict"].startswith("unusable:")
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
