"""The blocks of frames a fit is cross-validated on: its segments, else contiguous time blocks.

Both the kinematic method's model selection and the expected error leave these blocks out one
at a time and refit on the rest.
"""

from __future__ import annotations

import numpy as np

from spacecal.geometry.arrays import IntArray

#: Contiguous blocks a recording without segment labels is split into.
TIME_BLOCKS = 6


#: Below this many used frames each frame is its own held-out block (leave-one-out): six time
#: blocks would hold too few frames each, and leaving one frame out disturbs the refit least.
#: A count is no verdict: a small set of well-spread poses is judged by its held-out misfit
#: and its information like any other.
LEAVE_ONE_OUT_BELOW = 30


#: Segments with fewer frames than this get no block of their own.
MINIMUM_BLOCK_FRAMES = 5


def held_out_blocks(segments: np.ndarray, minimum_frames: int = MINIMUM_BLOCK_FRAMES) -> list[IntArray]:
    """Index blocks (into the used frames) to leave out one at a time.

    Parameters
    ----------
    segments : numpy.ndarray of str, shape (N,)
        Segment label of each used frame.

    Returns
    -------
    list of numpy.ndarray of int
        The recording's segments when at least three have ``minimum_frames`` frames each,
        else :data:`TIME_BLOCKS` contiguous blocks, or one block per frame (leave-one-out)
        when there are fewer than :data:`LEAVE_ONE_OUT_BELOW` frames.
    """
    labels = list(dict.fromkeys(np.asarray(segments).tolist()))
    blocks = [np.flatnonzero(segments == label) for label in labels]
    blocks = [b for b in blocks if len(b) >= minimum_frames]
    if len(blocks) >= 3:
        return blocks
    if len(segments) < LEAVE_ONE_OUT_BELOW:
        return [np.array([i]) for i in range(len(segments))]
    return [b for b in np.array_split(np.arange(len(segments)), TIME_BLOCKS) if len(b) > 0]
