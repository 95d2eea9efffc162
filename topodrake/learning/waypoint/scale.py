"""Training C_WP at scale: samples made by worker processes while a GPU trains.

The CPU loop of :mod:`topodrake.learning.waypoint.train` renders every batch from
poses and draws it from one fixed sample set; at tens of millions of samples
seen the renderer and the labeller (A* per sample) are the limit, not the
network. Here

* the expert drives of every house come packed (:mod:`topodrake.learning.trajpack`);
* the observations (lidar scans, or camera images as uint8) of every
  trajectory frame are rendered once into one tensor on the device (context
  frames are trajectory frames);
* worker processes make *shards* (``shard_samples`` samples of one world,
  seeded by ``(sample_seed, world, shard)``, shards taken round-robin over
  the worlds) and render their source observations; each shard joins a pool
  on the device as it arrives (a ring of ``pool_max`` samples, the oldest
  replaced, where memory is short: camera images);
* batches are drawn uniformly from the pool (a seeded generator on the
  device) and gathered there; the loss, Adam and the step decay are those of
  :func:`topodrake.learning.waypoint.train.train_network`;
* ``variants`` name more networks trained on the same batches (a width
  study at no extra data cost), each in its own folder.

A run resumes from the checkpoints in its folders (weights, optimizer,
samples seen, the next shard to make); a resumed run makes new shards
rather than the ones already used. Checkpoints are ordinary C_WP
checkpoints (CPU tensors): everything that loads a C_WP loads them.
Batch order depends on when shards arrive, so two runs agree in their data,
not bit for bit in their weights.

    topodrake train scale --config configs/scale_lidar_k5.yaml --out runs/lidar_k5_scale \\
        --minutes 8
"""

from __future__ import annotations

import copy
import json
import math
import multiprocessing as mp
import os
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_json, file_sha256
from topodrake.learning.config import TrainConfig
from topodrake.learning.networks import NetworkConfig
from topodrake.learning.samples import SampleConfig, make_samples
from topodrake.learning.trajpack import load_packed_trajectories
from topodrake.learning.waypoint.scale_data import (
    DeviceBatcher,
    Pool,
    as_network_input,
    gather_frames,
    init_worker,
    make_shard,
    render_world,
    warm_kernels,
)
from topodrake.typed_yaml import load_typed


@dataclass
class ScaleConfig:
    """How samples are made and where the networks train."""

    trajectories: str = "data/trajectories/pairs-s0.npz"   # packed drives of train and val worlds
    shard_samples: int = 2000       # samples per shard (one world, one seed)
    shards_per_world: int = 60      # made per world in each call (a resumed call makes new ones)
    workers: int = 0                # sample-making processes (0: all cores but one)
    min_pool: int = 100000          # samples made before the first step
    pool_max: int = 0               # samples the device pool holds (0: every shard of the call)
    device: str = "cuda"
    compare: list[str] = field(default_factory=list)    # C_WP checkpoints scored on the same val sets
    variants: dict[str, NetworkConfig] = field(default_factory=dict)


@dataclass
class ScaleRunConfig:
    train: TrainConfig = field(default_factory=TrainConfig)
    scale: ScaleConfig = field(default_factory=ScaleConfig)

    def validate(self, where: str = "scale config") -> "ScaleRunConfig":
        self.train.validate(where)
        net, cam = self.train.network, self.train.camera
        if net.modality == "camera" and not net.image_size == cam.width == cam.height:
            raise TopodrakeError(f"{where}: training at scale feeds the camera's {cam.width}x"
                                 f"{cam.height} images as they are; set network.image_size to "
                                 "the camera's side")
        s = self.scale
        for name in ("shard_samples", "shards_per_world", "min_pool"):
            if getattr(s, name) < 1:
                raise TopodrakeError(f"{where}: scale.{name} must be >= 1, got {getattr(s, name)}")
        if s.pool_max < 0:
            raise TopodrakeError(f"{where}: scale.pool_max must be >= 0, got {s.pool_max}")
        if s.workers < 0:
            raise TopodrakeError(f"{where}: scale.workers must be >= 0, got {s.workers}")
        for name, net in s.variants.items():
            net.validate(f"{where}: scale.variants.{name}")
            if (net.modality, net.k, net.frame_step, net.output) != \
                    (self.train.network.modality, self.train.network.k,
                     self.train.network.frame_step, self.train.network.output):
                raise TopodrakeError(f"{where}: scale.variants.{name} must share the main network's "
                                     "modality, k, frame_step and output (they share batches)")
        return self


def load_scale_config(path) -> ScaleRunConfig:
    return load_typed(ScaleRunConfig, path, "config").validate(f"config {path}")


# ---------------------------------------------------------------- training

@dataclass
class _Net:
    name: str
    cfg: TrainConfig
    out: Path
    model: object
    opt: object
    history: list
    metrics: dict


def _networks(run: ScaleRunConfig, out_dir: Path, size: int) -> tuple[list[_Net], dict]:
    import torch

    from topodrake.learning.checkpoint import RESUME, load_checkpoint, load_resume_state
    from topodrake.learning.networks import WaypointNetwork
    from topodrake.learning.waypoint.train import CHECKPOINT, config_change

    nets, state = [], {"samples_seen": 0, "wall_time_s": 0.0, "next_shard": 0, "shards_used": 0}
    specs = [("main", run.train)] + [(name, _with_network(run.train, net))
                                     for name, net in run.scale.variants.items()]
    for name, cfg in specs:
        out = out_dir if name == "main" else out_dir / name
        torch.manual_seed(cfg.seed)
        model = WaypointNetwork(cfg.network, size)
        opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
        history, metrics = [], {}
        path = out / CHECKPOINT
        if path.exists():
            ck = load_checkpoint(path, network=cfg.network)
            diff = config_change(ck, cfg.to_dict())
            if diff:
                raise TopodrakeError(f"checkpoint {path} was trained with {diff[0]} = {diff[1]!r}, "
                                     f"the config says {diff[2]!r}; use another output folder")
            model.load_state_dict(ck.model.state_dict())
            o = load_resume_state(out / RESUME, ck.meta.get("samples_seen"))
            if o is not None:
                opt.load_state_dict(o)
            history = list(ck.meta.get("history", []))
            metrics = history[-1]["metrics"] if history else {}
            if name == "main":
                state.update({k: v for k, v in (ck.train_state or {}).items() if k in state})
        nets.append(_Net(name, cfg, out, model, opt, history, metrics))
    return nets, state


def _with_network(cfg: TrainConfig, net: NetworkConfig) -> TrainConfig:
    c = copy.deepcopy(cfg)
    c.network = copy.deepcopy(net)
    return c


def train_at_scale(run: ScaleRunConfig, out_dir, *, minutes: float, progress: bool = True,
                   command: str | None = None) -> dict:
    """Train (or resume) the networks of ``run`` for at most ``minutes`` of
    wall time in this call; returns the card of the main network."""
    import torch
    from tqdm import tqdm

    from topodrake.learning.checkpoint import (
        RESUME,
        git_revision,
        save_checkpoint,
        save_resume_state,
    )
    from topodrake.learning.data import Batch, SampleBatcher
    from topodrake.learning.waypoint.train import CARD, CHECKPOINT, waypoint_loss

    t_start = time.perf_counter()
    deadline = t_start + minutes * 60.0
    run.validate()
    cfg, sc = run.train, run.scale
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    packed = load_packed_trajectories(sc.trajectories)
    missing = [w for w in cfg.data.train_worlds + cfg.data.val_worlds if w not in packed.worlds]
    if missing:
        raise TopodrakeError(f"{sc.trajectories} has no drives of {', '.join(missing[:5])}")
    train_trajs = packed.select_worlds(cfg.data.train_worlds)
    device = torch.device(sc.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise TopodrakeError("scale.device is cuda but torch sees no GPU")
    from topodrake.learning.networks import input_size

    modality = cfg.network.modality
    sensor_cfg = cfg.camera if modality == "camera" else cfg.lidar
    nets, state = _networks(run, out_dir, input_size(cfg.network, cfg.lidar.beams))
    # (on the CPU: CUDA waits until the workers fork)
    n_worlds = len(cfg.data.train_worlds)
    total = n_worlds * sc.shards_per_world
    first = int(state["next_shard"])
    workers = sc.workers or max(1, (os.cpu_count() or 2) - 1)
    train_dict = {**cfg.to_dict(), "shard_samples": sc.shard_samples}
    warm_kernels(sc.trajectories, cfg.data.train_worlds[0], modality)
    ctx = mp.get_context("fork")
    pool_proc = ctx.Pool(workers, initializer=init_worker,
                         initargs=(sc.trajectories, cfg.data.train_worlds, train_dict))
    # the workers render every house's frames first (tasks run in the order given), then shards
    rendered = pool_proc.imap(render_world, range(n_worlds), chunksize=1)
    shards = pool_proc.imap_unordered(make_shard, range(first, first + total), chunksize=1)
    try:
        # everything below may use CUDA: the workers exist already
        for net in nets:
            net.model.to(device)
            _optimizer_to(net.opt, device)
        torch.backends.cudnn.benchmark = True
        frames_t = gather_frames(rendered, train_trajs, modality, cfg.camera, cfg.lidar, device)
        val_sets = {"val": cfg.data.samples, "val_paper": SampleConfig()}
        val_trajs = packed.select_worlds(cfg.data.val_worlds)
        val = {key: DeviceBatcher(SampleBatcher(make_samples(val_trajs, cfg.data.val_samples,
                                                             cfg.data.sample_seed + 1, scfg),
                                                cfg.network, cfg.camera, cfg.lidar), device)
               for key, scfg in val_sets.items()}
        compared = _compare(sc.compare, val, device)
        made = total * sc.shard_samples
        pool = Pool(min(made, sc.pool_max) if sc.pool_max else made, tuple(frames_t.shape[1:]),
                    frames_t.dtype, cfg.network.frames, device)
        step = cfg.network.frame_step
        k = cfg.network.k
        got = 0

        def take(block: bool) -> bool:
            nonlocal got
            try:
                j, part, obs = shards.next() if block else shards.next(timeout=0)
            except (StopIteration, mp.TimeoutError):
                return False
            rows = train_trajs.context_rows(part["traj"].astype(np.int64),
                                            part["tgt"].astype(np.int64), k, step)
            pool.add(part, obs, rows)
            got += 1
            state["next_shard"] = max(state["next_shard"], j + 1)
            return True

        t_pool = time.perf_counter()
        while pool.n < min(sc.min_pool, len(pool.cur)) and take(True):
            pass
        pool_wait_s = time.perf_counter() - t_pool
        revision = git_revision()
        gen = torch.Generator(device=device)
        gen.manual_seed(cfg.seed * 1_000_003 + state["samples_seen"])
        bs = cfg.batch_size
        zero2 = torch.zeros((bs, 2), device=device)
        next_val = (state["samples_seen"] // cfg.val_every_samples + 1) * cfg.val_every_samples
        last_ckpt = time.perf_counter()
        start_seen, start_wall = state["samples_seen"], state["wall_time_s"]
        bar = tqdm(total=cfg.max_samples, initial=state["samples_seen"], unit="sample",
                   desc=f"train {modality} k={k} at scale", disable=not progress, smoothing=0.05,
                   mininterval=5.0)
        ema = None
        t_seg = time.perf_counter()

        def record(net: _Net) -> None:
            net.metrics = _validate(net.model, val)
            net.history.append({"samples_seen": state["samples_seen"],
                                "wall_time_s": round(state["wall_time_s"], 1),
                                "train_loss": round(ema, 5) if ema else None,
                                "pool": pool.n, "metrics": net.metrics})

        def save_all() -> None:
            for net in nets:
                net.out.mkdir(parents=True, exist_ok=True)
                cpu = copy.deepcopy(net.model).cpu()
                save_resume_state(net.out / RESUME, _state_to_cpu(net.opt.state_dict()),
                                  state["samples_seen"])
                save_checkpoint(net.out / CHECKPOINT, cpu, sensor_cfg, train_config=net.cfg.to_dict(),
                                metrics=net.metrics, history=net.history,
                                samples_seen=state["samples_seen"],
                                wall_time_s=state["wall_time_s"], train_state=dict(state),
                                revision=revision, extra={"scale": _scale_meta(sc, state, net.name)})

        while (state["samples_seen"] < cfg.max_samples and state["wall_time_s"] < cfg.max_minutes * 60
               and time.perf_counter() < deadline):
            while take(False):
                pass
            idx = torch.randint(0, pool.n, (bs,), device=device, generator=gen)
            cur = as_network_input(pool.cur[idx], modality)
            ctxs = as_network_input(frames_t[pool.ctx_rows[idx]], modality)
            batch = Batch(cur, ctxs, pool.waypoint[idx], pool.heading[idx], pool.overlap[idx], zero2)
            lr = cfg.lr * cfg.lr_decay ** (state["samples_seen"] // cfg.epoch_samples)
            losses = []
            for net in nets:
                net.model.train()
                for g in net.opt.param_groups:
                    g["lr"] = lr
                loss, _ = waypoint_loss(net.model.forward_split(batch.cur, batch.ctx), batch)
                net.opt.zero_grad(set_to_none=True)
                loss.backward()
                net.opt.step()
                losses.append(loss)
            state["samples_seen"] += bs
            now = time.perf_counter()
            state["wall_time_s"] += now - t_seg
            t_seg = now
            if state["samples_seen"] % (bs * 50) == 0 or state["samples_seen"] >= next_val:
                value = float(losses[0].detach())
                if not math.isfinite(value):
                    raise TopodrakeError("training diverged (non-finite loss); lower lr")
                ema = value if ema is None else 0.9 * ema + 0.1 * value
                bar.update(state["samples_seen"] - bar.n)
            if state["samples_seen"] >= next_val:
                next_val += cfg.val_every_samples
                for net in nets:
                    record(net)
                bar.set_postfix(loss=f"{ema:.3f}", pool=pool.n,
                                val=" ".join(f"{n.metrics['waypoint_error_m']:.3f}" for n in nets))
                t_seg = time.perf_counter()
            if time.perf_counter() - last_ckpt >= cfg.checkpoint_every_s:
                save_all()
                last_ckpt = t_seg = time.perf_counter()
        bar.close()
        for net in nets:
            if not net.history or net.history[-1]["samples_seen"] != state["samples_seen"]:
                record(net)
        state["shards_used"] = int(state.get("shards_used", 0)) + got
        save_all()
    finally:
        pool_proc.terminate()
        pool_proc.join()
    seen = state["samples_seen"] - start_seen
    rate = seen / max(state["wall_time_s"] - start_wall, 1e-9)
    cards = {}
    for net in nets:
        card = {"checkpoint": CHECKPOINT, "sha256": file_sha256(net.out / CHECKPOINT),
                "modality": modality, "k": k, "output": net.cfg.network.output,
                "samples_seen": state["samples_seen"], "wall_time_s": round(state["wall_time_s"], 1),
                "train_samples_per_s": round(rate, 1), "git_revision": revision,
                "data": {"train_worlds": net.cfg.data.train_worlds,
                         "val_worlds": net.cfg.data.val_worlds,
                         "trajectories": sc.trajectories,
                         "distinct_samples_made": state["next_shard"] * sc.shard_samples,
                         "val_samples": net.cfg.data.val_samples},
                "device": _device_name(device), "call": {
                    "minutes": minutes, "pool": pool.n, "pool_wait_s": round(pool_wait_s, 1),
                    "shards_this_call": got, "workers": workers,
                    "samples_per_s": round(rate, 1)},
                "metrics": net.metrics, "compared": compared, "command": command,
                "config": net.cfg.to_dict(), "scale": _scale_meta(sc, state, net.name)}
        card = _with_history(card, net.out / CARD, {
            "minutes": minutes, "device": card["device"], "samples_seen_after": state["samples_seen"],
            "train_wall_s": round(state["wall_time_s"] - start_wall, 1),
            "val_error_m": net.metrics["val"]["waypoint_error_m"],
            "val_paper_error_m": net.metrics["val_paper"]["waypoint_error_m"],
            "git_revision": revision})
        atomic_write_json(net.out / CARD, card)
        cards[net.name] = card
    if progress:
        for net in nets:
            m = net.metrics
            print(f"{net.name}: {state['samples_seen']} samples seen in "
                  f"{state['wall_time_s'] / 60:.1f} min ({rate:.0f}/s), pool {pool.n}; "
                  f"val {m['val']['waypoint_error_m']:.3f} m, val_paper "
                  f"{m['val_paper']['waypoint_error_m']:.3f} m -> {net.out / CHECKPOINT}",
                  file=sys.stderr)
    return cards["main"]


def _with_history(card: dict, path: Path, this_call: dict) -> dict:
    """The new card with the previous card's calls (this one appended) and the
    fields written by hand since (notes, measurements), which a resumed call keeps."""
    previous = {}
    if path.exists():
        try:
            previous = json.loads(path.read_text())
        except (OSError, ValueError) as e:
            raise TopodrakeError(f"{path} is not a readable card ({e}); move it away to start a new one")
    calls = previous.get("calls") if isinstance(previous.get("calls"), list) else []
    merged = {**card, "calls": [*calls, this_call]}
    for key, value in previous.items():
        merged.setdefault(key, value)
    return merged


def _validate(model, val: dict) -> dict:
    """Metrics on each validation set; the main set's figures also at the top level."""
    from topodrake.learning.waypoint.train import evaluate

    per = {key: evaluate(model, b) for key, b in val.items()}
    return {**per["val"], **per}


def _compare(paths: list[str], val: dict, device) -> dict:
    from topodrake.learning.checkpoint import load_checkpoint
    from topodrake.learning.waypoint.train import evaluate

    out = {}
    for p in paths:
        ck = load_checkpoint(p)
        model = ck.model.to(device)
        out[p] = {key: evaluate(model, b) for key, b in val.items()
                  if b.batcher.cfg.k == ck.network.k}
    return out


def _optimizer_to(opt, device) -> None:
    for st in opt.state.values():
        for key, v in st.items():
            if hasattr(v, "to"):
                st[key] = v.to(device)


def _state_to_cpu(obj):
    if hasattr(obj, "cpu"):
        return obj.cpu()
    if isinstance(obj, dict):
        return {k: _state_to_cpu(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_state_to_cpu(v) for v in obj]
    return obj


def _device_name(device) -> str:
    import torch

    return torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu"


def _scale_meta(sc: ScaleConfig, state: dict, name: str) -> dict:
    return {"variant": name, **asdict(sc), "next_shard": int(state["next_shard"]),
            "variants": {k: asdict(v) for k, v in sc.variants.items()}}
