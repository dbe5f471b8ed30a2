"""The guidance's needle poses and errors (paper §5.3) on needles placed off the plan by known
amounts, and the guidance record's refusals."""

import json

import numpy as np
import pytest

from spacecal.core.errors import DegenerateDataError, InvalidInputError
from spacecal.geometry.transforms import axis_angle_transform, make_transform
from spacecal.records.guidance import GuidanceResult, StageMeasurement
from spacecal.workflows.guidance import NeedleAxis, at_pose, needle_errors, stage_place_mm, stage_pose

AXIS = NeedleAxis(np.array([10.0, 20.0, 100.0]), np.array([10.0, 20.0, 40.0]))  # 60 mm deep, along -z
ROLL = np.array([1.0, 0.0, 0.0])


def test_stage_poses_lie_on_the_axis():
    standoff = stage_pose("standoff", AXIS, "advance", 20.0, ROLL)
    assert np.allclose(standoff[:3, 3], [10.0, 20.0, 120.0]) and np.allclose(standoff[:3, 2], [0, 0, -1])
    assert np.allclose(stage_pose("insert", AXIS, "advance", 20.0, ROLL)[:3, 3], AXIS.target)
    assert np.allclose(stage_pose("insert", AXIS, "hold", 20.0, ROLL)[:3, 3], AXIS.entry)
    assert stage_place_mm("insert", AXIS, "advance", 20.0) == pytest.approx(60.0)


def test_a_needle_shifted_sideways_is_off_by_the_shift_at_entry_and_target():
    planned = stage_pose("insert", AXIS, "advance", 20.0, ROLL)
    shifted = planned.copy()
    shifted[:3, 3] += [0.6, 0.8, 0.0]  # 1 mm sideways, parallel
    errors = needle_errors(shifted, AXIS, stage_place_mm("insert", AXIS, "advance", 20.0))
    assert errors.target_error_mm == pytest.approx(1.0) and errors.entry_error_mm == pytest.approx(1.0)
    assert errors.direction_error_deg == pytest.approx(0.0, abs=1e-6)


def test_a_needle_tilted_about_its_tip_keeps_the_target_and_misses_the_entry():
    planned = stage_pose("insert", AXIS, "advance", 20.0, ROLL)
    tilted = make_transform(
        axis_angle_transform([0, 1, 0], np.radians(1.0))[:3, :3] @ planned[:3, :3], AXIS.target
    )
    errors = needle_errors(tilted, AXIS, AXIS.depth_mm)
    assert errors.target_error_mm == pytest.approx(0.0, abs=1e-9)
    assert errors.entry_error_mm == pytest.approx(2 * 60.0 * np.sin(np.radians(0.5)), rel=1e-9)
    assert errors.direction_error_deg == pytest.approx(1.0)
    # held at the entry, the same tilt about the tip misses the target by the same chord
    held = make_transform(tilted[:3, :3], AXIS.entry)
    hold = needle_errors(held, AXIS, 0.0)
    assert hold.entry_error_mm == pytest.approx(0.0, abs=1e-9)
    assert hold.target_error_mm == pytest.approx(errors.entry_error_mm, rel=1e-9)


def test_at_pose_takes_position_and_axis():
    planned = stage_pose("standoff", AXIS, "advance", 20.0, ROLL)
    near = planned.copy()
    near[:3, 3] += [1.0, 0.0, 0.0]
    assert at_pose(near, planned)[0] and not at_pose(near, planned, tolerance_mm=0.5)[0]
    rolled = make_transform(planned[:3, :3] @ axis_angle_transform([0, 0, 1], 1.0)[:3, :3], planned[:3, 3])
    assert at_pose(rolled, planned)[0]  # the roll about the needle is free
    tilted = make_transform(
        axis_angle_transform([1, 0, 0], np.radians(5))[:3, :3] @ planned[:3, :3], planned[:3, 3]
    )
    assert not at_pose(tilted, planned)[0]


def test_entry_and_target_closer_than_a_millimetre_are_refused():
    with pytest.raises(DegenerateDataError):
        NeedleAxis(np.zeros(3), np.array([0.0, 0.0, 0.5]))


def _stage(**changes):
    values = dict(
        stage="insert",
        planned_tracker_from_needle=np.eye(4),
        measured_tracker_from_needle=np.eye(4),
        joints_rad=np.zeros(6),
        tip_error_mm=0.1,
        entry_error_mm=0.2,
        target_error_mm=0.1,
        direction_error_deg=0.3,
    )
    return StageMeasurement(**{**values, **changes})


def _result(**changes):
    values = dict(
        plan_name="Plan",
        image_frame="image_lps",
        entry_in_image=np.zeros(3),
        target_in_image=np.ones(3),
        tracker_frame="tracker",
        entry_in_tracker=np.zeros(3),
        target_in_tracker=np.ones(3),
        registration="tracker_from_image_ras from reg.tfm",
        insertion="advance",
        standoff_mm=20.0,
        stages=(_stage(),),
        predicted_entry_error_mm=0.4,
        predicted_target_error_mm=0.4,
        predicted_direction_error_deg=0.5,
    )
    return GuidanceResult(**{**values, **changes})


def test_the_record_reads_back_what_it_wrote():
    result = _result(interrupted=True, interruption="stopped")
    again = GuidanceResult.from_dict(json.loads(json.dumps(result.to_dict())))
    assert again.to_dict() == result.to_dict() and again.target_error_mm == pytest.approx(0.1)


@pytest.mark.parametrize(
    "make, words",
    [
        (lambda: _stage(target_error_mm=float("nan")), "target_error_mm"),
        (lambda: _stage(stage="retract"), "standoff or insert"),
        (lambda: _result(predicted_target_error_mm=float("inf")), "predicted_target_error_mm"),
        (lambda: _result(insertion="push"), "advance or hold"),
    ],
)
def test_the_record_refuses_what_is_not_a_guidance(make, words):
    with pytest.raises(InvalidInputError, match=words):
        make()


def test_a_file_of_another_schema_is_refused():
    with pytest.raises(InvalidInputError, match="spacecal.guidance"):
        GuidanceResult.from_dict({"schema": "spacecal.verification"})
