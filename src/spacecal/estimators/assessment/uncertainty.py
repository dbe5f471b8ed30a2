"""Uncertainty for estimators without a likelihood: the bootstrap over frames.

The closed forms and the paper's estimator have no covariance of their own. Resampling the
visible frames with replacement and re-solving gives the spread of each estimate around
the full-data one, expressed in the same 12 perturbation parameters as the ML covariance
(:func:`spacecal.models.kinematics.apply_pose_step`), so the predicted TRE is computed the
same way. Frames are treated as independent: with systematic errors the spread is
optimistic, as the verdict then says.

On a small set (ten poses, a handful of frames) some resamples draw so few distinct poses
that their motions lose an axis of rotation: a closed form then returns a solution metres
away, and one such resample dominates a sample covariance (eight frames gave tens of metres
for a calibration 0.3 mm off). Those resamples are not the spread of the estimate but a
different, degenerate problem, so resamples further than :data:`OUTLYING_MADS` scaled median
absolute deviations from the median in any parameter are left out before the covariance is
taken (the bootstrap fails when they are half of them).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from spacecal.core.errors import SpacecalError
from spacecal.geometry.arrays import FloatArray
from spacecal.models.kinematics import pose_step_between
from spacecal.records import Recording

#: Bootstrap resamples: enough for a 12x12 covariance to about +-20 % per variance.
RESAMPLES = 50

#: A resample this many scaled median absolute deviations (1.4826 MAD, the standard deviation
#: under a Gaussian) from the median in any parameter is a degenerate draw, not spread: a
#: Gaussian resample lands beyond it with probability 2e-9 per parameter.
OUTLYING_MADS = 6.0

#: MAD of a standard Gaussian's: 1.4826 MAD estimates its standard deviation.
MAD_TO_SD = 1.4826


def bootstrap_covariance(
    recording: Recording,
    solve: Callable[[Recording], tuple[FloatArray, FloatArray]],
    reference_tracker_from_base: FloatArray,
    reference_tcp_from_marker: FloatArray,
    resamples: int = RESAMPLES,
    seed: int = 0,
) -> np.ndarray | None:
    """Covariance (12, 12) of ``solve`` over frame resamples, or None if too few resamples solve.

    Parameters
    ----------
    solve : callable
        recording -> (tracker_from_base, tcp_from_marker).
    reference_tracker_from_base, reference_tcp_from_marker : numpy.ndarray, shape (4, 4)
        The full-data estimate the spread is measured around.
    """
    rng = np.random.default_rng(seed)
    visible = np.flatnonzero(recording.visible)
    samples = []
    for _ in range(resamples):
        rows = np.sort(rng.choice(visible, size=len(visible), replace=True))
        try:
            estimate = solve(recording.select(rows))
        except SpacecalError:
            continue
        samples.append(pose_step_between(reference_tracker_from_base, reference_tcp_from_marker, *estimate))
    steps = np.array(samples)
    if len(steps) >= 2:
        centre = np.median(steps, axis=0)
        spread = MAD_TO_SD * np.median(np.abs(steps - centre), axis=0)
        # a parameter that does not vary (spread 0) judges nothing
        distance = np.abs(steps - centre) / np.where(spread > 0, spread, np.inf)
        steps = steps[np.all(distance <= OUTLYING_MADS, axis=1)]
    if len(steps) < resamples // 2:
        return None
    return np.cov(steps.T)
