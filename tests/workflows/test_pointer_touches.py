"""Collecting pointer touches on the simulated phantom: accepted touches register to the truth;
a pointer not seen, moving, scattering or not moved on is refused with one line."""

import dataclasses

import numpy as np
import pytest

from spacecal.core.errors import DeviceError, InvalidInputError
from spacecal.geometry.transforms import apply_transform
from spacecal.io.touched_points import read_touched_points, write_touched_points
from spacecal.registration.image_fiducials import register_image_fiducials
from spacecal.registration.points import predicted_tre
from spacecal.sim.devices import SimulatedRobot, SimulatedTracker
from spacecal.sim.scenario import load_scenario
from spacecal.sim.tools import POINTER
from spacecal.sim.world import build_world
from spacecal.workflows.pointer_touches import (
    MOVING,
    NOT_MOVED_ON,
    NOT_SEEN,
    SCATTERED,
    TouchRejectedError,
    TouchSettings,
    collect_touch,
    collect_touches,
    touched_points,
)

QUICK = TouchSettings(wait_s=3.0)


def simulated(**changes):
    world = build_world(dataclasses.replace(load_scenario("paper-white"), **changes))
    return world, SimulatedTracker(world, SimulatedRobot(world), tools=(POINTER,))


def test_touches_register_to_the_true_image_within_the_predicted_tre(tmp_path):
    world, tracker = simulated()
    phantom = world.phantom
    prompted = []

    def touch(label):
        prompted.append(label)
        world.place_pointer(label)

    touches = collect_touches(tracker, POINTER, world.pointer_from_tip, phantom.labels, touch, QUICK)
    assert prompted == list(phantom.labels) == list(touches)
    assert all(
        t.frames == QUICK.frames and t.scatter_rms_mm <= QUICK.max_scatter_mm for t in touches.values()
    )
    path = write_touched_points(tmp_path / "touched.csv", touched_points(touches), comments=["simulated"])
    frame, points = read_touched_points(path)
    assert frame == "tracker" and list(points) == list(phantom.labels)
    registration = register_image_fiducials(phantom.fiducials_in_image, points, image_frame="image_lps")
    targets = np.array([p.target_in_image for p in phantom.paths])
    tre = predicted_tre(registration.pointer.fiducials_in_image, targets, registration.pointer.fle_rms_mm)
    error = np.linalg.norm(
        apply_transform(registration.tracker_from_image, targets)
        - apply_transform(phantom.tracker_from_image, targets),
        axis=1,
    )
    # Fitzpatrick's TRE covers the random part; the tip calibration's error is a bias of at most
    # its length that the FRE does not show (see tests/adapters/test_further_tools.py)
    tip_error = np.linalg.norm(world.pointer_from_tip[:3, 3] - world.pointer_from_tip_true[:3, 3])
    assert np.all(error < 3 * tre + tip_error), (error, tre, tip_error)
    # with the true tip, the random part alone
    world.put_pointer_away()
    true_touches = collect_touches(
        tracker, POINTER, world.pointer_from_tip_true, phantom.labels, touch, QUICK
    )
    exact = register_image_fiducials(
        phantom.fiducials_in_image, touched_points(true_touches), image_frame="image_lps"
    )
    tre = predicted_tre(exact.pointer.fiducials_in_image, targets, exact.pointer.fle_rms_mm)
    error = np.linalg.norm(
        apply_transform(exact.tracker_from_image, targets)
        - apply_transform(phantom.tracker_from_image, targets),
        axis=1,
    )
    assert np.all(error < 3 * tre), (error, tre)


def test_a_pointer_not_seen_is_refused():
    world, tracker = simulated()
    world.put_pointer_away()
    with pytest.raises(
        TouchRejectedError, match="^no touch of 'F-1' within 3 s: the pointer 'pointer' was not seen"
    ) as caught:
        collect_touch(tracker, POINTER, world.pointer_from_tip, "F-1", QUICK)
    assert caught.value.reason == NOT_SEEN and "\n" not in str(caught.value)
    assert isinstance(caught.value, DeviceError)


def test_a_moving_pointer_is_refused():
    world, tracker = simulated()
    world.place_pointer(1)
    world.pointer_sway_mm = 3.0
    with pytest.raises(TouchRejectedError, match="did not hold still on 'F-1'") as caught:
        collect_touch(tracker, POINTER, world.pointer_from_tip, "F-1", QUICK)
    assert caught.value.reason == MOVING


def test_scattered_frames_are_refused():
    world, tracker = simulated(white_noise_rms_mm=1.5)
    world.place_pointer(2)
    with pytest.raises(TouchRejectedError, match=r"scatter \d+\.\d+ mm RMS") as caught:
        collect_touch(tracker, POINTER, world.pointer_from_tip, "F-2", QUICK)
    assert caught.value.reason == SCATTERED


def test_a_pointer_still_on_the_last_fiducial_is_refused_and_the_touches_before_kept():
    world, tracker = simulated()
    with pytest.raises(TouchRejectedError, match="still where 'F-1' was touched") as caught:
        collect_touches(
            tracker, POINTER, world.pointer_from_tip, ["F-1", "F-2"], lambda _: world.place_pointer(1), QUICK
        )
    assert caught.value.reason == NOT_MOVED_ON and list(caught.value.touches) == ["F-1"]


def test_bad_requests_are_one_line():
    world, tracker = simulated()
    with pytest.raises(InvalidInputError, match="follows no tool 'stylus'"):
        collect_touch(tracker, "stylus", world.pointer_from_tip, "F-1", QUICK)
    with pytest.raises(InvalidInputError, match="touched twice"):
        collect_touches(tracker, POINTER, world.pointer_from_tip, ["F-1", "F-1"])
    with pytest.raises(InvalidInputError, match="pointer_from_tip"):
        collect_touch(tracker, POINTER, np.full((4, 4), np.nan), "F-1", QUICK)
    with pytest.raises(InvalidInputError, match="at least 2 frames"):
        TouchSettings(frames=1)
    with pytest.raises(InvalidInputError, match="max_scatter_mm"):
        TouchSettings(max_scatter_mm=float("nan"))
