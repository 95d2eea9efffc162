"""Training data and loop of SPTM's retrieval network (:mod:`topodrake.baselines.retrieval_net`).

Data, as SPTM builds it from its exploration episodes: per training house,
``drives_per_world`` expert demonstrations (picked with the seed; collected
into ``data_dir/demos/<protocol>-s<seed>/<house>`` once and reused), every
frame rendered once by the camera. A pair is drawn per sample:

- positive (probability ``positive_fraction``): a random frame and another
  frame of the same drive at most ``positive_max_frames`` away in time;
- negative: a random frame and a frame of the same drive more than
  ``negative_min_frames`` away in time, or (probability
  ``other_house_fraction`` of the negatives) a frame of another house.

Labels come from time only, never from geometry (SPTM's self-supervision);
frames of *other* drives of the same house are never used as negatives,
because the drives of a house run between the same places.

Loss: binary cross-entropy on the pair logit; both frames of a pair are
mirrored together with probability 1/2. Adam, constant ``lr``; stop after
``max_steps`` or ``max_minutes``. Everything is seeded.

Validation on ``eval_world`` (a test house, its own drives): pairs drawn
the same way from time (AUROC, accuracy at 0.5, share of scores above
SPTM's 0.99), and pairs of frames of *different* drives labelled by
geometry (positive within ``geo_radius_m`` and ``geo_heading_deg``,
negative beyond ``geo_far_m``), which is what shortcut edges and
localization rely on.
"""

from __future__ import annotations

import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch.nn import functional as F

from topodrake.baselines.retrieval_net import (
    RetrievalNet,
    RetrievalNetConfig,
    RetrievalScorer,
    save_retrieval_checkpoint,
)
from topodrake.demonstrations import demo_poses
from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_json, file_sha256
from topodrake.learning.networks import camera_input
from topodrake.sensing.config import CameraConfig
from topodrake.sensing.observe import observe
from topodrake.typed_yaml import load_typed
from topodrake.world import load_world

CHECKPOINT = "checkpoint.pt"
CARD = "card.json"


def _train_worlds() -> list[str]:
    return ["train-00", "train-01", "train-02"]


@dataclass
class RetrievalDataConfig:
    train_worlds: list[str] = field(default_factory=_train_worlds)
    eval_world: str = "test-0"
    demo_protocol: str = "pairs"
    demo_seed: int = 0
    drives_per_world: int = 30        # drives rendered per training house
    eval_drives: int = 20             # drives of the evaluation house
    positive_max_frames: int = 5      # |dt| <= this: a positive (~0.2 m of driving)
    negative_min_frames: int = 20     # |dt| > this on one drive: a negative
    positive_fraction: float = 0.5
    other_house_fraction: float = 0.25  # of the negatives: a frame of another house
    eval_pairs: int = 20000
    geo_radius_m: float = 0.3
    geo_heading_deg: float = 20.0
    geo_far_m: float = 3.0
    seed: int = 0


@dataclass
class RetrievalTrainConfig:
    network: RetrievalNetConfig = field(default_factory=RetrievalNetConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    data: RetrievalDataConfig = field(default_factory=RetrievalDataConfig)
    batch_size: int = 128
    lr: float = 1e-3
    mirror: bool = True
    max_steps: int = 8000
    max_minutes: float = 12.0
    log_every: int = 250
    seed: int = 0
    threads: int = 1

    def validate(self, where: str = "sptm retrieval config") -> "RetrievalTrainConfig":
        self.network.validate(where)
        d = self.data
        if not d.train_worlds:
            raise TopodrakeError(f"{where}: data.train_worlds is empty")
        if min(d.drives_per_world, d.eval_drives, d.positive_max_frames, d.eval_pairs,
               self.batch_size, self.max_steps) < 1:
            raise TopodrakeError(f"{where}: drives_per_world, eval_drives, positive_max_frames, "
                                 f"eval_pairs, batch_size and max_steps must be >= 1")
        if d.negative_min_frames < d.positive_max_frames:
            raise TopodrakeError(f"{where}: negative_min_frames must be >= positive_max_frames")
        if not (0 <= d.positive_fraction <= 1 and 0 <= d.other_house_fraction <= 1):
            raise TopodrakeError(f"{where}: positive_fraction and other_house_fraction must be "
                                 f"in [0, 1]")
        if d.other_house_fraction > 0 and len(d.train_worlds) < 2:
            raise TopodrakeError(f"{where}: other_house_fraction needs two training houses")
        if not self.lr > 0:
            raise TopodrakeError(f"{where}: lr must be > 0")
        return self


def load_retrieval_config(path) -> RetrievalTrainConfig:
    """Read an SPTM retrieval training YAML (one-line TopodrakeError if bad)."""
    return load_typed(RetrievalTrainConfig, path, "config").validate(f"config {path}")


# ---------------------------------------------------------------- data

@dataclass
class FrameSet:
    """Frames of several drives (network inputs) with their drive and time."""
    inputs: torch.Tensor      # (N, 3, S, S) float16
    poses: np.ndarray         # (N, 3) metadata (geometric validation only)
    drive: np.ndarray         # (N,) global drive index
    house: np.ndarray         # (N,) house index
    drive_start: np.ndarray   # (D,) first row of each drive
    drive_len: np.ndarray     # (D,) frames of each drive

    @classmethod
    def from_drives(cls, drives: list[tuple[np.ndarray, np.ndarray, int]], image_size: int,
                    ) -> "FrameSet":
        """``drives``: (images (T, H, W, 3) uint8, poses (T, 3), house index)."""
        inputs, poses, drive, house, lens = [], [], [], [], []
        for d, (images, p, h) in enumerate(drives):
            inputs.append(camera_input(images, image_size).half())
            poses.append(np.asarray(p, np.float64))
            drive.append(np.full(len(p), d))
            house.append(np.full(len(p), h))
            lens.append(len(p))
        lens = np.array(lens, np.int64)
        return cls(torch.cat(inputs), np.concatenate(poses), np.concatenate(drive),
                   np.concatenate(house), np.concatenate([[0], np.cumsum(lens)[:-1]]), lens)


def sample_pairs(frames: FrameSet, n: int, cfg: RetrievalDataConfig,
                 rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(a, b, label) rows of n temporally labelled pairs (see the module doc)."""
    a = rng.integers(0, len(frames.drive), n)
    d = frames.drive[a]
    start, length = frames.drive_start[d], frames.drive_len[d]
    t = a - start
    positive = rng.random(n) < cfg.positive_fraction
    # positives: |dt| <= positive_max_frames, clamped to the drive
    dt = rng.integers(-cfg.positive_max_frames, cfg.positive_max_frames + 1, n)
    b = start + np.clip(t + dt, 0, length - 1)
    # negatives on the same drive: uniform over frames with |dt| > negative_min_frames
    m = cfg.negative_min_frames
    lo_count = np.maximum(t - m, 0)                 # frames 0 .. t-m-1
    hi_count = np.maximum(length - (t + m + 1), 0)  # frames t+m+1 .. length-1
    far = lo_count + hi_count
    u = (rng.random(n) * np.maximum(far, 1)).astype(np.int64)
    b_far = start + np.where(u < lo_count, u, t + m + 1 + (u - lo_count))
    other = (rng.random(n) < cfg.other_house_fraction) | (far == 0)
    houses = np.unique(frames.house)
    if len(houses) > 1:
        b_other = rng.integers(0, len(frames.drive), n)
        same = frames.house[b_other] == frames.house[a]
        while same[other].any():            # redraw until another house
            redo = other & same
            b_other[redo] = rng.integers(0, len(frames.drive), int(redo.sum()))
            same = frames.house[b_other] == frames.house[a]
    else:
        b_other, other = b_far, np.zeros(n, bool)
    b_neg = np.where(other, b_other, b_far)
    b = np.where(positive, b, b_neg)
    return a, b, positive.astype(np.float32)


def load_drives(world_name: str, data_dir, cfg: RetrievalDataConfig, count: int,
                rng: np.random.Generator, camera: CameraConfig, progress: bool = False):
    """(images, poses) of ``count`` seeded-random drives of a house's demonstrations."""
    drives = demo_poses(world_name, data_dir, cfg.demo_protocol, cfg.demo_seed, progress)
    pick = np.sort(rng.choice(len(drives), min(count, len(drives)), replace=False))
    world = load_world(world_name)
    return [(observe(world, "camera", drives[i], camera), drives[i]) for i in pick]


def build_frames(cfg: RetrievalTrainConfig, data_dir, progress: bool = True
                 ) -> tuple[FrameSet, FrameSet]:
    """(training frames, evaluation frames), rendered once (seeded)."""
    d = cfg.data
    rng = np.random.default_rng(d.seed)
    train = []
    for h, name in enumerate(d.train_worlds):
        t0 = time.time()
        got = load_drives(name, data_dir, d, d.drives_per_world, rng, cfg.camera, progress)
        train += [(img, p, h) for img, p in got]
        if progress:
            print(f"retrieval data {name}: {len(got)} drives, {sum(len(p) for _, p in got)} "
                  f"frames ({time.time() - t0:.0f} s)", flush=True, file=sys.stderr)
    got = load_drives(d.eval_world, data_dir, d, d.eval_drives, rng, cfg.camera, progress)
    evals = [(img, p, 0) for img, p in got]
    size = cfg.network.image_size
    return FrameSet.from_drives(train, size), FrameSet.from_drives(evals, size)


# ---------------------------------------------------------------- metrics

def auroc(scores: np.ndarray, labels: np.ndarray) -> float:
    """Area under the ROC curve (ties count one half); nan without both classes."""
    from scipy.stats import rankdata

    labels = np.asarray(labels).astype(bool)
    n_pos, n_neg = int(labels.sum()), int((~labels).sum())
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    r = rankdata(scores)
    return float((r[labels].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def _pair_metrics(scores: np.ndarray, labels: np.ndarray) -> dict:
    pos, neg = scores[labels > 0.5], scores[labels < 0.5]
    return {"pairs": int(len(scores)), "positives": int(len(pos)),
            "auroc": round(auroc(scores, labels), 4),
            "accuracy_at_0.5": round(float(((scores > 0.5) == (labels > 0.5)).mean()), 4),
            "positives_above_0.99": round(float((pos > 0.99).mean()), 4) if len(pos) else None,
            "negatives_above_0.99": round(float((neg > 0.99).mean()), 4) if len(neg) else None}


def geometric_pairs(frames: FrameSet, n: int, cfg: RetrievalDataConfig,
                    rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairs of frames of different drives: half near in pose (label 1),
    half farther than ``geo_far_m`` (label 0)."""
    from scipy.spatial import cKDTree

    tree = cKDTree(frames.poses[:, :2])
    a_out, b_out = [], []
    cos_h = np.cos(np.radians(cfg.geo_heading_deg))
    for _ in range(20):
        if sum(len(x) for x in a_out) >= n // 2:
            break
        a = rng.integers(0, len(frames.drive), n)
        cands = tree.query_ball_point(frames.poses[a, :2], cfg.geo_radius_m)
        for i, c in zip(a, cands):
            c = np.asarray(c, np.int64)
            c = c[(frames.drive[c] != frames.drive[i])
                  & (np.cos(frames.poses[c, 2] - frames.poses[i, 2]) > cos_h)]
            if len(c):
                a_out.append([i])
                b_out.append([c[rng.integers(len(c))]])
    a_pos = np.concatenate(a_out)[: n // 2] if a_out else np.zeros(0, np.int64)
    b_pos = np.concatenate(b_out)[: n // 2] if b_out else np.zeros(0, np.int64)
    a = rng.integers(0, len(frames.drive), 4 * n)
    b = rng.integers(0, len(frames.drive), 4 * n)
    far = np.hypot(*(frames.poses[a, :2] - frames.poses[b, :2]).T) > cfg.geo_far_m
    a_neg, b_neg = a[far][: n - len(a_pos)], b[far][: n - len(a_pos)]
    y = np.concatenate([np.ones(len(a_pos)), np.zeros(len(a_neg))]).astype(np.float32)
    return np.concatenate([a_pos, a_neg]), np.concatenate([b_pos, b_neg]), y


@torch.inference_mode()
def evaluate(model: RetrievalNet, frames: FrameSet, cfg: RetrievalDataConfig) -> dict:
    """Temporal and geometric pair metrics on ``frames`` (seeded)."""
    model.eval()
    rng = np.random.default_rng(cfg.seed + 1)
    feats = torch.cat([model.features(frames.inputs[lo:lo + 2048].float())
                       for lo in range(0, len(frames.inputs), 2048)])
    scorer = RetrievalScorer(model)
    out = {}
    a, b, y = sample_pairs(frames, cfg.eval_pairs, cfg, rng)
    out["temporal"] = _pair_metrics(scorer.score_features(feats[a], feats[b]), y)
    a, b, y = geometric_pairs(frames, cfg.eval_pairs, cfg, rng)
    out["geometric_cross_drive"] = _pair_metrics(scorer.score_features(feats[a], feats[b]), y)
    return out


# ---------------------------------------------------------------- training

@dataclass
class RetrievalResult:
    checkpoint: Path
    steps: int
    wall_time_s: float
    metrics: dict


def train_steps(model: RetrievalNet, frames: FrameSet, cfg: RetrievalTrainConfig,
                log=None) -> tuple[int, float, list]:
    """Run the training loop in place; returns (steps, wall seconds, loss log)."""
    gen = torch.Generator().manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    model.train()
    t0, ema, history, step = time.time(), None, [], 0
    while step < cfg.max_steps and time.time() - t0 < 60.0 * cfg.max_minutes:
        a, b, y = sample_pairs(frames, cfg.batch_size, cfg.data, rng)
        xa = frames.inputs[torch.from_numpy(a)].float()
        xb = frames.inputs[torch.from_numpy(b)].float()
        if cfg.mirror:
            flip = torch.rand(len(a), generator=gen) < 0.5
            xa[flip] = xa[flip].flip(-1)
            xb[flip] = xb[flip].flip(-1)
        logits = model(xa, xb)
        loss = F.binary_cross_entropy_with_logits(logits, torch.from_numpy(y))
        opt.zero_grad()
        loss.backward()
        opt.step()
        step += 1
        ema = loss.item() if ema is None else 0.98 * ema + 0.02 * loss.item()
        if step % cfg.log_every == 0 or step == cfg.max_steps:
            history.append({"step": step, "loss_ema": round(ema, 5),
                            "wall_time_s": round(time.time() - t0, 1)})
            if log:
                log(f"step {step}: loss {ema:.4f}, {time.time() - t0:.0f} s")
    model.eval()
    return step, time.time() - t0, history


def train_retrieval(cfg: RetrievalTrainConfig, out_dir, data_dir="data", *, progress: bool = True,
                    command: str = "") -> RetrievalResult:
    """Render the data, train, evaluate on ``data.eval_world`` and write
    ``checkpoint.pt`` and ``card.json`` into ``out_dir``."""
    from topodrake.learning.checkpoint import git_revision
    from topodrake.learning.waypoint.train import _set_threads

    cfg.validate()
    _set_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    out_dir = Path(out_dir)
    t_data = time.time()
    train, evals = build_frames(cfg, data_dir, progress)
    t_data = time.time() - t_data
    model = RetrievalNet(cfg.network)
    log = (lambda s: print(s, flush=True)) if progress else None
    steps, wall, history = train_steps(model, train, cfg, log)
    metrics = {"eval_world": cfg.data.eval_world, **evaluate(model, evals, cfg.data)}
    meta = {"train_config": asdict(cfg), "steps": steps, "wall_time_s": round(wall, 1),
            "git_revision": git_revision(), "metrics": metrics}
    ckpt = save_retrieval_checkpoint(out_dir / CHECKPOINT, model, cfg.camera, **meta)
    card = {"checkpoint": CHECKPOINT, "sha256": file_sha256(ckpt),
            "parameters": int(sum(p.numel() for p in model.parameters())),
            "steps": steps, "samples_seen": steps * cfg.batch_size,
            "train_wall_time_s": round(wall, 1), "data_wall_time_s": round(t_data, 1),
            "git_revision": meta["git_revision"],
            "data": {"train_worlds": cfg.data.train_worlds, "train_drives": int(len(train.drive_len)),
                     "train_frames": int(len(train.drive)), "eval_world": cfg.data.eval_world,
                     "eval_drives": int(len(evals.drive_len)), "eval_frames": int(len(evals.drive))},
            "history": history, "metrics": metrics, "command": command, "config": asdict(cfg)}
    atomic_write_json(out_dir / CARD, card)
    if progress:
        print(f"trained SPTM retrieval: {steps} steps in {wall / 60:.1f} min -> {ckpt}",
              flush=True, file=sys.stderr)
    return RetrievalResult(ckpt, steps, wall, metrics)
