"""On-policy training of C_WP (DAgger): follow, label where the car went, retrain.

Each round:

1. follows RE chains of demonstration drives in a group of training houses
   not seen by earlier rounds (``worlds_per_round`` houses from
   ``train-<first_world>`` on) with the current C_WP and the follower's RE,
   and labels every visited state with the A* expert toward the anchor the
   follower aimed at and the one after it
   (:mod:`topodrake.learning.onpolicy.states`);
2. fine-tunes the current C_WP for ``round_minutes`` on the aggregate: a
   fixed base set of demonstration samples (``base_samples`` from the
   config's ``data.train_worlds``, drawn with its ``data.samples``: targets
   as far as the follower's hops reach) plus the on-policy samples of every
   round so far, validated on the standard validation samples.

Everything is kept under the output folder and resumed: ``round-<r>/onpolicy.npz``
(the round's labelled states), ``round-<r>/checkpoint.pt`` (its network;
an interrupted fine-tuning resumes from its last checkpoint, weights and
optimizer and data position) and ``dagger.json`` (finished rounds: houses,
states, the cover the followed chains reached, the validation error). The
last finished round's network is the result (``best.pt`` is a copy of it).

    topodrake train dagger --config configs/dagger_lidar_k5.yaml --out runs/dagger_lidar_k5
"""

from __future__ import annotations

import hashlib
import json
import shutil
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_json
from topodrake.learning.config import TrainConfig
from topodrake.learning.onpolicy.states import (
    OnPolicyConfig,
    collect_visited,
    concat_samples,
    label_visited,
    pick_drives,
    samples_from_fields,
)
from topodrake.learning.samples import SampleConfig, SampleSet, collect_trajectories
from topodrake.typed_yaml import load_typed
from topodrake.world import load_world

N_TRAIN_HOUSES = 96
STATE = "dagger.json"


@dataclass
class DaggerConfig:
    """On-policy rounds of one C_WP (``train``: its training profile; its
    ``lr`` is the fine-tuning rate)."""

    train: TrainConfig = field(default_factory=TrainConfig)
    init: str = "checkpoints/camera_k5/checkpoint.pt"       # C_WP of round 0
    reach: str = "checkpoints/reach_camera_k5/checkpoint.pt"  # the follower's RE
    reach_controller: str = "checkpoints/camera_k5/checkpoint.pt"  # the C_WP that RE measured
    rounds: int = 7
    first_world: int = 12
    worlds_per_round: int = 12
    base_samples: int = 100000
    round_minutes: float = 10.0
    seed: int = 0
    onpolicy: OnPolicyConfig = field(default_factory=OnPolicyConfig)

    def validate(self, where: str = "dagger config") -> "DaggerConfig":
        self.train.validate(f"{where}: train")
        self.onpolicy.validate()
        if self.rounds < 1 or self.worlds_per_round < 1 or self.base_samples < 1:
            raise TopodrakeError(f"{where}: rounds, worlds_per_round and base_samples must be >= 1")
        last = self.first_world + self.rounds * self.worlds_per_round
        if self.first_world < 0 or last > N_TRAIN_HOUSES:
            raise TopodrakeError(f"{where}: rounds need train houses {self.first_world}..{last - 1};"
                                 f" there are {N_TRAIN_HOUSES} (train-00..train-95)")
        overlap = set(self.round_worlds(0, self.rounds)) & set(self.train.data.train_worlds)
        if overlap:
            raise TopodrakeError(f"{where}: on-policy houses {sorted(overlap)} are also base houses")
        if not self.round_minutes > 0:
            raise TopodrakeError(f"{where}: round_minutes must be > 0")
        for name in ("init", "reach", "reach_controller"):
            if not Path(getattr(self, name)).is_file():
                raise TopodrakeError(f"{where}: {name} checkpoint {getattr(self, name)} does not exist")
        from topodrake.learning.checkpoint import load_checkpoint
        from topodrake.learning.waypoint.train import _diff

        diff = _diff(load_checkpoint(self.init).network.to_dict(), self.train.network.to_dict())
        if diff:
            raise TopodrakeError(f"{where}: init {self.init} has network {diff[0]} = {diff[1]!r}, "
                                 f"train.network says {diff[2]!r}")
        return self

    def round_worlds(self, r: int, n: int = 1) -> list[str]:
        lo = self.first_world + r * self.worlds_per_round
        return [f"train-{i:02d}" for i in range(lo, lo + n * self.worlds_per_round)]


def load_dagger_config(path) -> DaggerConfig:
    return load_typed(DaggerConfig, path, "config").validate(f"config {path}")


def _key(obj) -> str:
    return hashlib.sha1(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:10]


def base_and_val_samples(cfg: DaggerConfig, data_dir: Path, progress: bool):
    """The fixed demonstration samples of the base houses (drawn with
    ``train.data.samples``, e.g. farther targets than the first training
    had) and the validation samples (drawn as the networks' validation sets
    are, with the default :class:`SampleConfig`, so errors compare)."""
    from dataclasses import replace

    from topodrake.learning.waypoint.train import prepare_samples

    d = replace(cfg.train.data, train_samples=cfg.base_samples)
    base, val = prepare_samples(replace(cfg.train, data=d), data_dir, progress)
    if d.samples != SampleConfig():
        d = replace(d, samples=SampleConfig(), train_samples=cfg.train.batch_size)
        _, val = prepare_samples(replace(cfg.train, data=d), data_dir, progress)
    return base, val


def _demo_root(cfg: DaggerConfig, data_dir: Path) -> Path:
    d = cfg.train.data
    tag = d.demo_protocol + (f"{d.demo_count}" if d.demo_protocol == "random" else "")
    return data_dir / "demos" / f"{tag}-s{d.demo_seed}"


def collect_round(cfg: DaggerConfig, r: int, controller: Path, data_dir: Path, progress: bool):
    """The labelled on-policy samples of round ``r`` (followed with
    ``controller``) and the mean cover of its chains."""
    import torch

    from topodrake.learning.reachability.estimator import Reachability
    from topodrake.learning.waypoint.policy import LearnedWaypointPolicy

    torch.set_num_threads(max(cfg.train.threads, 1))
    d = cfg.train.data
    worlds = cfg.round_worlds(r)
    trajs = collect_trajectories(worlds, _demo_root(cfg, data_dir), protocol=d.demo_protocol,
                                 count=d.demo_count, seed=d.demo_seed, progress=progress)
    policy = LearnedWaypointPolicy.from_checkpoint(controller)
    reach = Reachability.from_checkpoint(cfg.reach, cfg.reach_controller)
    parts, covers, states = [], [], 0
    for w, name in enumerate(trajs.worlds):
        world = load_world(name)
        drives = pick_drives(trajs, w, cfg.onpolicy.drives_per_world, cfg.seed + r)
        visited = collect_visited(world, trajs, drives, policy, reach, cfg.onpolicy,
                                  seed=cfg.seed * 1000 + r * 100 + w)
        parts.append(label_visited(world, trajs, visited, cfg.onpolicy))
        covers.extend(visited.cover.tolist())
        states += len(visited)
        if progress:
            print(f"dagger round {r}: {name}: {len(visited)} states, cover "
                  f"{visited.cover.mean():.3f}, {len(parts[-1]['traj'])} samples",
                  flush=True, file=sys.stderr)
    meta = {"round": r, "worlds": worlds, "controller": str(controller),
            "cover": float(np.mean(covers)), "states": states}
    return samples_from_fields(trajs, parts, meta), meta


def run_dagger(cfg: DaggerConfig, out_dir, data_dir="data", *, progress: bool = True,
               command: str | None = None) -> dict:
    """Run (or resume) the rounds; returns the state (``dagger.json``)."""
    from dataclasses import replace

    from topodrake.learning.waypoint.train import CARD, CHECKPOINT, train_waypoint

    cfg.validate()
    out_dir, data_dir = Path(out_dir), Path(data_dir)
    state_path = out_dir / STATE
    ident = {"config": asdict(cfg)}
    state = {"format": "topodrake-dagger", "version": 1, **ident, "rounds": []}
    if state_path.is_file():
        try:
            stored = json.loads(state_path.read_text())
        except (OSError, ValueError):
            raise TopodrakeError(f"{state_path} is corrupt; remove it or use another --out") from None
        mine = _comparable(ident["config"])
        if _comparable(stored.get("config", {})) != mine:
            raise TopodrakeError(f"{out_dir} holds a DAgger run of another config; use another --out")
        state["rounds"] = stored.get("rounds", [])
    base, val = base_and_val_samples(cfg, data_dir, progress)
    onpolicy: list[SampleSet] = []
    for r in range(len(state["rounds"])):
        onpolicy.append(SampleSet.load(out_dir / f"round-{r}" / "onpolicy.npz"))
    t0 = time.perf_counter()
    for r in range(len(state["rounds"]), cfg.rounds):
        rdir = out_dir / f"round-{r}"
        controller = Path(cfg.init) if r == 0 else out_dir / f"round-{r - 1}" / CHECKPOINT
        path = rdir / "onpolicy.npz"
        if path.is_file():
            samples = SampleSet.load(path)
        else:
            samples, _ = collect_round(cfg, r, controller, data_dir, progress)
            samples.save(path)
        onpolicy.append(samples)
        agg = concat_samples([base] + onpolicy, meta={"dagger_round": r})
        tcfg = replace(cfg.train, init=str(controller), max_minutes=cfg.round_minutes,
                       max_samples=10 ** 9,
                       data=replace(cfg.train.data, train_samples=len(agg)))
        res = train_waypoint(tcfg, rdir, data_dir, samples=(agg, val), progress=progress,
                             command=command)
        state["rounds"].append({
            "round": r, "worlds": samples.meta.get("worlds"), "controller": str(controller),
            "states": samples.meta.get("states"), "onpolicy_samples": len(samples),
            "aggregate_samples": len(agg), "followed_cover": samples.meta.get("cover"),
            "val_waypoint_error_m": res.metrics.get("waypoint_error_m"),
            "train_wall_time_s": round(res.wall_time_s, 1)})
        atomic_write_json(state_path, state)
        shutil.copyfile(rdir / CHECKPOINT, out_dir / "best.pt")
        atomic_write_json(out_dir / "best.card.json",
                          dagger_card(json.loads((rdir / CARD).read_text()), state, r))
        if progress:
            print(f"dagger round {r} done: followed cover {samples.meta.get('cover'):.3f}, val "
                  f"error {res.metrics.get('waypoint_error_m'):.3f} m "
                  f"({(time.perf_counter() - t0) / 60:.1f} min)", flush=True, file=sys.stderr)
    return state


def dagger_card(card: dict, state: dict, last_round: int) -> dict:
    """The card of round ``last_round``'s network with its lineage: every
    round up to it (houses, visited states, the chains' cover, validation
    error, training time) and the houses its samples came from."""
    rounds = [r for r in state["rounds"] if r["round"] <= last_round]
    onpolicy = [w for r in rounds for w in r.get("worlds") or []]
    data = dict(card.get("data", {}))
    data["onpolicy_worlds"] = onpolicy
    return {**card, "data": data,
            "dagger": {"rounds": rounds, "init": state["config"]["init"],
                       "train_wall_time_s": round(sum(r["train_wall_time_s"] for r in rounds), 1)}}


def _comparable(config: dict) -> dict:
    """A DAgger config without the settings a resumed run may change."""
    c = json.loads(json.dumps(config))
    c.pop("rounds", None)
    c.get("train", {}).pop("threads", None)
    return c
