"""``spacecal touch`` on the simulated tracker: the simulated hand places the pointer on each of
the phantom's fiducials, the touches are registered, and the registration is compared with the
world's true ``tracker_from_image``; bad input is one line."""

import json
from pathlib import Path

import numpy as np
import pytest

from spacecal import app
from spacecal.cli.main import main
from spacecal.geometry.transforms import apply_transform
from spacecal.io.touched_points import read_touched_file, read_touched_points
from spacecal.registration.points import predicted_tre
from spacecal.sim.scenario import DEFAULT_SCENARIO, load_scenario
from spacecal.sim.tools import POINTER_TIP_ERROR_MM, pointer_geometry
from spacecal.sim.world import build_world
from spacecal.workflows.pointer_touches import TouchRejectedError
from tests.app.conftest import keep_simulated_devices

LINE = Path(__file__).parents[1] / "io" / "data" / "slicer_line.mrk.json"
#: Frames a touch averages (the command's default).
TOUCH_FRAMES = 20
#: The world whose tracker has white noise only.
WHITE = "paper-white"


def write_fiducials(path, fiducials_lps):
    """A Slicer markups point list of ``fiducials_lps`` (label -> (3,) mm, LPS)."""
    schema = json.loads(LINE.read_text())["@schema"]
    points = [{"label": k, "position": list(map(float, v))} for k, v in fiducials_lps.items()]
    markup = {"type": "Fiducial", "coordinateSystem": "LPS", "controlPoints": points}
    path.write_text(json.dumps({"@schema": schema, "markups": [markup]}))
    return path


@pytest.fixture
def phantom_fiducials(tmp_path):
    world = build_world(load_scenario(DEFAULT_SCENARIO))
    return write_fiducials(tmp_path / "fiducials.mrk.json", world.phantom.fiducials_in_image)


@pytest.fixture
def worlds(monkeypatch):
    """The simulated worlds the command opens, kept for the truth."""
    return keep_simulated_devices(monkeypatch, lambda world, robot: world)


def test_touches_register_the_image_as_the_truth_within_the_predicted_tre(
    phantom_fiducials, tmp_path, worlds
):
    touched, tfm = tmp_path / "touched.csv", tmp_path / "ImageToTracker.tfm"
    prompts = []
    # the white-noise world (the tracker's noise only, no volumetric bias): its phantom is the
    # default world's (the phantom is laid out from the arm's home and the seed)
    settings = app.TouchCommandSettings(
        fiducials=str(phantom_fiducials), output=str(touched), registration_output=str(tfm), scenario=WHITE
    )
    result = app.touch(settings, before_touch=prompts.append)
    ((world,),) = [worlds]
    phantom = world.phantom
    assert prompts == list(phantom.fiducials_in_image)
    frame, points = read_touched_points(touched)
    assert frame == "tracker" and list(points) == prompts
    registration = result.record.registration
    # the random error of a touch: the tracker's sphere noise carried to the pointer's tip
    # (Fitzpatrick's TRE of the pointer's spheres at its tip), averaged over the touch's frames;
    # its FLE gives Fitzpatrick's TRE of the registration. The pointer's pivot-calibration error
    # is a bias of at most its length that no FRE shows: the pointer is held in similar
    # orientations, so it moves every touch alike
    default = build_world(load_scenario(DEFAULT_SCENARIO)).phantom.fiducials_in_image
    assert all(np.allclose(default[k], v) for k, v in phantom.fiducials_in_image.items())
    tip = world.pointer_from_tip_true[:3, 3]
    per_frame = predicted_tre(
        pointer_geometry().spheres_in_marker, tip[None], world.scenario.white_noise_rms_mm
    )[0]
    tip_error = float(np.linalg.norm(world.pointer_from_tip[:3, 3] - tip))
    fle = float(per_frame / np.sqrt(TOUCH_FRAMES))
    fiducials = np.array(list(phantom.fiducials_in_image.values()))
    centroid = fiducials.mean(axis=0)
    expected_tre = float(predicted_tre(fiducials, centroid[None], fle)[0])
    error = float(
        np.linalg.norm(
            apply_transform(registration.tracker_from_image, centroid)
            - apply_transform(phantom.tracker_from_image, centroid)
        )
    )
    print(
        f"touch (sim): FLE from the noise {fle:.3f} mm (tip noise per frame {per_frame:.3f}, pivot error "
        f"{tip_error:.3f}); FRE {registration.pointer.fre_rms_mm:.3f} mm; predicted TRE at the centroid "
        f"{expected_tre:.3f} (reported {result.record.predicted_tre_mm:.3f}); true error there {error:.3f} mm"
    )
    # the TRE is a 3-D RMS: beyond three times it is past the 99.8th percentile of chi with 3;
    # the pivot's error is drawn with the simulated pointer's stated accuracy, which the
    # reported TRE carries and the touched file states
    assert error < 3 * np.hypot(expected_tre, POINTER_TIP_ERROR_MM)
    assert result.record.predicted_tre_mm >= POINTER_TIP_ERROR_MM
    assert read_touched_file(touched).tip_accuracy_mm == pytest.approx(POINTER_TIP_ERROR_MM)
    assert any("the simulated pointer's stated accuracy" in line for line in result.lines)
    assert any("FRE" in line and "predicted TRE at the fiducials' centroid" in line for line in result.lines)
    # plan-from-slicer reads the touches, and the Slicer transform, as the same registration
    from spacecal.io.slicer_registration import read_slicer_registration

    again = read_slicer_registration(tfm)
    lps_from_ras = np.diag([-1.0, -1.0, 1.0, 1.0])
    assert np.allclose(again.tracker_from_image @ lps_from_ras, registration.tracker_from_image, atol=1e-6)


def test_the_command_line_touches_and_prompts(phantom_fiducials, tmp_path, worlds, capsys):
    touched = tmp_path / "touched.csv"
    code = main(["touch", "--tracker", "sim", "--fiducials", str(phantom_fiducials), "-o", str(touched)])
    out = capsys.readouterr().out
    assert code == 0 and out.count("touch fiducial") == 6 and "and hold still" in out
    assert f"wrote {touched}" in out and "FRE" in out
    plan_argv = [
        "plan-from-slicer",
        str(LINE),
        "--fiducials",
        str(phantom_fiducials),
        "--touched",
        str(touched),
    ]
    # the touched file is the one plan-from-slicer reads (its plan's points are not the phantom's)
    assert main(plan_argv) == 0, capsys.readouterr().err


def test_a_stated_pointer_tip_accuracy_reaches_the_predicted_tre(phantom_fiducials, tmp_path, worlds, capsys):
    touched = tmp_path / "touched.csv"
    argv = ["touch", "--fiducials", str(phantom_fiducials), "-o", str(touched)]
    assert main([*argv, "--pointer-tip-accuracy-mm", "0.75"]) == 0
    out = capsys.readouterr().out
    assert "0.750 mm RMS: stated with --pointer-tip-accuracy-mm" in out
    assert read_touched_file(touched).tip_accuracy_mm == pytest.approx(0.75)
    plan = tmp_path / "plan.json"
    argv = ["plan-from-slicer", str(LINE), "--fiducials", str(phantom_fiducials), "--touched", str(touched)]
    assert main([*argv, "-o", str(plan)]) == 0, capsys.readouterr().err
    registration = json.loads(plan.read_text())["registration"]
    assert registration["pointer_tip_accuracy_mm"] == pytest.approx(0.75)
    assert registration["predicted_tre_at_target_mm"] >= 0.75
    refused = tmp_path / "u.csv"
    bad = [
        "touch",
        "--fiducials",
        str(phantom_fiducials),
        "-o",
        str(refused),
        "--pointer-tip-accuracy-mm",
        "-1",
    ]
    assert main(bad) == 1
    assert "--pointer-tip-accuracy-mm must be 0 to" in capsys.readouterr().err
    assert not refused.exists()


def run_one_line(argv, capsys):
    code = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    return code, err


def test_bad_input_is_one_line(phantom_fiducials, tmp_path, capsys, worlds):
    touched = str(tmp_path / "t.csv")
    code, err = run_one_line(["touch", "--fiducials", str(tmp_path / "none.mrk.json"), "-o", touched], capsys)
    assert code == 1 and len(err) == 1 and "none.mrk.json" in err[0]
    world = build_world(load_scenario(DEFAULT_SCENARIO))
    two = dict(list(world.phantom.fiducials_in_image.items())[:2])
    few = write_fiducials(tmp_path / "two.mrk.json", two)
    code, err = run_one_line(["touch", "--fiducials", str(few), "-o", touched], capsys)
    assert code == 1 and len(err) == 1 and "at least 3 fiducials" in err[0]
    code, err = run_one_line(
        ["touch", "--fiducials", str(phantom_fiducials), "-o", touched, "--max-fre-mm", "0.01"], capsys
    )
    assert code == 1 and len(err) == 1 and "FRE" in err[0] and "--accept-high-fre" in err[0]
    assert Path(touched).exists()  # the touches were written before the registration was refused
    code, err = run_one_line(
        [
            "touch",
            "--fiducials",
            str(phantom_fiducials),
            "-o",
            touched,
            "--force",
            "--max-fre-mm",
            "0.01",
            "--accept-high-fre",
        ],
        capsys,
    )
    assert code == 0
    code, err = run_one_line(
        ["touch", "--tracker", "ndi://127.0.0.1:1", "--fiducials", str(phantom_fiducials), "-o", touched],
        capsys,
    )
    assert code == 1 and len(err) == 1 and "--pointer-tip" in err[0]
    code, err = run_one_line(
        [
            "touch",
            "--pointer-tool",
            "stylus",
            "--fiducials",
            str(phantom_fiducials),
            "-o",
            touched,
            "--force",
        ],
        capsys,
    )
    assert code == 1 and len(err) == 1 and "stylus" in err[0]


def test_a_pointer_not_seen_is_one_line_and_the_touches_before_are_kept(
    phantom_fiducials, tmp_path, worlds, monkeypatch
):
    touched = tmp_path / "touched.csv"
    labels = []

    def away_at_the_fourth(label):
        labels.append(label)
        if len(labels) == 4:
            worlds[0].put_pointer_away()

    settings = app.TouchCommandSettings(fiducials=str(phantom_fiducials), output=str(touched), wait_s=2.0)
    with pytest.raises(TouchRejectedError, match="not seen") as caught:
        app.touch(settings, before_touch=away_at_the_fourth)
    assert "\n" not in str(caught.value) and "3 touches before it kept" in str(caught.value)
    assert not touched.exists()
    _, kept = read_touched_points(tmp_path / "touched.incomplete.csv")
    assert list(kept) == labels[:3]
