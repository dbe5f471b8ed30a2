"""The motion gate: every motion is checked all along its path before anything moves.

Good motions pass (the paper's sweeps, stop-and-go, the check poses, plans from ``spacecal
plan``); hostile or wrong plan files are refused by ``acquire --plan --dry-run`` with exit 1
and one line naming the move and the failing check, and a refused plan never moves the
simulated robot.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from spacecal import app
from spacecal.cli import main
from spacecal.core.errors import UnreachableError
from spacecal.models.kinematics import forward_kinematics, geometric_jacobian
from spacecal.planning import motion, motion_gate
from spacecal.planning.check_poses import check_plan
from spacecal.planning.motion import TimedMove, follow_path, track_path
from spacecal.planning.motion_gate import (
    CHECKS,
    CONTINUITY_MM,
    MAX_MOVES,
    MotionRefusedError,
    RobotPermits,
    gate_motion,
    singularity_distances,
    workspace_around,
)
from spacecal.planning.stop_and_go import stop_and_go_plan
from spacecal.planning.visibility import VisibilityModel
from spacecal.sim.motion import plan_for_world
from spacecal.sim.scenario import PRESETS
from spacecal.sim.world import build_world

from .gate_cases import (
    LIMITS,
    base_pose,
    shifted,
    spin_about_tool,
    timed,
    turned,
    with_end,
    with_start,
    wrist_singular_crossing,
)

SCENARIO = "paper-realistic"


@pytest.fixture(scope="module")
def world():
    return build_world(PRESETS[SCENARIO])


@pytest.fixture(scope="module")
def sweeps(world):
    return plan_for_world(world)


def visibility_of(world):
    return VisibilityModel(world.tracker, world.marker, world.tracker_from_base, world.tcp_from_marker)


def gate(world, moves, **options):
    """The gate as ``simulate`` runs it: from the world's home, at the planners' limits."""
    model = world.controller_model
    home = forward_kinematics(model, world.home_joints_rad)
    workspace = options.pop("workspace", None) or workspace_around(model, home)
    options.setdefault("home_base_from_tcp", home)
    return gate_motion(
        model, moves, world.home_joints_rad, options.pop("commanded", LIMITS), workspace, **options
    )


# -- good motions pass --------------------------------------------------------------------
def test_the_paper_sweeps_pass_every_check_and_the_report_says_what_was_checked(world, sweeps):
    report = gate(world, sweeps.moves, visibility=visibility_of(world))
    assert report.passed, report.refusal
    assert [c.name for c in report.checks] == list(CHECKS)
    assert all(c.status == "passed" for c in report.checks), report.lines()
    # every 2 mm and 1 degree along 19 moves: about 2200 points
    assert report.moves == len(sweeps.moves) == 19 and 1500 < report.points < 4000
    stats = report.stats
    assert stats["closest_wrist_deg"] > 10 and stats["closest_elbow_deg"] > 10
    assert stats["closest_shoulder_mm"] > 100 and stats["joint_speed_fraction"] < 1
    assert stats["largest_joint_step_deg"] < 5  # far below a flip (30 deg)
    assert stats["recorded_points"] == stats["visible_points"] > 0
    lines = report.lines()
    assert lines[0].startswith(f"motion gate: {report.points} points along 19 moves")
    assert json.loads(json.dumps(report.to_dict()))["passed"] is True
    assert report.summary().startswith("motion gate: passed")


def test_stop_and_go_and_the_check_poses_pass(world, sweeps):
    model = world.controller_model
    stations = stop_and_go_plan(sweeps, model, LIMITS, 0.05, 5)
    assert gate(world, stations.moves, visibility=visibility_of(world)).passed
    check = check_plan(model, world.home_joints_rad, 3, LIMITS, 0.05)
    report = gate(world, check.moves, visibility=visibility_of(world))
    assert report.passed and report.check("visibility").status == "passed"


def test_visibility_is_not_known_without_a_tracker_pose(world, sweeps):
    report = gate(world, sweeps.moves[:3], visibility_note="no tracker pose (pass --prior)")
    assert report.passed
    assert report.check("visibility").status == "not known"
    assert "not known" in report.summary() and "--prior" in report.check("visibility").line()


def test_follow_path_is_the_branch_a_movel_follows(world, sweeps):
    """The chunked follower finds the joints of following one pose at a time, to the tolerance,
    on the longest rotation (at the gate's sampling and at the simulator's)."""
    model = world.controller_model
    move = sweeps.moves[1]  # the longest rotation
    start = track_path(model, move.start[None], world.home_joints_rad)[0]
    for count in (181, 23):
        poses = move.poses_at(np.linspace(0.0, move.duration_s, count))
        fast, solved = follow_path(model, poses, start)
        one_by_one, followed = motion._follow_pose_by_pose(model, poses, start, None, motion.PATH_TOL_MM)
        assert solved == followed == len(poses)
        np.testing.assert_allclose(fast, one_by_one, atol=1e-9)
        np.testing.assert_allclose(forward_kinematics(model, fast), poses, atol=1e-9)


def test_follow_path_stops_where_the_arm_cannot_follow(world):
    """A line out of reach is followed up to the workspace's edge, NaN after it, and
    track_path names the pose."""
    model = world.controller_model
    home = forward_kinematics(model, world.home_joints_rad)
    poses = np.repeat(home[None], 40, axis=0)
    poses[:, 0, 3] += np.linspace(0.0, 2000.0, 40)  # 2 m out along x
    joints, followed = follow_path(model, poses, world.home_joints_rad)
    assert 0 < followed < 40
    assert np.isfinite(joints[:followed]).all() and np.isnan(joints[followed:]).all()
    with pytest.raises(UnreachableError, match=f"path pose {followed} "):
        track_path(model, poses, world.home_joints_rad)


def test_singularity_distances_are_the_factors_of_the_jacobian_determinant(world):
    model = world.nominal_model
    joints = np.random.default_rng(5).uniform(-np.pi, np.pi, (50, 6))
    wrist, elbow, shoulder = singularity_distances(model, joints)
    a2, a3 = model.a_mm[1], model.a_mm[2]
    predicted = a2 * a3 * np.sin(elbow) * np.sin(wrist) * shoulder
    np.testing.assert_allclose(predicted, np.abs(np.linalg.det(geometric_jacobian(model, joints))), rtol=1e-9)


def test_a_gap_within_the_tolerance_passes_and_is_reported(world, sweeps):
    moves = list(sweeps.moves)
    moves[4] = with_start(moves[4], shifted(moves[4].start, [0.6 * CONTINUITY_MM, 0, 0]))
    report = gate(world, moves)
    assert report.passed and 0.5 < report.stats["largest_gap_mm"] < CONTINUITY_MM


def test_a_slower_plan_passes(world, sweeps):
    slower = [
        dataclasses.replace(m, duration_s=2 * m.duration_s, accel_time_s=2 * m.accel_time_s)
        for m in sweeps.moves
    ]
    assert gate(world, slower).passed


# -- wrong motions are refused, in execution order, with the move and the check -------------
def refusal(world, moves, **options):
    report = gate(world, moves, **options)
    assert not report.passed, "the motion was accepted"
    return report.refusal


def test_a_move_three_metres_out_of_reach(world, sweeps):
    home = sweeps.home_base_from_tcp
    refused = refusal(world, [*sweeps.moves, timed(home, shifted(home, [-3000.0, 0, 0]))])
    assert (refused.move, refused.check) == (20, "workspace") and "box" in refused.detail
    # with a box that allows it, the arm itself cannot get there
    wide = workspace_around(world.controller_model, home, [-1e4, 1e4, -1e4, 1e4, -1e4, 1e4], "wide")
    refused = refusal(world, [timed(home, shifted(home, [-3000.0, 0, 0]))], workspace=wide)
    assert refused.move == 1 and refused.check in ("reach", "singularities")


def test_the_reach_bound_names_the_distance(world):
    """A target beyond every link laid end to end is refused before any IK."""
    model = world.controller_model
    home = forward_kinematics(model, world.home_joints_rad)
    far = shifted(home, [0, 0, 5000.0])
    wide = workspace_around(model, home, [-1e4, 1e4, -1e4, 1e4, -1e4, 1e4], "wide")
    # a plan that starts out there: the first sample is beyond the reach bound
    refused = refusal(
        world, [timed(far, far)], workspace=wide, home_base_from_tcp=None, start_base_from_tcp=far
    )
    assert refused.check == "reach" and "from the shoulder" in refused.detail


def test_a_move_that_ends_at_the_base(world, sweeps):
    home = sweeps.home_base_from_tcp
    refused = refusal(world, [timed(home, base_pose(home))])
    assert refused.move == 1 and refused.check in ("workspace", "joint speeds", "singularities", "reach")
    # the last stretch is inside the base cylinder: with the arm able to follow, the cylinder refuses
    near = base_pose(home, (-200.0, -100.0, 100.0))
    refused = refusal(world, [timed(home, near), timed(near, base_pose(home, (-60.0, -30.0, 100.0)))])
    assert refused.check in ("workspace", "joint speeds", "singularities")


def test_below_the_base_plane(world, sweeps):
    home = sweeps.home_base_from_tcp
    refused = refusal(world, [timed(home, shifted(home, [0, 0, -home[2, 3] - 50.0]))])
    assert refused.check == "workspace" and "below the base plane" in refused.detail


def test_a_discontinuity_between_moves(world, sweeps):
    moves = list(sweeps.moves)
    moves[5] = with_start(moves[5], shifted(moves[5].start, [0, 10.0, 0]))
    refused = refusal(world, moves)
    assert (refused.move, refused.check) == (6, "continuity")
    assert "10.0 mm" in refused.detail and "previous move" in refused.detail


def test_a_rotation_gap_and_a_first_move_away_from_where_the_robot_stands(world, sweeps):
    moves = list(sweeps.moves)
    moves[2] = with_start(moves[2], turned(moves[2].start, [1, 0, 0], np.radians(3.0)))
    assert (refusal(world, moves).move, refusal(world, moves).check) == (3, "continuity")
    moves = [with_start(sweeps.moves[0], shifted(sweeps.moves[0].start, [5.0, 0, 0])), *sweeps.moves[1:]]
    refused = refusal(world, moves)
    assert (refused.move, refused.check) == (1, "continuity") and "where the robot stands" in refused.detail


def test_joint_limits(world, sweeps):
    refused = refusal(world, spin_about_tool(sweeps.home_base_from_tcp, 4))
    assert refused.check == "joint limits" and refused.move == 3 and "joint 6" in refused.detail


def test_the_robot_standing_outside_its_limits(world):
    joints = np.array(world.home_joints_rad)
    joints[5] += 2 * np.pi + 0.1
    model = world.controller_model
    home = forward_kinematics(model, joints)
    report = gate_motion(model, [timed(home, home)], joints, LIMITS, workspace_around(model, home))
    assert (report.refusal.move, report.refusal.check) == (0, "joint limits")


def test_speeds_above_the_commanded_and_the_permitted(world, sweeps):
    moves = list(sweeps.moves)
    fast = moves[13]
    moves[13] = dataclasses.replace(
        fast, duration_s=fast.duration_s / 10, accel_time_s=fast.accel_time_s / 10
    )
    refused = refusal(world, moves)
    assert (refused.move, refused.check) == (14, "speeds") and "TCP speed" in refused.detail
    moves[13] = dataclasses.replace(fast, accel_time_s=1e-3)
    assert "acceleration" in refusal(world, moves).detail
    moves[13] = dataclasses.replace(fast, duration_s=0.0, accel_time_s=0.0)
    assert "instantaneous" in refusal(world, moves).detail
    # the commanded limits themselves above what the robot permits
    over = dataclasses.replace(LIMITS, linear_speed_mm_s=RobotPermits().tcp_speed_mm_s * 2)
    refused = refusal(world, sweeps.moves, commanded=over)
    assert (refused.move, refused.check) == (0, "speeds") and "permits" in refused.detail


def test_joint_speeds_at_the_commanded_speed(world, sweeps):
    """The executed speed is the commanded one: rotating the TCP at 180 deg/s, the sweeps turn
    joints faster than the UR10 can (at 45 deg/s they reach half its limits)."""
    fast = dataclasses.replace(LIMITS, angular_speed_rad_s=np.pi, angular_accel_rad_s2=4 * np.pi)
    refused = refusal(world, sweeps.moves, commanded=fast)
    assert refused.check == "joint speeds" and "deg/s" in refused.detail


def test_nan_inf_and_bad_timing(world, sweeps):
    moves = list(sweeps.moves)
    bad = np.array(moves[2].end)
    bad[0, 3] = np.nan
    moves[2] = with_end(moves[2], bad)
    assert (refusal(world, moves).move, refusal(world, moves).check) == (3, "plan")
    moves = list(sweeps.moves)
    moves[7] = dataclasses.replace(moves[7], duration_s=math.inf)
    assert (refusal(world, moves).move, refusal(world, moves).check) == (8, "plan")
    moves[7] = dataclasses.replace(sweeps.moves[7], accel_time_s=sweeps.moves[7].duration_s)
    assert refusal(world, moves).check == "plan"


def test_an_empty_plan_and_a_huge_one(world, sweeps):
    assert refusal(world, []).check == "plan"
    home = sweeps.home_base_from_tcp
    hold = TimedMove("station", home, home, 0.1, 0.0, 0.05)
    refused = refusal(world, [hold] * (MAX_MOVES + 1000))
    assert (refused.move, refused.check) == (MAX_MOVES + 1, "plan") and "moves" in refused.detail
    # few moves but an absurd path: refused before any IK by the number of check points
    far = shifted(home, [0, 0, 400.0])  # 201 check points each way
    there_and_back = [timed(home, far), timed(far, home)] * 600
    refused = refusal(world, there_and_back)
    assert refused.check == "plan" and "check points" in refused.detail


def test_a_move_through_the_wrist_singularity(world):
    for direction in ([1, 0, 0], [0, 1, 0], [0, 0, 1]):
        refused = refusal(
            world, wrist_singular_crossing(world.controller_model, world.home_joints_rad, direction)
        )
        assert refused.check in ("singularities", "joint speeds"), refused
        assert "singular" in refused.detail or "flips" in refused.detail


def test_a_recorded_move_the_tracker_cannot_see(world, sweeps):
    home = sweeps.home_base_from_tcp
    away = turned(home, [1, 0, 0], np.radians(170.0))
    moves = [timed(home, away, "rot_x", period=0.1)]
    refused = refusal(world, moves, visibility=visibility_of(world))
    assert refused.check in ("visibility", "joint speeds", "singularities")
    # transit is not recorded: visibility does not matter there
    assert gate(world, [timed(home, shifted(home, [0, 0, 60.0]))], visibility=visibility_of(world)).passed


def test_a_plan_box_and_the_resume_approach(world, sweeps):
    model = world.controller_model
    home = sweeps.home_base_from_tcp
    small = workspace_around(
        model, home, np.column_stack([home[:3, 3] - 50, home[:3, 3] + 50]).ravel(), "plan"
    )
    refused = refusal(world, sweeps.moves, workspace=small)
    assert refused.check == "workspace" and refused.move > 6  # the rotations stay at home
    # resuming: from where the arm stopped, the straight approach to the interrupted move is checked
    stopped = forward_kinematics(model, world.home_joints_rad + np.radians([5, 0, 0, 0, 0, 0]))
    report = gate(
        world,
        sweeps.moves,
        first_move=13,
        start_base_from_tcp=stopped,
        home_base_from_tcp=None,
    )
    assert report.passed and report.moves == len(sweeps.moves) - 13
    wild = shifted(stopped, [0, 0, -stopped[2, 3] - 100])
    refused = refusal(world, sweeps.moves, first_move=13, start_base_from_tcp=wild, home_base_from_tcp=None)
    assert (refused.move, refused.label) == (14, "approach")


def test_the_refusal_raises_one_line(world):
    report = gate(world, [])
    with pytest.raises(MotionRefusedError) as raised:
        report.raise_if_refused()
    assert "\n" not in str(raised.value) and str(raised.value).startswith("motion refused, nothing moved")
    assert isinstance(raised.value, ValueError) and raised.value.report is report


# -- through the command line: acquire --plan --dry-run -------------------------------------
@pytest.fixture(scope="module")
def plan_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("plans")
    sweeps = folder / "sweeps.json"
    app.plan(app.PlanSettings(scenario=SCENARIO, paper_sweeps=True, output=str(sweeps)))
    site = folder / "site.json"
    app.plan(app.PlanSettings(budget_s=10.0, scenario=SCENARIO, output=str(site)))
    return {"sweeps": sweeps, "site": site}


def acquire_dry_run(capsys, plan, tmp_path, *extra):
    code = main(
        [
            "acquire",
            "--scenario",
            SCENARIO,
            "--plan",
            str(plan),
            "--dry-run",
            "-o",
            str(tmp_path / "r.csv"),
            *extra,
        ]
    )
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.mark.parametrize("kind", ["sweeps", "site"])
def test_plans_from_spacecal_plan_pass_the_dry_run(plan_files, kind, tmp_path, capsys):
    code, out, err = acquire_dry_run(capsys, plan_files[kind], tmp_path)
    assert code == 0, err
    for name in CHECKS:
        assert f"  {name}: passed" in out
    assert "dry run: nothing moved" in out and not (tmp_path / "r.csv").exists()


def _moves(data):
    return data["moves"]


def _pose(move, key):
    return np.array(move[key])


def _append(data, start, end, label="transit", duration=None):
    move = timed(start, end, label)
    data["moves"].append(
        {
            "label": label,
            "start_base_from_tcp": np.asarray(start).tolist(),
            "end_base_from_tcp": np.asarray(end).tolist(),
            "duration_s": move.duration_s if duration is None else duration,
            "accel_time_s": move.accel_time_s,
            "sample_period_s": 0.0,
        }
    )


def _last_end(data):
    return _pose(data["moves"][-1], "end_base_from_tcp")


def _out_of_reach(data):
    _append(data, _last_end(data), shifted(_last_end(data), [-3000.0, 0, 0]))


def _out_of_reach_wide_box(data):
    data["workspace_box_mm"] = [-1e4, 1e4, -1e4, 1e4, -1e4, 1e4]
    _append(data, _last_end(data), shifted(_last_end(data), [-3000.0, 0, 0]))


def _to_the_base(data):
    _append(data, _last_end(data), base_pose(_last_end(data)))


def _below_the_base_plane(data):
    end = _last_end(data)
    _append(data, end, shifted(end, [0, 0, -end[2, 3] - 100.0]))


def _discontinuity(data):
    move = data["moves"][5]
    move["start_base_from_tcp"] = shifted(_pose(move, "start_base_from_tcp"), [0, 10.0, 0]).tolist()


def _first_move_elsewhere(data):
    move = data["moves"][0]
    move["start_base_from_tcp"] = shifted(_pose(move, "start_base_from_tcp"), [0, 0, 20.0]).tolist()


def _joint_limits(data):
    for move in spin_about_tool(_last_end(data), 4):
        _append(data, move.start, move.end, "spin")


def _too_fast(data):
    move = data["moves"][13]
    move["duration_s"] /= 10
    move["accel_time_s"] /= 10


def _too_sudden(data):
    data["moves"][13]["accel_time_s"] = 1e-3


def _nan(data):
    data["moves"][2]["end_base_from_tcp"][0][3] = float("nan")


def _infinite_duration(data):
    data["moves"][7]["duration_s"] = float("inf")


def _huge(data):
    home = data["home_base_from_tcp"]
    hold = {
        "label": "station",
        "start_base_from_tcp": home,
        "end_base_from_tcp": home,
        "duration_s": 0.1,
        "accel_time_s": 0.0,
        "sample_period_s": 0.05,
    }
    data["moves"] = [hold] * (MAX_MOVES + 10)


def _singular(data, world):
    data["moves"] = []
    for move in wrist_singular_crossing(world.controller_model, world.home_joints_rad, [0, 1, 0]):
        _append(data, move.start, move.end, move.label)


def _empty(data):
    data["moves"] = []


def _small_box(data):
    home = np.array(data["home_base_from_tcp"])[:3, 3]
    data["workspace_box_mm"] = np.column_stack([home - 50, home + 50]).ravel().tolist()


#: case -> (mutation, the refusal's move text, what the line must name)
HOSTILE = {
    "out of reach by 3 m": (_out_of_reach, "move 20/20", "workspace"),
    "out of reach by 3 m, in a wide box": (_out_of_reach_wide_box, "move 20/20", ("reach", "singularities")),
    "ending at the base": (
        _to_the_base,
        "move 20/20",
        ("workspace", "joint speeds", "singularities", "reach"),
    ),
    "below the base plane": (_below_the_base_plane, "move 20/20", "below the base plane"),
    "a discontinuity": (_discontinuity, "move 6/19", "continuity"),
    "first move away from home": (_first_move_elsewhere, "move 1/19", "continuity"),
    "joint limits": (_joint_limits, "move 22/23", "joint limits"),
    "speed above the limit": (_too_fast, "move 14/19", "speeds: its timing needs a TCP speed"),
    "acceleration above the limit": (_too_sudden, "move 14/19", "TCP acceleration"),
    # the JSON reader refuses non-finite numbers before a plan is read (the gate checks records too)
    "NaN in a pose": (_nan, "hostile.json", "NaN is not a number JSON allows"),
    "infinite duration": (_infinite_duration, "hostile.json", "Infinity is not a number JSON allows"),
    "a huge number of moves": (_huge, f"move {MAX_MOVES + 1}/{MAX_MOVES + 10}", "plan"),
    "through a singularity": (_singular, "move ", ("singularities", "joint speeds")),
    "an empty plan": (_empty, "", "no moves"),
    "a box the plan states": (_small_box, "move ", "workspace box (the plan file's box)"),
}


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_a_hostile_plan_is_refused_in_the_dry_run(plan_files, world, case, tmp_path, capsys):
    mutate, where, names = HOSTILE[case]
    data = json.loads(plan_files["sweeps"].read_text())
    if mutate is _singular:
        _singular(data, world)
    else:
        mutate(data)
    path = tmp_path / "hostile.json"
    path.write_text(json.dumps(data))
    code, out, err = acquire_dry_run(capsys, path, tmp_path)
    lines = err.strip().splitlines()
    assert code == 1 and len(lines) == 1, (code, out, err)
    assert where in lines[0], lines[0]
    assert any(name in lines[0] for name in ((names,) if isinstance(names, str) else names)), lines[0]
    assert "dry run: nothing moved" not in out and not (tmp_path / "r.csv").exists()


def test_a_refused_plan_never_moves_the_simulated_robot(plan_files, tmp_path, monkeypatch):
    """Not a dry run: the plan reaches the devices, and the gate stops it before a command."""
    import spacecal.app.motion_session as acquisition

    robots = []
    original = acquisition.simulated_devices

    def keep(scenario, start_s=0.0, speed=None):
        world, robot, tracker = original(scenario, start_s, speed)
        robots.append(robot)
        return world, robot, tracker

    monkeypatch.setattr(acquisition, "simulated_devices", keep)
    data = json.loads(plan_files["sweeps"].read_text())
    _to_the_base(data)
    path = tmp_path / "hostile.json"
    path.write_text(json.dumps(data))
    output = tmp_path / "rec.csv"
    with pytest.raises(MotionRefusedError, match="move 20/20"):
        app.acquire(app.AcquireSettings(str(output), scenario=SCENARIO, plan=str(path)))
    assert len(robots) == 1 and robots[0].commands == []
    assert robots[0].state().moving is False
    assert list(tmp_path.iterdir()) == [path]  # no recording, no streams, no progress file


def test_simulate_refuses_a_hostile_plan_before_running_it(plan_files, tmp_path, capsys):
    data = json.loads(plan_files["sweeps"].read_text())
    _discontinuity(data)
    path = tmp_path / "hostile.json"
    path.write_text(json.dumps(data))
    code = main(["simulate", "--scenario", SCENARIO, "--plan", str(path), "-o", str(tmp_path / "s.csv")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and "move 6/19 (rot_y): continuity" in err[0]
    assert not (tmp_path / "s.csv").exists()


def test_the_check_dry_run_reports_the_gate(tmp_path, capsys, white_simulation):
    from spacecal.estimators import calibrate
    from spacecal.io.results_json import write_calibration
    from spacecal.records import Provenance

    result = calibrate(white_simulation.recording, "ml").replace(
        provenance=Provenance(simulated=True, scenario=white_simulation.world.scenario.to_dict())
    )
    calibration = write_calibration(result, tmp_path / "cal.json")
    assert main(["check", str(calibration), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "motion gate:" in out and "  reach: passed" in out and "  visibility: passed" in out
    # a box the check poses leave: refused before the robot moves
    box = "--workspace-box=-600,-560,-200,-120,300,400"
    assert main(["check", str(calibration), "--dry-run", box]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "workspace box" in err[0] and "move " in err[0]


def test_motion_gate_module_is_pure():
    """Records in, a report out: the gate imports no device, app or workflow code."""
    import ast
    import inspect

    tree = ast.parse(inspect.getsource(motion_gate))
    imported = [n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module]
    ours = [m.split(".")[1] for m in imported if m.startswith("spacecal.")]
    assert ours and not set(ours) & {"app", "adapters", "sim", "workflows", "io", "cli"}
