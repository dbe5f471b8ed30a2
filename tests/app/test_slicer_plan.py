"""``plan-from-slicer``: a Slicer plan with a Slicer registration file or touched fiducials, through
the app and the command line, and one line for each bad input."""

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from spacecal import app
from spacecal.cli import main
from spacecal.core.errors import InvalidInputError
from spacecal.geometry.transforms import apply_transform, invert_transform, make_transform
from spacecal.io.slicer import write_slicer_transform
from spacecal.records.needle_plan import NeedlePlan

DATA = Path(__file__).parents[1] / "io" / "data"
LINE = DATA / "slicer_line.mrk.json"
LPS = np.diag([-1.0, -1.0, 1.0, 1.0])
TRACKER_FROM_IMAGE_LPS = make_transform(
    Rotation.from_rotvec([0.7, 0.2, -1.1]).as_matrix(), [12.0, -150.0, -1420.0]
)
ENTRY_LPS, TARGET_LPS = np.array([-31.25, 42.5, 118.75]), np.array([-12.5, 61.25, 62.5])
FIDUCIALS_LPS = {
    "F-1": [-60.0, 20.0, 10.0],
    "F-2": [55.0, 30.0, -5.0],
    "F-3": [0.0, -70.0, 25.0],
    "F-4": [10.0, 15.0, 80.0],
}


def _slicer_registration(folder, name="TrackerToRAS.tfm"):
    """The registration as Slicer would save it: the to-parent of TrackerToRAS is image_ras_from_tracker."""
    image_ras_from_tracker = LPS @ invert_transform(TRACKER_FROM_IMAGE_LPS)
    return write_slicer_transform(image_ras_from_tracker, folder / name)


def _pointer_files(folder, shift_mm=(0.0, 0.0, 0.0)):
    fiducials = folder / "fiducials.mrk.json"
    schema = json.loads(LINE.read_text())["@schema"]
    points = [{"label": k, "position": v} for k, v in FIDUCIALS_LPS.items()]
    fiducials.write_text(
        json.dumps(
            {
                "@schema": schema,
                "markups": [{"type": "Fiducial", "coordinateSystem": "LPS", "controlPoints": points}],
            }
        )
    )
    touched = folder / "touched.csv"
    rows = ["label,x_in_tracker_mm,y_in_tracker_mm,z_in_tracker_mm"]
    for index, (label, point) in enumerate(FIDUCIALS_LPS.items()):
        p = apply_transform(TRACKER_FROM_IMAGE_LPS, point) + (np.array(shift_mm) if index == 2 else 0.0)
        rows.append(f"{label},{float(p[0])!r},{float(p[1])!r},{float(p[2])!r}")
    touched.write_text("\n".join(rows) + "\n")
    return fiducials, touched


def test_a_slicer_registration_file_brings_the_plan_to_the_tracker(tmp_path):
    registration = _slicer_registration(tmp_path)
    result = app.plan_from_slicer(app.PlanFromSlicerSettings(plan=str(LINE), registration=str(registration)))
    located = result.record
    assert located.registration.name == "tracker_from_image_ras"
    assert np.allclose(
        located.entry_in_tracker, apply_transform(TRACKER_FROM_IMAGE_LPS, ENTRY_LPS), atol=1e-9
    )
    assert np.allclose(
        located.target_in_tracker, apply_transform(TRACKER_FROM_IMAGE_LPS, TARGET_LPS), atol=1e-9
    )
    assert located.predicted_tre_at_target_mm is None  # a file says nothing of its fiducials
    assert any(line.startswith("needle length: 62.19 mm") for line in result.lines)


def test_the_same_registration_named_the_other_way_needs_its_role(tmp_path):
    image_to_tracker = write_slicer_transform(TRACKER_FROM_IMAGE_LPS @ LPS, tmp_path / "reg.tfm")
    with pytest.raises(InvalidInputError, match="--registration-maps"):
        app.plan_from_slicer(app.PlanFromSlicerSettings(plan=str(LINE), registration=str(image_to_tracker)))
    settings = app.PlanFromSlicerSettings(
        plan=str(LINE), registration=str(image_to_tracker), registration_maps="image-to-tracker"
    )
    located = app.plan_from_slicer(settings).record
    assert np.allclose(
        located.entry_in_tracker, apply_transform(TRACKER_FROM_IMAGE_LPS, ENTRY_LPS), atol=1e-9
    )


def test_a_pointer_registration_gives_the_predicted_tre_at_the_target(tmp_path):
    fiducials, touched = _pointer_files(tmp_path, shift_mm=(0.0, 0.8, 0.0))
    settings = app.PlanFromSlicerSettings(plan=str(LINE), fiducials=str(fiducials), touched=str(touched))
    located = app.plan_from_slicer(settings).record
    pointer = located.registration.pointer
    assert located.registration.name == "tracker_from_image_lps" and 0.1 < pointer.fre_rms_mm < 0.8
    assert located.predicted_tre_at_target_mm == pytest.approx(
        located.registration.pointer.fle_rms_mm
        * np.sqrt(
            (1 + sum(_tre_ratio(np.array(list(FIDUCIALS_LPS.values())), TARGET_LPS)) / 3) / len(FIDUCIALS_LPS)
        )
    )


def _tre_ratio(fiducials, target):
    """sum_k d_k^2 / f_k^2 of Fitzpatrick–West–Maurer, written out again for the check."""
    centred = fiducials - fiducials.mean(axis=0)
    _, _, axes = np.linalg.svd(centred)
    t = target - fiducials.mean(axis=0)
    for axis in axes:
        f_sq = np.mean(np.sum((centred - np.outer(centred @ axis, axis)) ** 2, axis=1))
        yield np.sum((t - (t @ axis) * axis) ** 2) / f_sq


def test_a_high_fre_is_refused_unless_accepted(tmp_path):
    fiducials, touched = _pointer_files(tmp_path, shift_mm=(0.0, 9.0, 0.0))
    settings = dict(plan=str(LINE), fiducials=str(fiducials), touched=str(touched))
    with pytest.raises(InvalidInputError, match="above its limit"):
        app.plan_from_slicer(app.PlanFromSlicerSettings(**settings))
    result = app.plan_from_slicer(app.PlanFromSlicerSettings(**settings, accept_high_fre=True))
    assert any("used on request" in note for note in result.notes)


def test_the_plan_json_reads_back_and_keeps_its_frame(tmp_path):
    registration = _slicer_registration(tmp_path)
    output = tmp_path / "plan.json"
    app.plan_from_slicer(
        app.PlanFromSlicerSettings(plan=str(LINE), registration=str(registration), output=str(output))
    )
    data = json.loads(output.read_text())
    plan = NeedlePlan.from_dict(data)
    assert plan.image_frame == "image_lps" and np.array_equal(plan.entry_in_image, ENTRY_LPS)
    assert np.allclose(
        data["entry_in_tracker_mm"], apply_transform(TRACKER_FROM_IMAGE_LPS, ENTRY_LPS), atol=1e-9
    )
    again = app.plan_from_slicer(app.PlanFromSlicerSettings(plan=str(output), registration=str(registration)))
    assert np.allclose(again.record.entry_in_tracker, data["entry_in_tracker_mm"], atol=1e-12)
    # a plan whose image frame is not the registration's is refused
    data["image_frame"] = "image"
    output.write_text(json.dumps(data))
    with pytest.raises(InvalidInputError, match="must name the same image frame"):
        app.plan_from_slicer(app.PlanFromSlicerSettings(plan=str(output), registration=str(registration)))


def test_the_command_line_prints_every_frame(tmp_path, capsys, white_simulation):
    from spacecal.estimators import calibrate
    from spacecal.io.results_json import write_calibration

    calibration = calibrate(white_simulation.recording)
    cal = write_calibration(calibration, tmp_path / "cal.json")
    registration = _slicer_registration(tmp_path)
    code = main(
        ["plan-from-slicer", str(LINE), "--registration", str(registration), "--calibration", str(cal)]
    )
    out, err = capsys.readouterr()
    assert code == 0, err
    base_row = next(line for line in out.splitlines() if line.startswith("base "))
    entry_in_base = apply_transform(
        invert_transform(calibration.tracker_from_base) @ TRACKER_FROM_IMAGE_LPS, ENTRY_LPS
    )
    assert np.allclose([float(v) for v in base_row.split()[1:4]], entry_in_base, atol=0.006)
    assert "needle direction in base:" in out


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--registration", "{reg}", "--fiducials", "{fid}"], "one of the two"),
        (["--fiducials", "{fid}"], "needs both --fiducials and --touched"),
        (
            [
                "--registration",
                "{data}/slicer_forum_topic_270.tfm",
                "--registration-maps",
                "tracker-to-image",
            ],
            "not rigid",
        ),
        (
            [
                "--registration",
                "{data}/slicer_rotationAndAffine.tfm",
                "--registration-maps",
                "tracker-to-image",
            ],
            "holds 2",
        ),
    ],
)
def test_bad_input_is_one_line_and_exit_1(tmp_path, capsys, argv, message):
    registration = _slicer_registration(tmp_path)
    fiducials, _ = _pointer_files(tmp_path)
    filled = [a.format(reg=registration, fid=fiducials, data=DATA) for a in argv]
    code = main(["plan-from-slicer", str(LINE), *filled])
    _, err = capsys.readouterr()
    assert code == 1 and message in err and len(err.strip().splitlines()) == 1, err


def test_a_markups_file_without_a_coordinate_system_exits_1_naming_the_option(tmp_path, capsys):
    data = json.loads(LINE.read_text())
    del data["markups"][0]["coordinateSystem"]
    plan = tmp_path / "plan.mrk.json"
    plan.write_text(json.dumps(data))
    registration = _slicer_registration(tmp_path)
    assert main(["plan-from-slicer", str(plan), "--registration", str(registration)]) == 1
    assert "--coordinate-system" in capsys.readouterr().err
    assert (
        main(
            ["plan-from-slicer", str(plan), "--registration", str(registration), "--coordinate-system", "LPS"]
        )
        == 0
    )
