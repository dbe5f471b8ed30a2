"""Scenario files: a scenario of one's own keeps its own name; a saved preset loads as itself;
every other value still goes through the same checks."""

import dataclasses
import json

import pytest

from spacecal.cli import main
from spacecal.core.errors import InvalidInputError
from spacecal.io.recording_csv import read_recording
from spacecal.sim.scenario import PRESETS, load_scenario, scenario_from_dict


def test_a_scenario_of_ones_own_keeps_its_name_on_the_default_preset(tmp_path):
    path = tmp_path / "lab.json"
    path.write_text(json.dumps({"name": "bench 2, Vicra", "white_noise_rms_mm": 0.3, "seed": 7}))
    scenario = load_scenario(path)
    expected = dataclasses.replace(
        PRESETS["paper-realistic"], name="bench 2, Vicra", white_noise_rms_mm=0.3, seed=7
    )
    assert scenario == expected


def test_a_scenario_of_ones_own_on_a_named_preset_keeps_its_name():
    scenario = scenario_from_dict({"preset": "paper-white", "name": "lab-white"})
    assert scenario == dataclasses.replace(PRESETS["paper-white"], name="lab-white")


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_a_saved_preset_loads_as_itself(preset):
    """``to_dict`` writes no ``preset`` key: the name still picks the preset as the base, so a
    file holding only its name is that preset."""
    assert scenario_from_dict(PRESETS[preset].to_dict()) == PRESETS[preset]
    assert scenario_from_dict({"name": preset}) == PRESETS[preset]


def test_a_saved_scenario_of_ones_own_round_trips():
    own = dataclasses.replace(PRESETS["systematic-nominal-all"], name="my-systematic", payload_kg=1.5)
    assert scenario_from_dict(json.loads(json.dumps(own.to_dict()))) == own


@pytest.mark.parametrize(
    "name,message",
    [
        ("", "scenario name is empty"),
        ("two\nlines", "U\\+000A"),
        ("\u202egnp.exe", "U\\+202E"),
        (" padded", "must not start or end with a space"),
        ("x" * 201, "longer than 200 characters"),
        (3, "scenario name: expected text, got int"),
    ],
)
def test_a_name_no_one_can_read_as_it_is_is_one_line(name, message):
    with pytest.raises(InvalidInputError, match=message) as caught:
        scenario_from_dict({"name": name})
    assert "\n" not in str(caught.value)


def test_an_unknown_preset_named_as_the_preset_is_still_refused():
    with pytest.raises(InvalidInputError, match="unknown scenario preset 'paper-grey'"):
        scenario_from_dict({"preset": "paper-grey", "name": "mine"})


def test_simulate_runs_a_scenario_of_ones_own_and_the_recording_names_it(tmp_path, capsys):
    scenario = tmp_path / "lab.json"
    scenario.write_text(json.dumps({"name": "lab-bench", "motion": "stations", "stations": 6}))
    recording = tmp_path / "rec.csv"
    code = main(["simulate", "--scenario", str(scenario), "-o", str(recording)])
    _, err = capsys.readouterr()
    assert code == 0, err
    assert read_recording(recording).metadata["scenario"]["name"] == "lab-bench"
