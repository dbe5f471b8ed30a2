"""The simulated world's further tools: the pointer on the phantom's fiducials, the reference on
the needle guide, measured with the tracker's noise model; the marker's frames unchanged."""

import dataclasses

import numpy as np
import pytest

from spacecal.core.errors import InvalidInputError
from spacecal.geometry.transforms import apply_transform, invert_transform
from spacecal.models.kinematics import forward_kinematics
from spacecal.registration.points import predicted_tre
from spacecal.sim.devices import SimulatedRobot, SimulatedTracker
from spacecal.sim.scenario import load_scenario
from spacecal.sim.tools import POINTER, REFERENCE
from spacecal.sim.world import build_world

FRAMES = 20


def quiet_world(**changes):
    """paper-white (white sphere noise only: no error field, no bias) without dropouts."""
    scenario = dataclasses.replace(load_scenario("paper-white"), dropout_probability=0.0, **changes)
    assert scenario.volumetric_error_rms_mm == 0 and scenario.depth_scale_per_100mm == 0
    return build_world(scenario)


def tip_noise_rms_mm(world, geometry, point_in_tool):
    """The RMS 3-D error a rigid fit of the tool's spheres leaves at a point of the tool, from the
    scenario's white sphere noise (Fitzpatrick, West, Maurer 1998: FLE = the sphere noise)."""
    return float(
        predicted_tre(geometry.spheres_in_marker, [point_in_tool], world.scenario.white_noise_rms_mm)[0]
    )


def test_the_pointer_on_fiducial_k_gives_its_true_position_within_the_noise():
    world = quiet_world()
    tracker = SimulatedTracker(world, SimulatedRobot(world), tools=(POINTER,))
    tip = world.pointer_from_tip_true
    per_frame = tip_noise_rms_mm(world, world.tools[POINTER], tip[:3, 3])
    truth = world.phantom.fiducials_in_tracker
    for k, label in enumerate(world.phantom.labels, start=1):
        held = world.place_pointer(k)
        assert np.allclose(apply_transform(held @ tip, [0.0, 0.0, 0.0]), truth[label], atol=1e-9)
        tips = np.array([(tracker.next_frame(1.0).tools[POINTER] @ tip)[:3, 3] for _ in range(FRAMES)])
        scatter = np.sqrt(np.mean(np.sum((tips - tips.mean(axis=0)) ** 2, axis=1)))
        assert 0.5 * per_frame < scatter < 1.6 * per_frame  # the injected noise, at the tip
        # the mean of FRAMES frames: 4 sigma of its 3-D RMS
        assert np.linalg.norm(tips.mean(axis=0) - truth[label]) < 4 * per_frame / np.sqrt(FRAMES)


def test_the_pointer_put_away_is_not_seen_and_an_unknown_fiducial_is_one_line():
    world = quiet_world()
    tracker = SimulatedTracker(world, SimulatedRobot(world), tools=(POINTER, REFERENCE))
    world.place_pointer("F-2")
    assert tracker.next_frame(1.0).tools[POINTER] is not None
    world.put_pointer_away()
    frame = tracker.next_frame(1.0)
    assert frame.tools[POINTER] is None and frame.tool_statuses[POINTER] == "missing"
    assert frame.tools[REFERENCE] is not None
    with pytest.raises(InvalidInputError, match="no fiducial 'F-9'"):
        world.place_pointer("F-9")
    with pytest.raises(InvalidInputError, match="no tool 'stylus'"):
        SimulatedTracker(world, SimulatedRobot(world), tools=("stylus",))


def test_the_guide_reference_measures_the_needle_within_the_noise():
    world = quiet_world()
    robot = SimulatedRobot(world)
    tracker = SimulatedTracker(world, robot, tools=(REFERENCE,))
    needle_in_reference = world.reference_from_needle[:3, 3]
    per_frame = tip_noise_rms_mm(world, world.tools[REFERENCE], needle_in_reference)
    errors, rotations = [], []
    for _ in range(50):
        frame = tracker.next_frame(1.0)
        true_reference = tracker.tool_truth[frame.time_s][REFERENCE]
        measured_needle = frame.tools[REFERENCE] @ world.reference_from_needle
        true_needle = true_reference @ world.reference_from_needle
        errors.append(np.linalg.norm(measured_needle[:3, 3] - true_needle[:3, 3]))
        rotations.append(np.linalg.norm(measured_needle[:3, :3] - true_needle[:3, :3]))
    # the reference's definition of the needle is its own: with the arm at rest the needle it
    # measures is where the TCP really is (repeatability aside, 0.1 mm)
    true_tcp = world.tracker_from_base @ forward_kinematics(world.true_model, world.home_joints_rad)
    assert np.linalg.norm(true_needle[:3, 3] - true_tcp[:3, 3]) < 0.5
    rms = np.sqrt(np.mean(np.square(errors)))
    assert 0.5 * per_frame < rms < 1.6 * per_frame
    assert max(errors) < 4 * per_frame and max(rotations) < 0.05


def test_the_reference_is_not_the_marker():
    world = quiet_world()
    assert not np.allclose(world.tcp_from_reference, world.tcp_from_marker, atol=1.0)
    assert np.allclose(world.reference_from_needle, invert_transform(world.tcp_from_reference))


def test_tools_leave_the_markers_frames_as_they_were():
    plain, with_tools = quiet_world(), quiet_world()
    alone = SimulatedTracker(plain, SimulatedRobot(plain))
    beside = SimulatedTracker(with_tools, SimulatedRobot(with_tools), tools=(POINTER, REFERENCE))
    with_tools.place_pointer(1)
    for _ in range(30):
        a, b = alone.next_frame(1.0), beside.next_frame(1.0)
        assert a.tools == {} and set(b.tools) == {POINTER, REFERENCE}
        assert (a.tracker_from_marker is None) == (b.tracker_from_marker is None)
        if a.tracker_from_marker is not None:
            assert np.array_equal(a.tracker_from_marker, b.tracker_from_marker)


def test_the_phantom_is_in_view_reachable_and_its_truth_consistent():
    world = quiet_world()
    phantom = world.phantom
    assert len(phantom.labels) == world.PHANTOM_FIDUCIALS and len(phantom.paths) == world.PHANTOM_PATHS
    in_tracker = phantom.fiducials_in_tracker
    for label, point in phantom.fiducials_in_image.items():
        assert np.sum((point / phantom.head_radii_mm) ** 2) == pytest.approx(1.0)  # on the surface
        assert np.allclose(apply_transform(phantom.tracker_from_image, point), in_tracker[label])
    assert world.tracker.volume.contains(np.array(list(in_tracker.values()))).all()
    for path in phantom.paths:
        assert phantom.inside(path.target_in_image)[0]
    data = phantom.to_dict()
    assert data["image_frame"] == "image_lps" and set(data["fiducials_in_tracker_mm"]) == set(phantom.labels)
    # its own stream: the same phantom whatever was drawn before
    assert np.array_equal(build_world(world.scenario).phantom.tracker_from_image, phantom.tracker_from_image)
