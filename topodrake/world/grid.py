"""Occupancy grid and configuration space of a world.

The grid is a boolean raster (row = y, column = x) at 0.05 m by default;
``origin`` is the world position of the lower-left corner of cell (0, 0).
The configuration space treats the car as a disc of ``car_radius`` (the
circumscribed radius of its body), so a free c-space cell is collision-free at
every heading.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy import ndimage

from topodrake.errors import TopodrakeError
from topodrake.world.walls import WallSet

#: Circumscribed radius of the RC car's body (front 0.18 m, sides 0.08 m).
CAR_RADIUS = 0.2


@dataclass
class OccupancyGrid:
    occupied: np.ndarray  # (H, W) bool
    origin: np.ndarray    # (2,) world xy of the lower-left corner
    resolution: float = 0.05
    car_radius: float = CAR_RADIUS
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.occupied = np.ascontiguousarray(self.occupied, dtype=bool)
        self.origin = np.asarray(self.origin, dtype=np.float64).reshape(2)
        if self.occupied.ndim != 2 or min(self.occupied.shape) < 2:
            raise TopodrakeError(
                f"occupancy grid must be a 2-D raster, got shape {self.occupied.shape}")

    @property
    def shape(self) -> tuple[int, int]:
        return self.occupied.shape

    def to_cell(self, xy: np.ndarray) -> np.ndarray:
        """World xy (..., 2) -> integer (row, col) (..., 2); may be out of bounds."""
        xy = np.asarray(xy, dtype=np.float64)
        col = np.floor((xy[..., 0] - self.origin[0]) / self.resolution)
        row = np.floor((xy[..., 1] - self.origin[1]) / self.resolution)
        return np.stack([row, col], axis=-1).astype(np.int64)

    def to_world(self, rc: np.ndarray) -> np.ndarray:
        """Cell (row, col) (..., 2) -> world xy of the cell centre."""
        rc = np.asarray(rc)
        x = self.origin[0] + (rc[..., 1] + 0.5) * self.resolution
        y = self.origin[1] + (rc[..., 0] + 0.5) * self.resolution
        return np.stack([x, y], axis=-1)

    def in_bounds(self, rc: np.ndarray) -> np.ndarray:
        rc = np.asarray(rc)
        return ((rc[..., 0] >= 0) & (rc[..., 0] < self.shape[0])
                & (rc[..., 1] >= 0) & (rc[..., 1] < self.shape[1]))

    def bbox(self) -> np.ndarray:
        h, w = self.shape
        return np.array([self.origin, self.origin + self.resolution * np.array([w, h])])

    @cached_property
    def clearance(self) -> np.ndarray:
        """(H, W) distance in metres from each cell centre to the nearest occupied
        cell, where everything beyond the grid counts as occupied (a map that
        ends in free space must not let the car drive off its edge)."""
        free = np.pad(~self.occupied, 1, constant_values=False)
        return ndimage.distance_transform_edt(free)[1:-1, 1:-1] * self.resolution

    @cached_property
    def free_space(self) -> np.ndarray:
        """(H, W) bool: configuration space free for the car at any heading."""
        return self.clearance > self.car_radius

    @cached_property
    def reachable(self) -> np.ndarray:
        """The largest 8-connected component of :attr:`free_space`."""
        return largest_component(self.free_space)

    def clearance_at(self, xy: np.ndarray) -> np.ndarray:
        """Clearance (m) at world points (..., 2); 0 outside the grid."""
        rc = self.to_cell(xy)
        inside = self.in_bounds(rc)
        rcc = np.clip(rc, 0, np.array(self.shape) - 1)
        out = self.clearance[rcc[..., 0], rcc[..., 1]]
        return np.where(inside, out, 0.0)

    def is_free(self, xy: np.ndarray) -> np.ndarray:
        """True where the car's reference point can be (any heading)."""
        return self.clearance_at(xy) > self.car_radius


def largest_component(mask: np.ndarray) -> np.ndarray:
    """The largest 8-connected component of a boolean raster."""
    labels, n = ndimage.label(mask, structure=np.ones((3, 3), bool))
    if n == 0:
        return np.zeros_like(mask)
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    return labels == int(np.argmax(sizes))


def rasterize_walls(walls: WallSet, origin: np.ndarray, shape: tuple[int, int],
                    resolution: float) -> np.ndarray:
    """Mark every cell whose centre lies within half a cell of a wall box."""
    occ = np.zeros(shape, dtype=bool)
    corners = walls.corners()
    half = 0.5 * resolution
    for i in range(len(walls)):
        c = corners[i]
        lo = np.floor((c.min(axis=0) - origin - half) / resolution).astype(int)
        hi = np.ceil((c.max(axis=0) - origin + half) / resolution).astype(int)
        c0, r0 = np.maximum(lo, 0)
        c1, r1 = np.minimum(hi, [shape[1], shape[0]])
        if c0 >= c1 or r0 >= r1:
            continue
        xs = origin[0] + (np.arange(c0, c1) + 0.5) * resolution
        ys = origin[1] + (np.arange(r0, r1) + 0.5) * resolution
        px, py = np.meshgrid(xs, ys)
        p0 = walls.segments[i, :2]
        d = walls.segments[i, 2:] - p0
        length = np.hypot(*d)
        d = d / length
        rx, ry = px - p0[0], py - p0[1]
        along = rx * d[0] + ry * d[1]
        across = -rx * d[1] + ry * d[0]
        inside = ((along >= -half) & (along <= length + half)
                  & (np.abs(across) <= 0.5 * walls.thickness[i] + half))
        occ[r0:r1, c0:c1] |= inside
    return occ
