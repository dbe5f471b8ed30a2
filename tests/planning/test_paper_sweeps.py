import numpy as np
import pytest

from spacecal.core.errors import DegenerateDataError, UnreachableError
from spacecal.geometry.transforms import invert_transform
from spacecal.planning.motion import MotionLimits, trapezoid_duration, trapezoid_progress
from spacecal.planning.paper_sweeps import PaperSweepSettings, plan_paper_sweeps
from spacecal.sim.motion import plan_for_world
from spacecal.sim.scenario import PRESETS
from spacecal.sim.world import build_world


def test_trapezoid_profile_is_monotone_and_complete():
    duration, accel_time = trapezoid_duration(500.0, 100.0, 400.0)
    assert duration == pytest.approx(5.25) and accel_time == pytest.approx(0.25)
    s = trapezoid_progress(np.linspace(0, duration, 200), duration, accel_time)
    assert s[0] == 0 and s[-1] == pytest.approx(1.0) and np.all(np.diff(s) >= 0)
    short, short_accel = trapezoid_duration(10.0, 100.0, 400.0)
    assert short == pytest.approx(2 * np.sqrt(10 / 400)) and short_accel == short / 2


def test_paper_plan_takes_about_a_minute_and_keeps_the_tcp_origin_fixed():
    world = build_world(PRESETS["paper-realistic"])
    plan = plan_for_world(world)
    assert 45.0 < plan.motion_time_s < 75.0  # the paper: "about one minute"
    home = plan.home_base_from_tcp
    for move in plan.moves:
        poses = move.poses_at(np.linspace(0, move.duration_s, 9))
        if move.label.startswith("rot_"):
            assert np.allclose(poses[:, :3, 3], home[:3, 3], atol=1e-9)
        else:
            assert np.allclose(poses[:, :3, :3], home[:3, :3], atol=1e-12)
    assert set(plan.extents) == {"rot_x", "rot_y", "rot_z", "lin_x", "lin_y", "lin_z"}


def test_sweeps_are_shrunk_to_what_the_tracker_sees_and_the_plan_says_so():
    world = build_world(PRESETS["paper-realistic"])
    plan = plan_for_world(world)
    shrunk = [
        label
        for label, (lo, hi) in plan.extents.items()
        if (label.startswith("rot") and min(-lo, hi) < 90) or (label.startswith("lin") and min(-lo, hi) < 250)
    ]
    assert shrunk, "the default layout is expected to limit some sweeps"
    for label in shrunk:
        assert any(m.startswith(label) and "marker visibility" in m for m in plan.messages)
    # every planned sampled pose is predicted visible
    from spacecal.planning.visibility import VisibilityModel

    visibility = VisibilityModel(world.tracker, world.marker, world.tracker_from_base, world.tcp_from_marker)
    for move in plan.moves:
        if move.label != "transit":
            assert visibility.visible(move.poses_at(np.linspace(0, move.duration_s, 15))).all()


def test_joint_speed_limit_stretches_moves():
    world = build_world(PRESETS["paper-white"])
    fast = plan_paper_sweeps(world.nominal_model, world.home_joints_rad, PaperSweepSettings())
    slow = plan_paper_sweeps(
        world.nominal_model,
        world.home_joints_rad,
        PaperSweepSettings(limits=MotionLimits(joint_speed_rad_s=0.1)),
    )
    assert slow.motion_time_s > 1.5 * fast.motion_time_s


def test_infeasible_home_and_too_small_sweeps_are_refused():
    world = build_world(PRESETS["paper-white"])
    from spacecal.planning.visibility import VisibilityModel

    behind = VisibilityModel(
        world.tracker, world.marker, invert_transform(world.tracker_from_base), world.tcp_from_marker
    )
    with pytest.raises(UnreachableError, match="not visible"):
        plan_paper_sweeps(world.nominal_model, world.home_joints_rad, visibility=behind)
    with pytest.raises(DegenerateDataError, match="rotation is feasible"):
        plan_paper_sweeps(
            world.nominal_model, world.home_joints_rad, PaperSweepSettings(rotation_each_way_deg=5.0)
        )
