"""The motion gate as the commands use it: what each command hands it, and its refusal.

``acquire``, ``check`` and ``simulate`` pass every motion (the paper's sweeps planned where the
robot stands, a plan file, the check poses) through :func:`spacecal.planning.motion_gate.gate_motion`
before anything moves, dry run or not. This module turns a command's settings and devices into
the gate's inputs: the workspace box (``--workspace-box``, the plan file's, or the default
around home), the visibility model where a tracker pose is known, and where the arm stands.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from spacecal.app.motion_settings import COMMANDED_BY
from spacecal.core.errors import InvalidInputError
from spacecal.core.ports import RobotState
from spacecal.geometry.transforms import matrix_to_rotvec
from spacecal.io.acquisition_progress import read_progress
from spacecal.io.results_json import read_calibration
from spacecal.models.kinematics import RobotModel
from spacecal.models.marker import ndi_8700339_like
from spacecal.models.tracker import TrackerModel
from spacecal.planning.motion import MotionLimits, MotionPlan, trapezoid_duration
from spacecal.planning.motion_gate import (
    DEFAULT_BOX_HALF_MM,
    MAX_MOVES,
    MotionGateReport,
    Workspace,
    gate_motion,
    workspace_around,
)
from spacecal.planning.visibility import VisibilityModel
from spacecal.sim.world import World
from spacecal.workflows.acquisition import plan_fingerprint

if TYPE_CHECKING:
    from spacecal.app.acquire_settings import AcquireSettings

#: Margin (mm) added around a stroke the command itself asks for (``--translation-mm``, a
#: scenario's sweeps or station cube) when that reaches beyond the default box.
REQUESTED_STROKE_MARGIN_MM = 100.0

#: A resumed run whose TCP stands this close to the interrupted move's start (mm, rad) needs no
#: approach (the acquisition's own test, ``workflows.acquisition._at_pose``).
APPROACH_NONE_MM, APPROACH_NONE_RAD = 1e-3, 1e-6


def default_box_half_mm(*requested_reach_mm: float) -> float:
    """Half side of the default box: :data:`DEFAULT_BOX_HALF_MM`, or more when the command asks
    for a longer stroke from home (``requested_reach_mm``: the largest offset it plans)."""
    return max([DEFAULT_BOX_HALF_MM] + [r + REQUESTED_STROKE_MARGIN_MM for r in requested_reach_mm])


def plan_workspace(
    model: RobotModel,
    plan: MotionPlan,
    box_mm: Sequence[float] | None,
    half_mm: float = DEFAULT_BOX_HALF_MM,
) -> Workspace:
    """The workspace a plan is checked in: ``--workspace-box`` and the plan file's box where
    given (both hold: their intersection), else the default box around the plan's home."""
    boxes = []
    if box_mm is not None:
        boxes.append((np.asarray(box_mm, dtype=float), "--workspace-box"))
    if plan.workspace_box_mm is not None:
        boxes.append((np.asarray(plan.workspace_box_mm, dtype=float), "the plan file's box"))
    if not boxes:
        return workspace_around(model, plan.home_base_from_tcp, half_mm=half_mm)
    merged = np.array(boxes[0][0])
    for box, _ in boxes[1:]:
        merged[0::2] = np.maximum(merged[0::2], box[0::2])
        merged[1::2] = np.minimum(merged[1::2], box[1::2])
    if np.any(merged[0::2] >= merged[1::2]):
        raise InvalidInputError(
            "--workspace-box and the plan file's workspace_box_mm do not overlap; nothing moved"
        )
    return workspace_around(model, plan.home_base_from_tcp, merged, " and ".join(s for _, s in boxes))


def gate_plan(
    plan: MotionPlan,
    model: RobotModel,
    state: RobotState | None,
    commanded: MotionLimits,
    workspace: Workspace,
    *,
    visibility: VisibilityModel | None = None,
    visibility_note: str = "",
    first_move: int = 0,
    resuming: bool = False,
    commanded_by: str = "",
) -> MotionGateReport:
    """Pass a plan through the motion gate from where the arm stands (``state``; None: at the
    plan's home joints, as a simulated run starts) and raise its one-line refusal.

    A resumed run (``resuming``) runs from ``first_move`` on, after the straight approach from
    where the arm stands to that move's start, which the gate checks as the move "approach":
    a stop in the middle of a move leaves the arm between two poses of the plan, also in its
    first move.

    Raises
    ------
    spacecal.planning.motion_gate.MotionRefusedError
        The first check that fails, with the move's index; nothing has moved.
    """
    moves, first, shift = list(plan.moves), first_move, 0
    if resuming and first_move == 0 and 0 < len(moves) < MAX_MOVES:
        # gate_motion checks the approach for a move after the first only: the first move is
        # put before itself as done, and the report's move numbers are given back
        moves, first, shift = [moves[0], *moves], 1, 1
    report = gate_motion(
        model,
        moves,
        plan.home_joints_rad if state is None else state.joints_rad,
        commanded,
        workspace,
        start_base_from_tcp=None if state is None else state.base_from_tcp,
        home_base_from_tcp=plan.home_base_from_tcp if first == 0 and not resuming else None,
        visibility=visibility,
        visibility_note=visibility_note,
        first_move=first,
        commanded_by=commanded_by,
    )
    report = _numbered_from(report, shift)
    report.raise_if_refused()
    return report


def _numbered_from(report: MotionGateReport, shift: int) -> MotionGateReport:
    """``report`` with its move numbers ``shift`` lower (the plan's own numbers)."""
    refusal = report.refusal
    if shift == 0 or refusal is None:
        return report
    number = max(refusal.move - shift, 1) if refusal.move else 0
    before, after = f"passed before move {refusal.move}", f"passed before move {number}"
    checks = tuple(
        dataclasses.replace(check, status=after) if check.status == before else check
        for check in report.checks
    )
    return dataclasses.replace(
        report,
        checks=checks,
        refusal=dataclasses.replace(refusal, move=number, moves=refusal.moves - shift),
    )


def resumed_move(settings: AcquireSettings, plan: MotionPlan) -> int | None:
    """The move a resumed ``acquire`` starts from (0-based; the number of moves completed, as
    its progress file says for this plan), or None when not resuming this plan."""
    if not settings.resume:
        return None
    progress = read_progress(settings.output)
    if progress is None or progress.plan_fingerprint != plan_fingerprint(plan):
        return None
    return progress.moves_completed


def approach_line(
    plan: MotionPlan, first_move: int, base_from_tcp: np.ndarray, commanded: MotionLimits
) -> str:
    """What a resumed run does before the interrupted move (one line for the operator): the
    straight move from where the TCP stands (``base_from_tcp``, mm) to that move's start, how
    far and how long at the commanded limits, or that none is needed."""
    move = plan.moves[first_move]
    where = f"move {first_move + 1}/{len(plan.moves)} ({move.label})"
    target = np.asarray(move.start, dtype=float)
    distance_mm = float(np.linalg.norm(target[:3, 3] - base_from_tcp[:3, 3]))
    angle_rad = float(np.linalg.norm(matrix_to_rotvec(base_from_tcp[:3, :3].T @ target[:3, :3])))
    if distance_mm < APPROACH_NONE_MM and angle_rad < APPROACH_NONE_RAD:
        return f"resume: from {where}; the robot stands at its start"
    duration_s = max(
        trapezoid_duration(distance_mm, commanded.linear_speed_mm_s, commanded.linear_accel_mm_s2)[0],
        trapezoid_duration(angle_rad, commanded.angular_speed_rad_s, commanded.angular_accel_rad_s2)[0],
    )
    return (
        f"resume: a straight move back to the start of {where}, {distance_mm:.1f} mm and "
        f"{np.degrees(angle_rad):.1f} deg from where the robot stands (about {duration_s:.1f} s at "
        "the commanded speeds; checked by the motion gate as the move 'approach'), then the plan "
        "from there"
    )


def world_visibility(world: World) -> VisibilityModel:
    """What a simulated world's tracker sees (its layout is the truth)."""
    return VisibilityModel(world.tracker, world.marker, world.tracker_from_base, world.tcp_from_marker)


def acquisition_gate(
    settings: AcquireSettings,
    plan: MotionPlan,
    model: RobotModel,
    state: RobotState,
    commanded: MotionLimits,
    world: World | None,
) -> MotionGateReport | None:
    """Pass ``acquire``'s plan through the motion gate from where the robot stands; a resumed
    run from the interrupted move on, after the straight approach to its start (the first move
    too). None when a resumed plan has nothing left to run.

    The visibility is predicted in a simulated world, or with ``--prior`` on real devices; the
    default box grows to cover a stroke the command itself asks for (``--translation-mm``, a
    scenario's sweeps or stations), never for a plan file's moves.
    """
    resumed = resumed_move(settings, plan)
    first = resumed or 0
    if settings.resume and first >= len(plan.moves):
        return None
    visibility: VisibilityModel | None = None
    if world is not None:
        s = world.scenario
        visibility = world_visibility(world)
        reach = (s.translation_mm / 2, s.station_cube_mm / 2 if s.motion == "stations" else 0.0)
    else:
        if settings.prior:
            prior = read_calibration(settings.prior)
            visibility = VisibilityModel(
                TrackerModel(), ndi_8700339_like(), prior.tracker_from_base, prior.tcp_from_marker
            )
        reach = (settings.translation_mm / 2, 0.0)
    half = default_box_half_mm(*reach) if settings.plan is None else default_box_half_mm()
    return gate_plan(
        plan,
        model,
        state,
        commanded,
        plan_workspace(model, plan, settings.workspace_box, half),
        visibility=visibility,
        visibility_note="no tracker pose (pass --prior with an earlier calibration)",
        first_move=first,
        resuming=resumed is not None,
        commanded_by=COMMANDED_BY,
    )
