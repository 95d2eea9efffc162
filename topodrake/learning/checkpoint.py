"""Waypoint-network checkpoints: save atomically, load with checks.

A checkpoint is one ``torch.save`` file (read back with
``weights_only=True``, so loading never runs pickled code) holding::

    format, version            "topodrake-waypoint-net", 1
    network                    NetworkConfig as a dict (shape of the model)
    modality, image_size       "camera" | "lidar", the camera input side
    sensor                     the CameraConfig / LidarConfig it was trained with
    train_config               the full TrainConfig as a dict
    git_revision               of the code that trained it ("unknown" outside git)
    metrics, history           latest validation metrics, and every evaluation
    samples_seen, wall_time_s  training progress
    created                    ISO time of writing
    model                      state dict
    train_state                (optional) where training stands, to resume
    extra                      (optional) task data, e.g. the controller an RE measured
    payload_sha256             SHA-256 of all of the above (:mod:`~topodrake.learning.sealed`;
                               absent in checkpoints written before it existed)

The optimizer state, twice the size of the weights, goes to ``resume.pt``
beside the checkpoint (:func:`save_resume_state`), so the checkpoint that is
shipped stays small; an older checkpoint that holds ``optimizer`` itself is
still read.

Loading refuses, with one line naming the file and the mismatch, a file that
is not a checkpoint, a corrupt one, or one trained for another sensor,
context length or camera than the caller needs. A damaged file is refused
before anything of it is used: one whose bytes differ from the SHA-256 its
card records, whose archive fails its CRC-32, or whose payload differs from
its ``payload_sha256`` (:func:`~topodrake.fileio.check_intact`,
:func:`~topodrake.learning.sealed.check_seal`). Writing a checkpoint drops
the ``sha256`` of a card beside it (the card no longer describes the new
bytes); the trainer writes the card anew with the new checksum.
"""

from __future__ import annotations

import datetime as _dt
import io
import subprocess
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch

from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_bytes, check_intact, forget_card_sha256
from topodrake.learning.networks import NetworkConfig, WaypointNetwork, input_size
from topodrake.learning.sealed import SEAL, check_seal, seal
from topodrake.sensing.config import CameraConfig, LidarConfig

FORMAT = "topodrake-waypoint-net"
VERSION = 1

#: Camera fields that change what the network sees (must match to reuse weights).
_CAMERA_KEYS = ("hfov_deg", "forward_m", "height_m", "max_depth_m")
_LIDAR_KEYS = ("beams", "fov_deg", "range_m", "forward_m")


def git_revision() -> str:
    """The package's git revision, or "unknown" (no git, not a checkout, ...)."""
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(__file__).resolve().parent,
                             capture_output=True, text=True, timeout=5)
        rev = out.stdout.strip()
        return rev if out.returncode == 0 and rev else "unknown"
    except Exception:
        return "unknown"


@dataclass
class Checkpoint:
    path: Path
    network: NetworkConfig
    sensor: CameraConfig | LidarConfig
    model: WaypointNetwork
    meta: dict = field(default_factory=dict)       # everything but the tensors
    optimizer: dict | None = None
    train_state: dict | None = None

    @property
    def modality(self) -> str:
        return self.network.modality

    @property
    def camera(self) -> CameraConfig | None:
        return self.sensor if isinstance(self.sensor, CameraConfig) else None

    @property
    def lidar(self) -> LidarConfig | None:
        return self.sensor if isinstance(self.sensor, LidarConfig) else None


def save_checkpoint(path, model: WaypointNetwork, sensor: CameraConfig | LidarConfig, *,
                    train_config: dict | None = None, metrics: dict | None = None,
                    history: list | None = None, samples_seen: int = 0,
                    wall_time_s: float = 0.0, optimizer: dict | None = None,
                    train_state: dict | None = None, revision: str | None = None,
                    extra: dict | None = None) -> Path:
    """Write a checkpoint atomically (temporary file, then rename); ``extra``
    (JSON-like) is kept as ``meta["extra"]``, e.g. the controller an RE
    was trained for."""
    cfg = model.cfg
    blob = {
        "format": FORMAT, "version": VERSION,
        "network": cfg.to_dict(), "modality": cfg.modality,
        "image_size": int(cfg.image_size) if cfg.modality == "camera" else 0,
        "sensor": asdict(sensor),
        "train_config": train_config or {},
        "git_revision": revision if revision is not None else git_revision(),
        "metrics": metrics or {}, "history": history or [],
        "samples_seen": int(samples_seen), "wall_time_s": float(wall_time_s),
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "model": model.state_dict(),
    }
    if optimizer is not None:
        blob["optimizer"] = optimizer
    if train_state is not None:
        blob["train_state"] = train_state
    if extra:
        blob["extra"] = extra
    buf = io.BytesIO()
    torch.save(seal(blob), buf)
    forget_card_sha256(path)
    return atomic_write_bytes(path, buf.getvalue())


RESUME = "resume.pt"


def save_resume_state(path, optimizer: dict, samples_seen: int) -> Path:
    """Write the optimizer state of a training run at ``samples_seen``."""
    buf = io.BytesIO()
    torch.save(seal({"format": FORMAT + "-resume", "samples_seen": int(samples_seen),
                     "optimizer": optimizer}), buf)
    return atomic_write_bytes(path, buf.getvalue())


def load_resume_state(path, samples_seen) -> dict | None:
    """The optimizer state in ``path`` if it belongs to the checkpoint at
    ``samples_seen``; None when missing, unreadable or from another step
    (training then resumes with a fresh optimizer)."""
    path = Path(path)
    if not path.is_file():
        return None
    try:
        check_intact(path, "optimizer state")
        blob = torch.load(path, map_location="cpu", weights_only=True)
        if isinstance(blob, dict):
            check_seal(blob, path, "optimizer state")
    except Exception:
        return None
    if (not isinstance(blob, dict) or blob.get("format") != FORMAT + "-resume"
            or blob.get("samples_seen") != samples_seen):
        return None
    return blob.get("optimizer")


def _mismatch(path, what: str, have, want) -> TopodrakeError:
    return TopodrakeError(f"checkpoint {path} was trained with {what} = {have!r}, "
                          f"but {want!r} is required")


def load_checkpoint(path, *, modality: str | None = None, k: int | None = None,
                    output: str | None = None, camera: CameraConfig | None = None,
                    lidar: LidarConfig | None = None, network: NetworkConfig | None = None
                    ) -> Checkpoint:
    """Load and check a checkpoint. Every given expectation must match:
    ``modality``, ``k``, ``output`` (waypoint / control), the sensor config
    the caller renders with (``camera`` fields that change the image, or
    ``lidar``), or a whole ``network`` config (resuming training)."""
    path = Path(path)
    if not path.is_file():
        raise TopodrakeError(f"checkpoint {path} does not exist")
    check_intact(path, "checkpoint")
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:
        raise TopodrakeError(f"checkpoint {path} is corrupt or not a torch file "
                             f"({type(e).__name__})") from None
    if not isinstance(blob, dict) or blob.get("format") != FORMAT:
        raise TopodrakeError(f"{path} is not a {FORMAT} checkpoint")
    check_seal(blob, path, "checkpoint")
    if blob.get("version") != VERSION:
        raise TopodrakeError(f"checkpoint {path} has format version {blob.get('version')}; "
                             f"this topodrake reads {VERSION}")
    for key in ("network", "sensor", "model"):
        if key not in blob:
            raise TopodrakeError(f"checkpoint {path} lacks {key!r}")
    try:
        net_cfg = NetworkConfig(**blob["network"]).validate(f"checkpoint {path}")
        sensor_cls = CameraConfig if net_cfg.modality == "camera" else LidarConfig
        sensor = sensor_cls(**blob["sensor"])
    except TypeError as e:
        raise TopodrakeError(f"checkpoint {path} has an unreadable config ({e})") from None
    # -- expectations -------------------------------------------------------
    if modality is not None and modality != net_cfg.modality:
        raise _mismatch(path, "modality", net_cfg.modality, modality)
    if k is not None and k != net_cfg.k:
        raise _mismatch(path, "context k", net_cfg.k, k)
    if output is not None and output != net_cfg.output:
        raise _mismatch(path, "output", net_cfg.output, output)
    if camera is not None:
        if net_cfg.modality != "camera":
            raise _mismatch(path, "modality", net_cfg.modality, "camera")
        for key in _CAMERA_KEYS:
            if abs(getattr(camera, key) - getattr(sensor, key)) > 1e-9:
                raise _mismatch(path, f"camera {key}", getattr(sensor, key), getattr(camera, key))
        if camera.width % net_cfg.image_size or camera.height != camera.width:
            raise TopodrakeError(
                f"checkpoint {path} needs {net_cfg.image_size}x{net_cfg.image_size} inputs; "
                f"a {camera.width}x{camera.height} camera cannot provide them")
    if lidar is not None:
        if net_cfg.modality != "lidar":
            raise _mismatch(path, "modality", net_cfg.modality, "lidar")
        for key in _LIDAR_KEYS:
            if abs(getattr(lidar, key) - getattr(sensor, key)) > 1e-9:
                raise _mismatch(path, f"lidar {key}", getattr(sensor, key), getattr(lidar, key))
    if network is not None:
        want = network.to_dict()
        for key, value in want.items():
            if blob["network"].get(key) != value:
                raise _mismatch(path, f"network.{key}", blob["network"].get(key), value)
    size = input_size(net_cfg, getattr(sensor, "beams", 0))
    model = WaypointNetwork(net_cfg, size)
    try:
        model.load_state_dict(blob["model"])
    except Exception as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise TopodrakeError(f"checkpoint {path}: weights do not fit its network config ({first})") from None
    model.eval()
    meta = {key: v for key, v in blob.items()
            if key not in ("model", "optimizer", "train_state", SEAL)}
    return Checkpoint(path, net_cfg, sensor, model, meta, blob.get("optimizer"),
                      blob.get("train_state"))
