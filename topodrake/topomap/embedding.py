"""A cheap place embedding that ranks map vertices before the exact RE runs.

Map building and planning ask RE about a query against every vertex, which
does not scale. :class:`PlaceEmbedding` maps one raw observation (camera
image or lidar scan) to a unit vector; the score of a pair is the dot
product, trained to track the pair's symmetric camera overlap
``min(R_a->b, R_b->a)`` (see :mod:`topodrake.topomap.embedding_train`), so
a query ranks high the vertices whose view overlaps its own in both
directions. Retrieval keeps the top K and runs the exact RE on those only.

Networks (``PlaceNetConfig``, a few hundred thousand weights)::

    camera: 3 x S x S in [-0.5, 0.5] -> 3 strided Conv2d + ReLU -> Linear -> ReLU -> Linear(dim)
    lidar:  1 x beams in [0, 1]      -> 3 strided Conv1d + ReLU -> Linear -> ReLU -> Linear(dim)

then L2 normalisation. A checkpoint is one ``torch.save`` file read back
with ``weights_only=True``: ``format`` "topodrake-place-embedding",
``version``, ``network`` (PlaceNetConfig), ``sensor``, ``train_config``,
``metrics``, ``model`` (state dict). :meth:`PlaceEmbedding.fingerprint` is
the SHA-1 of the file's bytes, for map files to record.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from topodrake.errors import TopodrakeError
from topodrake.learning.networks import camera_input, lidar_input
from topodrake.sensing.config import CameraConfig, LidarConfig

FORMAT = "topodrake-place-embedding"
VERSION = 1
MODALITIES = ("camera", "lidar")


@dataclass
class PlaceNetConfig:
    """Shape of a place network (stored in every checkpoint)."""

    modality: str = "camera"        # camera | lidar
    image_size: int = 32            # camera input side (64 x 64 images are area-averaged down)
    channels: list[int] = field(default_factory=lambda: [32, 64, 64])
    hidden: int = 128
    dim: int = 64

    def validate(self, where: str = "place network config") -> "PlaceNetConfig":
        if self.modality not in MODALITIES:
            raise TopodrakeError(f"{where}: modality must be one of {MODALITIES}, "
                                 f"got {self.modality!r}")
        if len(self.channels) != 3 or min(self.channels) < 1:
            raise TopodrakeError(f"{where}: channels must be three positive widths")
        if self.image_size < 8 or self.image_size % 8:
            raise TopodrakeError(f"{where}: image_size must be a multiple of 8, got {self.image_size}")
        if self.hidden < 1 or self.dim < 1:
            raise TopodrakeError(f"{where}: hidden and dim must be >= 1")
        return self


class PlaceNet(nn.Module):
    """Observation tensor -> unit embedding (N, dim)."""

    def __init__(self, cfg: PlaceNetConfig, beams: int = 64):
        super().__init__()
        self.cfg = cfg
        c1, c2, c3 = cfg.channels
        if cfg.modality == "camera":
            conv, length = nn.Conv2d, cfg.image_size // 8
            self.features = nn.Sequential(
                conv(3, c1, 4, 2, 1), nn.ReLU(), conv(c1, c2, 3, 2, 1), nn.ReLU(),
                conv(c2, c3, 3, 2, 1), nn.ReLU(), nn.Flatten())
            flat = c3 * length * length
        else:
            conv = nn.Conv1d
            self.features = nn.Sequential(
                conv(1, c1, 5, 2, 2), nn.ReLU(), conv(c1, c2, 3, 2, 1), nn.ReLU(),
                conv(c2, c3, 3, 2, 1), nn.ReLU(), nn.Flatten())
            length = beams
            for _ in range(3):
                length = (length - 1) // 2 + 1
            flat = c3 * length
        self.head = nn.Sequential(nn.Linear(flat, cfg.hidden), nn.ReLU(), nn.Linear(cfg.hidden, cfg.dim))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.normalize(self.head(self.features(x)), dim=-1)


def to_input(cfg: PlaceNetConfig, sensor, observations: np.ndarray) -> torch.Tensor:
    """Raw observations -> the network's input tensor, checking their shape."""
    obs = np.asarray(observations)
    if cfg.modality == "camera":
        if obs.ndim != 4 or obs.shape[-1] != 3 or obs.dtype != np.uint8:
            raise TopodrakeError(f"camera place embedding needs uint8 images (N, H, W, 3), "
                                 f"got {obs.dtype} {obs.shape}")
        return camera_input(obs, cfg.image_size)
    if obs.ndim != 2 or obs.shape[1] != sensor.beams:
        raise TopodrakeError(f"lidar place embedding needs ranges (N, {sensor.beams}), got {obs.shape}")
    return lidar_input(obs, sensor.range_m)


class PlaceEmbedding:
    """Unit-norm embeddings of raw observations; scores are dot products."""

    def __init__(self, model: PlaceNet, sensor: CameraConfig | LidarConfig, name: str = "",
                 fingerprint: str = "", batch: int = 1024):
        self.model = model.eval()
        self.cfg = model.cfg
        self.sensor = sensor
        self.name = name or f"place_{self.cfg.modality}"
        self._fingerprint = fingerprint
        self.batch = int(batch)

    @property
    def observation(self) -> str:
        return self.cfg.modality

    @property
    def dim(self) -> int:
        return self.cfg.dim

    @torch.inference_mode()
    def embed(self, observations: np.ndarray) -> np.ndarray:
        """Raw observations (N, H, W, 3) uint8 or (N, beams) -> (N, dim) float32, unit norm."""
        obs = np.asarray(observations)
        out = np.empty((len(obs), self.dim), np.float32)
        for lo in range(0, len(obs), self.batch):
            x = to_input(self.cfg, self.sensor, obs[lo:lo + self.batch])
            out[lo:lo + len(x)] = self.model(x).numpy()
        return out

    def fingerprint(self) -> str:
        """SHA-1 of the checkpoint's bytes ("" for a model not loaded from a file)."""
        return self._fingerprint

    @classmethod
    def from_checkpoint(cls, path) -> "PlaceEmbedding":
        """Load a place-embedding checkpoint; a missing, corrupt or foreign
        file raises a one-line TopodrakeError naming it."""
        from topodrake.learning.tagged import load_tagged

        def build(blob):
            cfg = PlaceNetConfig(**blob["network"]).validate(f"checkpoint {path}")
            sensor = (CameraConfig if cfg.modality == "camera" else LidarConfig)(**blob["sensor"])
            model = PlaceNet(cfg, getattr(sensor, "beams", 64))
            model.load_state_dict(blob["model"])
            return model, sensor

        (model, sensor), sha1 = load_tagged(path, FORMAT, VERSION, "place embedding checkpoint",
                                            build)
        return cls(model, sensor, name=Path(path).parent.name, fingerprint=sha1)


def save_place_checkpoint(path, model: PlaceNet, sensor, **meta) -> Path:
    """Write a place-embedding checkpoint atomically; ``meta`` (JSON-like:
    train_config, metrics, wall_time_s, ...) is stored beside the weights."""
    from topodrake.learning.tagged import save_tagged

    return save_tagged(path, FORMAT, VERSION, model, sensor, **meta)


class ThumbnailEmbedding:
    """Untrained baseline: camera images as centred, unit-norm 8 x 8 colour
    thumbnails (192-d); lidar scans as centred, unit-norm normalised ranges."""

    name = "thumbnail"

    def __init__(self, observation: str, sensor=None, size: int = 8):
        self.observation = observation
        self.sensor = sensor or (CameraConfig() if observation == "camera" else LidarConfig())
        self.size = size

    @property
    def dim(self) -> int:
        return 3 * self.size * self.size if self.observation == "camera" else self.sensor.beams

    @torch.inference_mode()
    def embed(self, observations: np.ndarray) -> np.ndarray:
        if self.observation == "camera":
            x = camera_input(np.asarray(observations), self.size).reshape(len(observations), -1)
        else:
            x = lidar_input(observations, self.sensor.range_m).reshape(len(observations), -1)
        x = x - x.mean(dim=1, keepdim=True)
        return F.normalize(x, dim=1).numpy().astype(np.float32)

    def fingerprint(self) -> str:
        return f"thumbnail-{self.observation}-{self.size}"
