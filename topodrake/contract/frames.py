"""Context frames: which frames of a trajectory form a target's context.

A target at frame ``j`` is seen through 2k + 1 frames ``frame_step`` apart
around it, clamped to the trajectory. Samples, policies, the map and the
follower all pick contexts this way.
"""

from __future__ import annotations

import numpy as np

from topodrake.errors import TopodrakeError


def context_frames(n_frames: int, j: int, k: int, frame_step: int = 3) -> np.ndarray:
    """Indices j - k*step .. j + k*step of a trajectory of ``n_frames``, clamped:
    (2k+1,) for one frame ``j``, (M, 2k+1) for an array of M frames (``n_frames``
    may be an (M, 1) array: one trajectory length per frame)."""
    return np.clip(np.asarray(j)[..., None] + frame_step * np.arange(-k, k + 1), 0, n_frames - 1)


def centre_pose(context, k: int) -> np.ndarray:
    """A pose oracle's target: the centre pose (N, 3) of N contexts of poses
    (N, 2k+1, 3); any other shape is refused in one line."""
    ctx = np.asarray(context, np.float64)
    if ctx.ndim != 3 or ctx.shape[1:] != (2 * k + 1, 3):
        raise TopodrakeError(f"oracle target context must be (N, {2 * k + 1}, 3) poses, "
                             f"got {ctx.shape}")
    return ctx[:, k].copy()
