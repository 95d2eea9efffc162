"""Context frames: which frames of a trajectory form a target's context.

A target at frame ``j`` is seen through 2k + 1 frames ``frame_step`` apart
around it, clamped to the trajectory. Samples, policies, the map and the
follower all pick contexts this way.
"""

from __future__ import annotations

import numpy as np


def context_frames(n_frames: int, j: int, k: int, frame_step: int = 3) -> np.ndarray:
    """Indices j - k*step .. j + k*step of a trajectory of ``n_frames``, clamped:
    (2k+1,) for one frame ``j``, (M, 2k+1) for an array of M frames (``n_frames``
    may be an (M, 1) array: one trajectory length per frame)."""
    return np.clip(np.asarray(j)[..., None] + frame_step * np.arange(-k, k + 1), 0, n_frames - 1)
