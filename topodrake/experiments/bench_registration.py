"""Registration throughput: scan pairs registered per second on one core.

:func:`registration_rate` times :func:`topodrake.registration.icp.register`
on pairs of scans from poses of expert drives, each source three periods
after its target and started 0.2 m / 0.1 rad off the truth (a tracking
controller's warm start). The kernel is single-threaded, so the rate is one
core's.
"""

from __future__ import annotations

import time

import numpy as np

from topodrake.registration.icp import register
from topodrake.se2 import compose, invert
from topodrake.sensing.lidar import Lidar


def registration_rate(world, drive_poses: np.ndarray, batch: int = 256, min_seconds: float = 2.0,
                      seed: int = 0, gap: int = 3) -> float:
    """Registrations per second of ``batch`` pairs (frames ``i`` and ``i +
    gap`` of ``drive_poses`` (T, 3)) of ``world``, timed over at least
    ``min_seconds``."""
    poses = np.asarray(drive_poses, np.float64).reshape(-1, 3)
    if len(poses) <= gap:
        from topodrake.errors import TopodrakeError
        raise TopodrakeError(f"a drive of {len(poses)} poses has no frame pairs {gap} apart")
    rng = np.random.default_rng(seed)
    i = rng.integers(0, len(poses) - gap, batch)
    tgt, src = poses[i], poses[i + gap]
    lidar = Lidar(world)
    st, ss = lidar.scan(tgt), lidar.scan(src)
    truth = compose(invert(tgt), src)
    ang = rng.uniform(0, 2 * np.pi, batch)
    guess = truth + np.column_stack([0.2 * np.cos(ang), 0.2 * np.sin(ang),
                                     rng.choice([-0.1, 0.1], batch)])
    register(ss[:2], st[:2], guess[:2])          # compiles (or loads the cached kernel)
    calls, start = 0, time.perf_counter()
    while True:
        register(ss, st, guess)
        calls += 1
        elapsed = time.perf_counter() - start
        if elapsed >= min_seconds:
            return calls * batch / elapsed
