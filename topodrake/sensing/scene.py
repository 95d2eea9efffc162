"""The ray-casting scene: wall faces bucketed into a coarse uniform grid.

Rays walk the coarse grid cell by cell (Amanatides-Woo traversal) and test
only the faces listed in each cell, so the cost of a ray grows with the
distance it travels, not with the number of walls. Floor and ceiling texture
ids are stored per fine grid cell so floor casting is a single lookup.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from topodrake.world.textures import texture_bank


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


def _bucket_faces(a, b, length, lo, cell_m, nx, ny):
    """CSR lists of the faces touching each coarse cell.

    Every face is sampled at a quarter of a cell (so no crossed cell is
    missed) and each sample is nudged by +-1e-6 m to catch cells it only
    grazes; duplicates are removed with one ``np.unique``.
    """
    n_s = np.maximum(2, np.ceil(length / (0.25 * cell_m)).astype(np.int64) + 1)
    face_id = np.repeat(np.arange(len(a)), n_s)
    start = np.repeat(np.cumsum(n_s) - n_s, n_s)
    frac = (np.arange(face_id.size) - start) / (n_s[face_id] - 1)
    pts = a[face_id] + frac[:, None] * (b[face_id] - a[face_id])
    keys = []
    for d in ((-1e-6, -1e-6), (-1e-6, 1e-6), (1e-6, -1e-6), (1e-6, 1e-6)):
        c = np.floor((pts + d - lo) / cell_m).astype(np.int64)
        ok = (c[:, 0] >= 0) & (c[:, 0] < nx) & (c[:, 1] >= 0) & (c[:, 1] < ny)
        keys.append((c[ok, 1] * nx + c[ok, 0]) * len(a) + face_id[ok])
    keys = np.unique(np.concatenate(keys))          # sorted by cell, then face
    cells, faces = np.divmod(keys, len(a))
    cell_start = np.zeros(nx * ny + 1, np.int32)
    np.cumsum(np.bincount(cells, minlength=nx * ny), out=cell_start[1:])
    return cell_start, faces.astype(np.int32)


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
    cell_start, cell_faces = _bucket_faces(a, b, length, lo, cell_m, nx, ny)
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
