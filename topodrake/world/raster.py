"""Worlds from occupancy rasters (scanned maps, rasterised floor plans).

:func:`world_from_occupancy` turns a boolean raster into a :class:`World`:

* the outermost ring of cells is made occupied so nothing can leave the map;
* only the largest 4-connected free region is kept, everything else becomes
  occupied (enclosed free specks inside walls or unknown areas vanish, and a
  one-cell diagonal wall does not join two regions); 4-connected free with
  8-connected walls is the consistent pairing, and faces are drawn on 4-edges;
* one-cell-wide dead-end cracks of free space (cells with at most one free
  4-neighbour, repeatedly) are filled: SLAM leaves many along walls, no car
  fits into them and each would cost the renderer two or three extra faces;
* occupied specks of fewer than ``min_obstacle_cells`` cells (default 2, so
  single isolated cells) are SLAM noise and become free; anything larger is
  kept as a real obstacle (chair and table legs, furniture, glass frames);
* all occupied cells become walls: maximal row runs merged across
  consecutive rows into axis-aligned boxes (covering the solid unknown areas
  as whole blocks gives fewer boxes than a thin band along the free space);
* the faces the renderer draws are the cell edges between occupied and free,
  merged into maximal straight segments, split every ``texture_block_m`` so
  that each block and facing direction gets its own wall texture (a seeded
  hash into :data:`WALL_TEXTURES`), and oriented like :meth:`Faces.from_walls`
  (``a -> b`` with free space on the right, normal ``(dy, -dx)``);
* one room: every free cell (and the one-cell rim of wall around it) is
  region 0 with one floor and one ceiling texture; ``places`` are 10 places
  from :func:`choose_places`.
"""

from __future__ import annotations

import zlib

import numpy as np
from scipy import ndimage

from topodrake.errors import TopodrakeError
from topodrake.world.textures import CEILING_TEXTURES, FLOOR_TEXTURES, WALL_TEXTURES
from topodrake.world.grid import OccupancyGrid
from topodrake.world.places import choose_places
from topodrake.world.walls import Faces, WallSet
from topodrake.world.world import World

_EIGHT = np.ones((3, 3), bool)


def world_from_occupancy(name: str, occupied: np.ndarray, origin, resolution: float,
                         source: str = "", *, min_obstacle_cells: int = 2,
                         fill_cracks: bool = True, texture_block_m: float = 4.0,
                         seed: int = 0, n_places: int = 10) -> World:
    """A world from an (H, W) occupancy raster, row 0 = lowest y.

    ``origin`` is the world xy of the lower-left corner of cell (0, 0);
    unknown cells must already be marked occupied by the caller. Errors name
    ``source`` (the file) when given, else ``name``.
    """
    where = source or name
    occ = np.array(occupied, dtype=bool)
    if occ.ndim != 2 or min(occ.shape) < 3:
        raise TopodrakeError(f"{where}: occupancy raster must be 2-D and at least 3 x 3 "
                             f"cells, got shape {occ.shape}")
    if not (np.isfinite(resolution) and resolution > 0):
        raise TopodrakeError(f"{where}: resolution must be a positive number, got {resolution}")
    origin = np.asarray(origin, dtype=np.float64).reshape(2)
    occ[0, :] = occ[-1, :] = True
    occ[:, 0] = occ[:, -1] = True

    free = _largest_4(~occ)
    if not free.any():
        raise TopodrakeError(f"{where}: the map has no free space")
    if fill_cracks:
        _fill_cracks(free)
    occ = ~free
    if min_obstacle_cells > 1:
        labels, n = ndimage.label(occ, structure=_EIGHT)
        sizes = np.bincount(labels.ravel(), minlength=n + 1)
        small = sizes < min_obstacle_cells
        small[0] = False
        # A small occupied component touches only free cells (all non-free
        # cells are occupied and would belong to it), and those are all in the
        # kept region, so clearing it keeps the free region connected.
        occ &= ~small[labels]
        free = ~occ

    grid = OccupancyGrid(occ, origin, float(resolution))
    if not grid.reachable.any():
        raise TopodrakeError(f"{where}: no free space wide enough for the car "
                             f"(radius {grid.car_radius} m)")

    block = max(1, int(round(texture_block_m / resolution)))
    walls = _walls(occ, origin, resolution, block, seed)
    faces = _faces(occ, free, origin, resolution, block, seed)

    regions = np.full(occ.shape, -1, np.int32)
    regions[ndimage.binary_dilation(free, structure=_EIGHT)] = 0
    key = zlib.crc32(name.encode()) + seed
    floor = np.array([FLOOR_TEXTURES[key % len(FLOOR_TEXTURES)]], np.int32)
    ceiling = np.array([CEILING_TEXTURES[key % len(CEILING_TEXTURES)]], np.int32)

    world = World(name, walls, grid, regions, floor, ceiling, source=source,
                  faces_override=faces)
    try:
        world.places = choose_places(grid, n_places, seed=seed)
    except TopodrakeError as exc:
        raise TopodrakeError(f"{where}: {exc}") from None
    return world


def _largest_4(mask: np.ndarray) -> np.ndarray:
    """The largest 4-connected component of a boolean raster."""
    labels, n = ndimage.label(mask)
    if n == 0:
        return np.zeros_like(mask)
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    return labels == int(np.argmax(sizes))


def _fill_cracks(free: np.ndarray) -> None:
    """In place: clear free cells with at most one free 4-neighbour, until
    none is left. Removing 4-leaves never disconnects a 4-connected region
    (bigger than two cells); ``free`` must be False on the outer ring."""
    f = free
    nb = np.zeros(f.shape, np.int8)
    nb[1:-1, 1:-1] = (f[:-2, 1:-1].astype(np.int8) + f[2:, 1:-1] + f[1:-1, :-2] + f[1:-1, 2:])
    cand = np.argwhere(f & (nb <= 1))
    steps = np.array([[-1, 0], [1, 0], [0, -1], [0, 1]])
    while len(cand) and f.sum() > 2:
        f[cand[:, 0], cand[:, 1]] = False
        nbr = (cand[:, None, :] + steps[None]).reshape(-1, 2)
        nbr = nbr[f[nbr[:, 0], nbr[:, 1]]]
        if not len(nbr):
            break
        nbr = np.unique(nbr, axis=0)
        r, c = nbr[:, 0], nbr[:, 1]
        count = (f[r - 1, c].astype(np.int8) + f[r + 1, c] + f[r, c - 1] + f[r, c + 1])
        cand = nbr[count <= 1]


# -- walls ------------------------------------------------------------------------

def occupied_boxes(mask: np.ndarray) -> np.ndarray:
    """Cover a boolean raster with axis-aligned cell boxes.

    Maximal runs of each row, then runs with identical columns in consecutive
    rows merged. Returns (K, 4) int ``row0, col0, row1, col1`` (end exclusive).
    """
    mask = np.asarray(mask, dtype=bool)
    h, w = mask.shape
    pad = np.zeros((h, w + 2), np.int8)
    pad[:, 1:-1] = mask
    d = np.diff(pad, axis=1)
    sr, sc = np.nonzero(d == 1)
    er, ec = np.nonzero(d == -1)          # row-major order: starts and ends pair up
    if len(sr) == 0:
        return np.zeros((0, 4), np.int64)
    order = np.lexsort((sr, ec, sc))      # by column start, column end, row
    r, c0, c1 = sr[order], sc[order], ec[order]
    new = np.ones(len(r), bool)
    new[1:] = (c0[1:] != c0[:-1]) | (c1[1:] != c1[:-1]) | (r[1:] != r[:-1] + 1)
    first = np.flatnonzero(new)
    last = np.append(first[1:], len(r)) - 1
    return np.column_stack([r[first], c0[first], r[last] + 1, c1[first]]).astype(np.int64)


def _walls(occ, origin, res, block, seed) -> WallSet:
    boxes = occupied_boxes(occ)
    xy = np.column_stack([origin[0] + boxes[:, 1] * res, origin[1] + boxes[:, 0] * res,
                          origin[0] + boxes[:, 3] * res, origin[1] + boxes[:, 2] * res])
    tex = _texture(boxes[:, 1] // block, boxes[:, 0] // block, np.zeros(len(boxes)), seed)
    return WallSet.from_boxes(xy, tex)


# -- faces ------------------------------------------------------------------------

def _runs(edge: np.ndarray, block: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Maximal runs of True along each row of ``edge``, split every ``block``
    columns. Returns row, first column, last column + 1."""
    h, w = edge.shape
    prev = np.zeros_like(edge)
    prev[:, 1:] = edge[:, :-1]
    nxt = np.zeros_like(edge)
    nxt[:, :-1] = edge[:, 1:]
    col = np.arange(w)
    start = edge & (~prev | (col % block == 0))
    end = edge & (~nxt | ((col + 1) % block == 0))
    sr, sc = np.nonzero(start)
    _, ec = np.nonzero(end)
    return sr, sc, ec + 1


def _faces(occ, free, origin, res, block, seed) -> Faces:
    ox, oy = origin
    parts = []  # (ax, ay, bx, by, block x, block y, side)
    # Free cell with occupied below: edge y = row, runs right to left.
    e = np.zeros_like(free)
    e[1:] = free[1:] & occ[:-1]
    r, c0, c1 = _runs(e, block)
    parts.append((c1, r, c0, r, c0, r, 0))
    # Free cell with occupied above: edge y = row + 1, left to right.
    e = np.zeros_like(free)
    e[:-1] = free[:-1] & occ[1:]
    r, c0, c1 = _runs(e, block)
    parts.append((c0, r + 1, c1, r + 1, c0, r, 1))
    # Free cell with occupied on the left: edge x = col, runs upward.
    e = np.zeros_like(free)
    e[:, 1:] = free[:, 1:] & occ[:, :-1]
    c, r0, r1 = _runs(e.T, block)
    parts.append((c, r0, c, r1, c, r0, 2))
    # Free cell with occupied on the right: edge x = col + 1, runs downward.
    e = np.zeros_like(free)
    e[:, :-1] = free[:, :-1] & occ[:, 1:]
    c, r0, r1 = _runs(e.T, block)
    parts.append((c + 1, r1, c + 1, r0, c, r0, 3))

    cols = [np.concatenate([np.asarray(p[k], np.float64) if k < 6 else
                            np.full(len(p[0]), p[6], np.float64) for p in parts])
            for k in range(7)]
    ax, ay, bx, by, cx, cy, side = cols
    a = np.column_stack([ox + ax * res, oy + ay * res])
    b = np.column_stack([ox + bx * res, oy + by * res])
    tex = _texture(cx.astype(np.int64) // block, cy.astype(np.int64) // block,
                   side, seed)
    # Texture coordinate along the face direction, so u runs on continuously
    # across faces of one straight wall that were split at block borders.
    d = np.sign(b - a)
    u0 = a[:, 0] * d[:, 0] + a[:, 1] * d[:, 1]
    return Faces(a, b, tex, u0)


def _texture(bx, by, side, seed: int) -> np.ndarray:
    """Wall texture id per (block x, block y, facing side), a seeded hash."""
    with np.errstate(over="ignore"):
        k = (np.asarray(bx, np.int64).astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)
             ^ np.asarray(by, np.int64).astype(np.uint64) * np.uint64(0xC2B2AE3D27D4EB4F)
             ^ np.asarray(side, np.int64).astype(np.uint64) * np.uint64(0x165667B19E3779F9)
             ^ np.uint64(seed & 0xFFFFFFFF))
        # splitmix64 finaliser
        k ^= k >> np.uint64(30)
        k *= np.uint64(0xBF58476D1CE4E5B9)
        k ^= k >> np.uint64(27)
        k *= np.uint64(0x94D049BB133111EB)
        k ^= k >> np.uint64(31)
    pool = np.asarray(WALL_TEXTURES, np.int32)
    return pool[(k % np.uint64(len(pool))).astype(np.int64)]
