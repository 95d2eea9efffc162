"""Training loop of the waypoint network (and the direct-control baseline).

Loss per sample (the paper's C_WP loss)::

    |w_hat - w|^2 / max(|w|, 0.1)  +  BCE(sigmoid(overlap logits), overlaps)
                                    +  MSE((cos, sin)_hat, (cos, sin))

and for the direct-control baseline the waypoint term is replaced by the
MSE of the scaled controls. Adam, ``lr`` (3e-4) multiplied by ``lr_decay``
(0.7) after every ``epoch_samples`` samples. Batches walk through a seeded
permutation of the training samples (one per pass), so a resumed run draws
exactly the batches the uninterrupted run would have drawn.

Files in the output folder: ``checkpoint.pt`` (written atomically every
``checkpoint_every_s`` and at the end; a rerun with the same config resumes
from it) and ``card.json`` (config, data, samples seen, wall time, metrics,
git revision) when training ends.
"""

from __future__ import annotations

import hashlib
import json
import math
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch.nn import functional as F

from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_json, file_sha1, file_sha256
from topodrake.learning.checkpoint import (RESUME, git_revision, load_checkpoint, load_resume_state,
                                           save_checkpoint, save_resume_state)
from topodrake.learning.config import TrainConfig
from topodrake.learning.data import Batch, SampleBatcher
from topodrake.learning.networks import WaypointNetwork, input_size
from topodrake.learning.samples import SampleSet, collect_trajectories, make_samples

CHECKPOINT = "checkpoint.pt"
CARD = "card.json"


# ---------------------------------------------------------------- loss, metrics

def waypoint_loss(out: dict, batch: Batch, output: str = "waypoint") -> tuple[torch.Tensor, dict]:
    """(mean loss, per-term means as floats)."""
    if output == "control":
        main = (out["control"] - batch.control).square().sum(1)
    else:
        norm = batch.waypoint.norm(dim=1).clamp_min(0.1)
        main = (out["waypoint"] - batch.waypoint).square().sum(1) / norm
    ov = F.binary_cross_entropy_with_logits(out["overlap_logits"], batch.overlap,
                                            reduction="none").sum(1)
    hd = (out["heading"] - batch.heading).square().sum(1)
    loss = (main + ov + hd).mean()
    return loss, {"loss": loss.item(), f"loss_{output}": main.mean().item(),
                  "loss_overlap": ov.mean().item(), "loss_heading": hd.mean().item()}


@torch.no_grad()
def evaluate(model: WaypointNetwork, batcher: SampleBatcher, batch_size: int = 256) -> dict:
    """Validation metrics over every sample of ``batcher``."""
    model.eval()
    sums: dict[str, float] = {}
    n_total = 0
    output = model.cfg.output
    for start in range(0, len(batcher), batch_size):
        idx = np.arange(start, min(start + batch_size, len(batcher)))
        b = batcher.batch(idx)
        out = model.forward_split(b.cur, b.ctx)
        _, parts = waypoint_loss(out, b, output)
        n = len(idx)
        err = (out["waypoint"] - b.waypoint).norm(dim=1)
        long = b.waypoint.norm(dim=1) > 0.3
        ang = torch.atan2(out["waypoint"][:, 1], out["waypoint"][:, 0]) - \
            torch.atan2(b.waypoint[:, 1], b.waypoint[:, 0])
        ang = torch.remainder(ang + math.pi, 2 * math.pi) - math.pi
        hd = torch.atan2(out["heading"][:, 1], out["heading"][:, 0]) - \
            torch.atan2(b.heading[:, 1], b.heading[:, 0])
        hd = torch.remainder(hd + math.pi, 2 * math.pi) - math.pi
        ov = torch.sigmoid(out["overlap_logits"])
        both_pred = (ov > 0.5).all(1)
        both_true = (b.overlap > 0.5).all(1)
        extra = {"waypoint_error_m": float(err.sum()),
                 "heading_error_deg": float(hd.abs().sum() * 180 / math.pi),
                 "overlap_mae": float((ov - b.overlap).abs().mean(1).sum()),
                 "overlap_accuracy": float((both_pred == both_true).float().sum())}
        if long.any():
            sums["_n_long"] = sums.get("_n_long", 0.0) + float(long.sum())
            sums["waypoint_angle_error_deg"] = sums.get("waypoint_angle_error_deg", 0.0) + \
                float(ang[long].abs().sum() * 180 / math.pi)
        if output == "control":
            extra["control_mae"] = float((out["control"] - b.control).abs().mean(1).sum())
        for key, v in parts.items():
            sums[key] = sums.get(key, 0.0) + v * n
        for key, v in extra.items():
            sums[key] = sums.get(key, 0.0) + v
        n_total += n
    n_long = sums.pop("_n_long", 0.0)
    metrics = {k: v / max(n_total, 1) for k, v in sums.items()}
    if "waypoint_angle_error_deg" in metrics:
        metrics["waypoint_angle_error_deg"] = sums["waypoint_angle_error_deg"] / max(n_long, 1)
    metrics["samples"] = n_total
    return {k: (round(v, 5) if isinstance(v, float) else v) for k, v in metrics.items()}


# ---------------------------------------------------------------- data

def _key(obj) -> str:
    return hashlib.sha1(json.dumps(obj, sort_keys=True).encode()).hexdigest()[:10]


def prepare_samples(cfg: TrainConfig, data_dir, progress: bool = True) -> tuple[SampleSet, SampleSet]:
    """Training and validation samples, built once into ``data_dir`` and reused.

    Demonstrations go to ``data_dir/demos/<protocol>-s<seed>/<world>``;
    sample sets to ``data_dir/samples-<train|val>-<hash>.npz`` where the hash
    covers everything that determines them.
    """
    d = cfg.data
    data_dir = Path(data_dir)
    tag = d.demo_protocol + (f"{d.demo_count}" if d.demo_protocol == "random" else "")
    demo_root = data_dir / "demos" / f"{tag}-s{d.demo_seed}"
    out = []
    for split, worlds, n, seed in (("train", d.train_worlds, d.train_samples, d.sample_seed),
                                   ("val", d.val_worlds, d.val_samples, d.sample_seed + 1)):
        key = _key({"worlds": worlds, "protocol": d.demo_protocol, "count": d.demo_count,
                    "demo_seed": d.demo_seed, "n": n, "seed": seed, "cfg": asdict(d.samples)})
        path = data_dir / f"samples-{split}-{key}.npz"
        if path.exists():
            out.append(SampleSet.load(path))
            continue
        trajs = collect_trajectories(worlds, demo_root, protocol=d.demo_protocol,
                                     count=d.demo_count, seed=d.demo_seed, progress=progress)
        samples = make_samples(trajs, n, seed, d.samples, progress=progress)
        samples.save(path)
        out.append(samples)
    return out[0], out[1]


# ---------------------------------------------------------------- training

@dataclass
class TrainResult:
    checkpoint: Path
    metrics: dict
    samples_seen: int
    wall_time_s: float
    train_samples_per_s: float


def _sensor(cfg: TrainConfig):
    return cfg.camera if cfg.network.modality == "camera" else cfg.lidar


#: Settings a resumed run may change: budgets, bookkeeping and RE's
#: calibration after training (rerunning a finished RE's command refits it).
_RUNTIME = ("max_samples", "max_minutes", "val_every_samples", "checkpoint_every_s", "threads",
            "temperature_scaling", "anchor_calibration", "mirror_average")


def _comparable(cfg_dict: dict) -> dict:
    """The parts of a training config that must not change on resume:
    everything but the budgets and the sensor the network does not use."""
    unused = "lidar" if cfg_dict["network"]["modality"] == "camera" else "camera"
    return {k: v for k, v in cfg_dict.items() if k not in _RUNTIME and k != unused}


def config_change(ck, cfg_dict: dict) -> tuple | None:
    """The first (key, trained with, config says) where checkpoint ``ck``'s
    training config and ``cfg_dict`` differ beyond the runtime settings
    (None when the config would resume, or rerun, that checkpoint)."""
    return _diff(_comparable(ck.meta.get("train_config") or {"network": ck.network.to_dict()}),
                 _comparable(cfg_dict))


def _diff(a, b, prefix=""):
    """The first (key, old, new) where two configs differ; a key one side
    lacks counts as None there (a field added later with a None default)."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            r = _diff(a.get(k), b.get(k), f"{prefix}{k}.")
            if r:
                return r
        return None
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b)):
            r = _diff(x, y, f"{prefix}{i}.")
            if r:
                return r
        return None
    return None if a == b else (prefix.rstrip("."), a, b)


@dataclass
class Task:
    """What a training run optimises: batches, loss and validation metrics.

    ``loss(model, batch) -> (loss tensor, {name: float})`` and
    ``evaluate(model, batcher) -> metrics`` (``metric`` names the validation
    figure shown on the progress bar). ``card`` is merged into card.json and
    ``meta`` into the checkpoint. ``init(model)``, if given, sets the
    starting weights of a fresh run (not of a resumed one); ``finish(model,
    val) -> dict`` runs after the last step and its result goes into the
    checkpoint's ``meta`` and the card (e.g. a fitted temperature)."""

    train: object
    val: object
    loss: object
    evaluate: object
    metric: str
    card: dict
    meta: dict | None = None
    init: object = None
    finish: object = None


def train_waypoint(cfg: TrainConfig, out_dir, data_dir="data", *, resume: bool = True,
                   progress: bool = True, samples: tuple[SampleSet, SampleSet] | None = None,
                   command: str | None = None) -> TrainResult:
    """Train (or resume) a C_WP / direct-control network into ``out_dir``;
    ``command`` (the command line that redoes it) goes into the card."""
    cfg.validate()
    _set_threads(cfg.threads)
    warm = warm_start(cfg) if cfg.init else None
    train_set, val_set = samples if samples is not None else prepare_samples(cfg, data_dir, progress)
    output = cfg.network.output
    task = Task(
        train=SampleBatcher(train_set, cfg.network, cfg.camera, cfg.lidar),
        val=SampleBatcher(val_set, cfg.network, cfg.camera, cfg.lidar),
        loss=lambda model, b: waypoint_loss(model.forward_split(b.cur, b.ctx), b, output),
        evaluate=evaluate, metric="control_mae" if output == "control" else "waypoint_error_m",
        card={"data": {"train_worlds": cfg.data.train_worlds, "val_worlds": cfg.data.val_worlds,
                       "train_samples": len(train_set), "val_samples": len(val_set)}})
    if warm is not None:
        task.init, task.card["init"] = warm
        task.meta = {"init": warm[1]}      # the checkpoint keeps its lineage (RE warm starts)
    return train_network(cfg, task, out_dir, resume=resume, progress=progress, command=command)


def warm_start(cfg: TrainConfig):
    """``(Task.init, card entry)`` of a C_WP fine-tuned from checkpoint
    ``cfg.init``, checked before any sample is made: the checkpoint must
    exist and have the config's network."""
    path = Path(cfg.init)
    if not path.is_file():
        raise TopodrakeError(f"init: C_WP checkpoint {path} does not exist")
    ck = load_checkpoint(path)
    diff = _diff(ck.network.to_dict(), cfg.network.to_dict())
    if diff:
        raise TopodrakeError(f"cannot start from {path}: its network has {diff[0]} = {diff[1]!r}, "
                             f"the config says {diff[2]!r}")
    weights = ck.model.state_dict()
    ident = {"checkpoint": str(path), "sha1": file_sha1(path),
             "samples_seen": ck.meta.get("samples_seen")}
    return (lambda model: model.load_state_dict(weights)), ident


def _set_threads(threads: int) -> None:
    if threads > 0:
        torch.set_num_threads(threads)
        try:
            import numba
            numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
        except Exception:
            pass


def train_network(cfg: TrainConfig, task: Task, out_dir, *, resume: bool = True,
                  progress: bool = True, command: str | None = None) -> TrainResult:
    """The training loop shared by C_WP, the direct-control baseline and RE:
    Adam with step decay, seeded batch order, periodic validation and
    checkpoints, resume, and the card."""
    from tqdm import tqdm

    out_dir = Path(out_dir)
    ckpt_path = out_dir / CHECKPOINT
    sensor = _sensor(cfg)
    train_b, val_b = task.train, task.val
    torch.manual_seed(cfg.seed)
    model = WaypointNetwork(cfg.network, input_size(cfg.network, cfg.lidar.beams))
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    state = {"epoch": 0, "pos": 0, "samples_seen": 0, "wall_time_s": 0.0}
    history: list[dict] = []
    cfg_dict = cfg.to_dict()
    if task.init is not None and not ckpt_path.exists():
        task.init(model)
    if ckpt_path.exists():
        if not resume:
            raise TopodrakeError(f"{ckpt_path} exists; resume it or choose another output folder")
        ck = load_checkpoint(ckpt_path, network=cfg.network)
        diff = config_change(ck, cfg_dict)
        if diff:
            raise TopodrakeError(f"checkpoint {ckpt_path} was trained with {diff[0]} = {diff[1]!r}, "
                                 f"the config says {diff[2]!r}; use another output folder")
        model.load_state_dict(ck.model.state_dict())
        optimizer = ck.optimizer or load_resume_state(out_dir / RESUME, ck.meta.get("samples_seen"))
        if optimizer is not None:
            opt.load_state_dict(optimizer)
        state.update(ck.train_state or {})
        history = list(ck.meta.get("history", []))
    revision = git_revision()

    def lr_at(seen: int) -> float:
        return cfg.lr * cfg.lr_decay ** (seen // cfg.epoch_samples)

    def write(metrics: dict) -> None:
        # The optimizer state (twice the weights) stays beside the shipped
        # checkpoint, written first so a checkpoint never precedes its state.
        save_resume_state(out_dir / RESUME, opt.state_dict(), state["samples_seen"])
        save_checkpoint(ckpt_path, model, sensor, train_config=cfg_dict, metrics=metrics,
                        history=history, samples_seen=state["samples_seen"],
                        wall_time_s=state["wall_time_s"], train_state=dict(state),
                        revision=revision, extra=task.meta)

    n = len(train_b)
    bs = cfg.batch_size
    budget_s = cfg.max_minutes * 60.0
    next_val = (state["samples_seen"] // cfg.val_every_samples + 1) * cfg.val_every_samples
    last_ckpt = time.perf_counter()
    start_seen, start_wall = state["samples_seen"], state["wall_time_s"]
    bar = tqdm(total=cfg.max_samples, initial=state["samples_seen"], unit="sample",
               desc=f"train {cfg.network.modality} k={cfg.network.k} {cfg.network.output}",
               disable=not progress, smoothing=0.05)
    ema = None
    metrics = history[-1]["metrics"] if history else {}
    order = np.random.default_rng([cfg.seed, state["epoch"]]).permutation(n)
    t_seg = time.perf_counter()
    try:
        while state["samples_seen"] < cfg.max_samples and state["wall_time_s"] < budget_s:
            if state["pos"] + bs > n:
                state["epoch"] += 1
                state["pos"] = 0
                order = np.random.default_rng([cfg.seed, state["epoch"]]).permutation(n)
            idx = order[state["pos"]:state["pos"] + bs]
            model.train()
            for g in opt.param_groups:
                g["lr"] = lr_at(state["samples_seen"])
            batch = train_b.batch(idx)
            loss, parts = task.loss(model, batch)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            if not math.isfinite(parts["loss"]):
                raise TopodrakeError("training diverged (non-finite loss); lower lr")
            state["pos"] += bs
            state["samples_seen"] += bs
            now = time.perf_counter()
            state["wall_time_s"] += now - t_seg
            t_seg = now
            ema = parts["loss"] if ema is None else 0.98 * ema + 0.02 * parts["loss"]
            bar.update(bs)
            if state["samples_seen"] >= next_val:
                next_val += cfg.val_every_samples
                metrics = task.evaluate(model, val_b)
                history.append({"samples_seen": state["samples_seen"],
                                "wall_time_s": round(state["wall_time_s"], 1),
                                "train_loss": round(ema, 5), "metrics": metrics})
                t_seg = time.perf_counter()   # validation is not training time
            bar.set_postfix(loss=f"{ema:.3f}", **{f"val_{task.metric}": metrics.get(task.metric,
                                                                                  float("nan"))})
            if time.perf_counter() - last_ckpt >= cfg.checkpoint_every_s:
                write(metrics)
                last_ckpt = time.perf_counter()
                t_seg = time.perf_counter()
    except KeyboardInterrupt:
        write(metrics)
        bar.close()
        raise
    bar.close()
    if not history or history[-1]["samples_seen"] != state["samples_seen"]:
        metrics = task.evaluate(model, val_b)
        history.append({"samples_seen": state["samples_seen"],
                        "wall_time_s": round(state["wall_time_s"], 1),
                        "train_loss": round(ema, 5) if ema is not None else None,
                        "metrics": metrics})
    if task.finish is not None:
        finished = task.finish(model, val_b)
        task.meta = {**(task.meta or {}), **finished}
        task.card = {**task.card, **finished}
    write(metrics)
    seen = state["samples_seen"] - start_seen
    if seen == 0:      # a finished run rerun (e.g. to recalibrate): its overall rate
        seen, start_wall = state["samples_seen"], 0.0
    rate = seen / max(state["wall_time_s"] - start_wall, 1e-9)
    card = {"checkpoint": CHECKPOINT, "sha256": file_sha256(ckpt_path),
            "modality": cfg.network.modality, "k": cfg.network.k,
            "output": cfg.network.output, "samples_seen": state["samples_seen"],
            "wall_time_s": round(state["wall_time_s"], 1),
            "train_samples_per_s": round(rate, 1), "git_revision": revision,
            **task.card, "metrics": metrics, "command": command, "config": cfg_dict}
    atomic_write_json(out_dir / CARD, card)
    if progress:
        print(f"trained {cfg.network.modality} k={cfg.network.k} {cfg.network.output}: "
              f"{state['samples_seen']} samples in {state['wall_time_s'] / 60:.1f} min "
              f"({rate:.0f}/s); val {task.metric} {metrics.get(task.metric, float('nan')):.3f} "
              f"-> {ckpt_path}", file=sys.stderr)
    return TrainResult(ckpt_path, metrics, state["samples_seen"], state["wall_time_s"], rate)
