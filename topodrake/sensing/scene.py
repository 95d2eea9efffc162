"""The ray-casting scene: wall faces bucketed into a coarse uniform grid.

Rays walk the coarse grid cell by cell (Amanatides-Woo traversal) and test
only the faces listed in each cell, so the cost of a ray grows with the
distance it travels, not with the number of walls. Floor and ceiling texture
ids are stored per fine grid cell so floor casting is a single lookup.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from topodrake.sensing.textures import texture_bank


@dataclass(frozen=True)
class RayScene:
    faces: np.ndarray       # (M, 8) float64: ax, ay, bx, by, u0, length, shade, texture
    cell_start: np.ndarray  # (ny * nx + 1,) int32 CSR offsets
    cell_faces: np.ndarray  # (K,) int32 face indices
    grid: np.ndarray        # (6,) float64: ox, oy, cell, nx, ny, wall_height
    floor_tex: np.ndarray   # (H, W) int16 floor texture id per fine cell, -1 outside
    ceil_tex: np.ndarray    # (H, W) int16
    fine: np.ndarray        # (3,) float64: origin x, origin y, resolution of floor grids
    textures: np.ndarray    # (T, S, S, 3) float32

    def packed(self) -> tuple:
        """The arrays in the order the compiled kernels take them."""
        return (self.faces, self.cell_start, self.cell_faces, self.grid,
                self.floor_tex, self.ceil_tex, self.fine, self.textures)


def _face_shade(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Directional light so that walls of different orientation differ."""
    e = b - a
    n = np.stack([e[:, 1], -e[:, 0]], axis=1)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    light = np.array([0.6, 0.8])
    return 0.7 + 0.3 * np.abs(n @ light)


def build_scene(world, cell_m: float = 0.5) -> RayScene:
    faces = world.faces
    a, b = faces.a, faces.b
    length = np.linalg.norm(b - a, axis=1)
    keep = length > 1e-9
    a, b, length = a[keep], b[keep], length[keep]
    table = np.column_stack([a, b, faces.u0[keep], length, _face_shade(a, b),
                             faces.texture[keep].astype(np.float64)])
    lo = world.bbox[0] - cell_m
    hi = world.bbox[1] + cell_m
    nx = int(np.ceil((hi[0] - lo[0]) / cell_m))
    ny = int(np.ceil((hi[1] - lo[1]) / cell_m))
    buckets: list[list[int]] = [[] for _ in range(nx * ny)]
    for i in range(len(table)):
        # Sample the segment densely enough to touch every cell it crosses,
        # and pad by one cell's fraction to be conservative at corners.
        n_s = max(2, int(np.ceil(length[i] / (0.25 * cell_m))) + 1)
        s = np.linspace(0.0, 1.0, n_s)
        pts = a[i] + s[:, None] * (b[i] - a[i])
        cells = set()
        for dx in (-1e-6, 1e-6):
            for dy in (-1e-6, 1e-6):
                c = np.floor((pts + [dx, dy] - lo) / cell_m).astype(int)
                cells.update(zip(c[:, 0].tolist(), c[:, 1].tolist()))
        for cx, cy in cells:
            if 0 <= cx < nx and 0 <= cy < ny:
                buckets[cy * nx + cx].append(i)
    counts = np.array([len(bk) for bk in buckets], dtype=np.int32)
    cell_start = np.zeros(nx * ny + 1, np.int32)
    np.cumsum(counts, out=cell_start[1:])
    cell_faces = np.array([f for bk in buckets for f in bk], dtype=np.int32)
    grid = np.array([lo[0], lo[1], cell_m, nx, ny, world.wall_height])
    regions = world.regions
    floor_ids = np.where(regions >= 0, world.floor_texture[np.maximum(regions, 0)], -1)
    ceil_ids = np.where(regions >= 0, world.ceiling_texture[np.maximum(regions, 0)], -1)
    fine = np.array([world.grid.origin[0], world.grid.origin[1], world.grid.resolution])
    return RayScene(table, cell_start, cell_faces, grid,
                    np.ascontiguousarray(floor_ids, np.int16),
                    np.ascontiguousarray(ceil_ids, np.int16), fine, texture_bank())


def scene_of(world) -> RayScene:
    """The world's ray scene, built once and kept on the world object."""
    scene = world.__dict__.get("_ray_scene")
    if scene is None:
        scene = build_scene(world)
        world.__dict__["_ray_scene"] = scene
    return scene
