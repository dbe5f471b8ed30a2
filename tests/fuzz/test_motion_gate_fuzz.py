"""Seeded random plans against the motion gate: hostile variants of the paper's sweeps must be
refused at the right move by the right check, harmless variants must pass.

Each case draws one mutation (a gap, a turn, a move far out of reach or into the base, a
timing too fast or instantaneous, NaN or inf, too many moves, a wind-up past the joint limits,
a line through the wrist singularity, ...) with random parameters from its own seeded
generator, so a failing case is reproduced by its id alone.
"""

from __future__ import annotations

import dataclasses
import random

import numpy as np
import pytest

from spacecal.geometry.transforms import interpolate_transforms
from spacecal.models.kinematics import forward_kinematics
from spacecal.planning.motion import follow_path
from spacecal.planning.motion_gate import MAX_MOVES, gate_motion, workspace_around
from spacecal.planning.visibility import VisibilityModel
from spacecal.sim.motion import plan_for_world
from spacecal.sim.scenario import PRESETS
from spacecal.sim.world import build_world

from ..planning.gate_cases import (
    LIMITS,
    base_pose,
    shifted,
    spin_about_tool,
    timed,
    turned,
    with_start,
    wrist_singular_crossing,
)

SEED = 20260611
HOSTILE_CASES = 48
VALID_CASES = 12
#: Checks that may refuse a move sent somewhere the arm cannot or must not go.
GEOMETRIC = {"workspace", "reach", "singularities", "joint speeds", "joint limits"}
HOSTILE_KINDS = (
    "gap",
    "turn gap",
    "first gap",
    "too fast",
    "instantaneous",
    "far out",
    "into the base",
    "below the base plane",
    "nan or inf",
    "bad timing",
    "too many moves",
    "wind-up",
    "singular line",
    "empty",
    "commanded too fast",
)
VALID_KINDS = ("prefix", "slower", "tiny gaps", "holds", "resume")


@pytest.fixture(scope="module")
def setup():
    world = build_world(PRESETS["paper-white"])
    plan = plan_for_world(world)
    visibility = VisibilityModel(world.tracker, world.marker, world.tracker_from_base, world.tcp_from_marker)
    return world, plan, visibility


def _direction(rng: random.Random) -> np.ndarray:
    v = np.array([rng.gauss(0, 1) for _ in range(3)])
    return v / np.linalg.norm(v)


def _moving(moves, rng: random.Random) -> int:
    """A random move that is not a hold."""
    return rng.choice([k for k, m in enumerate(moves) if not np.allclose(m.start, m.end)])


def hostile_case(index: int, world, plan):
    """(kind, moves, gate options, expected move number or None, allowed checks)."""
    rng = random.Random(SEED + index)
    kind = HOSTILE_KINDS[index % len(HOSTILE_KINDS)]
    moves = list(plan.moves)
    n = len(moves)
    home = plan.home_base_from_tcp
    options: dict = {}
    if kind == "gap":
        k = rng.randrange(1, n)
        moves[k] = with_start(moves[k], shifted(moves[k].start, rng.uniform(1.5, 300.0) * _direction(rng)))
        return kind, moves, options, k + 1, {"continuity"}
    if kind == "turn gap":
        k = rng.randrange(1, n)
        moves[k] = with_start(
            moves[k], turned(moves[k].start, _direction(rng), np.radians(rng.uniform(1.0, 45.0)))
        )
        return kind, moves, options, k + 1, {"continuity"}
    if kind == "first gap":
        moves[0] = with_start(moves[0], shifted(moves[0].start, rng.uniform(1.5, 100.0) * _direction(rng)))
        return kind, moves, options, 1, {"continuity"}
    if kind == "too fast":
        k = _moving(moves, rng)
        factor = rng.uniform(3.0, 1000.0)
        moves[k] = dataclasses.replace(
            moves[k], duration_s=moves[k].duration_s / factor, accel_time_s=moves[k].accel_time_s / factor
        )
        return kind, moves, options, k + 1, {"speeds"}
    if kind == "instantaneous":
        k = _moving(moves, rng)
        moves[k] = dataclasses.replace(moves[k], duration_s=0.0, accel_time_s=0.0)
        return kind, moves, options, k + 1, {"speeds"}
    if kind == "far out":
        k = rng.randrange(n)
        offset = rng.uniform(1000.0, 5000.0) * _direction(rng)
        # timed for its new length: the path, not the timing, is what is wrong
        moves[k] = timed(moves[k].start, shifted(moves[k].end, offset), moves[k].label)
        if k + 1 < n:
            moves[k + 1] = with_start(moves[k + 1], shifted(moves[k + 1].start, offset))
        return kind, moves, options, k + 1, GEOMETRIC
    if kind == "into the base":
        angle, radius = rng.uniform(0, 2 * np.pi), rng.uniform(0.0, 100.0)
        point = (radius * np.cos(angle), radius * np.sin(angle), rng.uniform(0.0, 200.0))
        moves.append(timed(moves[-1].end, base_pose(home, point)))
        return kind, moves, options, n + 1, GEOMETRIC
    if kind == "below the base plane":
        end = moves[-1].end
        moves.append(timed(end, shifted(end, [0, 0, -end[2, 3] - rng.uniform(10.0, 500.0)])))
        return kind, moves, options, n + 1, GEOMETRIC
    if kind == "nan or inf":
        k = rng.randrange(n)
        value = rng.choice([np.nan, np.inf, -np.inf])
        where = rng.choice(["start", "end", "duration_s", "accel_time_s", "sample_period_s"])
        if where in ("start", "end"):
            pose = np.array(getattr(moves[k], where))
            pose[rng.randrange(3), rng.randrange(4)] = value
            moves[k] = dataclasses.replace(moves[k], **{where: pose})
        else:
            moves[k] = dataclasses.replace(moves[k], **{where: value})
        return kind, moves, options, k + 1, {"plan"}
    if kind == "bad timing":
        k = _moving(moves, rng)
        move = moves[k]
        moves[k] = rng.choice(
            [
                dataclasses.replace(move, accel_time_s=move.duration_s * rng.uniform(0.6, 5.0)),
                dataclasses.replace(move, accel_time_s=-rng.uniform(0.01, 1.0)),
                dataclasses.replace(move, sample_period_s=-rng.uniform(0.01, 1.0)),
            ]
        )
        return kind, moves, options, k + 1, {"plan"}
    if kind == "too many moves":
        hold = timed(home, home, "station", period=0.05)
        return kind, [hold] * (MAX_MOVES + rng.randrange(1, 5000)), options, MAX_MOVES + 1, {"plan"}
    if kind == "wind-up":
        extra = spin_about_tool(moves[-1].end, rng.randrange(4, 7), rng.uniform(150.0, 175.0))
        return kind, moves + extra, options, None, {"joint limits"}
    if kind == "singular line":
        crossing = wrist_singular_crossing(world.nominal_model, world.home_joints_rad, _direction(rng))
        return kind, crossing, options, None, {"singularities", "joint speeds"}
    if kind == "empty":
        return kind, [], options, 0, {"plan"}
    options["commanded"] = dataclasses.replace(LIMITS, linear_speed_mm_s=rng.uniform(1001.0, 5000.0))
    return kind, moves, options, 0, {"speeds"}


def valid_case(index: int, world, plan):
    """(kind, moves, gate options): variants that must pass."""
    rng = random.Random(SEED + 10_000 + index)
    kind = VALID_KINDS[index % len(VALID_KINDS)]
    moves = list(plan.moves)
    n = len(moves)
    options: dict = {}
    if kind == "prefix":
        return kind, moves[: rng.randrange(1, n + 1)], options
    if kind == "slower":
        factor = rng.uniform(1.0, 4.0)
        return (
            kind,
            [
                dataclasses.replace(m, duration_s=m.duration_s * factor, accel_time_s=m.accel_time_s * factor)
                for m in moves
            ],
            options,
        )
    if kind == "tiny gaps":
        for _ in range(rng.randrange(1, 6)):
            k = rng.randrange(1, n)
            start = turned(moves[k].start, _direction(rng), rng.uniform(0.0, 0.004))
            start = shifted(start, rng.uniform(0.0, 0.9) * _direction(rng))
            # timed from its own (slightly different) start, as a plan written elsewhere would be
            moves[k] = dataclasses.replace(
                timed(start, moves[k].end, moves[k].label, moves[k].sample_period_s),
                duration_s=max(moves[k].duration_s, timed(start, moves[k].end).duration_s),
            )
        return kind, moves, options
    if kind == "holds":
        for _ in range(rng.randrange(1, 6)):
            k = rng.randrange(n)
            end = moves[k].end
            moves.insert(
                k + 1,
                dataclasses.replace(
                    timed(end, end, "station", period=0.05), duration_s=rng.uniform(0.1, 2.0)
                ),
            )
        return kind, moves, options
    first = rng.randrange(1, n)
    options.update(first_move=first, start_base_from_tcp=moves[first - 1].end, home_base_from_tcp=None)
    return kind, moves, options


def _joints_after(model, moves, joints):
    """Where the arm stands after running ``moves`` from ``joints`` (on its branch)."""
    for move in moves:
        poses = interpolate_transforms(move.start, move.end, np.linspace(0.0, 1.0, 91))
        followed, solved = follow_path(model, poses, joints)
        assert solved == len(poses)
        joints = followed[-1]
    return joints


def _gate(world, plan, visibility, moves, options):
    model = world.controller_model
    start = options.pop("start_base_from_tcp", None)
    joints = world.home_joints_rad
    if start is not None:  # resume: where the arm stopped, at the end of the last move done
        joints = _joints_after(model, moves[: options["first_move"]], joints)
    options.setdefault("home_base_from_tcp", plan.home_base_from_tcp)
    return gate_motion(
        model,
        moves,
        joints,
        options.pop("commanded", LIMITS),
        workspace_around(model, forward_kinematics(model, world.home_joints_rad)),
        start_base_from_tcp=start,
        visibility=visibility,
        **options,
    )


@pytest.mark.parametrize(
    "index", range(HOSTILE_CASES), ids=lambda i: f"hostile-{i:02d}-{HOSTILE_KINDS[i % len(HOSTILE_KINDS)]}"
)
def test_a_hostile_plan_is_refused_at_its_move_by_its_check(setup, index):
    world, plan, visibility = setup
    kind, moves, options, move, checks = hostile_case(index, world, plan)
    report = _gate(world, plan, visibility, moves, options)
    assert not report.passed, f"{kind}: accepted"
    refusal = report.refusal
    assert refusal.check in checks, f"{kind}: {refusal.line()}"
    if move is not None:
        assert refusal.move == move, f"{kind}: {refusal.line()}"
    line = refusal.line()
    assert "\n" not in line and line.startswith("motion refused, nothing moved: ")
    assert (f"move {refusal.move}/" in line) == (refusal.move > 0)


@pytest.mark.parametrize(
    "index", range(VALID_CASES), ids=lambda i: f"valid-{i:02d}-{VALID_KINDS[i % len(VALID_KINDS)]}"
)
def test_a_harmless_variant_passes(setup, index):
    world, plan, visibility = setup
    kind, moves, options = valid_case(index, world, plan)
    report = _gate(world, plan, visibility, moves, options)
    assert report.passed, f"{kind}: {report.refusal.line()}"
    assert all(c.status == "passed" for c in report.checks)
