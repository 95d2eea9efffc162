"""SPTM's retrieval network: are two camera frames a few steps apart?

The baseline's only learned part (Savinov et al., "Semi-parametric
topological memory"): a siamese pair classifier trained on frames of one
drive that are temporally close (positives) or far apart (negatives), see
:mod:`topodrake.baselines.train_retrieval`. Its score is a probability in
[0, 1] that the two frames are within a few steps of each other; SPTM uses
it as a proxy of reachability for shortcut edges and localization.

Network (``RetrievalNetConfig``, about 0.2 M weights)::

    encoder: 3 x S x S in [-0.5, 0.5] -> 3 strided Conv2d + ReLU -> Linear(feature) -> ReLU
    head:    [|e_a - e_b|, e_a * e_b, e_a + e_b] -> Linear(hidden) -> ReLU -> Linear(1) -> sigmoid

Each frame is encoded once (:meth:`RetrievalNet.features`), so scoring
many pairs costs only the small head (:meth:`RetrievalNet.score_features`).
The head sees symmetric functions of the two features, so the score is
symmetric by construction (SPTM averages the two orders of its matrix).

A checkpoint is one ``torch.save`` file read back with
``weights_only=True``: ``format`` "topodrake-sptm-retrieval", ``version``,
``network`` (RetrievalNetConfig), ``sensor`` (CameraConfig),
``train_config``, ``metrics``, ``model`` (state dict). Any other file is
refused with a one-line :class:`~topodrake.errors.TopodrakeError`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn

from topodrake.errors import TopodrakeError
from topodrake.learning.networks import camera_input
from topodrake.sensing.config import CameraConfig

FORMAT = "topodrake-sptm-retrieval"
VERSION = 1


@dataclass
class RetrievalNetConfig:
    """Shape of a retrieval network (stored in every checkpoint)."""

    image_size: int = 32            # 64 x 64 camera images are area-averaged down
    channels: list[int] = field(default_factory=lambda: [32, 64, 64])
    feature: int = 64
    hidden: int = 64

    def validate(self, where: str = "retrieval network config") -> "RetrievalNetConfig":
        if len(self.channels) != 3 or min(self.channels) < 1:
            raise TopodrakeError(f"{where}: channels must be three positive widths")
        if self.image_size < 8 or self.image_size % 8:
            raise TopodrakeError(f"{where}: image_size must be a multiple of 8, got {self.image_size}")
        if self.feature < 1 or self.hidden < 1:
            raise TopodrakeError(f"{where}: feature and hidden must be >= 1")
        return self


class RetrievalNet(nn.Module):
    """Siamese pair classifier: (x_a, x_b) -> logit that they are close in time."""

    def __init__(self, cfg: RetrievalNetConfig):
        super().__init__()
        self.cfg = cfg
        c1, c2, c3 = cfg.channels
        side = cfg.image_size // 8
        self.encoder = nn.Sequential(
            nn.Conv2d(3, c1, 4, 2, 1), nn.ReLU(), nn.Conv2d(c1, c2, 3, 2, 1), nn.ReLU(),
            nn.Conv2d(c2, c3, 3, 2, 1), nn.ReLU(), nn.Flatten(),
            nn.Linear(c3 * side * side, cfg.feature), nn.ReLU())
        self.head = nn.Sequential(nn.Linear(3 * cfg.feature, cfg.hidden), nn.ReLU(),
                                  nn.Linear(cfg.hidden, 1))

    def features(self, x: torch.Tensor) -> torch.Tensor:
        return self.encoder(x)

    def pair_logits(self, ea: torch.Tensor, eb: torch.Tensor) -> torch.Tensor:
        return self.head(torch.cat([(ea - eb).abs(), ea * eb, ea + eb], -1)).squeeze(-1)

    def forward(self, xa: torch.Tensor, xb: torch.Tensor) -> torch.Tensor:
        return self.pair_logits(self.features(xa), self.features(xb))


class RetrievalScorer:
    """Inference: encode frames once, score pairs of encoded frames."""

    def __init__(self, model: RetrievalNet, sensor: CameraConfig | None = None, name: str = "",
                 fingerprint: str = "", batch: int = 1024, pair_batch: int = 1 << 16):
        self.model = model.eval()
        self.cfg = model.cfg
        self.sensor = sensor or CameraConfig()
        self.name = name or "sptm_retrieval"
        self._fingerprint = fingerprint
        self.batch = int(batch)
        self.pair_batch = int(pair_batch)

    observation = "camera"

    def fingerprint(self) -> str:
        """SHA-1 of the checkpoint's bytes ("" for a model not loaded from a file)."""
        return self._fingerprint

    @torch.inference_mode()
    def encode(self, images: np.ndarray) -> torch.Tensor:
        """uint8 camera images (N, H, W, 3) -> features (N, feature) float32."""
        images = np.asarray(images)
        if images.ndim != 4 or images.shape[-1] != 3 or images.dtype != np.uint8:
            raise TopodrakeError(f"the SPTM retrieval network needs uint8 images (N, H, W, 3), "
                                 f"got {images.dtype} {images.shape}")
        out = torch.empty(len(images), self.cfg.feature)
        for lo in range(0, len(images), self.batch):
            out[lo:lo + self.batch] = self.model.features(
                camera_input(images[lo:lo + self.batch], self.cfg.image_size))
        return out

    @torch.inference_mode()
    def score_features(self, fa: torch.Tensor, fb: torch.Tensor) -> np.ndarray:
        """Scores of the pairs (fa[i], fb[i]) of encoded frames, (N,) float32 in [0, 1]."""
        out = np.empty(len(fa), np.float32)
        for lo in range(0, len(fa), self.pair_batch):
            hi = lo + self.pair_batch
            out[lo:hi] = torch.sigmoid(self.model.pair_logits(fa[lo:hi], fb[lo:hi])).numpy()
        return out

    def score(self, images_a: np.ndarray, images_b: np.ndarray) -> np.ndarray:
        """Scores of the image pairs (images_a[i], images_b[i])."""
        return self.score_features(self.encode(images_a), self.encode(images_b))

    @classmethod
    def from_checkpoint(cls, path) -> "RetrievalScorer":
        """Load a retrieval checkpoint; a missing, corrupt or foreign file
        raises a one-line TopodrakeError naming it."""
        from topodrake.learning.tagged import load_tagged

        def build(blob):
            cfg = RetrievalNetConfig(**blob["network"]).validate(f"checkpoint {path}")
            model = RetrievalNet(cfg)
            model.load_state_dict(blob["model"])
            return model, CameraConfig(**blob["sensor"])

        (model, sensor), sha1 = load_tagged(path, FORMAT, VERSION, "SPTM retrieval checkpoint",
                                            build)
        return cls(model, sensor, name=Path(path).parent.name, fingerprint=sha1)


def save_retrieval_checkpoint(path, model: RetrievalNet, sensor: CameraConfig, **meta) -> Path:
    """Write a retrieval checkpoint atomically; ``meta`` (JSON-like:
    train_config, metrics, wall_time_s, ...) is stored beside the weights."""
    from topodrake.learning.tagged import save_tagged

    return save_tagged(path, FORMAT, VERSION, model, sensor, **meta)