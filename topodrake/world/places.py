"""Choose named places spread over a world's reachable area.

The paper's maps have 10 destinations per environment. We pick them by
farthest-point sampling over reachable cells with generous clearance (so a
place is somewhere a robot would stop, not a doorway), and face each place
toward its most open direction so the camera sees the room.
"""

from __future__ import annotations

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.world.grid import OccupancyGrid


def choose_places(grid: OccupancyGrid, n: int = 10, seed: int = 0,
                  min_clearance: float = 0.9) -> np.ndarray:
    """(n, 3) places ``x, y, heading`` spread over ``grid.reachable``."""
    reach = grid.reachable
    # Prefer open spots (room centres, not corners); relax on cramped maps.
    for clearance in (min_clearance, 0.5 * min_clearance, 0.0):
        cells = np.argwhere(reach & (grid.clearance >= clearance))
        if len(cells) >= 20 * n:
            break
    if len(cells) < n:
        raise TopodrakeError(f"only {len(cells)} free cells: cannot place {n} places")
    xy = grid.to_world(cells)
    rng = np.random.default_rng(seed)
    chosen = [int(rng.integers(len(xy)))]
    dist = np.linalg.norm(xy - xy[chosen[0]], axis=1)
    for _ in range(n - 1):
        # Prefer far cells; among near-ties prefer more clearance.
        score = dist + 0.1 * np.minimum(grid.clearance[cells[:, 0], cells[:, 1]], 2.0)
        k = int(np.argmax(score))
        chosen.append(k)
        dist = np.minimum(dist, np.linalg.norm(xy - xy[k], axis=1))
    pts = xy[chosen]
    headings = np.array([open_direction(grid, p) for p in pts])
    return np.column_stack([pts, headings])


def open_direction(grid: OccupancyGrid, xy: np.ndarray, n_dirs: int = 32,
                   max_range: float = 6.0) -> float:
    """Heading (rad) of the longest free ray from ``xy`` on the grid."""
    angles = np.linspace(-np.pi, np.pi, n_dirs, endpoint=False)
    steps = np.arange(grid.resolution, max_range, grid.resolution)
    best, best_len = 0.0, -1.0
    for a in angles:
        pts = xy + steps[:, None] * np.array([np.cos(a), np.sin(a)])
        rc = grid.to_cell(pts)
        ok = grid.in_bounds(rc)
        rcc = np.clip(rc, 0, np.array(grid.shape) - 1)
        blocked = ~ok | grid.occupied[rcc[:, 0], rcc[:, 1]]
        length = steps[np.argmax(blocked)] if blocked.any() else max_range
        if length > best_len + 1e-9:
            best, best_len = float(a), float(length)
    return best
