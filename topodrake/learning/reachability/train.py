"""Training the reachability estimator RE for one controller.

RE has the C_WP design with one logit (``network.output = "reach"``) and is
trained with binary cross-entropy on labels from rollouts of the controller
it describes (:mod:`topodrake.learning.reachability.labels`): training houses for
training, test houses for validation (ECE, Brier score, AUROC). The
checkpoint names its controller (path and SHA-1 of the C_WP checkpoint), and
:func:`load_reachability` refuses an RE next to another controller.

A controller without a network, the registration C_WP
(:class:`~topodrake.registration.policy.RegistrationPolicy`), is named
``controller: registration``; its fingerprint is the SHA-1 of its settings
and lidar (:func:`~topodrake.learning.reachability.controllers.registration_identity`),
so an RE trained for it is refused next to a registration controller with
other settings. It has no encoder to start from: ``init`` is ``scratch`` or
an RE checkpoint, and with ``init_any_controller`` that RE may be another controller's (its
weights only: a warm start from an RE that has learnt to compare scans).

Beyond the paper's recipe (each a config switch): RE starts from its
controller's encoder, frame combiner and overlap head (``init``), or from
all the weights of an earlier RE of the same controller, to fine-tune it on
new labels; an auxiliary head learns the pair's geometric image overlaps at the start
(``overlap_weight``), the cue for the many pairs that fail at once because
the two views share nothing; a temperature fitted on the validation
rollouts is stored and applied on load when it lowers their BCE
(``temperature_scaling``); and a second calibration, for the hops between
frames of one drive, is fitted on rollouts of such hops
(``anchor_calibration``). ``labels.more`` sets may come from houses the
controller never saw (``worlds``), which is what RE's generalisation to new
houses needs most.

Config: a :class:`ReachTrainConfig` YAML (``configs/reach_*.yaml``). Its
``data`` section picks the demonstrations (worlds, protocol, seed) as for
C_WP; ``labels`` sets how many pairs are rolled out and how (``labels.more``
adds training pairs drawn another way, e.g. with every source on the path).
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
from topodrake.fileio import file_sha1
from topodrake.learning.config import TrainConfig
from topodrake.learning.data import ObservationSource, to_network_input
from topodrake.learning.networks import NetworkConfig, mirrored
from topodrake.learning.onpolicy.reach_labels import FollowerStateLabels, label_follower_states
from topodrake.learning.reachability.calibration import (
    calibration_summary,
    fit_platt,
    fit_temperature,
)
from topodrake.learning.reachability.controllers import (
    REGISTRATION,
    controller_identity,
    controller_policy,
    load_reachability,
)
from topodrake.learning.reachability.labels import (
    ReachLabelConfig,
    ReachLabels,
    concat_reach_labels,
    label_reachability,
    load_reach_labels,
)
from topodrake.learning.samples import collect_trajectories
from topodrake.navigation.follower import FollowerConfig
from topodrake.sensing.config import LidarConfig
from topodrake.sensing.overlap import mutual_overlap
from topodrake.typed_yaml import load_typed
from topodrake.world import load_world


@dataclass
class MoreReachLabels:
    """More training pairs, drawn another way (e.g. every source on the
    expert's path) or in other houses (``worlds``; default: the config's
    ``data.train_worlds``); validation stays on the main set. Its own seed
    (not one of the main sets')."""

    train_pairs: int = 20000
    seed: int = 10
    rollout: ReachLabelConfig = field(default_factory=ReachLabelConfig)
    worlds: list[str] | None = None


@dataclass
class ReachLabelSets:
    train_pairs: int = 60000
    val_pairs: int = 4000
    seed: int = 0                  # training pairs; validation uses seed + 1
    rollout: ReachLabelConfig = field(default_factory=ReachLabelConfig)
    more: list[MoreReachLabels] = field(default_factory=list)
    # training pairs from states the follower visits (sources off the drives; None: none,
    # as configs before the switch read)
    follower: list[FollowerStateLabels] | None = None


def _anchor_hops() -> ReachLabelConfig:
    return ReachLabelConfig(same_trajectory=1.0, distance_min_m=0.0, distance_max_m=3.0,
                            unjittered_sources=1.0)


@dataclass
class AnchorCalibration:
    """Rollouts for RE's second calibration (Platt scaling), the one for
    queries between frames of a drive (sparsification and the edges between
    consecutive anchors): the source on an expert frame, the target up to
    3 m ahead on the same drive, in the validation houses. These hops are far
    easier than the average validation pair (success about 0.9 instead of
    0.45), and the temperature fitted on the latter leaves RE miscalibrated
    on them. ``pairs: 0``: none (the temperature serves for them too)."""

    pairs: int = 2000
    seed: int = 2
    rollout: ReachLabelConfig = field(default_factory=_anchor_hops)


def _reach_network() -> NetworkConfig:
    return NetworkConfig(output="reach")


@dataclass
class ReachTrainConfig(TrainConfig):
    network: NetworkConfig = field(default_factory=_reach_network)
    controller: str = "checkpoints/camera_k5/checkpoint.pt"   # the C_WP it describes
    labels: ReachLabelSets = field(default_factory=ReachLabelSets)
    # "controller": start from the C_WP's encoder and frame combiner (same
    # profile needed); "scratch": random initialisation; or the path of an
    # RE checkpoint for the same controller and profile: a warm start from
    # all its weights with a fresh optimizer (fine-tuning on new labels)
    init: str = "controller"
    # the RE checkpoint in ``init`` may describe another controller (its weights
    # are a starting point only; the card names it; None: no, as configs before
    # the switch read)
    init_any_controller: bool | None = None
    # weight of the auxiliary loss on the pair's starting image overlaps
    # (geometric, from the poses; 0 = the paper's RE, reach logit only)
    overlap_weight: float = 1.0
    # probability of mirroring a training pair left-right (both views; the
    # label and overlaps stay): the controller's task is nearly symmetric,
    # and the mirrored pair doubles the views RE learns places from
    # (None or 0: never; None is how configs before the switch read)
    mirror_augment: float | None = None
    # RE's logit is the mean of the pair's and of its mirror image's (the
    # calibrations are fitted on that mean; doubles RE's cost): it ranks
    # pairs better than either alone (validation AUROC +0.008)
    mirror_average: bool = True
    # fit a temperature on the validation rollouts after training (kept
    # only if it lowers their BCE; Reachability applies it)
    temperature_scaling: bool = True
    anchor_calibration: AnchorCalibration = field(default_factory=AnchorCalibration)

    def validate(self, where: str = "reach train config") -> "ReachTrainConfig":
        if self.network.output != "reach":
            raise TopodrakeError(f"{where}: network.output must be 'reach' for RE")
        if self.labels.train_pairs < self.batch_size or self.labels.val_pairs < 1:
            raise TopodrakeError(f"{where}: need labels.train_pairs >= batch_size and val_pairs >= 1")
        if self.overlap_weight < 0:
            raise TopodrakeError(f"{where}: overlap_weight must be >= 0, got {self.overlap_weight}")
        if not 0.0 <= (self.mirror_augment or 0.0) <= 1.0:
            raise TopodrakeError(f"{where}: mirror_augment must be a probability, got "
                                 f"{self.mirror_augment}")
        if self.init == "controller" and self.controller == REGISTRATION:
            raise TopodrakeError(f"{where}: the registration controller has no network to start "
                                 "from; set init to 'scratch' or the path of an RE checkpoint")
        if not self.init:
            raise TopodrakeError(f"{where}: init must be 'controller', 'scratch' or the path of an "
                                 "RE checkpoint to start from")
        self.labels.rollout.validate()
        self.anchor_calibration.rollout.validate()
        if self.anchor_calibration.pairs < 0:
            raise TopodrakeError(f"{where}: anchor_calibration.pairs must be >= 0")
        seeds = [self.labels.seed, self.labels.seed + 1]
        if self.anchor_calibration.pairs and self.anchor_calibration.seed in seeds:
            raise TopodrakeError(f"{where}: anchor_calibration.seed {self.anchor_calibration.seed} "
                                 "is a main label set's")
        if self.anchor_calibration.pairs:
            seeds.append(self.anchor_calibration.seed)
        for extra in self.labels.more:
            if extra.worlds is not None and (not extra.worlds
                                             or set(extra.worlds) & set(self.data.val_worlds)):
                raise TopodrakeError(f"{where}: labels.more worlds must be a non-empty list of "
                                     f"houses outside data.val_worlds, got {extra.worlds}")
            if extra.train_pairs < 1 or extra.seed in seeds:
                raise TopodrakeError(f"{where}: every labels.more set needs train_pairs >= 1 and a "
                                     f"seed of its own (seed {extra.seed} is taken)")
            seeds.append(extra.seed)
            extra.rollout.validate()
        for extra in self.labels.follower or []:
            extra.validate(where)
            if extra.worlds is not None and (not extra.worlds
                                             or set(extra.worlds) & set(self.data.val_worlds)):
                raise TopodrakeError(f"{where}: labels.follower worlds must be a non-empty list of "
                                     f"houses outside data.val_worlds, got {extra.worlds}")
            if extra.seed in seeds:
                raise TopodrakeError(f"{where}: every labels.follower set needs a seed of its own "
                                     f"(seed {extra.seed} is taken)")
            seeds.append(extra.seed)
            if extra.reach is None and self.init in ("controller", "scratch"):
                raise TopodrakeError(f"{where}: labels.follower needs reach (the RE that steers "
                                     "the follower) when init is not an RE checkpoint")
        super().validate(where)
        return self


def load_reach_config(path) -> ReachTrainConfig:
    return load_typed(ReachTrainConfig, path, "config").validate(f"config {path}")


def init_from_controller(model, controller_path) -> None:
    """Copy the C_WP's encoder, frame combiner and overlap head into RE
    ``model`` (the controller has already learnt to compare observations
    from far more samples than there are reachability labels); the reach
    head stays random."""
    from topodrake.learning.checkpoint import load_checkpoint

    ck = load_checkpoint(controller_path)
    src = {k: v for k, v in ck.model.state_dict().items()
           if k.startswith(("encoder.", "combine.", "overlap."))}
    dst = model.state_dict()
    bad = [k for k, v in src.items() if k not in dst or dst[k].shape != v.shape]
    if bad:
        raise TopodrakeError(f"cannot start RE from {controller_path}: its network profile differs "
                             f"(e.g. {bad[0]}); give RE the controller's profile or set init: scratch")
    model.load_state_dict(src, strict=False)


def controller_parent(controller_path) -> str | None:
    """SHA-1 of the C_WP checkpoint ``controller_path`` was fine-tuned from
    (None for a controller trained from scratch or not readable)."""
    from topodrake.learning.checkpoint import load_checkpoint

    if str(controller_path) == REGISTRATION:
        return None
    try:
        extra = load_checkpoint(controller_path).meta.get("extra") or {}
    except TopodrakeError:
        return None
    return (extra.get("init") or {}).get("sha1")


def init_from_reachability(model, re_path, controller_path, any_controller: bool = False) -> dict:
    """Copy every weight of the RE checkpoint ``re_path`` (trained for
    ``controller_path``, or for the C_WP that controller was fine-tuned
    from, or for any controller with ``any_controller``; same profile) into
    ``model``: a warm start for fine-tuning on new labels. Returns its
    identity for the card (path, SHA-1, the samples it had seen and, with
    ``any_controller``, the controller it was trained for)."""
    from topodrake.learning.checkpoint import load_checkpoint

    ck = load_checkpoint(re_path, output="reach")
    owner = (ck.meta.get("extra") or {}).get("controller") or {}
    have = owner.get("sha1")
    if not any_controller and (have is None or have not in (
            controller_identity(controller_path)["sha1"], controller_parent(controller_path))):
        load_reachability(re_path, controller_path)     # refuses it, naming both controllers
    src, dst = ck.model.state_dict(), model.state_dict()
    bad = sorted(set(src) ^ set(dst)) or [k for k in src if src[k].shape != dst[k].shape]
    if bad:
        raise TopodrakeError(f"cannot start RE from {re_path}: its network profile differs "
                             f"(e.g. {bad[0]}); give the config that RE's network section")
    model.load_state_dict(src)
    out = {"checkpoint": str(re_path), "sha1": file_sha1(re_path),
           "samples_seen": ck.meta.get("samples_seen")}
    if any_controller:
        out["controller"] = owner
    return out


def _init(cfg: ReachTrainConfig, controller: dict):
    """``(Task.init, card entry)`` for ``cfg.init``. A warm start is checked
    here, before any rollout: an RE of another controller or profile is
    refused at once."""
    if cfg.init == "scratch":
        return None, {"init": "scratch"}
    if cfg.init == "controller":
        return (lambda model: init_from_controller(model, controller["checkpoint"])), \
            {"init": "controller"}
    from topodrake.learning.networks import WaypointNetwork, input_size

    if not Path(cfg.init).is_file():
        raise TopodrakeError(f"init: RE checkpoint {cfg.init} does not exist (init must be "
                             "'controller', 'scratch' or the path of an RE checkpoint)")
    probe = WaypointNetwork(cfg.network, input_size(cfg.network, cfg.lidar.beams))
    ident = init_from_reachability(probe, cfg.init, controller["checkpoint"],
                                   bool(cfg.init_any_controller))
    return (lambda model: model.load_state_dict(probe.state_dict())), {"init": ident}


# ---------------------------------------------------------------- batches

@dataclass
class ReachBatch:
    cur: torch.Tensor      # (B, C, ...) observation at the jittered source
    ctx: torch.Tensor      # (B, 2k+1, C, ...) target context
    label: torch.Tensor    # (B,) 1 = reached
    overlap: torch.Tensor  # (B, 2) image overlaps of source and target at the start

    def __len__(self) -> int:
        return len(self.label)


class ReachBatcher:
    """Batches of a :class:`ReachLabels` set, rendered on the fly."""
    def __init__(self, labels: ReachLabels, cfg, camera=None, lidar=None):
        self.labels = labels
        self.cfg = cfg
        self.lidar = lidar or LidarConfig()
        self.source = ObservationSource(labels.trajectories.worlds, cfg.modality, camera, self.lidar)
        self._label = torch.from_numpy(labels.label.astype(np.float32))
        self._overlap = torch.from_numpy(start_overlaps(labels).astype(np.float32))

    def __len__(self) -> int:
        return len(self.labels)

    def context_rows(self, idx) -> np.ndarray:
        return self.labels.trajectories.context_rows(self.labels.traj[idx], self.labels.tgt[idx],
                                                     self.cfg.k, self.cfg.frame_step)

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
        sel = torch.from_numpy(idx)
        return ReachBatch(cur, ctx, self._label[sel], self._overlap[sel])


def start_overlaps(labels: ReachLabels) -> np.ndarray:
    """(N, 2) geometric image overlaps (R_src->tgt, R_tgt->src) of every
    pair's jittered source and target pose, as the rollout starts."""
    t = labels.trajectories
    world = t.traj_world[labels.traj]
    tgt = t.poses[t.traj_offsets[labels.traj] + labels.tgt]
    out = np.zeros((len(labels), 2))
    for w in np.unique(world):
        sel = world == w
        out[sel] = mutual_overlap(load_world(t.worlds[w]), labels.src_pose[sel], tgt[sel])
    return out


def mirror_some(batch: ReachBatch, p: float, generator: torch.Generator | None = None
                ) -> ReachBatch:
    """``batch`` with each pair mirrored (both views) with probability ``p``."""
    if not p:
        return batch
    flip = torch.rand(len(batch), generator=generator) < p
    cur, ctx = batch.cur.clone(), batch.ctx.clone()
    cur[flip], ctx[flip] = mirrored(cur[flip]), mirrored(ctx[flip])
    return ReachBatch(cur, ctx, batch.label, batch.overlap)


def reach_loss(model, batch: ReachBatch, overlap_weight: float = 1.0
               ) -> tuple[torch.Tensor, dict]:
    out = model.forward_split(batch.cur, batch.ctx)
    reach = F.binary_cross_entropy_with_logits(out["reach_logit"][:, 0], batch.label)
    ov = F.binary_cross_entropy_with_logits(out["overlap_logits"], batch.overlap,
                                            reduction="none").sum(1).mean()
    loss = reach + overlap_weight * ov
    return loss, {"loss": loss.item(), "loss_reach": reach.item(), "loss_overlap": ov.item()}


@torch.no_grad()
def reach_logits(model, batcher: ReachBatcher, batch_size: int = 256, mirror: bool = False
                 ) -> tuple[torch.Tensor, torch.Tensor]:
    """(logits, labels) of every pair of ``batcher``; ``mirror``: the mean
    of each pair's logit and its mirror image's."""
    model.eval()
    logits, labels = [], []
    for start in range(0, len(batcher), batch_size):
        b = batcher.batch(np.arange(start, min(start + batch_size, len(batcher))))
        z = model.forward_split(b.cur, b.ctx)["reach_logit"][:, 0]
        if mirror:
            z = 0.5 * (z + model.forward_split(mirrored(b.cur), mirrored(b.ctx))["reach_logit"][:, 0])
        logits.append(z)
        labels.append(b.label)
    return torch.cat(logits), torch.cat(labels)


def _reach_metrics(z: torch.Tensor, y: torch.Tensor) -> dict:
    p = torch.sigmoid(z).numpy().astype(np.float64)
    out = {"bce": float(F.binary_cross_entropy_with_logits(z, y)),
           "accuracy": float(((p > 0.5) == (y.numpy() > 0.5)).mean())}
    out.update(calibration_summary(p, y.numpy()))
    return {k: (round(v, 5) if isinstance(v, float) else v) for k, v in out.items()}


def evaluate_reach(model, batcher: ReachBatcher, batch_size: int = 256) -> dict:
    """BCE, accuracy at 0.5, ECE (10 bins), Brier score and AUROC."""
    return _reach_metrics(*reach_logits(model, batcher, batch_size))


def fit_reach_temperature(model, batcher: ReachBatcher, mirror: bool = False) -> dict:
    """Temperature scaling on the validation pairs, kept only if it lowers
    their BCE: ``{"temperature": T, "calibrated_metrics": ...}`` (T = 1
    when it does not help)."""
    z, y = reach_logits(model, batcher, mirror=mirror)
    t = fit_temperature(z.numpy(), y.numpy())
    before, after = _reach_metrics(z, y), _reach_metrics(z / t, y)
    if not after["bce"] < before["bce"]:
        t, after = 1.0, before
    return {"temperature": round(float(t), 5), "calibrated_metrics": after}


# ---------------------------------------------------------------- data and training

def label_folder(data_dir, controller: dict, split: str, demos: str, worlds: list[str], n: int,
                 seed: int, rollout: ReachLabelConfig | dict) -> Path:
    """``data_dir/reach-labels/<controller sha1[:10]>-<split>-<key>``: where one
    label set lives. The key hashes what the labels depend on, the
    demonstrations by their folder's name ``demos``, not its path, so a
    relative and an absolute ``--data`` find the same labels."""
    cfg = rollout if isinstance(rollout, dict) else asdict(rollout)
    key = hashlib.sha1(json.dumps({"worlds": list(worlds), "n": int(n), "seed": int(seed),
                                   "cfg": cfg, "demos": str(demos)},
                                  sort_keys=True).encode()).hexdigest()[:10]
    return Path(data_dir) / "reach-labels" / f"{controller['sha1'][:10]}-{split}-{key}"


def _demo_root(cfg: ReachTrainConfig, data_dir) -> Path:
    d = cfg.data
    tag = d.demo_protocol + (f"{d.demo_count}" if d.demo_protocol == "random" else "")
    return Path(data_dir) / "demos" / f"{tag}-s{d.demo_seed}"


def prepare_labels(cfg: ReachTrainConfig, data_dir, progress: bool = True,
                   only: str | None = None) -> tuple[ReachLabels, ReachLabels, dict]:
    """Training and validation labels of the config's controller, rolled out
    once into ``data_dir/reach-labels/`` (resumable) and reused. ``only``
    ("train" or "val") makes just that split (the other is None), so two
    processes can roll out both at once."""
    ident = controller_identity(cfg.controller)
    policy = controller_policy(cfg.controller)
    d, lab = cfg.data, cfg.labels
    sets = {"train": [(d.train_worlds, lab.train_pairs, lab.seed, lab.rollout)]
            + [(m.worlds or d.train_worlds, m.train_pairs, m.seed, m.rollout) for m in lab.more],
            "val": [(d.val_worlds, lab.val_pairs, lab.seed + 1, lab.rollout)]}
    out = []
    for split, parts in sets.items():
        if only is not None and split != only:
            out.append(None)
            continue
        sets = [_label_set(cfg, data_dir, policy, ident, split, worlds, n, seed, rollout, progress)
                for worlds, n, seed, rollout in parts]
        if split == "train":
            sets += [_follower_set(cfg, data_dir, policy, ident, extra, progress)
                     for extra in lab.follower or []]
        out.append(concat_reach_labels(sets))
    return out[0], out[1], ident


def _follower_set(cfg: ReachTrainConfig, data_dir, policy, ident: dict,
                  extra: FollowerStateLabels, progress: bool) -> ReachLabels:
    """One set of follower-state labels (:mod:`topodrake.learning.onpolicy.reach_labels`),
    made once in ``data_dir/reach-labels/`` (resumable) and loaded."""
    from topodrake.learning.reachability.estimator import Reachability

    d = cfg.data
    reach_path = extra.reach or cfg.init
    reach = Reachability.from_checkpoint(reach_path, cfg.controller)
    reach_ident = {"checkpoint": str(reach_path), "sha1": file_sha1(reach_path),
                   "follower_platt": list(reach.follower_platt or [])}
    worlds = extra.worlds or d.train_worlds
    demo_root = _demo_root(cfg, data_dir)
    key_cfg = {"follower_states": [reach_ident["sha1"], reach_ident["follower_platt"],
                                   extra.drives_per_world, extra.next_share,
                                   asdict(FollowerConfig())], **asdict(extra.rollout)}
    folder = label_folder(data_dir, ident, "follower", demo_root.name, worlds, extra.train_pairs,
                          extra.seed, key_cfg)
    trajs = collect_trajectories(worlds, demo_root, protocol=d.demo_protocol, count=d.demo_count,
                                 seed=d.demo_seed, progress=progress)
    label_follower_states(trajs, policy, reach, folder, extra.train_pairs, seed=extra.seed,
                          controller=ident, reach_identity=reach_ident,
                          drives_per_world=extra.drives_per_world, next_share=extra.next_share,
                          config=extra.rollout, progress=progress)
    return load_reach_labels(folder)


def _label_set(cfg: ReachTrainConfig, data_dir, policy, ident: dict, split: str, worlds, n: int,
               seed: int, rollout: ReachLabelConfig, progress: bool) -> ReachLabels:
    """One label set of ``policy`` (identified by ``ident``) in ``worlds``,
    rolled out into its :func:`label_folder` once (resumable) and loaded."""
    d = cfg.data
    demo_root = _demo_root(cfg, data_dir)
    folder = label_folder(data_dir, ident, split, demo_root.name, worlds, n, seed, rollout)
    trajs = collect_trajectories(worlds, demo_root, protocol=d.demo_protocol, count=d.demo_count,
                                 seed=d.demo_seed, progress=progress)
    label_reachability(trajs, policy, folder, n, seed=seed, controller=ident, config=rollout,
                       progress=progress)
    return load_reach_labels(folder)


def prepare_anchor_labels(cfg: ReachTrainConfig, data_dir, progress: bool = True
                          ) -> ReachLabels | None:
    """The anchor-hop rollouts of :class:`AnchorCalibration` in the
    validation houses (None when ``pairs`` is 0), made once and reused."""
    a = cfg.anchor_calibration
    if not a.pairs:
        return None
    return _label_set(cfg, data_dir, controller_policy(cfg.controller),
                      controller_identity(cfg.controller), "anchor", cfg.data.val_worlds, a.pairs,
                      a.seed, a.rollout, progress)


def calibrate(model, val: ReachBatcher, anchors: ReachBatcher | None, scaling: bool = True,
              mirror: bool = False) -> dict:
    """What training adds after the last step: the temperature of the
    validation pairs (if ``scaling``) and the Platt scaling of the anchor
    hops (``anchor_platt`` = [slope, bias], with the hops' metrics before
    (under the temperature) and after), both of the mirror-averaged logit
    if ``mirror`` (recorded as ``mirror_average``, which
    :class:`~topodrake.learning.reachability.estimator.Reachability` follows)."""
    out = {"mirror_average": bool(mirror)}
    if scaling:
        out.update(fit_reach_temperature(model, val, mirror=mirror))
    if anchors is not None:
        z, y = reach_logits(model, anchors, mirror=mirror)
        a, b = fit_platt(z.numpy(), y.numpy())
        out.update(anchor_platt=[round(a, 5), round(b, 5)], anchor_pairs=len(anchors),
                   anchor_success_rate=round(float(y.mean()), 4),
                   anchor_metrics_temperature=_reach_metrics(z / out.get("temperature", 1.0), y),
                   anchor_metrics=_reach_metrics(a * z + b, y))
    return out


def train_reachability(cfg: ReachTrainConfig, out_dir, data_dir="data", *, resume: bool = True,
                       progress: bool = True, labels: tuple[ReachLabels, ...] | None = None,
                       controller: dict | None = None, command: str | None = None):
    """Train (or resume) RE for ``cfg.controller`` into ``out_dir``.
    ``labels``: (train, validation[, anchor hops]) instead of the config's
    rollouts."""
    from topodrake.learning.waypoint.train import Task, _set_threads, train_network

    cfg.validate()
    _set_threads(cfg.threads)
    controller = controller or controller_identity(cfg.controller)
    init, init_card = _init(cfg, controller)
    if labels is None:
        train_l, val_l, controller = prepare_labels(cfg, data_dir, progress)
        anchor_l = prepare_anchor_labels(cfg, data_dir, progress)
    else:
        train_l, val_l, *rest = labels
        anchor_l = rest[0] if rest else None
    anchors = None if anchor_l is None else ReachBatcher(anchor_l, cfg.network, cfg.camera, cfg.lidar)
    task = Task(
        train=ReachBatcher(train_l, cfg.network, cfg.camera, cfg.lidar),
        val=ReachBatcher(val_l, cfg.network, cfg.camera, cfg.lidar),
        loss=lambda model, b: reach_loss(model, mirror_some(b, cfg.mirror_augment or 0.0),
                                         cfg.overlap_weight),
        evaluate=evaluate_reach, metric="ece",
        card={"controller": controller,
              "data": {"train_worlds": train_l.trajectories.worlds, "val_worlds": cfg.data.val_worlds,
                       "train_pairs": len(train_l), "val_pairs": len(val_l),
                       "train_success_rate": round(float(train_l.label.mean()), 4),
                       "val_success_rate": round(float(val_l.label.mean()), 4)},
              **init_card},
        meta={"controller": controller},
        init=init,
        finish=lambda model, val: calibrate(model, val, anchors, cfg.temperature_scaling,
                                            cfg.mirror_average))
    return train_network(cfg, task, out_dir, resume=resume, progress=progress, command=command)
