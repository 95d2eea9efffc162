"""Batches of C_WP samples: observations rendered from poses on the fly.

Rendering a 64 x 64 image costs ~0.1 ms on one core (far less than reading
it from disk), so a batch renders its source images and the context frames
of its targets from the stored poses, grouped by world, with the same
batched camera / lidar the closed loop uses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from topodrake.learning.networks import CONTROL_SCALE, NetworkConfig, camera_input, lidar_input
from topodrake.learning.samples import SampleSet
from topodrake.sensing.config import CameraConfig, LidarConfig


class ObservationSource:
    """Raw observations of one modality for poses in a list of named worlds."""

    def __init__(self, worlds: list[str], modality: str, camera: CameraConfig | None = None,
                 lidar: LidarConfig | None = None):
        self.worlds = list(worlds)
        self.modality = modality
        self.camera_config = camera or CameraConfig()
        self.lidar_config = lidar or LidarConfig()
        self._sensors: dict[int, object] = {}

    def _sensor(self, w: int):
        if w not in self._sensors:
            from topodrake.world import load_world

            world = load_world(self.worlds[w])
            if self.modality == "camera":
                from topodrake.sensing.camera import Camera
                self._sensors[w] = Camera(world, self.camera_config)
            else:
                from topodrake.sensing.lidar import Lidar
                self._sensors[w] = Lidar(world, self.lidar_config)
        return self._sensors[w]

    def raw(self, world_index: np.ndarray, poses: np.ndarray) -> np.ndarray:
        """uint8 images (N, H, W, 3) or float32 ranges (N, beams)."""
        world_index = np.asarray(world_index)
        poses = np.asarray(poses, np.float64).reshape(-1, 3)
        if self.modality == "camera":
            c = self.camera_config
            out = np.empty((len(poses), c.height, c.width, 3), np.uint8)
        else:
            out = np.empty((len(poses), self.lidar_config.beams), np.float32)
        for w in np.unique(world_index):
            sel = np.flatnonzero(world_index == w)
            sensor = self._sensor(int(w))
            out[sel] = sensor.render(poses[sel]) if self.modality == "camera" else sensor.scan(poses[sel])
        return out


def to_network_input(raw: np.ndarray, cfg: NetworkConfig, lidar: LidarConfig) -> torch.Tensor:
    """Raw observations (..., H, W, 3) / (..., beams) -> network input tensors."""
    if cfg.modality == "camera":
        return camera_input(raw, cfg.image_size)
    return lidar_input(raw, lidar.range_m)


@dataclass
class Batch:
    cur: torch.Tensor       # (B, C, ...) current (jittered source) observation
    ctx: torch.Tensor       # (B, 2k+1, C, ...) target context, past to future
    waypoint: torch.Tensor  # (B, 2)
    heading: torch.Tensor   # (B, 2) cos, sin
    overlap: torch.Tensor   # (B, 2)
    control: torch.Tensor   # (B, 2) scaled by CONTROL_SCALE

    def __len__(self) -> int:
        return len(self.waypoint)


class SampleBatcher:
    """Draws :class:`Batch` es of a :class:`SampleSet` for one network config."""

    def __init__(self, samples: SampleSet, cfg: NetworkConfig, camera: CameraConfig | None = None,
                 lidar: LidarConfig | None = None):
        self.samples = samples
        self.cfg = cfg
        self.lidar = lidar or LidarConfig()
        self.source = ObservationSource(samples.trajectories.worlds, cfg.modality, camera, self.lidar)
        # per-sample label tensors, ready to index
        s = samples
        self._waypoint = torch.from_numpy(s.waypoint.astype(np.float32))
        hd = s.heading_diff.astype(np.float32)
        self._heading = torch.from_numpy(np.column_stack([np.cos(hd), np.sin(hd)]))
        self._overlap = torch.from_numpy(s.overlap.astype(np.float32))
        self._control = torch.from_numpy((s.control / CONTROL_SCALE).astype(np.float32))

    def __len__(self) -> int:
        return len(self.samples)

    def batch(self, idx) -> Batch:
        idx = np.asarray(idx, np.int64)
        s, cfg = self.samples, self.cfg
        trajs = s.trajectories
        world = s.world_index[idx]
        rows = s.context_rows(cfg.k, cfg.frame_step, idx)             # (B, m)
        uniq, inv = np.unique(rows, return_inverse=True)
        ctx_raw = self.source.raw(trajs.traj_world[np.searchsorted(trajs.traj_offsets, uniq,
                                                                   side="right") - 1],
                                  trajs.poses[uniq])
        cur_raw = self.source.raw(world, s.src_pose[idx])
        cur = to_network_input(cur_raw, cfg, self.lidar)
        ctx_all = to_network_input(ctx_raw, cfg, self.lidar)
        ctx = ctx_all[torch.from_numpy(inv.reshape(rows.shape))]
        t = torch.from_numpy(idx)
        return Batch(cur, ctx, self._waypoint[t], self._heading[t], self._overlap[t],
                     self._control[t])
