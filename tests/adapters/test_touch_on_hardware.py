"""``spacecal touch`` through the real NDI client on the protocol fake: the prompt before each
touch asks the fake world (its control port) to hold the pointer on that fiducial; the
registration is compared with the fake's true ``tracker_from_image_lps``."""

import json

import numpy as np
import pytest

pytest.importorskip("ndicapy")

from spacecal import app
from spacecal.geometry.transforms import apply_transform
from spacecal.io.ndi_rom import rom_bytes
from spacecal.io.results_json import write_json
from spacecal.records import PivotResult
from spacecal.registration.points import predicted_tre
from spacecal.sim.tools import pointer_geometry
from spacecal.workflows.pointer_touches import TouchRejectedError

from ..app.test_touch import TOUCH_FRAMES, write_fiducials

#: Real client libraries against the protocol fakes, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime


def test_touch_through_ndi_registers_the_phantom_as_the_truth(world, rom_file, tmp_path):
    truth = world.truth()
    phantom = json.loads(world.control("phantom"))
    fiducials = write_fiducials(tmp_path / "fiducials.mrk.json", phantom["fiducials_in_image_lps_mm"])
    pointer_rom = tmp_path / "pointer.rom"
    pointer_rom.write_bytes(rom_bytes(pointer_geometry().spheres_in_marker))
    tip = np.asarray(truth["pointer_from_tip"])[:3, 3]
    pivot = tmp_path / "pivot.json"
    write_json(PivotResult("aos", tip, np.zeros(3), np.array([0.1, 0.1, 0.1])).to_dict(), pivot)
    settings = app.TouchCommandSettings(
        fiducials=str(fiducials),
        output=str(tmp_path / "touched.csv"),
        tracker=f"ndi://{world.info['host']}:{world.info['ndi_port']}",
        rom=(str(rom_file), str(pointer_rom)),
        pointer_tip=str(pivot),
        wait_s=10.0,
    )
    prompts = []

    def hold_it_there(label):
        prompts.append(label)
        assert world.control(f"pointer touch {label}") == f"OK {label}"

    result = app.touch(settings, before_touch=hold_it_there)
    assert prompts == list(phantom["fiducials_in_image_lps_mm"])
    registration = result.record.registration
    points = np.array(list(phantom["fiducials_in_image_lps_mm"].values()))
    centroid = points.mean(axis=0)
    error = float(
        np.linalg.norm(
            apply_transform(registration.tracker_from_image, centroid)
            - apply_transform(np.array(phantom["tracker_from_image_lps"]), centroid)
        )
    )
    # as on the simulated tracker (tests/app/test_touch.py): the random FLE from the fake's sphere
    # noise at the tip over a touch's frames, Fitzpatrick's TRE from it; the pivot error a bias
    noise = truth["scenario"]["white_noise_rms_mm"]
    per_frame = predicted_tre(
        pointer_geometry().spheres_in_marker, np.asarray(truth["pointer_from_tip_true"])[:3, 3][None], noise
    )[0]
    expected = float(predicted_tre(points, centroid[None], per_frame / np.sqrt(TOUCH_FRAMES))[0])
    tip_error = float(np.linalg.norm(tip - np.asarray(truth["pointer_from_tip_true"])[:3, 3]))
    print(
        f"touch (NDI fake): FRE {registration.pointer.fre_rms_mm:.3f} mm, predicted TRE "
        f"{result.record.predicted_tre_mm:.3f}; from the noise {expected:.3f} + pivot error {tip_error:.3f}; "
        f"true error at the centroid {error:.3f} mm"
    )
    assert error < 3 * expected + tip_error


def test_a_pointer_put_away_is_one_line(world, rom_file, tmp_path):
    phantom = json.loads(world.control("phantom"))
    fiducials = write_fiducials(tmp_path / "fiducials.mrk.json", phantom["fiducials_in_image_lps_mm"])
    pointer_rom = tmp_path / "pointer.rom"
    pointer_rom.write_bytes(rom_bytes(pointer_geometry().spheres_in_marker))
    pivot = tmp_path / "pivot.json"
    tip = np.asarray(world.truth()["pointer_from_tip"])[:3, 3]
    write_json(PivotResult("aos", tip, np.zeros(3), np.array([0.1, 0.1, 0.1])).to_dict(), pivot)
    settings = app.TouchCommandSettings(
        fiducials=str(fiducials),
        output=str(tmp_path / "touched.csv"),
        tracker=f"ndi://{world.info['host']}:{world.info['ndi_port']}",
        rom=(str(rom_file), str(pointer_rom)),
        pointer_tip=str(pivot),
        wait_s=2.0,
    )
    world.control("pointer away")
    with pytest.raises(TouchRejectedError, match="not seen") as caught:
        app.touch(settings)
    assert "\n" not in str(caught.value)
