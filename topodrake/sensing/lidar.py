"""Batched planar lidar: ranges of evenly spread beams against the walls."""

from __future__ import annotations

import numpy as np

from topodrake.sensing.camera import check_poses
from topodrake.sensing.config import LidarConfig
from topodrake.sensing.raycast import cast_fan
from topodrake.sensing.scene import scene_of


class Lidar:
    """The car's lidar in one world."""

    def __init__(self, world, config: LidarConfig | None = None):
        self.world = world
        self.config = config or LidarConfig()
        scene = scene_of(world)
        self._scene = (scene.faces, scene.cell_start, scene.cell_faces, scene.grid)
        self._offsets = self.config.beam_angles().astype(np.float64)

    def origins(self, poses: np.ndarray) -> np.ndarray:
        f = self.config.forward_m
        return poses[:, :2] + f * np.column_stack([np.cos(poses[:, 2]), np.sin(poses[:, 2])])

    def scan(self, poses, extra: np.ndarray | None = None) -> np.ndarray:
        """Ranges (N, beams) float32 in metres; ``inf`` where a beam hits nothing in range.
        ``extra`` (N, F, 8): each car's faces that the world lacks
        (:meth:`topodrake.world.changes.CarChanges.faces`)."""
        poses = check_poses(poses)
        return cast_fan(*self._scene, np.ascontiguousarray(self.origins(poses)),
                        np.ascontiguousarray(poses[:, 2]), self._offsets,
                        float(self.config.range_m), extra)

    def points(self, poses, ranges: np.ndarray | None = None):
        """World hit points (N, beams, 2) and a validity mask (N, beams)."""
        poses = check_poses(poses)
        if ranges is None:
            ranges = self.scan(poses)
        ang = poses[:, 2:3] + self._offsets[None]
        r = np.where(np.isfinite(ranges), ranges, 0.0)
        o = self.origins(poses)
        pts = o[:, None, :] + r[..., None] * np.stack([np.cos(ang), np.sin(ang)], axis=-1)
        return pts, np.isfinite(ranges)
