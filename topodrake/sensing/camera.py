"""Batched 2.5-D pinhole camera: textured walls, floor and ceiling.

Walls are vertical extrusions of the floor plan, so each image column needs
one ray: it gives the wall's z-depth ``t``; rows then split into ceiling,
wall and floor by the wall's projected top and bottom. Floor and ceiling
pixels are cast onto their planes and textured by the room they fall in.
Colours fade with distance so depth is visible. Everything runs in one
compiled kernel, parallel over the batch of poses.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.sensing.config import CameraConfig
from topodrake.sensing.raycast import cast, cast_extra, extra_faces
from topodrake.sensing.scene import scene_of
from topodrake.world.textures import TEXELS, TILE_M

FOG = 0.06          # colour *= exp(-FOG * distance)
SKY = np.array([0.5, 0.5, 0.55], np.float32)  # outside the map


def check_poses(poses) -> np.ndarray:
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim == 1:
        poses = poses[None]
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise TopodrakeError(f"poses must be (N, 3) x, y, heading; got shape {poses.shape}")
    if not np.all(np.isfinite(poses)):
        raise TopodrakeError("poses contain NaN or infinite values")
    return np.ascontiguousarray(poses)


@nb.njit(cache=True, fastmath=True, inline="always")
def _plane_texel(tex_grid, fine, textures, px, py):
    r = int(math.floor((py - fine[1]) / fine[2]))
    c = int(math.floor((px - fine[0]) / fine[2]))
    if r < 0 or c < 0 or r >= tex_grid.shape[0] or c >= tex_grid.shape[1]:
        return -1, 0, 0
    tid = tex_grid[r, c]
    scale = TEXELS / TILE_M
    tu = int(math.floor(px * scale)) % TEXELS
    tv = int(math.floor(py * scale)) % TEXELS
    return tid, tv, tu


@nb.njit(cache=True, fastmath=True)
def _render_pose(faces, cell_start, cell_faces, grid, floor_tex, ceil_tex, fine, textures,
                 poses, k, xn, yn, plane_shade, fwd, cam_h, max_depth, want_rgb, extra, rgb_out,
                 depth_out):
    """Render image ``k`` of the batch (one column ray, then the rows);
    ``extra[k]``: the faces image ``k`` sees besides the scene's."""
    width = xn.shape[0]
    height = yn.shape[0]
    wall_h = grid[5]
    scale = TEXELS / TILE_M
    ct = math.cos(poses[k, 2])
    st = math.sin(poses[k, 2])
    ox = poses[k, 0] + fwd * ct
    oy = poses[k, 1] + fwd * st
    for j in range(width):
        dx = ct + xn[j] * st
        dy = st - xn[j] * ct
        inv_norm = 1.0 / math.sqrt(dx * dx + dy * dy)
        t, f, s = cast(faces, cell_start, cell_faces, grid, ox, oy, dx, dy, max_depth)
        if extra.shape[1] > 0:
            t, f, s = cast_extra(extra[k], ox, oy, dx, dy, max_depth, t, f, s)
        row = faces[f] if f >= 0 else extra[k, -2 - f] if f <= -2 else faces[0]
        if f != -1:
            u = row[4] + s * row[5]
            tu = int(math.floor(u * scale)) % TEXELS
            tid = int(row[7])
            wall_shade = row[6] * math.exp(-FOG * t / inv_norm)
            f = 0
        for i in range(height):
            y = yn[i]
            z = cam_h - y * t if f >= 0 else (cam_h - y * 1e9)
            if f >= 0 and 0.0 <= z <= wall_h:
                if want_rgb:
                    tv = int(math.floor(z * scale)) % TEXELS
                    for ch in range(3):
                        v = textures[tid, tv, tu, ch] * wall_shade
                        rgb_out[k, i, j, ch] = min(255, int(v * 255.0 + 0.5))
                else:
                    depth_out[k, i, j] = t
                continue
            if y > 1e-12:   # below the horizon: floor
                tp = cam_h / y
                tex_grid = floor_tex
            elif y < -1e-12:  # above: ceiling
                tp = (cam_h - wall_h) / y
                tex_grid = ceil_tex
            else:
                tp = math.inf
                tex_grid = floor_tex
            if not want_rgb:
                depth_out[k, i, j] = tp if tp <= max_depth else math.inf
                continue
            if tp > max_depth:
                for ch in range(3):
                    rgb_out[k, i, j, ch] = int(SKY[ch] * 255.0 * math.exp(-FOG * max_depth))
                continue
            px = ox + tp * dx
            py = oy + tp * dy
            tid2, tv, tu2 = _plane_texel(tex_grid, fine, textures, px, py)
            shade = plane_shade[i, j]
            if tid2 < 0:
                for ch in range(3):
                    rgb_out[k, i, j, ch] = int(SKY[ch] * 255.0 * shade)
            else:
                for ch in range(3):
                    v = textures[tid2, tv, tu2, ch] * shade
                    rgb_out[k, i, j, ch] = min(255, int(v * 255.0 + 0.5))


# Small batches (a Drake sensor renders one image) run serially: starting the
# thread pool costs more than the image. Two explicit loops, not a factory,
# so numba's on-disk cache keeps them apart.
@nb.njit(cache=True)
def _render_serial(faces, cell_start, cell_faces, grid, floor_tex, ceil_tex, fine, textures,
                   poses, xn, yn, plane_shade, fwd, cam_h, max_depth, want_rgb, extra, rgb_out,
                   depth_out):
    for k in range(poses.shape[0]):
        _render_pose(faces, cell_start, cell_faces, grid, floor_tex, ceil_tex, fine,
                     textures, poses, k, xn, yn, plane_shade, fwd, cam_h, max_depth, want_rgb,
                     extra, rgb_out, depth_out)


@nb.njit(cache=True, parallel=True)
def _render_parallel(faces, cell_start, cell_faces, grid, floor_tex, ceil_tex, fine, textures,
                     poses, xn, yn, plane_shade, fwd, cam_h, max_depth, want_rgb, extra, rgb_out,
                     depth_out):
    for k in nb.prange(poses.shape[0]):
        _render_pose(faces, cell_start, cell_faces, grid, floor_tex, ceil_tex, fine,
                     textures, poses, k, xn, yn, plane_shade, fwd, cam_h, max_depth, want_rgb,
                     extra, rgb_out, depth_out)


from topodrake.sensing.raycast import SERIAL_BELOW  # noqa: E402


class Camera:
    """The car's camera in one world; renders batches of car poses."""

    def __init__(self, world, config: CameraConfig | None = None):
        self.world = world
        self.config = config or CameraConfig()
        self._scene = scene_of(world).packed()
        c = self.config
        self._xn = (np.arange(c.width) - c.cx) / c.fx
        self._yn = (np.arange(c.height) - c.cy) / c.fx
        # Fog on floor and ceiling pixels does not depend on the pose: the
        # plane distance of a pixel is fixed by its row and column.
        with np.errstate(divide="ignore"):
            wall_h = world.wall_height
            plane_t = np.where(self._yn > 0, c.height_m / self._yn, (c.height_m - wall_h) / self._yn)
        ray_len = np.sqrt(1.0 + self._xn ** 2)
        self._plane_shade = np.exp(-FOG * plane_t[:, None] * ray_len[None, :])

    def _run(self, poses, want_rgb: bool, extra=None):
        c = self.config
        poses = check_poses(poses)
        n = len(poses)
        extra = extra_faces(extra, n)
        rgb = np.empty((n, c.height, c.width, 3) if want_rgb else (1, 1, 1, 3), np.uint8)
        depth = np.empty((1, 1, 1) if want_rgb else (n, c.height, c.width), np.float32)
        kernel = _render_serial if n < SERIAL_BELOW else _render_parallel
        kernel(*self._scene, poses, self._xn, self._yn, self._plane_shade, c.forward_m, c.height_m,
               c.max_depth_m, want_rgb, extra, rgb, depth)
        return rgb if want_rgb else depth

    def render(self, poses, extra: np.ndarray | None = None) -> np.ndarray:
        """RGB images (N, H, W, 3) uint8 for car poses (N, 3) (or one pose -> (1, H, W, 3));
        ``extra`` (N, F, 8): each car's faces that the world lacks."""
        return self._run(poses, True, extra)

    def render_depth(self, poses, extra: np.ndarray | None = None) -> np.ndarray:
        """z-depth images (N, H, W) float32 in metres; ``inf`` beyond ``max_depth_m``."""
        return self._run(poses, False, extra)
