"""The motion gate of a resumed acquisition: a stop in the middle of a move (the first one too)
leaves the arm between two poses of the plan, and the resumed run first takes it back to the
interrupted move's start in a straight line, checked by the gate as the move "approach"."""

import dataclasses

import numpy as np
import pytest

from spacecal import app
from spacecal.app.gate import approach_line, default_box_half_mm, gate_plan, plan_workspace
from spacecal.app.run_plan import planned_motion
from spacecal.core.errors import InvalidInputError
from spacecal.core.ports import RobotState
from spacecal.geometry.transforms import interpolate_transforms, make_transform
from spacecal.io.acquisition_progress import progress_path, write_progress
from spacecal.models.kinematics import forward_kinematics
from spacecal.planning.motion import MotionLimits, track_path
from spacecal.planning.motion_gate import MotionRefusedError
from spacecal.records import AcquisitionProgress
from spacecal.sim.motion import plan_for_world
from spacecal.sim.scenario import PRESETS
from spacecal.sim.world import build_world
from spacecal.workflows.acquisition import plan_fingerprint


@pytest.fixture(scope="module")
def set_up():
    world = build_world(PRESETS["paper-white"])
    plan = plan_for_world(world)
    model = world.controller_model
    limits = MotionLimits()
    workspace = plan_workspace(model, plan, None, default_box_half_mm(world.scenario.translation_mm / 2))
    return plan, model, limits, workspace


def standing_at(model, plan, move_index, fraction):
    """The arm stopped ``fraction`` of the way through a move, as the controller reports it."""
    move = plan.moves[move_index]
    poses = interpolate_transforms(move.start, move.end, np.linspace(0.0, fraction, 50))
    start_joints = track_path(model, [move.start], plan.home_joints_rad)[0]
    joints = track_path(model, poses, start_joints)[-1]
    return RobotState(0.0, joints, np.asarray(poses[-1]))


def test_a_stop_mid_first_move_is_resumed_through_a_gated_approach(set_up):
    plan, model, limits, workspace = set_up
    assert plan.moves[0].label == "rot_x"
    state = standing_at(model, plan, 0, 0.04)
    # the plan from where the arm stands, without the approach: refused (the reported bug)
    with pytest.raises(MotionRefusedError, match=r"move 1/\d+ \(rot_x\): continuity: it starts 0\.0 mm"):
        gate_plan(plan, model, state, limits, workspace)
    report = gate_plan(plan, model, state, limits, workspace, resuming=True)
    from_home = gate_plan(plan, model, None, limits, workspace)
    assert report.passed and report.moves == from_home.moves == len(plan.moves)
    # the approach's own points are checked besides the plan's
    assert report.points > from_home.points
    line = approach_line(plan, 0, state.base_from_tcp, limits)
    assert line.startswith(
        f"resume: a straight move back to the start of move 1/{len(plan.moves)} (rot_x), 0.0 mm"
    )
    sweep_deg = plan.extents["rot_x"][1]
    assert f"and {0.04 * sweep_deg:.1f} deg" in line, line


def test_an_approach_the_gate_refuses_is_refused_as_the_approach(set_up):
    plan, model, limits, _ = set_up
    state = standing_at(model, plan, 0, 0.04)
    # a box that holds the whole plan with 30 mm to spare, and the operator jogged the arm 50 mm
    # beyond it (along the base axis where the box is closest)
    tcp = np.array([p[:3, 3] for m in plan.moves for p in (m.start, m.end)])
    box = np.column_stack([tcp.min(axis=0) - 30.0, tcp.max(axis=0) + 30.0]).ravel()
    workspace = plan_workspace(model, plan, box)
    here = state.base_from_tcp[:3, 3]
    axis = int(np.argmin(box[1::2] - here))
    offset = np.zeros(3)
    offset[axis] = box[2 * axis + 1] - here[axis] + 50.0
    moved = make_transform(np.eye(3), offset) @ state.base_from_tcp
    path = interpolate_transforms(state.base_from_tcp, moved, np.linspace(0.0, 1.0, 100))
    away = RobotState(0.0, track_path(model, path, state.joints_rad)[-1], moved)
    with pytest.raises(MotionRefusedError) as refused:
        gate_plan(plan, model, away, limits, workspace, resuming=True)
    line = str(refused.value)
    assert line.startswith(
        f"motion refused, nothing moved: move 1/{len(plan.moves)} (approach): workspace:"
    ), line
    assert refused.value.report.moves == len(plan.moves)


def test_a_stop_in_a_later_move_is_resumed_from_it(set_up):
    plan, model, limits, workspace = set_up
    state = standing_at(model, plan, 2, 0.3)
    report = gate_plan(plan, model, state, limits, workspace, first_move=2, resuming=True)
    assert report.passed and report.moves == len(plan.moves) - 2
    assert f"to the start of move 3/{len(plan.moves)}" in approach_line(plan, 2, state.base_from_tcp, limits)


def test_a_robot_at_the_interrupted_moves_start_needs_no_approach(set_up):
    plan, _, limits, _ = set_up
    line = approach_line(plan, 3, np.asarray(plan.moves[3].start), limits)
    assert (
        line
        == f"resume: from move 4/{len(plan.moves)} ({plan.moves[3].label}); the robot stands at its start"
    )


class StandingRobot:
    """A robot that stands where a stop left it (``planned_motion`` asks only its state)."""

    def __init__(self, state):
        self._state = state

    def state(self):
        return self._state


def test_a_plan_file_run_stopped_mid_move_resumes_from_where_the_arm_stands(tmp_path):
    world = build_world(PRESETS["paper-white"])
    plan_path = tmp_path / "plan.json"
    app.plan(app.PlanSettings(budget_s=10.0, scenario="paper-white", output=str(plan_path)))
    recording = tmp_path / "rec.csv"
    settings = app.AcquireSettings(str(recording), scenario="paper-white", plan=str(plan_path))
    model = world.controller_model
    home = forward_kinematics(model, world.home_joints_rad)
    at_home = planned_motion(settings, StandingRobot(RobotState(0.0, world.home_joints_rad, home)), model)
    stopped = StandingRobot(standing_at(model, at_home, 0, 0.3))
    # a fresh run from there is refused: the arm is not at the plan's home
    with pytest.raises(InvalidInputError, match="from the plan's home"):
        planned_motion(settings, stopped, model)
    write_progress(
        AcquisitionProgress(
            plan_fingerprint(at_home), 0, len(at_home.moves), "robot safeguard stop", at_home.home_joints_rad
        ),
        progress_path(recording),
    )
    resumed = dataclasses.replace(settings, resume=True)
    plan = planned_motion(resumed, stopped, model)
    assert plan_fingerprint(plan) == plan_fingerprint(at_home)
    workspace = plan_workspace(model, plan, None)
    report = gate_plan(plan, model, stopped.state(), MotionLimits(), workspace, resuming=True)
    assert report.passed and report.moves == len(plan.moves)
