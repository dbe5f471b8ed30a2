"""A simulated pivot of the needle on the robot's marker: the tool turned about its tip in a
divot at the site, tracked by the world's tracker (its noise, bias fields and visibility).

The needle tip is the true TCP origin, so a pivot measures it in the marker frame
(:mod:`spacecal.registration.pivot`) as a user would with the tool in hand, with the error the
tracker leaves in it.
"""

from __future__ import annotations

import numpy as np

from spacecal.core.errors import DegenerateDataError
from spacecal.geometry.arrays import FloatArray, as_float_array
from spacecal.geometry.transforms import invert_transform, rotvec_to_matrix
from spacecal.models.kinematics import forward_kinematics
from spacecal.records import PivotResult
from spacecal.registration.pivot import pivot_calibration
from spacecal.sim.world import World

#: Frames of a pivot, and the largest tilt (deg) of the tool from its pose at home.
PIVOT_FRAMES = 200
PIVOT_CONE_DEG = 25.0


def pivot_poses_true(world: World, frames: int, cone_deg: float, rng: np.random.Generator) -> FloatArray:
    """True ``tracker_from_marker`` (frames, 4, 4) of the tool turned about its tip: tilts up to
    ``cone_deg`` about random axes from its pose with the robot at home, the tip in a divot at
    the site."""
    base_from_tcp = forward_kinematics(world.true_model, world.home_joints_rad)
    home = world.tracker_from_base @ base_from_tcp @ world.tcp_from_marker
    tip_in_marker = invert_transform(world.tcp_from_marker)[:3, 3]
    pivot_in_tracker = home[:3, :3] @ tip_in_marker + home[:3, 3]
    axes = rng.normal(size=(frames, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.radians(cone_deg) * np.sqrt(rng.uniform(0.0, 1.0, (frames, 1)))  # even over the cone
    poses = np.tile(np.eye(4), (frames, 1, 1))
    poses[:, :3, :3] = rotvec_to_matrix(axes * angles) @ home[:3, :3]
    poses[:, :3, 3] = pivot_in_tracker - poses[:, :3, :3] @ tip_in_marker
    return as_float_array(poses)


def simulate_pivot(
    world: World, frames: int = PIVOT_FRAMES, cone_deg: float = PIVOT_CONE_DEG, seed: int = 0
) -> PivotResult:
    """The needle's pivot calibration (``aos``) from the world's tracker.

    Parameters
    ----------
    world : World
        Its tracker measures the poses (noise, bias fields, visibility); its noise generator
        is not drawn from, so the world's recording is unchanged.
    frames : int
    cone_deg : float
        Largest tilt from the pose at home, deg.
    seed : int
        Seeds the tilts and the tracker's noise of the pivot.

    Raises
    ------
    DegenerateDataError
        When the tracker sees too few of the frames.
    """
    rng = np.random.default_rng([world.scenario.seed, 17, seed])
    truth = pivot_poses_true(world, frames, cone_deg, rng)
    kept_rng = world.noise_rng
    world.noise_rng = rng
    try:
        tracked = world.track_marker(truth)
    finally:
        world.noise_rng = kept_rng
    seen = np.isfinite(tracked.tracker_from_marker[:, 0, 0])
    if seen.sum() < 10:
        raise DegenerateDataError(f"the tracker saw {int(seen.sum())} of {frames} pivot frames")
    return pivot_calibration(tracked.tracker_from_marker[seen], "aos")
