"""Whether a plan's link is true: its two ends within the controller's reach in truth.

A link (a start, goal or direct link, a cross or junction edge) joins two
poses that perception judged one place. In truth (privileged geometry,
evaluation only) the ends are within reach (:func:`within_reach`) where the
free space joins them by a way of at most :data:`REACH_M` (the geometric
oracle RE's reach) that does not wind round walls: the straight line keeps
clear of them (sight), or the A* way is at most :data:`WINDING` times the
straight distance plus :data:`WINDING_SLACK_M` (a door beside the line). A
link through a wall to a look-alike room is not within reach, however short;
a link across an open room is, however long.
"""

from __future__ import annotations

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.expert.sight import segment_clear
from topodrake.topomap.scorer import OracleConfig
from topodrake.world.astar import AStarConfig, astar, cell_costs, path_length

#: the farthest the controller reaches, metres (the geometric oracle RE's reach)
REACH_M = OracleConfig().reach_m
#: the clearance a straight line keeps from walls to count as sight, metres
SIGHT_CLEARANCE_M = OracleConfig().sight_clearance_m
#: a way round walls at most this times the straight distance ...
WINDING = 1.5
#: ... plus this, metres, is still within reach
WINDING_SLACK_M = 1.0

_COSTS: dict[int, tuple[object, np.ndarray]] = {}


def _costs(grid) -> np.ndarray:
    """A* cell costs of ``grid``, computed once per grid."""
    held = _COSTS.get(id(grid))
    if held is None or held[0] is not grid:
        _COSTS.clear()
        held = _COSTS[id(grid)] = (grid, cell_costs(grid, AStarConfig()))
    return held[1]


def way_m(world, a, b) -> float:
    """The A* way from the point ``a`` to ``b`` (x, y, ...) in metres; inf
    where no way joins them or an end is not free."""
    try:
        return path_length(astar(world.grid, a, b, costs=_costs(world.grid)))
    except TopodrakeError:
        return float("inf")


def within_reach(world, a, b) -> bool:
    """Whether the poses (or points) ``a`` and ``b`` lie within the
    controller's reach of each other in truth (the module's rule)."""
    a, b = np.asarray(a, np.float64)[:2], np.asarray(b, np.float64)[:2]
    d = float(np.hypot(*(b - a)))
    if d > REACH_M:
        return False
    g = world.grid
    if segment_clear(g.clearance, g.origin[0], g.origin[1], g.resolution, SIGHT_CLEARANCE_M,
                     a[0], a[1], b[0], b[1]):
        return True
    way = way_m(world, a, b)
    return way <= REACH_M and way <= WINDING * d + WINDING_SLACK_M
