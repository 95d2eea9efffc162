"""Training the reachability estimator RE for one controller.

RE has the C_WP design with one logit (``network.output = "reach"``) and is
trained with binary cross-entropy on labels from rollouts of the controller
it describes (:mod:`topodrake.learning.reach_labels`): training houses for
training, test houses for validation (ECE, Brier score, AUROC). The
checkpoint names its controller (path and SHA-1 of the C_WP checkpoint), and
:func:`load_reachability` refuses an RE next to another controller.

Config: a :class:`ReachTrainConfig` YAML (``configs/reach_*.yaml``). Its
``data`` section picks the demonstrations (worlds, protocol, seed) as for
C_WP; ``labels`` sets how many pairs are rolled out and how.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch.nn import functional as F

from topodrake.errors import TopodrakeError
from topodrake.learning.calibration import calibration_summary
from topodrake.learning.config import TrainConfig
from topodrake.learning.data import ObservationSource, to_network_input
from topodrake.learning.networks import NetworkConfig
from topodrake.learning.reach_labels import (ReachLabelConfig, ReachLabels, label_reachability,
                                             load_reach_labels)
from topodrake.typed_yaml import load_typed


@dataclass
class ReachLabelSets:
    train_pairs: int = 60000
    val_pairs: int = 4000
    seed: int = 0
    rollout: ReachLabelConfig = field(default_factory=ReachLabelConfig)


def _reach_network() -> NetworkConfig:
    return NetworkConfig(output="reach")


@dataclass
class ReachTrainConfig(TrainConfig):
    network: NetworkConfig = field(default_factory=_reach_network)
    controller: str = "checkpoints/camera_k5/checkpoint.pt"   # the C_WP it describes
    labels: ReachLabelSets = field(default_factory=ReachLabelSets)

    def validate(self, where: str = "reach train config") -> "ReachTrainConfig":
        if self.network.output != "reach":
            raise TopodrakeError(f"{where}: network.output must be 'reach' for RE")
        if self.labels.train_pairs < self.batch_size or self.labels.val_pairs < 1:
            raise TopodrakeError(f"{where}: need labels.train_pairs >= batch_size and val_pairs >= 1")
        self.labels.rollout.validate()
        super().validate(where)
        return self


def load_reach_config(path) -> ReachTrainConfig:
    return load_typed(ReachTrainConfig, path, "config").validate(f"config {path}")


def file_sha1(path) -> str:
    h = hashlib.sha1()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def controller_identity(path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise TopodrakeError(f"controller checkpoint {path} does not exist")
    return {"checkpoint": str(path), "sha1": file_sha1(path)}


# ---------------------------------------------------------------- batches

@dataclass
class ReachBatch:
    cur: torch.Tensor      # (B, C, ...) observation at the jittered source
    ctx: torch.Tensor      # (B, 2k+1, C, ...) target context
    label: torch.Tensor    # (B,) 1 = reached

    def __len__(self) -> int:
        return len(self.label)


class ReachBatcher:
    """Batches of a :class:`ReachLabels` set, rendered on the fly."""

    def __init__(self, labels: ReachLabels, cfg, camera=None, lidar=None):
        from topodrake.sensing.config import LidarConfig

        self.labels = labels
        self.cfg = cfg
        self.lidar = lidar or LidarConfig()
        self.source = ObservationSource(labels.trajectories.worlds, cfg.modality, camera, self.lidar)
        self._label = torch.from_numpy(labels.label.astype(np.float32))

    def __len__(self) -> int:
        return len(self.labels)

    def context_rows(self, idx) -> np.ndarray:
        t = self.labels.trajectories
        traj, tgt = self.labels.traj[idx], self.labels.tgt[idx]
        lo = t.traj_offsets[traj]
        hi = t.traj_offsets[traj + 1] - 1
        frames = tgt[:, None] + self.cfg.frame_step * np.arange(-self.cfg.k, self.cfg.k + 1)[None]
        return np.clip(lo[:, None] + frames, lo[:, None], hi[:, None])

    def batch(self, idx) -> ReachBatch:
        idx = np.asarray(idx, np.int64)
        t = self.labels.trajectories
        world = t.traj_world[self.labels.traj[idx]]
        rows = self.context_rows(idx)
        uniq, inv = np.unique(rows, return_inverse=True)
        owner = np.searchsorted(t.traj_offsets, uniq, side="right") - 1
        ctx_all = to_network_input(self.source.raw(t.traj_world[owner], t.poses[uniq]), self.cfg,
                                   self.lidar)
        cur = to_network_input(self.source.raw(world, self.labels.src_pose[idx]), self.cfg, self.lidar)
        ctx = ctx_all[torch.from_numpy(inv.reshape(rows.shape))]
        return ReachBatch(cur, ctx, self._label[torch.from_numpy(idx)])


def reach_loss(model, batch: ReachBatch) -> tuple[torch.Tensor, dict]:
    logit = model.forward_split(batch.cur, batch.ctx)["reach_logit"][:, 0]
    loss = F.binary_cross_entropy_with_logits(logit, batch.label)
    return loss, {"loss": loss.item()}


@torch.no_grad()
def evaluate_reach(model, batcher: ReachBatcher, batch_size: int = 256) -> dict:
    """BCE, accuracy at 0.5, ECE (10 bins), Brier score and AUROC."""
    model.eval()
    logits, labels = [], []
    for start in range(0, len(batcher), batch_size):
        b = batcher.batch(np.arange(start, min(start + batch_size, len(batcher))))
        logits.append(model.forward_split(b.cur, b.ctx)["reach_logit"][:, 0])
        labels.append(b.label)
    z, y = torch.cat(logits), torch.cat(labels)
    p = torch.sigmoid(z).numpy().astype(np.float64)
    out = {"bce": float(F.binary_cross_entropy_with_logits(z, y)),
           "accuracy": float(((p > 0.5) == (y.numpy() > 0.5)).mean())}
    out.update(calibration_summary(p, y.numpy()))
    return {k: (round(v, 5) if isinstance(v, float) else v) for k, v in out.items()}


# ---------------------------------------------------------------- data and training

def prepare_labels(cfg: ReachTrainConfig, data_dir, progress: bool = True,
                   only: str | None = None) -> tuple[ReachLabels, ReachLabels, dict]:
    """Training and validation labels of the config's controller, rolled out
    once into ``data_dir/reach-labels/`` (resumable) and reused. ``only``
    ("train" or "val") makes just that split (the other is None), so two
    processes can roll out both at once."""
    from topodrake.learning.policy import LearnedWaypointPolicy
    from topodrake.learning.samples import collect_trajectories

    ident = controller_identity(cfg.controller)
    policy = LearnedWaypointPolicy.from_checkpoint(cfg.controller)
    if policy.is_direct_control:
        raise TopodrakeError(f"{cfg.controller} is a direct-control network; RE needs a C_WP")
    d, lab = cfg.data, cfg.labels
    tag = d.demo_protocol + (f"{d.demo_count}" if d.demo_protocol == "random" else "")
    demo_root = Path(data_dir) / "demos" / f"{tag}-s{d.demo_seed}"
    out = []
    for split, worlds, n, seed in (("train", d.train_worlds, lab.train_pairs, lab.seed),
                                   ("val", d.val_worlds, lab.val_pairs, lab.seed + 1)):
        if only is not None and split != only:
            out.append(None)
            continue
        key = hashlib.sha1(json.dumps({"worlds": worlds, "n": n, "seed": seed,
                                       "cfg": asdict(lab.rollout), "demos": str(demo_root)},
                                      sort_keys=True).encode()).hexdigest()[:10]
        folder = Path(data_dir) / "reach-labels" / f"{ident['sha1'][:10]}-{split}-{key}"
        trajs = collect_trajectories(worlds, demo_root, protocol=d.demo_protocol,
                                     count=d.demo_count, seed=d.demo_seed, progress=progress)
        label_reachability(trajs, policy, folder, n, seed=seed, controller=ident,
                           config=lab.rollout, progress=progress)
        out.append(load_reach_labels(folder))
    return out[0], out[1], ident


def train_reachability(cfg: ReachTrainConfig, out_dir, data_dir="data", *, resume: bool = True,
                       progress: bool = True, labels: tuple[ReachLabels, ReachLabels] | None = None,
                       controller: dict | None = None, command: str | None = None):
    """Train (or resume) RE for ``cfg.controller`` into ``out_dir``."""
    from topodrake.learning.train import Task, _set_threads, train_network

    cfg.validate()
    _set_threads(cfg.threads)
    if labels is None:
        train_l, val_l, controller = prepare_labels(cfg, data_dir, progress)
    else:
        (train_l, val_l), controller = labels, controller or controller_identity(cfg.controller)
    task = Task(
        train=ReachBatcher(train_l, cfg.network, cfg.camera, cfg.lidar),
        val=ReachBatcher(val_l, cfg.network, cfg.camera, cfg.lidar),
        loss=reach_loss, evaluate=evaluate_reach, metric="ece",
        card={"controller": controller,
              "data": {"train_worlds": cfg.data.train_worlds, "val_worlds": cfg.data.val_worlds,
                       "train_pairs": len(train_l), "val_pairs": len(val_l),
                       "train_success_rate": round(float(train_l.label.mean()), 4),
                       "val_success_rate": round(float(val_l.label.mean()), 4)}},
        meta={"controller": controller})
    return train_network(cfg, task, out_dir, resume=resume, progress=progress, command=command)


def load_reachability(path, controller_checkpoint):
    """An RE checkpoint for ``controller_checkpoint``; an RE trained for
    another controller (other file contents) is refused."""
    from topodrake.learning.checkpoint import load_checkpoint

    ck = load_checkpoint(path, output="reach")
    want = controller_identity(controller_checkpoint)
    have = (ck.meta.get("extra") or {}).get("controller") or {}
    if have.get("sha1") != want["sha1"]:
        raise TopodrakeError(f"reachability estimator {path} was trained for controller "
                             f"{have.get('checkpoint', 'unknown')!r} (sha1 {str(have.get('sha1'))[:10]}), "
                             f"not {want['checkpoint']!r} (sha1 {want['sha1'][:10]})")
    return ck
