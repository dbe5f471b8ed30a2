"""Stop-and-go sampling: the robot stops at stations along each recorded move and rests while
frames are taken, so no sample depends on the robot–tracker clock offset.

This is how hand-eye tools (easy_handeye and others) sample when the timing of the two
streams is unknown. Each recorded move of a plan becomes a walk through stations spread
evenly along its path; at each the arm settles, then ``frames_per_station`` frames are taken
(:func:`spacecal.workflows.stations.average_stations` averages them into one sample).
"""

from __future__ import annotations

import numpy as np

from spacecal.geometry.transforms import interpolate_transforms
from spacecal.models.kinematics import RobotModel
from spacecal.planning.motion import MotionLimits, MotionPlan, TimedMove, time_move, track_path

#: Rest before frames count at a station, s (the arm settles after its deceleration).
SETTLE_S = 0.3


#: Label of the moves between stations (never a station's).
TRANSIT = "transit"


def station_label(label: str) -> str:
    """A station's label: its move's, except that a recorded transit's stations are ``station``."""
    return "station" if label == TRANSIT else label


def stop_and_go_plan(
    plan: MotionPlan,
    model: RobotModel,
    limits: MotionLimits,
    frame_period_s: float,
    frames_per_station: int = 10,
    stations_per_move: int = 6,
    settle_s: float = SETTLE_S,
) -> MotionPlan:
    """The plan with each recorded move replaced by stations along its path.

    Parameters
    ----------
    plan : MotionPlan
    model : RobotModel
        For timing the moves between stations (joint speed limits along the path).
    limits : MotionLimits
    frame_period_s : float
        Tracker frame period, s.
    frames_per_station : int
        Frames taken at each station.
    stations_per_move : int
        Stations along each recorded move, evenly spread in path length, its end included
        (its start is the previous move's end).
    settle_s : float

    Returns
    -------
    MotionPlan
        Transits (``transit``, not recorded) between stations and holds (recorded, labelled
        with the move's label, :func:`station_label`) at them; moves that were not recorded
        and holds stay as they were.
    """
    moves: list[TimedMove] = []
    joints = np.asarray(plan.home_joints_rad, dtype=float)
    hold_s = settle_s + frames_per_station * frame_period_s
    for move in plan.moves:
        hold = move.duration_s > 0 and np.allclose(move.start, move.end, atol=1e-9)
        if move.sample_period_s <= 0 or hold:
            moves.append(move)
            joints = track_path(model, move.end[None], joints)[0]
            continue
        pose = move.start
        # stations evenly spread along the path (s in (0, 1] of the move's interpolation)
        fractions = np.arange(1, stations_per_move + 1) / stations_per_move
        for station in interpolate_transforms(move.start, move.end, fractions):
            transit, joints = time_move(model, TRANSIT, pose, station, joints, limits, 0.0)
            moves.append(transit)
            moves.append(TimedMove(station_label(move.label), station, station, hold_s, 0.0, frame_period_s))
            pose = station
    extents = {**plan.extents, "stop_and_go": {"frames_per_station": frames_per_station}}
    return MotionPlan(plan.home_joints_rad, plan.home_base_from_tcp, moves, extents, list(plan.messages))
