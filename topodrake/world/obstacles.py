"""Obstacles that were not there when a map was built.

A planned route drives past furniture that moved, a box left in a corridor,
a person standing still: :func:`with_boxes` returns a copy of a world with
extra square boxes (seen by the camera and the lidar, occupied on the grid,
so collisions count), and :func:`boxes_on_path` places such boxes on a
driven or planned path the way the paper's real-car trials did: on the
route, away from its start and its goal, never closing the way (A* must
still find a path around them, so a good local controller can pass).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.world.grid import OccupancyGrid, rasterize_walls
from topodrake.world.textures import FURNITURE_TEXTURES
from topodrake.world.walls import Faces, WallSet
from topodrake.world.world import World

SIZE_M = (0.3, 0.6)        # side of a box, uniform
KEEP_CLEAR_M = 1.0          # from the path's start and end


def with_boxes(world: World, boxes: np.ndarray, texture: int | None = None) -> World:
    """``world`` with axis-aligned boxes (B, 4) ``xmin, ymin, xmax, ymax``
    added as walls (rendered, ray-cast and occupied on the grid)."""
    boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
    if len(boxes) == 0:
        return world
    if not np.all(np.isfinite(boxes)) or np.any(boxes[:, 2:] <= boxes[:, :2]):
        raise TopodrakeError("an obstacle box needs finite xmin < xmax and ymin < ymax")
    tex = np.full(len(boxes), FURNITURE_TEXTURES[0] if texture is None else texture, np.int32)
    return with_walls(world, WallSet.from_boxes(boxes, tex))


def with_walls(world: World, extra: WallSet) -> World:
    """``world`` with the walls ``extra`` added (rendered, ray-cast and
    occupied on the grid)."""
    grid = world.grid
    occupied = grid.occupied | rasterize_walls(extra, grid.origin, grid.shape, grid.resolution)
    faces = None
    if world.faces_override is not None:
        new = Faces.from_walls(extra)
        old = world.faces_override
        faces = Faces(np.concatenate([old.a, new.a]), np.concatenate([old.b, new.b]),
                      np.concatenate([old.texture, new.texture]), np.concatenate([old.u0, new.u0]))
    return replace(world, walls=world.walls.concat(extra),
                   grid=OccupancyGrid(occupied, grid.origin, grid.resolution, grid.car_radius),
                   faces_override=faces)


def boxes_on_path(world: World, path: np.ndarray, n: int, rng: np.random.Generator,
                  size_m: tuple[float, float] = SIZE_M, keep_clear_m: float = KEEP_CLEAR_M,
                  attempts: int = 200) -> np.ndarray:
    """(n, 4) square boxes centred on the polyline ``path`` (K, 2+) (uniform
    in arc length, jittered by up to 0.1 m), each
    farther than ``keep_clear_m`` from the path's ends and from the other
    boxes' centres, such that the car can still get from the path's start
    to its end (A* in the world with the boxes). Raises when ``attempts``
    draws do not place them all."""
    path = np.asarray(path, np.float64)
    if path.ndim != 2 or path.shape[1] < 2 or len(path) < 2:
        raise TopodrakeError(f"a path for obstacles must be (K >= 2, 2), got {path.shape}")
    xy = densify(path[:, :2], 0.05)      # uniform in arc length, not at the path's points
    ends = np.stack([xy[0], xy[-1]])
    far = np.min(np.hypot(*(xy[:, None, :] - ends[None]).transpose(2, 0, 1)), axis=1) > keep_clear_m
    candidates = xy[far]
    if n > 0 and len(candidates) == 0:
        raise TopodrakeError(f"the path ({len(path)} points) has no point {keep_clear_m} m away "
                             f"from both its ends to put an obstacle on")
    boxes: list[np.ndarray] = []
    for _ in range(attempts):
        if len(boxes) == n:
            break
        c = candidates[rng.integers(len(candidates))] + rng.uniform(-0.1, 0.1, 2)
        if any(np.hypot(*(c - 0.5 * (b[:2] + b[2:]))) < keep_clear_m for b in boxes):
            continue
        half = 0.5 * rng.uniform(*size_m)
        box = np.array([c[0] - half, c[1] - half, c[0] + half, c[1] + half])
        trial = with_boxes(world, np.array(boxes + [box]))
        if _passable(trial, xy[0], xy[-1]):
            boxes.append(box)
    if len(boxes) < n:
        raise TopodrakeError(f"could place only {len(boxes)} of {n} obstacles on the path "
                             f"without closing it")
    return np.array(boxes).reshape(-1, 4)


def densify(xy: np.ndarray, step: float) -> np.ndarray:
    """Points every ``step`` metres along the polyline ``xy``."""
    seg = np.hypot(*np.diff(xy, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] <= 0:
        return xy[:1]
    t = np.linspace(0.0, s[-1], max(2, int(np.ceil(s[-1] / step)) + 1))
    return np.column_stack([np.interp(t, s, xy[:, 0]), np.interp(t, s, xy[:, 1])])


def _passable(world: World, a: np.ndarray, b: np.ndarray) -> bool:
    """Whether the car can still drive from ``a`` to ``b`` (both in free
    space and in one connected component of it)."""
    from scipy import ndimage

    grid = world.grid
    ra, rb = grid.to_cell(a), grid.to_cell(b)
    free = grid.free_space
    if not (grid.in_bounds(ra) and grid.in_bounds(rb)) or not (free[tuple(ra)] and free[tuple(rb)]):
        return False
    labels, _ = ndimage.label(free, structure=np.ones((3, 3), bool))
    return labels[tuple(ra)] == labels[tuple(rb)] != 0
