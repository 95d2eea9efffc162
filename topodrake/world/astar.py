"""A* on the occupancy grid: 8-connected, octile heuristic, wall-averse cost.

The step cost is the step length times ``1 + wall_weight * exp(-(d - r) / falloff)``
where ``d`` is the cell's clearance and ``r`` the car radius, so paths keep
away from walls where there is room and still pass narrow doors. The octile
distance stays an admissible heuristic because every multiplier is >= 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.world.grid import OccupancyGrid


@dataclass(frozen=True)
class AStarConfig:
    wall_weight: float = 4.0
    falloff_m: float = 0.25


@nb.njit(cache=True, inline="always")
def _heap_push(heap_f, heap_i, size, f, i):
    k = size
    heap_f[k] = f
    heap_i[k] = i
    while k > 0:
        p = (k - 1) >> 1
        if heap_f[p] <= heap_f[k]:
            break
        heap_f[p], heap_f[k] = heap_f[k], heap_f[p]
        heap_i[p], heap_i[k] = heap_i[k], heap_i[p]
        k = p
    return size + 1


@nb.njit(cache=True, inline="always")
def _heap_pop(heap_f, heap_i, size):
    top = heap_i[0]
    size -= 1
    heap_f[0] = heap_f[size]
    heap_i[0] = heap_i[size]
    k = 0
    while True:
        left = 2 * k + 1
        if left >= size:
            break
        c = left
        if left + 1 < size and heap_f[left + 1] < heap_f[left]:
            c = left + 1
        if heap_f[k] <= heap_f[c]:
            break
        heap_f[c], heap_f[k] = heap_f[k], heap_f[c]
        heap_i[c], heap_i[k] = heap_i[k], heap_i[c]
        k = c
    return top, size


@nb.njit(cache=True)
def _astar(free, cell_cost, start, goal):
    h, w = free.shape
    n = h * w
    g = np.full(n, np.inf)
    parent = np.full(n, -1, np.int64)
    closed = np.zeros(n, np.bool_)
    cap = 8 * n + 8
    heap_f = np.empty(cap)
    heap_i = np.empty(cap, np.int64)
    s = start[0] * w + start[1]
    t = goal[0] * w + goal[1]
    g[s] = 0.0
    size = _heap_push(heap_f, heap_i, 0, 0.0, s)
    dr = np.array([-1, -1, -1, 0, 0, 1, 1, 1])
    dc = np.array([-1, 0, 1, -1, 1, -1, 0, 1])
    sq2 = np.sqrt(2.0)
    gr, gc = goal[0], goal[1]
    while size > 0:
        cur, size = _heap_pop(heap_f, heap_i, size)
        if closed[cur]:
            continue
        if cur == t:
            break
        closed[cur] = True
        r = cur // w
        c = cur - r * w
        for k in range(8):
            rr = r + dr[k]
            cc = c + dc[k]
            if rr < 0 or rr >= h or cc < 0 or cc >= w or not free[rr, cc]:
                continue
            diag = dr[k] != 0 and dc[k] != 0
            if diag and not (free[r, cc] and free[rr, c]):
                continue  # no corner cutting
            nxt = rr * w + cc
            if closed[nxt]:
                continue
            step = sq2 if diag else 1.0
            ng = g[cur] + step * 0.5 * (cell_cost[r, c] + cell_cost[rr, cc])
            if ng < g[nxt]:
                g[nxt] = ng
                parent[nxt] = cur
                ddr = abs(rr - gr)
                ddc = abs(cc - gc)
                hh = max(ddr, ddc) + (sq2 - 1.0) * min(ddr, ddc)
                size = _heap_push(heap_f, heap_i, size, ng + hh, nxt)
    if not np.isfinite(g[t]):
        return np.zeros((0, 2), np.int64), np.inf
    count = 1
    k = t
    while k != s:
        k = parent[k]
        count += 1
    path = np.empty((count, 2), np.int64)
    k = t
    for i in range(count - 1, -1, -1):
        path[i, 0] = k // w
        path[i, 1] = k - (k // w) * w
        k = parent[k]
    return path, g[t]


def cell_costs(grid: OccupancyGrid, config: AStarConfig) -> np.ndarray:
    d = np.minimum(grid.clearance, 1e3)
    return 1.0 + config.wall_weight * np.exp(-(d - grid.car_radius) / config.falloff_m)


def astar(grid: OccupancyGrid, start_xy, goal_xy, config: AStarConfig = AStarConfig(),
          costs: np.ndarray | None = None) -> np.ndarray:
    """Shortest wall-averse path from ``start_xy`` to ``goal_xy`` in metres.

    Returns a (K, 2) array whose first and last rows are the exact start and
    goal. Raises :class:`TopodrakeError` when either end is not in the free
    configuration space or no path joins them.
    """
    start_xy = np.asarray(start_xy, dtype=np.float64)[:2]
    goal_xy = np.asarray(goal_xy, dtype=np.float64)[:2]
    free = grid.free_space
    ends = grid.to_cell(np.stack([start_xy, goal_xy]))
    for name, xy, rc in (("start", start_xy, ends[0]), ("goal", goal_xy, ends[1])):
        if not grid.in_bounds(rc):
            raise TopodrakeError(f"{name} ({xy[0]:.2f}, {xy[1]:.2f}) is outside the map")
        if not free[rc[0], rc[1]]:
            raise TopodrakeError(
                f"{name} ({xy[0]:.2f}, {xy[1]:.2f}) is not free: within "
                f"{grid.car_radius:.2f} m of an obstacle")
    if costs is None:
        costs = cell_costs(grid, config)
    cells, cost = _astar(free, costs, ends[0], ends[1])
    if not np.isfinite(cost):
        raise TopodrakeError(
            f"goal ({goal_xy[0]:.2f}, {goal_xy[1]:.2f}) is unreachable from "
            f"start ({start_xy[0]:.2f}, {start_xy[1]:.2f})")
    path = grid.to_world(cells)
    path[0] = start_xy
    path[-1] = goal_xy
    return path


def path_length(path: np.ndarray) -> float:
    return float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1)))
