"""Rest-to-rest paths for a Franka arm's motion generators, and their decelerated stop.

libfranka's motion generators are fed one set-point per 1 ms control cycle, and the robot
refuses (a reflex) set-points whose velocity or acceleration jump from one cycle to the next
(``joint_motion_generator_velocity_discontinuity``, ``..._acceleration_discontinuity``). The
paths here are therefore minimum-jerk: position, velocity and acceleration are continuous and
start and end at rest, and a stop slows the path's own clock down smoothly instead of cutting
the velocity. Pure functions of time; nothing here talks to a robot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.geometry.transforms import make_transform, matrix_to_rotvec, rotvec_to_matrix

#: Peak of ds/dtau and of d2s/dtau2 of the minimum-jerk path s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5.
PEAK_SPEED = 1.875
PEAK_ACCEL = 10.0 / np.sqrt(3.0)
#: The shortest stop, s: a path already at rest ends in this.
MIN_STOP_S = 0.05


def minimum_jerk(tau: float) -> tuple[float, float]:
    """Path parameter s and ds/dtau at ``tau`` (clipped to [0, 1])."""
    tau = min(max(tau, 0.0), 1.0)
    s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau * tau)
    ds = 30.0 * tau * tau * (1.0 - tau) ** 2
    return s, ds


def path_duration(distance: float, speed: float, accel: float) -> float:
    """The duration (s) of a minimum-jerk path over ``distance`` whose peak speed and
    acceleration stay within ``speed`` and ``accel`` (same units: rad or mm, per s and s^2)."""
    if not (speed > 0 and accel > 0 and np.isfinite(speed) and np.isfinite(accel)):
        raise InvalidInputError(f"a move needs a positive speed and acceleration (got {speed}, {accel})")
    if distance <= 0:
        return 0.0
    return max(PEAK_SPEED * distance / speed, float(np.sqrt(PEAK_ACCEL * distance / accel)))


@dataclass
class PathClock:
    """The clock of one rest-to-rest path, s in [0, 1] over ``duration_s``, that a stop slows
    down to rest.

    The path advances by ``rate * dt / duration`` per cycle; before a stop the rate is 1, after
    it the rate falls as 1 - smoothstep over ``stop_s``, so the commanded velocity reaches
    zero with a continuous acceleration (the rate's own slope is zero at both ends).

    Attributes
    ----------
    duration_s : float
        The path's duration at full rate, s (0: a path already at its end).
    stop_s : float
        How long a stop takes, s.
    """

    duration_s: float
    stop_s: float
    tau: float = 0.0
    elapsed_s: float = 0.0
    stopping_since_s: float | None = None

    def stop(self) -> None:
        """Begin the decelerated stop (from the next cycle on)."""
        if self.stopping_since_s is None:
            self.stopping_since_s = self.elapsed_s

    def rate(self) -> float:
        if self.stopping_since_s is None:
            return 1.0
        x = min((self.elapsed_s - self.stopping_since_s) / self.stop_s, 1.0)
        return 1.0 - x * x * (3.0 - 2.0 * x)

    def advance(self, dt_s: float) -> float:
        """Move the clock on by one control cycle of ``dt_s`` s; the path parameter s."""
        rate_before = self.rate()
        self.elapsed_s += dt_s
        rate = 0.5 * (rate_before + self.rate())  # trapezoidal integration of the rate
        if self.duration_s > 0:
            self.tau = min(self.tau + rate * dt_s / self.duration_s, 1.0)
        else:
            self.tau = 1.0
        return minimum_jerk(self.tau)[0]

    @property
    def finished(self) -> bool:
        """At the path's end, or at rest after a stop."""
        if self.tau >= 1.0:
            return True
        return self.stopping_since_s is not None and self.elapsed_s - self.stopping_since_s >= self.stop_s


def stop_duration(peak_speed: float, stop_accel: float) -> float:
    """How long a stop from ``peak_speed`` takes at most ``stop_accel`` (the smoothstep's peak
    slope is 1.5 / stop time), s, at least :data:`MIN_STOP_S`."""
    return max(MIN_STOP_S, 1.5 * peak_speed / stop_accel)


def interpolate_pose(start: np.ndarray, end: np.ndarray, s: float) -> np.ndarray:
    """The pose (4, 4) a fraction ``s`` along the straight line from ``start`` to ``end``:
    translation linear, rotation about the fixed axis of ``start.R^T end.R`` (units kept)."""
    start, end = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
    turn = matrix_to_rotvec(start[:3, :3].T @ end[:3, :3])
    rotation = start[:3, :3] @ rotvec_to_matrix(s * turn)
    return make_transform(rotation, start[:3, 3] + s * (end[:3, 3] - start[:3, 3]))
