"""Tracker kinds as data: each entry's numbers are the maker's, a missing one is None (never a
guess), the simulated tracker's volume is the Vicra's entry, and a tracker's own model string
finds its kind."""

import pytest

from spacecal.core.errors import InvalidInputError
from spacecal.models.tracker import PyramidVolume, TrackerModel
from spacecal.models.tracker_kinds import TRACKER_KINDS, _kind, tracker_kind, tracker_kind_of


def test_every_kind_names_its_sources_and_states_only_what_they_give():
    assert {"Polaris Vicra", "Polaris Vega ST", "OptiTrack"} <= set(TRACKER_KINDS)
    for kind in TRACKER_KINDS.values():
        assert kind.sources and kind.protocol in ("ndi", "natnet", "igtl", "camera")
    assert tracker_kind("Polaris Vicra").accuracy_rms_mm == 0.25
    assert tracker_kind("OptiTrack").accuracy_rms_mm is None  # by set-up: the user states it


def test_the_simulated_tracker_is_the_vicra_entry():
    vicra = tracker_kind("Polaris Vicra")
    assert vicra.volume == TrackerModel().volume == PyramidVolume()
    assert vicra.rate_hz == TrackerModel().rate_hz


def test_a_tracker_model_string_finds_its_kind():
    assert tracker_kind_of("Polaris Vicra").name == "Polaris Vicra"
    assert tracker_kind_of("polaris  vega st  (firmware 1.2)").name == "Polaris Vega ST"
    assert tracker_kind_of("Aurora") is None and tracker_kind_of(None) is None


def test_an_unknown_kind_or_a_bad_entry_is_one_line():
    with pytest.raises(InvalidInputError, match="unknown tracker kind 'Polaris X'; known: Polaris Vicra"):
        tracker_kind("Polaris X")
    entry = {"vendor": "v", "protocol": "ndi", "marker_format": "m", "accuracy_rms_mm": -1}
    with pytest.raises(InvalidInputError, match="accuracy_rms_mm must be a positive number"):
        _kind("bad", entry)
    entry = {
        **entry,
        "accuracy_rms_mm": None,
        "volume": {"near_mm": 9, "far_mm": 5, "far_width_mm": 1, "far_height_mm": 1},
    }
    with pytest.raises(InvalidInputError, match="near < far"):
        _kind("bad", entry)
