# ruff: noqa: F811 (the fixtures of test_guide.py, imported by name)
"""``guide(..., then=...)``: an insertion that follows its standoff in the standoff's session (the
station's way on simulated devices, where a new session starts a fresh world at home)."""

import dataclasses
import json

import pytest

from spacecal import app
from spacecal.core.errors import InvalidInputError
from tests.app.guide_files import write_plan
from tests.app.test_guide import calibration, registration, world  # noqa: F401 (fixtures)


def standoff_settings(plan, calibration, registration, output):
    return app.GuideSettings(
        plan=str(plan),
        calibration=str(calibration),
        registration=str(registration),
        devices=app.DeviceSettings("sim", "sim"),
        stage="standoff",
        confirm_robot_motion=True,
        output=str(output),
    )


def test_the_insertion_follows_in_the_standoffs_session(calibration, world, registration, robots, tmp_path):
    plan, _ = write_plan(tmp_path / "plan.mrk.json", world)
    first = standoff_settings(plan, calibration, registration, tmp_path / "standoff.json")
    asked = []

    def then(standoff):
        asked.append(standoff.record.result.stages[-1].stage)
        return dataclasses.replace(
            first, stage="insert", insertion="hold", output=str(tmp_path / "insert.json")
        )

    out = app.guide(first, then=then)
    assert asked == ["standoff"] and len(robots) == 1  # one session, one simulated world
    assert [s.stage for s in out.record.result.stages] == ["insert"] and out.record.stage == "insert"
    assert json.loads((tmp_path / "standoff.json").read_text())["stages_reached"] == ["standoff"]
    # the insertion checked the robot stood at the standoff, and it did: within the at-pose bound
    assert out.record.result.stages[0].entry_error_mm < 2.0


def test_none_ends_at_the_standoff_and_another_plan_is_refused(
    calibration, world, registration, robots, tmp_path
):
    plan, _ = write_plan(tmp_path / "plan.mrk.json", world)
    other, _ = write_plan(tmp_path / "other.mrk.json", world, 1)
    first = standoff_settings(plan, calibration, registration, tmp_path / "standoff.json")
    out = app.guide(first, then=lambda standoff: None)
    assert out.record.stage == "standoff" and len(robots) == 1
    again = dataclasses.replace(first, output=str(tmp_path / "again.json"))
    with pytest.raises(InvalidInputError, match="differs in plan"):
        app.guide(again, then=lambda standoff: dataclasses.replace(again, stage="insert", plan=str(other)))
    assert len(robots) == 2
