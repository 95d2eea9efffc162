"""Training data and loop of the place embedding (:mod:`topodrake.topomap.embedding`).

Data, per training house: every ``frame_step``-th pose of its expert
demonstrations, rendered once (rendering is faster than a disk cache), and
``pairs_per_world`` labelled pairs of those frames, label = the symmetric
geometric overlap ``min(R_a->b, R_b->a)``
(:func:`topodrake.sensing.overlap.mutual_overlap`). Pairs come in three
kinds, by the fractions in :class:`PlaceDataConfig`:

- near: a random frame and one within ``near_radius_m`` whose heading
  differs by less than ``near_heading_deg`` (the frame nearest a random
  point of that disk: most positives, graded);
- look-alike: a random frame and one of its ``lookalike_top`` most similar
  8 x 8 thumbnails anywhere in the house (hard negatives from rooms the
  houses copy on purpose, and some positives);
- random: two random frames (mostly easy negatives).

Loss per batch of B pairs (a_i, b_i) with labels m_i, embeddings e, f::

    mean_i (e_i . f_i - m_i)^2  +  cross_weight * mean_{i,j: other house} (e_i . f_j)^2

Frames of different houses never overlap, so every cross-house pair in the
batch is a free, exact negative. With ``data.group = G > 1`` pairs come in
groups of G sharing an anchor (kinds in the same shares), and
``rank_weight`` adds a listwise term: each anchor's softmax over the
scores / ``rank_tau`` of its own G partners and of every other house's
partners in the batch, against its own labels normalised to sum 1
(:func:`rank_loss`): recall@K is a ranking figure, which the regression
alone does not target. Both views of a pair are mirrored together
with probability 1/2 (the overlap is unchanged). Adam, constant ``lr``;
stop after ``max_steps`` or ``max_minutes``. Everything is seeded.
"""

from __future__ import annotations

import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from topodrake.demonstrations import demo_poses
from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_json, file_sha256
from topodrake.sensing.config import CameraConfig, LidarConfig
from topodrake.sensing.observe import observe
from topodrake.sensing.overlap import mutual_overlap
from topodrake.topomap.embedding import (
    PlaceEmbedding,
    PlaceNet,
    PlaceNetConfig,
    ThumbnailEmbedding,
    save_place_checkpoint,
    to_input,
)
from topodrake.topomap.embedding_eval import recall_study
from topodrake.typed_yaml import load_typed
from topodrake.world import load_world

CHECKPOINT = "checkpoint.pt"
CARD = "card.json"


def _train_worlds() -> list[str]:
    return ["train-00", "train-01", "train-02"]


@dataclass
class PlaceDataConfig:
    train_worlds: list[str] = field(default_factory=_train_worlds)
    eval_world: str = "test-0"        # recall measured there when training ends
    demo_protocol: str = "pairs"
    demo_seed: int = 0
    frame_step: int = 4               # every this-th demonstration pose is a frame
    pairs_per_world: int = 150000
    near_fraction: float = 0.5
    lookalike_fraction: float = 0.25  # the rest are random pairs
    near_radius_m: float = 2.5
    near_heading_deg: float = 90.0
    lookalike_top: int = 32
    group: int = 1                    # partners per anchor frame (> 1: for the ranking loss)
    seed: int = 0


@dataclass
class PlaceTrainConfig:
    network: PlaceNetConfig = field(default_factory=PlaceNetConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    lidar: LidarConfig = field(default_factory=LidarConfig)
    data: PlaceDataConfig = field(default_factory=PlaceDataConfig)
    batch_size: int = 128
    lr: float = 1e-3
    cross_weight: float = 1.0
    rank_weight: float = 0.0          # listwise ranking term (needs data.group > 1)
    rank_tau: float = 0.1
    mirror: bool = True
    max_steps: int = 6000
    max_minutes: float = 12.0
    log_every: int = 250
    seed: int = 0
    threads: int = 1

    def validate(self, where: str = "place config") -> "PlaceTrainConfig":
        self.network.validate(where)
        d = self.data
        if not d.train_worlds:
            raise TopodrakeError(f"{where}: data.train_worlds is empty")
        if min(d.frame_step, d.pairs_per_world, d.lookalike_top, self.batch_size, self.max_steps) < 1:
            raise TopodrakeError(f"{where}: frame_step, pairs_per_world, lookalike_top, "
                                 f"batch_size and max_steps must be >= 1")
        if not (0 <= d.near_fraction and 0 <= d.lookalike_fraction
                and d.near_fraction + d.lookalike_fraction <= 1):
            raise TopodrakeError(f"{where}: need 0 <= near_fraction, lookalike_fraction and "
                                 f"their sum <= 1")
        if not self.lr > 0:
            raise TopodrakeError(f"{where}: lr must be > 0")
        if self.rank_weight > 0 and d.group < 2:
            raise TopodrakeError(f"{where}: rank_weight needs data.group >= 2")
        return self

    @property
    def sensor(self):
        return self.camera if self.network.modality == "camera" else self.lidar


def load_place_config(path) -> PlaceTrainConfig:
    """Read a place-embedding training YAML (one-line TopodrakeError if bad)."""
    return load_typed(PlaceTrainConfig, path, "config").validate(f"config {path}")


# ---------------------------------------------------------------- data

@dataclass
class PlaceData:
    """Frames of several houses (network inputs, poses, house ids) and labelled pairs."""
    inputs: torch.Tensor      # (N, C, ...) network inputs, float16
    poses: np.ndarray         # (N, 3)
    house: np.ndarray         # (N,) index into the house list
    pairs: np.ndarray         # (M, 2) frame indices
    labels: np.ndarray        # (M,) min mutual overlap


def sample_pairs(poses: np.ndarray, thumbs: np.ndarray, n: int, cfg: PlaceDataConfig,
                 rng: np.random.Generator) -> np.ndarray:
    """(n, 2) frame pairs of one house: near, look-alike and random ones."""
    from scipy.spatial import cKDTree

    m = len(poses)
    g = cfg.group
    if g == 1:
        n_near = int(round(n * cfg.near_fraction))
        n_look = int(round(n * cfg.lookalike_fraction))
        near_rows, look_rows = np.arange(n_near), np.arange(n_near, n_near + n_look)
        a = rng.integers(0, m, n)
    else:       # groups of g rows sharing an anchor, each with the kinds' share of slots
        n = n // g * g
        g_near = int(round(g * cfg.near_fraction))
        g_look = int(round(g * cfg.lookalike_fraction))
        slot = np.tile(np.arange(g), n // g)
        near_rows = np.flatnonzero(slot < g_near)
        look_rows = np.flatnonzero((slot >= g_near) & (slot < g_near + g_look))
        n_near, n_look = len(near_rows), len(look_rows)
        a = rng.integers(0, m, n // g).repeat(g)
    b = rng.integers(0, m, n)
    cos_h = np.cos(np.radians(cfg.near_heading_deg))
    # near: aim at a random point of the disk around the frame, take the frame
    # nearest to it; keep it if it is near enough and headed alike (a few rounds)
    tree = cKDTree(poses[:, :2])
    todo = near_rows
    for _ in range(8):
        if not len(todo):
            break
        i = a[todo]
        rad = cfg.near_radius_m * np.sqrt(rng.random(len(todo)))
        ang = rng.uniform(-np.pi, np.pi, len(todo))
        aim = poses[i, :2] + rad[:, None] * np.column_stack([np.cos(ang), np.sin(ang)])
        _, j = tree.query(aim)
        ok = ((j != i) & (np.hypot(*(poses[j, :2] - poses[i, :2]).T) < cfg.near_radius_m)
              & (np.cos(poses[j, 2] - poses[i, 2]) > cos_h))
        b[todo[ok]] = j[ok]
        todo = todo[~ok]
    if n_look:
        top = min(cfg.lookalike_top, m - 1)
        rows = np.unique(a[look_rows])
        alike = np.empty((len(rows), top), np.int64)
        for lo in range(0, len(rows), 1024):
            sims = thumbs[rows[lo:lo + 1024]] @ thumbs.T
            sims[np.arange(len(sims)), rows[lo:lo + 1024]] = -np.inf
            alike[lo:lo + 1024] = np.argpartition(-sims, top - 1, axis=1)[:, :top]
        b[look_rows] = alike[np.searchsorted(rows, a[look_rows]), rng.integers(0, top, n_look)]
    return np.column_stack([a, b])


def build_data(cfg: PlaceTrainConfig, data_dir, progress: bool = True) -> PlaceData:
    """Render the training houses' frames and label their pairs (seeded)."""
    d = cfg.data
    rng = np.random.default_rng(d.seed)
    thumb = ThumbnailEmbedding("camera")
    inputs, poses, house, pairs, labels = [], [], [], [], []
    offset = 0
    for h, name in enumerate(d.train_worlds):
        t0 = time.time()
        world = load_world(name)
        p = np.concatenate([q[::d.frame_step] for q in
                            demo_poses(name, data_dir, d.demo_protocol, d.demo_seed, progress)])
        obs = observe(world, cfg.network.modality, p, cfg.sensor)
        x = to_input(cfg.network, cfg.sensor, obs).half()
        images = obs if cfg.network.modality == "camera" else observe(world, "camera", p, cfg.camera)
        pr = sample_pairs(p, thumb.embed(images), d.pairs_per_world, d, rng)
        lab = mutual_overlap(world, p[pr[:, 0]], p[pr[:, 1]], cfg.camera).min(axis=1)
        inputs.append(x)
        poses.append(p)
        house.append(np.full(len(p), h))
        pairs.append(pr + offset)
        labels.append(lab)
        offset += len(p)
        if progress:
            print(f"place data {name}: {len(p)} frames, {len(pr)} pairs, "
                  f"{(lab > 0.5).mean():.3f} with overlap > 0.5 ({time.time() - t0:.0f} s)",
                  flush=True, file=sys.stderr)
    return PlaceData(torch.cat(inputs), np.concatenate(poses), np.concatenate(house),
                     np.concatenate(pairs), np.concatenate(labels).astype(np.float32))


# ---------------------------------------------------------------- training

def place_loss(e: torch.Tensor, f: torch.Tensor, labels: torch.Tensor, house_a: torch.Tensor,
               house_b: torch.Tensor, cross_weight: float) -> tuple[torch.Tensor, dict]:
    """Pair regression of e_i . f_i onto the overlap, plus cross-house negatives."""
    pair = ((e * f).sum(-1) - labels).pow(2).mean()
    cross = house_a[:, None] != house_b[None, :]
    if cross_weight > 0 and bool(cross.any()):
        neg = (e @ f.T)[cross].pow(2).mean()
    else:
        neg = torch.zeros(())
    return pair + cross_weight * neg, {"pair": pair.item(), "cross": neg.item()}


def rank_loss(e: torch.Tensor, f: torch.Tensor, labels: torch.Tensor, house_a: torch.Tensor,
              house_b: torch.Tensor, group: int, tau: float) -> torch.Tensor:
    """Listwise ranking: anchor n (embedding ``e[n]``) against every partner
    ``f`` of the batch, where partners ``n * group ...`` are its own (labelled)
    and other houses' partners are exact negatives; cross-entropy of the
    softmax of the scores / ``tau`` against the own labels, normalised."""
    n = len(e)
    col_group = torch.arange(f.shape[0]) // group
    own = col_group[None, :] == torch.arange(n)[:, None]
    valid = own | (house_a[:, None] != house_b[None, :])
    target = torch.where(own, labels[None, :], torch.zeros(()))
    mass = target.sum(1)
    rows = mass > 0
    if not bool(rows.any()):
        return torch.zeros(())
    logp = torch.log_softmax((e @ f.T / tau).masked_fill(~valid, float("-inf")), dim=1)
    logp = logp.masked_fill(~valid, 0.0)
    return -((target[rows] / mass[rows, None]) * logp[rows]).sum(1).mean()


@dataclass
class PlaceResult:
    checkpoint: Path
    steps: int
    wall_time_s: float
    metrics: dict


def train_steps(model: PlaceNet, data: PlaceData, cfg: PlaceTrainConfig,
                log=None) -> tuple[int, float, list]:
    """Run the training loop in place; returns (steps, wall seconds, loss log)."""
    gen = torch.Generator().manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    house = torch.from_numpy(data.house)
    labels = torch.from_numpy(data.labels)
    g = cfg.data.group
    model.train()
    t0, ema, history, step = time.time(), None, [], 0
    while step < cfg.max_steps and time.time() - t0 < 60.0 * cfg.max_minutes:
        if g == 1:
            idx = torch.from_numpy(rng.integers(0, len(data.pairs), cfg.batch_size))
        else:       # whole groups: one anchor, g partners
            first = rng.integers(0, len(data.pairs) // g, max(cfg.batch_size // g, 1)) * g
            idx = torch.from_numpy((first[:, None] + np.arange(g)).ravel())
        a = torch.from_numpy(data.pairs[idx.numpy(), 0])
        b = torch.from_numpy(data.pairs[idx.numpy(), 1])
        a_once = a[::g]
        xa, xb = data.inputs[a_once].float(), data.inputs[b].float()
        if cfg.mirror:
            flip = torch.rand(len(a_once), generator=gen) < 0.5
            xa[flip] = xa[flip].flip(-1)
            flip = flip.repeat_interleave(g)
            xb[flip] = xb[flip].flip(-1)
        e_once, f = model(xa), model(xb)
        e = e_once.repeat_interleave(g, dim=0)
        loss, parts = place_loss(e, f, labels[idx], house[a], house[b], cfg.cross_weight)
        if cfg.rank_weight > 0:
            rank = rank_loss(e_once, f, labels[idx], house[a_once], house[b], g, cfg.rank_tau)
            loss = loss + cfg.rank_weight * rank
            parts["rank"] = rank.item()
        opt.zero_grad()
        loss.backward()
        opt.step()
        step += 1
        value = loss.item()
        ema = value if ema is None else 0.98 * ema + 0.02 * value
        if step % cfg.log_every == 0 or step == cfg.max_steps:
            history.append({"step": step, "loss_ema": round(ema, 5),
                            "wall_time_s": round(time.time() - t0, 1)})
            if log:
                log(f"step {step}: loss {ema:.4f} ("
                    + ", ".join(f"{k} {v:.4f}" for k, v in parts.items())
                    + f"), {time.time() - t0:.0f} s")
    model.eval()
    return step, time.time() - t0, history


def train_place(cfg: PlaceTrainConfig, out_dir, data_dir="data", *, progress: bool = True,
                command: str = "") -> PlaceResult:
    """Build the data, train, measure recall on ``data.eval_world`` and write
    ``checkpoint.pt`` and ``card.json`` into ``out_dir``."""
    from topodrake.learning.checkpoint import git_revision
    from topodrake.learning.waypoint.train import _set_threads

    cfg.validate()
    _set_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    out_dir = Path(out_dir)
    t_data = time.time()
    data = build_data(cfg, data_dir, progress)
    t_data = time.time() - t_data
    model = PlaceNet(cfg.network, cfg.lidar.beams)
    log = (lambda s: print(s, flush=True)) if progress else None
    steps, wall, history = train_steps(model, data, cfg, log)
    ckpt = out_dir / CHECKPOINT
    meta = {"train_config": asdict(cfg), "steps": steps, "wall_time_s": round(wall, 1),
            "git_revision": git_revision()}
    save_place_checkpoint(ckpt, model, cfg.sensor, **meta)
    emb = PlaceEmbedding.from_checkpoint(ckpt)
    study = recall_study(cfg.data.eval_world, data_dir, [emb, ThumbnailEmbedding(
        cfg.network.modality, cfg.sensor)], camera=cfg.camera, seed=cfg.seed)
    metrics = {"eval_world": cfg.data.eval_world, **study}
    save_place_checkpoint(ckpt, model, cfg.sensor, **meta, metrics=metrics)
    n_params = sum(p.numel() for p in model.parameters())
    card = {"checkpoint": CHECKPOINT, "sha256": file_sha256(ckpt),
            "modality": cfg.network.modality, "dim": cfg.network.dim,
            "parameters": int(n_params), "steps": steps, "train_wall_time_s": round(wall, 1),
            "data_wall_time_s": round(t_data, 1), "git_revision": meta["git_revision"],
            "data": {"train_worlds": cfg.data.train_worlds, "frames": int(len(data.poses)),
                     "pairs": int(len(data.pairs)),
                     "pairs_overlap_gt_0.5": round(float((data.labels > 0.5).mean()), 4)},
            "history": history, "metrics": metrics, "command": command, "config": asdict(cfg)}
    atomic_write_json(out_dir / CARD, card)
    if progress:
        print(f"trained place {cfg.network.modality}: {steps} steps in {wall / 60:.1f} min "
              f"-> {ckpt}", flush=True, file=sys.stderr)
    return PlaceResult(ckpt, steps, wall, metrics)
