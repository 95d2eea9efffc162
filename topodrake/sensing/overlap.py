"""Geometric image overlap R_a->b between two camera poses.

Cast ``n_rays`` rays across camera a's horizontal field of view on the floor
plan; R_a->b is the fraction of a's wall hits that camera b also sees: the
point lies inside b's horizontal field of view and b's ray toward it reaches
it unblocked. Rays of a that hit nothing within range count as unseen. This
is the 2-D overlap the paper uses for sample labels and success checks.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from topodrake.sensing.camera import check_poses
from topodrake.sensing.config import CameraConfig
from topodrake.sensing.raycast import cast
from topodrake.sensing.scene import scene_of


@nb.njit(cache=True, parallel=True, fastmath=True)
def _overlap(faces, cell_start, cell_faces, grid, pa, pb, fwd, half_fov, n_rays, tmax):
    n = pa.shape[0]
    out = np.empty(n)
    cos_half = math.cos(half_fov)
    for k in nb.prange(n):
        ca, sa = math.cos(pa[k, 2]), math.sin(pa[k, 2])
        cb, sb = math.cos(pb[k, 2]), math.sin(pb[k, 2])
        ax = pa[k, 0] + fwd * ca
        ay = pa[k, 1] + fwd * sa
        bx = pb[k, 0] + fwd * cb
        by = pb[k, 1] + fwd * sb
        seen = 0
        for r in range(n_rays):
            ang = pa[k, 2] - half_fov + (2.0 * half_fov) * (r + 0.5) / n_rays
            dx = math.cos(ang)
            dy = math.sin(ang)
            t, f, s = cast(faces, cell_start, cell_faces, grid, ax, ay, dx, dy, tmax)
            if f < 0:
                continue
            px = ax + t * dx
            py = ay + t * dy
            vx = px - bx
            vy = py - by
            dist = math.sqrt(vx * vx + vy * vy)
            if dist < 1e-6 or dist > tmax:
                continue
            if (vx * cb + vy * sb) / dist < cos_half:
                continue
            t2, f2, s2 = cast(faces, cell_start, cell_faces, grid, bx, by,
                              vx / dist, vy / dist, tmax)
            if t2 >= dist - 0.02 - 1e-3 * dist:
                seen += 1
        out[k] = seen / n_rays
    return out


def image_overlap(world, poses_a, poses_b, camera: CameraConfig | None = None,
                  n_rays: int = 100, max_range_m: float = 10.0) -> np.ndarray:
    """R_a->b for paired car poses (N, 3) -> (N,) in [0, 1]."""
    camera = camera or CameraConfig()
    pa = check_poses(poses_a)
    pb = check_poses(poses_b)
    if pa.shape != pb.shape:
        raise ValueError(f"pose batches differ in shape: {pa.shape} vs {pb.shape}")
    s = scene_of(world)
    return _overlap(s.faces, s.cell_start, s.cell_faces, s.grid, pa, pb,
                    float(camera.forward_m), 0.5 * np.radians(camera.hfov_deg),
                    int(n_rays), float(max_range_m))


def mutual_overlap(world, poses_a, poses_b, camera: CameraConfig | None = None,
                   n_rays: int = 100) -> np.ndarray:
    """(N, 2): R_a->b and R_b->a."""
    return np.column_stack([image_overlap(world, poses_a, poses_b, camera, n_rays),
                            image_overlap(world, poses_b, poses_a, camera, n_rays)])
