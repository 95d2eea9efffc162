"""Training configuration of the waypoint network, loadable from YAML.

Example (every key optional; see ``configs/waypoint_camera_k5.yaml``)::

    network: {modality: camera, k: 5, image_size: 64, channels: [32, 64, 64], first_pool: 2}
    data: {train_samples: 200000, val_samples: 2000}
    batch_size: 64
    max_minutes: 60

:func:`load_train_config` reads a file with ``pydrake``'s typed YAML loader
and turns any problem into one :class:`~topodrake.errors.TopodrakeError`
line naming the file.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from topodrake.errors import TopodrakeError
from topodrake.validate import (check_count, check_fraction, check_nonnegative, check_positive,
                                check_seed)
from topodrake.typed_yaml import load_typed, load_typed_data
from topodrake.learning.networks import NetworkConfig
from topodrake.learning.samples import SampleConfig
from topodrake.sensing.config import CameraConfig, LidarConfig


def _train_worlds() -> list[str]:
    return [f"train-{i:02d}" for i in range(12)]


def _val_worlds() -> list[str]:
    return [f"test-{i}" for i in range(5)]


@dataclass
class DataConfig:
    """Where samples come from: expert demonstrations of the training houses
    (validation: the test houses), then :func:`~topodrake.learning.samples.make_samples`."""

    train_worlds: list[str] = field(default_factory=_train_worlds)
    val_worlds: list[str] = field(default_factory=_val_worlds)
    demo_protocol: str = "pairs"    # all ordered pairs of each world's 10 places (90 drives)
    demo_count: int = 90            # drives per world for the "random" protocol
    demo_seed: int = 0
    train_samples: int = 400000
    val_samples: int = 2000
    sample_seed: int = 0
    samples: SampleConfig = field(default_factory=SampleConfig)


@dataclass
class TrainConfig:
    network: NetworkConfig = field(default_factory=NetworkConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    lidar: LidarConfig = field(default_factory=LidarConfig)
    data: DataConfig = field(default_factory=DataConfig)
    batch_size: int = 64
    lr: float = 3e-4
    lr_decay: float = 0.7           # learning rate x this after every epoch_samples samples
    epoch_samples: int = 120000
    max_samples: int = 720000       # stop after this many samples ...
    max_minutes: float = 60.0       # ... or this much training wall time, whichever first
    val_every_samples: int = 30000
    checkpoint_every_s: float = 300.0
    seed: int = 0
    threads: int = 0                # torch threads (0: torch's default)
    init: str | None = None         # a C_WP checkpoint of the same profile to start from

    def validate(self, where: str = "train config") -> "TrainConfig":
        self.network.validate(where)
        for name in ("batch_size", "epoch_samples", "max_samples", "val_every_samples"):
            if getattr(self, name) < 1:
                raise TopodrakeError(f"{where}: {name} must be >= 1, got {getattr(self, name)}")
        check_positive(f"{where}: lr", self.lr)
        if check_fraction(f"{where}: lr_decay", self.lr_decay) == 0:
            raise TopodrakeError(f"{where}: lr_decay must be a number in (0, 1], got 0")
        check_positive(f"{where}: max_minutes", self.max_minutes)
        check_positive(f"{where}: checkpoint_every_s", self.checkpoint_every_s)
        check_seed(f"{where}: seed", self.seed)
        check_count(f"{where}: threads", self.threads, 0)
        d = self.data
        check_count(f"{where}: data.demo_count", d.demo_count)
        check_count(f"{where}: data.val_samples", d.val_samples)
        check_seed(f"{where}: data.demo_seed", d.demo_seed)
        check_seed(f"{where}: data.sample_seed", d.sample_seed)
        sm = d.samples
        for name in ("lateral_std_m", "lateral_clip_m", "heading_std_deg", "target_snap_m"):
            check_nonnegative(f"{where}: data.samples.{name}", getattr(sm, name))
        check_fraction(f"{where}: data.samples.min_overlap", sm.min_overlap)
        check_positive(f"{where}: data.samples.lookahead_m", sm.lookahead_m)
        check_count(f"{where}: data.samples.jitter_tries", sm.jitter_tries)
        check_count(f"{where}: data.samples.overlap_rays", sm.overlap_rays)
        if self.data.train_samples < self.batch_size:
            raise TopodrakeError(f"{where}: data.train_samples ({self.data.train_samples}) is "
                                 f"smaller than one batch ({self.batch_size})")
        if not self.data.train_worlds:
            raise TopodrakeError(f"{where}: data.train_worlds is empty")
        if self.network.modality == "camera":
            c = self.camera
            if c.width != c.height or c.width % self.network.image_size:
                raise TopodrakeError(
                    f"{where}: camera {c.width}x{c.height} cannot be reduced to the network's "
                    f"{self.network.image_size}x{self.network.image_size} input")
        return self

    def to_dict(self) -> dict:
        return asdict(self)


def train_config_from_dict(d: dict, where: str = "train config") -> TrainConfig:
    """Rebuild a :class:`TrainConfig` from :meth:`TrainConfig.to_dict` output."""
    import yaml

    return load_typed_data(TrainConfig, yaml.safe_dump(d), where).validate(where)


def load_train_config(path) -> TrainConfig:
    """Read a training YAML; a bad file gives a one-line TopodrakeError naming it."""
    return load_typed(TrainConfig, path, "config").validate(f"config {path}")


def dump_train_config(cfg: TrainConfig) -> str:
    from pydrake.common.yaml import yaml_dump_typed

    return yaml_dump_typed(cfg)
