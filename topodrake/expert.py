"""The A* expert: waypoints along a planned path, for many cars at once.

Each car has an A* path to its goal. Every control step the expert advances
the car's progress index to the nearest path point a little ahead of it, then
returns the farthest path point within ``lookahead_m`` of path length that the
car can see along a collision-free straight line (checked on the c-space
grid). Paths of different lengths are packed into one array with offsets.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np


@dataclass(frozen=True)
class ExpertConfig:
    lookahead_m: float = 5.0
    search_ahead_m: float = 2.0   # how far ahead the progress index may jump per step


@dataclass
class PackedPaths:
    """Paths (K_i, 2) packed as ``points`` with ``offsets`` (N + 1,) and arc length."""

    points: np.ndarray
    offsets: np.ndarray
    arclen: np.ndarray

    @classmethod
    def pack(cls, paths: list[np.ndarray]) -> "PackedPaths":
        offsets = np.zeros(len(paths) + 1, np.int64)
        offsets[1:] = np.cumsum([len(p) for p in paths])
        points = np.ascontiguousarray(np.concatenate(paths), np.float64)
        arclen = np.concatenate([np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
                                 for p in paths])
        return cls(points, offsets, arclen)

    def goals(self) -> np.ndarray:
        return self.points[self.offsets[1:] - 1]


@nb.njit(cache=True, inline="always")
def line_free(free, ox, oy, res, x0, y0, x1, y1):
    """True when every point of the segment lies in free c-space cells."""
    dx = x1 - x0
    dy = y1 - y0
    n = int(math.ceil(math.sqrt(dx * dx + dy * dy) / (0.5 * res))) + 1
    h, w = free.shape
    for k in range(n + 1):
        s = k / n
        c = int(math.floor((x0 + s * dx - ox) / res))
        r = int(math.floor((y0 + s * dy - oy) / res))
        if r < 0 or c < 0 or r >= h or c >= w or not free[r, c]:
            return False
    return True


@nb.njit(cache=True)
def _expert(free, ox, oy, res, points, offsets, arclen, cars, progress, positions,
            lookahead, search_ahead, out_wp, out_progress):
    for i in range(positions.shape[0]):
        car = cars[i]
        lo = offsets[car]
        hi = offsets[car + 1]
        px = positions[i, 0]
        py = positions[i, 1]
        p = max(lo, min(progress[car], hi - 1))
        best = p
        best_d = math.inf
        j = p
        while j < hi and arclen[j] - arclen[p] <= search_ahead:
            d = (points[j, 0] - px) ** 2 + (points[j, 1] - py) ** 2
            if d < best_d:
                best_d = d
                best = j
            j += 1
        out_progress[i] = best
        wp = best
        j = best + 1
        while j < hi and arclen[j] - arclen[best] <= lookahead:
            if not line_free(free, ox, oy, res, px, py, points[j, 0], points[j, 1]):
                break
            wp = j
            j += 1
        out_wp[i, 0] = points[wp, 0]
        out_wp[i, 1] = points[wp, 1]


def expert_waypoints(grid, paths: PackedPaths, progress: np.ndarray, positions: np.ndarray,
                     config: ExpertConfig = ExpertConfig(),
                     cars: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """World-frame waypoints (M, 2) and updated progress (M,) for ``cars`` (M,)
    (default: all), whose positions (M, 2) are given. ``progress`` (N,) holds
    absolute indices into ``paths.points``; start each car at
    ``paths.offsets[:-1]``."""
    n = len(positions)
    cars = np.arange(n) if cars is None else np.asarray(cars, np.int64)
    wp = np.empty((n, 2))
    prog = np.empty(n, np.int64)
    _expert(grid.free_space, grid.origin[0], grid.origin[1], grid.resolution,
            paths.points, paths.offsets, paths.arclen, cars, np.asarray(progress, np.int64),
            np.ascontiguousarray(positions[:, :2], np.float64), config.lookahead_m,
            config.search_ahead_m, wp, prog)
    return wp, prog
