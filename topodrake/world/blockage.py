"""A passage closed on a planned route: a door shut in a building.

A navigation system that planned through a door must notice that the door is
shut and find another way. :func:`block_on_path` places a thin wall across
the route, wall to wall, at a narrow place (a door, a corridor) away from
the route's ends, where another way from its start to its goal remains and
the shortest way grows (so the block really closes the route as planned);
:func:`blocked_world` is the world with that block (rendered, ray-cast and
occupied on the grid) for A* and oracles.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from topodrake.errors import TopodrakeError
from topodrake.world.astar import AStarConfig, astar, path_length
from topodrake.world.grid import OccupancyGrid, rasterize_walls
from topodrake.world.obstacles import densify, with_walls
from topodrake.world.textures import FURNITURE_TEXTURES
from topodrake.world.walls import WallSet
from topodrake.world.world import World

THICKNESS_M = 0.1
INTO_WALL_M = 0.05        # how far the block reaches into the walls at its ends
MIN_DETOUR_M = 1.0        # the shortest way must grow by this much
STEP_M = 0.05             # spacing of candidate points along the path
PIECE_M = 1.0             # a narrow stretch longer than this offers several candidates
RAY_M = 4.0               # rays reach this far looking for the walls of a passage
ANGLES = np.deg2rad(np.arange(-45.0, 46.0, 15.0))   # chords tried around the normal
_GEODESIC = AStarConfig(wall_weight=0.0)


def block_on_path(world: World, path: np.ndarray, rng: np.random.Generator,
                  max_width_m: float = 2.0, keep_clear_m: float = 1.5) -> np.ndarray:
    """(4, 2) corners (counter-clockwise) of a block ``THICKNESS_M`` thick
    closing, wall to wall, a passage at most ``max_width_m`` wide that the
    polyline ``path`` (K, 2+) crosses, farther than ``keep_clear_m`` from
    the path's ends, such that the path's start and end stay connected in
    free space and the shortest way between them grows by at least
    ``MIN_DETOUR_M``. Picked at random with ``rng`` among such passages;
    raises when there is none."""
    path = np.asarray(path, np.float64)
    if path.ndim != 2 or path.shape[1] < 2 or len(path) < 2:
        raise TopodrakeError(f"a path to block must be (K >= 2, 2), got {path.shape}")
    if not np.all(np.isfinite(path[:, :2])):
        raise TopodrakeError("a path to block must have finite coordinates")
    if not (np.isfinite(max_width_m) and max_width_m > 0
            and np.isfinite(keep_clear_m) and keep_clear_m >= 0):
        raise TopodrakeError(f"max_width_m must be > 0 and keep_clear_m >= 0, got "
                             f"{max_width_m} and {keep_clear_m}")
    xy = densify(path[:, :2], STEP_M)
    start = world.check_pose(xy[0], "the path's start")[:2]
    goal = world.check_pose(xy[-1], "the path's end")[:2]
    before = path_length(astar(world.grid, start, goal, _GEODESIC))
    segs = _chords(world, xy)
    ok = np.isfinite(segs).all(axis=1)
    ok[ok] &= np.hypot(*(segs[ok, 2:] - segs[ok, :2]).T) <= max_width_m + 2 * INTO_WALL_M
    ok[ok] &= np.minimum(_to_segment(start, segs[ok]),
                         _to_segment(goal, segs[ok])) - 0.5 * THICKNESS_M > keep_clear_m
    tried = 0
    for idx in _pieces(ok, segs, rng):
        corners = _corners(segs[idx])
        grid = _blocked_grid(world.grid, corners)
        tried += 1
        if not _connected(grid, start, goal):
            continue
        after = path_length(astar(grid, start, goal, _GEODESIC))
        if after >= before + MIN_DETOUR_M:
            return corners
    why = (f"closing any of its {tried} narrow place(s) cuts the start off the goal or "
           f"lengthens the way by less than {MIN_DETOUR_M} m" if tried else
           f"it has no place at most {max_width_m} m wide farther than {keep_clear_m} m "
           f"from its ends")
    raise TopodrakeError(f"no passage on the route can be closed with another way left: "
                         f"on the {path_length(xy):.1f} m route {why}")


def blocked_world(world: World, corners: np.ndarray) -> World:
    """A copy of ``world`` with the block ``corners`` (4, 2) added as a wall
    (rendered, ray-cast and occupied on the grid)."""
    return with_walls(world, _as_wall(corners))


def block_faces(corners: np.ndarray) -> np.ndarray:
    """(4, 4) sides ``ax, ay, bx, by`` of the block, counter-clockwise."""
    c = _as_wall(corners).corners()[0]
    return np.concatenate([c, np.roll(c, -1, axis=0)], axis=1)


def _chords(world: World, xy: np.ndarray) -> np.ndarray:
    """(N, 4) for each point of ``xy``: the shortest segment through it,
    within 45 degrees of the path's normal, whose centre line and both
    edges (``THICKNESS_M`` apart) reach walls, extended ``INTO_WALL_M``
    into them; NaN where a ray meets nothing."""
    k = max(1, round(0.2 / STEP_M))          # tangent over +-0.2 m of path
    ahead = xy[np.minimum(np.arange(len(xy)) + k, len(xy) - 1)]
    behind = xy[np.maximum(np.arange(len(xy)) - k, 0)]
    heading = np.arctan2(*(ahead - behind).T[::-1])
    angle = heading[:, None] + 0.5 * np.pi + ANGLES[None]          # (N, A)
    u = np.stack([np.cos(angle), np.sin(angle)], axis=-1)           # (N, A, 2)
    side = np.stack([-u[..., 1], u[..., 0]], axis=-1)
    offsets = np.array([-0.5, 0.0, 0.5]) * THICKNESS_M
    origins = xy[:, None, None] + offsets[None, None, :, None] * side[:, :, None]   # (N, A, 3, 2)
    origins = np.broadcast_to(origins[None], (2, *origins.shape))
    dirs = np.stack([u, -u])[:, :, :, None].repeat(3, axis=3)        # (2, N, A, 3, 2)
    t = _grid_rays(world.grid, origins.reshape(-1, 2), dirs.reshape(-1, 2), RAY_M)
    # the walls as the grid holds them (a cell is a wall), reached into by INTO_WALL_M
    reach = t.reshape(2, len(xy), len(ANGLES), 3).max(axis=3) + INTO_WALL_M + world.grid.resolution
    best = np.argmin(np.nan_to_num(reach.sum(axis=0), nan=np.inf), axis=1)
    rows = np.arange(len(xy))
    ub = u[rows, best]
    ends = [xy + reach[0, rows, best, None] * ub, xy - reach[1, rows, best, None] * ub]
    seg = np.concatenate(ends, axis=1)
    seg[~np.isfinite(seg).all(axis=1)] = np.nan
    return seg


def _grid_rays(grid, origins: np.ndarray, dirs: np.ndarray, tmax: float) -> np.ndarray:
    """(R,) distance along each unit ray (R, 2) from ``origins`` (R, 2) to
    the first occupied cell of ``grid``, sampled every half cell; inf
    where none lies within ``tmax``."""
    step = 0.5 * grid.resolution
    t = np.arange(0.0, tmax + step, step)
    out = np.full(len(origins), np.inf)
    for lo in range(0, len(origins), 4096):          # bounded memory on long routes
        o, d = origins[lo:lo + 4096], dirs[lo:lo + 4096]
        pts = o[:, None, :] + t[None, :, None] * d[:, None, :]
        rc = grid.to_cell(pts.reshape(-1, 2))
        inside = grid.in_bounds(rc)
        occ = np.ones(len(rc), bool)                 # off the grid counts as a wall
        occ[inside] = grid.occupied[rc[inside, 0], rc[inside, 1]]
        occ = occ.reshape(len(o), len(t))
        hit = occ.any(axis=1)
        out[lo:lo + 4096][hit] = t[np.argmax(occ[hit], axis=1)]
    return out


def _pieces(ok: np.ndarray, segs: np.ndarray, rng: np.random.Generator):
    """Indices of candidate points in random order: one per narrow stretch
    of the path (split every ``PIECE_M``), its narrowest point."""
    idx = np.flatnonzero(ok)
    if len(idx) == 0:
        return []
    breaks = np.flatnonzero(np.diff(idx) > 1) + 1
    runs = [r for run in np.split(idx, breaks)
            for r in np.array_split(run, int(np.ceil(len(run) * STEP_M / PIECE_M)))]
    width = np.hypot(*(segs[:, 2:] - segs[:, :2]).T)
    picks = [int(r[np.argmin(width[r])]) for r in runs]
    return [picks[i] for i in rng.permutation(len(picks))]


def _corners(seg: np.ndarray) -> np.ndarray:
    return WallSet(seg[None], np.array([THICKNESS_M]), np.zeros(1, np.int32)).corners()[0]


def _as_wall(corners: np.ndarray) -> WallSet:
    """The block (4, 2) corners of a rectangle as one wall."""
    c = np.asarray(corners, np.float64)
    if c.shape != (4, 2) or not np.all(np.isfinite(c)):
        raise TopodrakeError(f"a block needs (4, 2) finite corners, got {c.shape}")
    e, f = c[1] - c[0], c[2] - c[1]
    if e[0] * f[1] - e[1] * f[0] < 0:     # clockwise: turn it round
        c = c[::-1]
    p0, p1 = 0.5 * (c[0] + c[3]), 0.5 * (c[1] + c[2])
    side, across = c[1] - c[0], c[3] - c[0]
    # corners as recorded (to the millimetre) still make their rectangle
    if (not np.allclose(c[2] - c[1], across, atol=5e-3)
            or abs(side @ across) > 5e-3 * max(1.0, np.hypot(*side), np.hypot(*across))):
        raise TopodrakeError("a block's corners must be those of a rectangle, in order")
    texture = np.array([FURNITURE_TEXTURES[0]], np.int32)
    return WallSet(np.concatenate([p0, p1])[None], np.array([np.hypot(*across)]), texture)


def _blocked_grid(grid: OccupancyGrid, corners: np.ndarray) -> OccupancyGrid:
    mask = rasterize_walls(_as_wall(corners), grid.origin, grid.shape, grid.resolution)
    return OccupancyGrid(grid.occupied | mask, grid.origin, grid.resolution, grid.car_radius)


def _connected(grid: OccupancyGrid, a: np.ndarray, b: np.ndarray) -> bool:
    """Whether ``a`` and ``b`` lie in one 8-connected component of free space."""
    ra, rb = grid.to_cell(a), grid.to_cell(b)
    free = grid.free_space
    if not (free[tuple(ra)] and free[tuple(rb)]):
        return False
    labels, _ = ndimage.label(free, structure=np.ones((3, 3), bool))
    return labels[tuple(ra)] == labels[tuple(rb)] != 0


def _to_segment(p: np.ndarray, segs: np.ndarray) -> np.ndarray:
    """Distance from point ``p`` to each segment (N, 4)."""
    a, d = segs[:, :2], segs[:, 2:] - segs[:, :2]
    s = np.clip(np.einsum("ij,ij->i", p - a, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-12),
                0.0, 1.0)
    return np.hypot(*(a + s[:, None] * d - p).T)
