"""Is the recording what it claims? The file conventions that could explain it better.

A recording written by another tool can be read with the wrong conventions and still parse:
quaternions stored x,y,z,w read as w,x,y,z, a pose given inverted (``marker_from_tracker``
for ``tracker_from_marker``, or a camera on the robot written as eye-to-hand), rotations
conjugated, lengths in metres read as millimetres, or the robot and tracker columns swapped.
No residual threshold can tell such a mistake from a sound recording of a distant camera:
a camera 0.4–2 m from its target leaves residuals of several mm, a Polaris fractions of one.

So the recording is judged by comparison, not by a threshold. Each alternative reading is
applied to the pose stacks, solved in closed form (Shah's AX = YB, :mod:`robot_world`) and its
median residuals compared with those of the reading as given. Only an alternative that
explains the data *clearly* better (:data:`CLEARLY_BETTER` in position with the rotation no
worse, or the other way round) is a finding; a recording that nothing explains well is left to
the expected error and the verdict, which grade it by its held-out misfit.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from spacecal.core.errors import DegenerateDataError
from spacecal.core.units import METRES_BELOW_MM, MILLIMETRES_TWICE_ABOVE_MM
from spacecal.estimators.methods.robot_world import solve_shah
from spacecal.geometry.arrays import FloatArray, as_float_array
from spacecal.geometry.rotations import rotation_angle
from spacecal.geometry.transforms import invert_transform
from spacecal.records import Recording

#: An alternative reading is a finding when its median residual is at most this share of the
#: given reading's (a sound recording's alternatives are many times worse, never this much better).
CLEARLY_BETTER = 1.0 / 3.0
#: ... while its other residual (rotation for position, or the reverse) grows by at most this.
NO_WORSE = 1.5
#: Below these median residuals the given reading explains the data; nothing is compared (mm, deg).
EXPLAINED_MM, EXPLAINED_DEG = 0.5, 0.25
#: Frames (evenly spread) the comparison is made on: medians need no more.
COMPARISON_FRAMES = 300


@dataclass(frozen=True)
class ConventionFinding:
    """An alternative reading of the recording that explains it clearly better.

    Attributes
    ----------
    alternative : str
        What the alternative reading assumes, in words (e.g. ``tracker quaternions x,y,z,w``).
    given_mm, given_deg : float
        Median marker residuals of the recording as given (closed-form fit), mm and deg.
    alternative_mm, alternative_deg : float
        The same under the alternative reading.
    """

    alternative: str
    given_mm: float
    given_deg: float
    alternative_mm: float
    alternative_deg: float

    def message(self, what: str) -> str:
        """One line for the user: what was found and how much better it explains the data."""
        return (
            f"{what}: the recording is explained far better if {self.alternative} (median residual "
            f"{self.alternative_mm:.2g} mm, {self.alternative_deg:.2g} deg, against {self.given_mm:.2g} mm, "
            f"{self.given_deg:.2g} deg as read); fix the file or the import options"
        )


def _roll_quaternion(stack: FloatArray) -> FloatArray:
    """Rotations as if their quaternions, stored x,y,z,w, had been read as w,x,y,z."""
    out = as_float_array(stack.copy())
    x, y, z, w = Rotation.from_matrix(stack[:, :3, :3]).as_quat().T
    # the file's numbers n0..n3 were taken as (w, x, y, z) = (n0, n1, n2, n3); read as the
    # file meant them, (x, y, z, w) = (n0, n1, n2, n3) = (w, x, y, z) of the rotation as read
    out[:, :3, :3] = Rotation.from_quat(np.stack([w, x, y, z], axis=1)).as_matrix()
    return out


def _conjugate_rotation(stack: FloatArray) -> FloatArray:
    out = as_float_array(stack.copy())
    out[:, :3, :3] = np.swapaxes(stack[:, :3, :3], 1, 2)
    return out


def _scaled(factor: float) -> Callable[[FloatArray], FloatArray]:
    def scale(stack: FloatArray) -> FloatArray:
        out = as_float_array(stack.copy())
        out[:, :3, 3] *= factor
        return out

    return scale


_TO_MM = _scaled(1000.0)
_FROM_MM = _scaled(0.001)
_SCALINGS = (_TO_MM, _FROM_MM)

#: (words, change to base_from_tcp, change to tracker_from_marker, length unit of the result
#: in mm); None leaves a stack as read. A reading that divides one stack by 1000 puts the whole
#: chain in metres: its residuals are scaled back to mm before they are compared.
_Change = Callable[[FloatArray], FloatArray] | None
ALTERNATIVES: tuple[tuple[str, _Change, _Change, float], ...] = (
    ("the tracker's quaternions are x,y,z,w", None, _roll_quaternion, 1.0),
    ("the robot's quaternions are x,y,z,w", _roll_quaternion, None, 1.0),
    ("the tracker's rotations are conjugated (transposed)", None, _conjugate_rotation, 1.0),
    ("the robot's rotations are conjugated (transposed)", _conjugate_rotation, None, 1.0),
    ("the tracker's poses are inverted (marker_from_tracker)", None, invert_transform, 1.0),
    ("the robot's poses are inverted (eye-in-hand / tcp_from_base)", invert_transform, None, 1.0),
    ("the tracker's lengths are in metres", None, _TO_MM, 1.0),
    ("the robot's lengths are in metres", _TO_MM, None, 1.0),
    ("the tracker's lengths were multiplied by 1000 twice", None, _FROM_MM, 1000.0),
    ("the robot's lengths were multiplied by 1000 twice", _FROM_MM, None, 1000.0),
)
#: The robot and tracker columns swapped is tried as well.
SWAPPED = "the robot and tracker poses are swapped"


def _median_residuals(base_from_tcp: FloatArray, tracker_from_marker: FloatArray) -> tuple[float, float]:
    """Median marker residuals (mm, deg) of Shah's closed form on the two stacks."""
    try:
        tcp_from_marker, base_from_tracker = solve_shah(base_from_tcp, tracker_from_marker)
    except (DegenerateDataError, np.linalg.LinAlgError, ValueError):
        return float("inf"), float("inf")
    predicted = invert_transform(base_from_tracker) @ base_from_tcp @ tcp_from_marker
    distance = np.linalg.norm(predicted[:, :3, 3] - tracker_from_marker[:, :3, 3], axis=1)
    angle = rotation_angle(predicted[:, :3, :3] @ np.swapaxes(tracker_from_marker[:, :3, :3], 1, 2))
    if not (np.all(np.isfinite(distance)) and np.all(np.isfinite(angle))):
        return float("inf"), float("inf")
    return float(np.median(distance)), float(np.degrees(np.median(angle)))


def _clearly_better(given: tuple[float, float], other: tuple[float, float]) -> bool:
    (g_mm, g_deg), (o_mm, o_deg) = given, other
    if not (np.isfinite(o_mm) and np.isfinite(o_deg)):
        return False  # no reading explains what none can solve (a robot that never rotated)
    by_position = o_mm <= CLEARLY_BETTER * g_mm and o_deg <= NO_WORSE * max(g_deg, EXPLAINED_DEG)
    by_rotation = o_deg <= CLEARLY_BETTER * g_deg and o_mm <= NO_WORSE * max(g_mm, EXPLAINED_MM)
    return by_position or by_rotation


def find_better_convention(recording: Recording) -> ConventionFinding | None:
    """The alternative reading of ``recording`` that explains it clearly better, or None.

    Parameters
    ----------
    recording : Recording
        Its visible frames' ``base_from_tcp`` and ``tracker_from_marker`` (mm) are compared
        as read and under each of :data:`ALTERNATIVES` and :data:`SWAPPED`.

    Returns
    -------
    ConventionFinding or None
        The best alternative when it is clearly better (see the module), else None; also None
        when the recording as read is already explained to :data:`EXPLAINED_MM` /
        :data:`EXPLAINED_DEG`.
    """
    rows = np.flatnonzero(recording.visible)
    if len(rows) < 3:
        return None
    rows = rows[np.unique(np.linspace(0, len(rows) - 1, min(COMPARISON_FRAMES, len(rows))).astype(int))]
    robot = np.asarray(recording.base_from_tcp_stack[rows], dtype=float)
    tracker = np.asarray(recording.tracker_from_marker_stack[rows], dtype=float)
    given = _median_residuals(robot, tracker)
    if given[0] <= EXPLAINED_MM and given[1] <= EXPLAINED_DEG:
        return None
    candidates = []
    for words, r, t, unit_mm in ALTERNATIVES:
        if (r is not None and r in _SCALINGS) or (t is not None and t in _SCALINGS):
            # a stack is rescaled only when its lengths are implausible in mm: below
            # METRES_BELOW_MM a robot or tracker moved in metres, above MILLIMETRES_TWICE_ABOVE_MM
            # one already in mm was multiplied again (a tie between the two stacks is so avoided)
            stack = robot if r is not None else tracker
            reach = float(np.median(np.linalg.norm(stack[:, :3, 3], axis=1)))
            if not (reach < METRES_BELOW_MM if unit_mm == 1.0 else reach > MILLIMETRES_TWICE_ABOVE_MM):
                continue
        mm, deg = _median_residuals(robot if r is None else r(robot), tracker if t is None else t(tracker))
        candidates.append((words, (mm * unit_mm, deg)))
    candidates.append((SWAPPED, _median_residuals(tracker, robot)))
    better = [(words, found) for words, found in candidates if _clearly_better(given, found)]
    if not better:
        return None
    # the best of them: the smallest residual relative to the given reading's
    words, (mm, deg) = min(
        better, key=lambda item: item[1][0] / max(given[0], 1e-12) + item[1][1] / max(given[1], 1e-12)
    )
    return ConventionFinding(words, given[0], given[1], mm, deg)


def median_residuals_of(
    recording: Recording, tracker_from_base: FloatArray, tcp_from_marker: FloatArray
) -> tuple[float, float]:
    """Median marker residuals (mm, deg) of a given calibration over the recording's visible frames."""
    rows = np.flatnonzero(recording.visible)
    predicted = tracker_from_base @ recording.base_from_tcp_stack[rows] @ tcp_from_marker
    measured = recording.tracker_from_marker_stack[rows]
    distance = np.linalg.norm(predicted[:, :3, 3] - measured[:, :3, 3], axis=1)
    angle = rotation_angle(predicted[:, :3, :3] @ np.swapaxes(measured[:, :3, :3], 1, 2))
    return float(np.median(distance)), float(np.degrees(np.median(angle)))


def calibration_mismatch(
    recording: Recording, tracker_from_base: FloatArray, tcp_from_marker: FloatArray
) -> str | None:
    """Why a calibration does not belong to a recording, or None when it does.

    It belongs when it explains the recording about as well as the recording's own closed-form
    fit: neither median residual above ``1 / CLEARLY_BETTER`` times the fit's (or than
    :data:`EXPLAINED_MM` / :data:`EXPLAINED_DEG`, whichever is larger).
    """
    rows = np.flatnonzero(recording.visible)
    if len(rows) < 3:
        return None
    given = median_residuals_of(recording, tracker_from_base, tcp_from_marker)
    own = _median_residuals(recording.base_from_tcp_stack[rows], recording.tracker_from_marker_stack[rows])
    limit_mm = max(own[0], EXPLAINED_MM) / CLEARLY_BETTER
    limit_deg = max(own[1], EXPLAINED_DEG) / CLEARLY_BETTER
    if given[0] <= limit_mm and given[1] <= limit_deg:
        return None
    return (
        f"the calibration does not explain this recording (median residual {given[0]:.2g} mm, "
        f"{given[1]:.2g} deg, where the recording's own closed-form fit leaves {own[0]:.2g} mm, "
        f"{own[1]:.2g} deg): it belongs to another recording"
    )
