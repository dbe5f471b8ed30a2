"""Static station poses around the surgical site: the classic hand-eye data collection.

The robot visits random poses (position in a cube around the home TCP, orientation tilted
from home about a random axis) and holds still while the tracker records a few frames at
each. Every station is checked for reach, joint limits, predicted marker visibility, and a
continuous Cartesian path from the previous one.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from spacecal.core.errors import DegenerateDataError, UnreachableError
from spacecal.geometry.transforms import axis_angle_transform, make_transform
from spacecal.models.kinematics import RobotModel, forward_kinematics, within_joint_limits
from spacecal.planning.motion import MotionLimits, MotionPlan, TimedMove, time_move, track_path
from spacecal.planning.visibility import VisibilityModel


@dataclass(frozen=True)
class StationSettings:
    """How many stations, where, and how long to hold at each.

    Attributes
    ----------
    count : int
    frames_per_station : int
    frame_period_s : float
    cube_mm : float
        Side of the cube around the home TCP the station positions are drawn in.
    tilt_deg : float
        Largest tilt of a station's orientation from home.
    limits : MotionLimits
    """

    count: int = 50
    frames_per_station: int = 10
    frame_period_s: float = 0.05
    cube_mm: float = 150.0
    tilt_deg: float = 35.0
    limits: MotionLimits = field(default_factory=MotionLimits)


def random_station(
    home_base_from_tcp, rng: np.random.Generator, cube_mm: float, tilt_deg: float
) -> np.ndarray:
    """A TCP pose (4, 4) in a cube of side ``cube_mm`` around home, tilted up to ``tilt_deg``
    from the home orientation about a random axis."""
    offset = rng.uniform(-0.5, 0.5, 3) * cube_mm
    tilt = axis_angle_transform(rng.normal(size=3), np.radians(rng.uniform(0, tilt_deg)))
    return make_transform(home_base_from_tcp[:3, :3] @ tilt[:3, :3], home_base_from_tcp[:3, 3] + offset)


def plan_stations(
    model: RobotModel,
    home_joints_rad,
    settings: StationSettings,
    visibility: VisibilityModel | None,
    rng: np.random.Generator,
    max_attempts_per_station: int = 50,
) -> MotionPlan:
    """Plan ``settings.count`` feasible stations, visited in turn from home and back.

    Raises
    ------
    DegenerateDataError
        If a station cannot be found within the attempts allowed.
    """
    home_joints = np.asarray(home_joints_rad, dtype=float)
    home = forward_kinematics(model, home_joints)
    moves: list[TimedMove] = []
    q, current = home_joints, home
    for index in range(settings.count):
        for _ in range(max_attempts_per_station):
            station = random_station(home, rng, settings.cube_mm, settings.tilt_deg)
            if visibility is not None and not visibility.visible(station[None])[0]:
                continue
            try:
                move, q_end = time_move(model, "transit", current, station, q, settings.limits, 0.0)
            except UnreachableError:
                continue
            if within_joint_limits(model, track_path(model, station[None], q)).all():
                break
        else:
            raise DegenerateDataError(
                f"could not find a feasible station {index + 1} in "
                f"{max_attempts_per_station} attempts; widen the cube or lower the tilt"
            )
        moves.append(move)
        hold = settings.frames_per_station * settings.frame_period_s
        moves.append(TimedMove("station", station, station, hold, 0.0, settings.frame_period_s))
        q, current = q_end, station
    move, _ = time_move(model, "transit", current, home, q, settings.limits, 0.0)
    moves.append(move)
    return MotionPlan(home_joints, home, moves, {"stations": settings.count}, [])
