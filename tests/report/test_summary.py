"""The judgement and the numbers behind the figures, without a browser."""

import numpy as np

from spacecal.estimators import ESTIMATORS, calibrate
from spacecal.records import CheckResult, Verdict
from spacecal.report.evidence import check_series, tick_format, uncertainty
from spacecal.report.html import (
    Report,
    _check_figure,
    _sweep_figure,
    _uncertainty_figure,
    _verification_figure,
)
from spacecal.report.summary import assess, provenance_facts, residuals_of
from spacecal.testing.calibrations import with_stored


def test_tick_formats_follow_the_scale():
    assert tick_format([0.0089]) == ".3f"
    assert tick_format([0.7]) == ".1f"
    assert tick_format([12.0]) == ".0f"
    assert tick_format([1e-9]) == ".1e"


def test_the_verdict_word_sets_the_colour(white_simulation):
    calibration = calibrate(white_simulation.recording, "ml")
    residuals = residuals_of(calibration, white_simulation.recording)
    assert assess(calibration, residuals).level == "ok"
    poor = "Poor: use only where an error up to 2 mm is tolerable"
    for verdict, headline in (
        (Verdict("poor", 1.5, 0.3, 2.0, ("because",), tolerable_mm=2.0).to_dict(), poor),
        (Verdict("unusable", reasons=("because",)).to_dict(), "Do not use: unusable"),
        (
            "check: an older file's sentence",
            "Poor: use only where an error up to the tolerable limit is tolerable",
        ),
        ("unusable: an older file's sentence", "Do not use: unusable"),
    ):
        flagged = with_stored(calibration, verdict=verdict)
        found = assess(flagged, residuals)
        assert (found.level, found.headline) == ("alarm", headline)
        assert found.headline == flagged.verdict.headline  # the verdict's words, not the report's
    silent = calibration.replace(diagnostics={}, predicted_tre_mm=None, covariance=None, assessment=None)
    assert assess(silent).level == "unknown"


def test_the_method_line_is_the_registry_entry_summary(white_simulation):
    calibration = calibrate(white_simulation.recording, "shah", uncertainty=False)
    for name, spec in ESTIMATORS.items():
        facts = dict(provenance_facts(calibration.replace(method=name)))
        assert facts["method"] == f"{name}: {spec.summary}"
    # a method this version does not know (a file from elsewhere) is shown by its name alone
    assert dict(provenance_facts(calibration.replace(method="opencv-park")))["method"] == "opencv-park"


def test_an_expected_error_entry_is_shown_and_not_judged_again(white_simulation):
    """The report shows the expected error; the grade is the verdict's, made once against the
    thresholds in force when the calibration was made (no limit of the report's own)."""
    calibration = calibrate(white_simulation.recording, "ml")
    expected = {"position_mm": 1.6, "posture_deg": 0.4, "basis": "tip 150 mm from the flange"}
    found = assess(with_stored(calibration, expected_error=expected))
    assert ("expected error at the target", "1.60 mm, 0.40 deg (tip 150 mm from the flange)") in found.numbers
    assert (found.level, found.headline) == ("ok", calibration.verdict.headline) == ("ok", "Good")


def test_figures_have_units_and_points(white_simulation):
    calibration = calibrate(white_simulation.recording, "paper")
    sweep = _sweep_figure(Report(calibration, white_simulation.recording)).layout.scene
    assert [sweep.xaxis.title.text, sweep.yaxis.title.text, sweep.zaxis.title.text] == [
        "x (mm)",
        "y (mm)",
        "z (mm)",
    ]
    split = uncertainty(calibration)
    assert set(split.translation_sd_mm) == {"tracker_from_base", "tcp_from_marker"}
    figure = _uncertainty_figure(calibration)
    assert figure.layout.yaxis.title.text == "standard deviation (mm)"
    assert figure.layout.yaxis2.title.text == "standard deviation (deg)"
    one_check = [
        CheckResult(np.array([0.3]), np.array([0.1]), 1.0, 1.0, checked_utc="2025-03-01T10:00:00+00:00")
    ]
    figure = _check_figure(one_check)
    assert all(trace.mode == "markers" for trace in figure.data)  # a point, not a bar
    assert check_series(one_check).dated
    # thresholds derived from a calibration print as the check does, to 0.01, not as 1.8862
    derived = [CheckResult(np.array([0.3]), np.array([0.1]), 1.88623, 0.491178)]
    labels = [a.text for a in _check_figure(derived).layout.annotations]
    assert "threshold 1.89 mm" in labels and "threshold 0.49 deg" in labels
    assert not any("1.8862" in label or "0.4911" in label for label in labels)


def test_verification_points_and_the_paper_bound(white_simulation):
    from spacecal.experiments.verification import verify_in_simulation

    calibration = calibrate(white_simulation.recording, "ml")
    figure = _verification_figure(verify_in_simulation(calibration, white_simulation.world.scenario))
    assert all(trace.mode == "markers" for trace in figure.data)
    labels = [a.text for a in figure.layout.annotations]
    assert "paper: mean < 1.05 mm (a bound)" in labels


def test_check_thresholds_print_to_two_decimals_everywhere(white_simulation, tmp_path, monkeypatch):
    # thresholds a check derived from a calibration (1.8862 mm, 0.491178 deg) print as the
    # check's own line does: 1.89 mm, 0.49 deg (the interactive figure: the test above)
    from spacecal.report import figures

    history = [CheckResult(np.array([0.3]), np.array([0.1]), 1.88623, 0.491178, ["pose 1"])]
    shown = {}

    def keep(fig, path):
        shown["labels"] = [t.get_text() for ax in fig.axes for t in ax.get_legend().get_texts()]
        return path

    monkeypatch.setattr(figures, "_save", keep)
    figures.plot_check_history(history, tmp_path / "check_history.png")
    assert shown["labels"] == ["threshold 1.89 mm", "threshold 0.49 deg"]
    calibration = calibrate(white_simulation.recording, "paper")
    numbers = dict(assess(calibration, check_history=history).numbers)
    assert "(threshold 1.89 mm)" in numbers["last check (1 in the history)"]
    assert "1.8862" not in numbers["last check (1 in the history)"]
