"""The samples of training at scale (:mod:`topodrake.learning.waypoint.scale`).

Worker side: each worker process makes *shards* (samples of one world with
their source observations) and renders every trajectory frame of a world,
both in the pool's storage (lidar ranges as float16 in [0, 1], camera
images as uint8). Device side: the :class:`Pool` of samples, a ring once
full, and the conversion of its storage into the network's input.
"""

from __future__ import annotations

import sys

import numpy as np

from topodrake.learning.samples import SampleConfig, _world_samples
from topodrake.learning.trajpack import load_packed_trajectories
from topodrake.sensing.config import CameraConfig, LidarConfig
from topodrake.world import load_world

# ---------------------------------------------------------------- shards (worker side)

_W: dict = {}


def init_worker(traj_path: str, worlds: list[str], train: dict) -> None:
    """A worker process's state: the packed drives of ``worlds`` and the
    sample and sensor configs of ``train`` (a TrainConfig dict)."""
    import numba
    import torch

    numba.set_num_threads(1)
    torch.set_num_threads(1)


    _W.update(trajs=load_packed_trajectories(traj_path).select_worlds(worlds), worlds=worlds,
              samples=SampleConfig(**train["data"]["samples"]),
              modality=train["network"]["modality"], camera=CameraConfig(**train["camera"]),
              lidar=LidarConfig(**train["lidar"]), seed=train["data"]["sample_seed"],
              n=train["shard_samples"], cache={})


def make_shard(j: int):
    """Shard ``j``: (j, sample fields, source observations in the pool's storage)."""
    worlds, trajs = _W["worlds"], _W["trajs"]
    w, s = j % len(worlds), j // len(worlds)
    if w not in _W["cache"]:
        world = load_world(worlds[w])
        sensor = _Sensor(world, _W["modality"], _W["camera"], _W["lidar"])
        _W["cache"] = {w: (world, sensor)}      # one world per process at a time
    world, sensor = _W["cache"][w]
    ids = np.flatnonzero(trajs.traj_world == w)
    part = _world_samples(world, trajs, ids, _W["n"], np.random.default_rng([_W["seed"], w, s]),
                          _W["samples"], controls=False)
    keep = ("traj", "tgt", "waypoint", "heading_diff", "overlap")
    return j, {k: np.asarray(part[k]) for k in keep}, sensor.observe(part["src_pose"])


class _Sensor:
    """A world's sensor, observing in the pool's storage: lidar ranges as
    float16 in [0, 1], camera images as uint8 (H, W, 3)."""
    def __init__(self, world, modality: str, camera, lidar):
        self.modality, self.range_m = modality, lidar.range_m
        if modality == "camera":
            from topodrake.sensing.camera import Camera

            self.sensor = Camera(world, camera)
        else:
            from topodrake.sensing.lidar import Lidar

            self.sensor = Lidar(world, lidar)

    def observe(self, poses: np.ndarray) -> np.ndarray:
        if self.modality == "camera":
            return self.sensor.render(poses)
        return normalised(self.sensor.scan(poses), self.range_m)


def as_network_input(obs, modality: str):
    """Pool storage (..., beams) or (..., H, W, 3) -> the network's float input
    (..., 1, beams) or (..., 3, H, W), as :func:`topodrake.learning.data.to_network_input`."""
    if modality == "camera":
        return obs.movedim(-1, -3).float() * (1.0 / 255.0) - 0.5
    return obs.float().unsqueeze(-2)


def warm_kernels(traj_path: str, world: str, modality: str) -> None:
    """Compile (or load) the labeller's and the renderer's kernels in a child
    process, so the forked workers load them from the disk cache instead of
    compiling them each (numba's thread pool must not exist before a fork)."""
    import subprocess

    code = ("import numpy as np; "
            "from topodrake.learning.waypoint.scale_data import init_worker, make_shard, _W; "
            f"from topodrake.learning.config import TrainConfig; t = TrainConfig().to_dict(); "
            f"t['data']['sample_seed'] = 0; t['shard_samples'] = 20; "
            f"t['network']['modality'] = {modality!r}; "
            f"init_worker({traj_path!r}, [{world!r}], t); make_shard(0)")
    subprocess.run([sys.executable, "-c", code], check=True)


def normalised(ranges: np.ndarray, range_m: float) -> np.ndarray:
    """The network's lidar input, float16 (the pool's storage)."""
    from topodrake.learning.networks import lidar_unit_ranges

    return lidar_unit_ranges(ranges, range_m).astype(np.float16)


# ---------------------------------------------------------------- the pool (device side)

class Pool:
    """Samples on the device, grown shard by shard; once full, each shard
    replaces the oldest samples (a ring)."""
    def __init__(self, capacity: int, obs_shape: tuple, obs_dtype, frames: int, device):
        import torch

        self.n = 0
        self.head = 0
        self.cur = torch.empty((capacity, *obs_shape), dtype=obs_dtype, device=device)
        self.ctx_rows = torch.empty((capacity, frames), dtype=torch.int64, device=device)
        self.waypoint = torch.empty((capacity, 2), device=device)
        self.heading = torch.empty((capacity, 2), device=device)
        self.overlap = torch.empty((capacity, 2), device=device)

    def add(self, part: dict, obs: np.ndarray, ctx_rows: np.ndarray) -> None:
        import torch

        cap = len(self.cur)
        m = min(len(obs), cap)
        dev = self.cur.device
        at = torch.from_numpy((self.head + np.arange(m)) % cap).to(dev)
        hd = part["heading_diff"][:m].astype(np.float32)
        for dst, src in ((self.cur, obs[:m]), (self.ctx_rows, ctx_rows[:m].astype(np.int64)),
                         (self.waypoint, part["waypoint"][:m].astype(np.float32)),
                         (self.heading, np.column_stack([np.cos(hd), np.sin(hd)])),
                         (self.overlap, part["overlap"][:m].astype(np.float32))):
            dst[at] = torch.from_numpy(np.ascontiguousarray(src)).to(dev, dst.dtype)
        self.head = (self.head + m) % cap
        self.n = min(self.n + m, cap)


class DeviceBatcher:
    """A CPU batcher (validation) whose batches land on the device."""

    def __init__(self, batcher, device):
        self.batcher, self.device = batcher, device

    def __len__(self) -> int:
        return len(self.batcher)

    def batch(self, idx):
        from dataclasses import fields, replace

        b = self.batcher.batch(idx)
        return replace(b, **{f.name: getattr(b, f.name).to(self.device) for f in fields(b)})


def frame_rows(trajs, w: int) -> np.ndarray:
    """Rows of ``trajs.poses`` that belong to world ``w``."""
    ids = np.flatnonzero(trajs.traj_world == w)
    return np.concatenate([np.arange(trajs.traj_offsets[t], trajs.traj_offsets[t + 1]) for t in ids]
                          or [np.zeros(0, np.int64)]).astype(np.int64)


def render_world(w: int):
    """Worker side: (w, rows, observations) of every trajectory frame of world ``w``."""
    trajs = _W["trajs"]
    rows = frame_rows(trajs, w)
    sensor = _Sensor(load_world(_W["worlds"][w]), _W["modality"], _W["camera"], _W["lidar"])
    return w, rows, sensor.observe(trajs.poses[rows])


def frames_tensor(n: int, modality: str, camera_cfg, lidar_cfg, device):
    import torch

    if modality == "camera":
        return torch.empty((n, camera_cfg.height, camera_cfg.width, 3), dtype=torch.uint8,
                           device=device)
    return torch.empty((n, lidar_cfg.beams), dtype=torch.float16, device=device)


def gather_frames(rendered, trajs, modality: str, camera_cfg, lidar_cfg, device):
    """The observation of every pose of ``trajs`` in the pool's storage, on
    ``device``, from the workers' :func:`render_world` results."""
    import torch

    out = frames_tensor(len(trajs.poses), modality, camera_cfg, lidar_cfg, device)
    for _, rows, obs in rendered:
        out[torch.from_numpy(rows).to(device)] = torch.from_numpy(obs).to(device)
    return out
