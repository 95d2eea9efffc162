"""Reachability labels whose sources are states a following car visited.

RE's usual labels start from jittered frames of the expert's drives. The
follower asks RE from elsewhere: off the drive, at other headings, toward
the anchor it aims at from wherever it got to. This module makes labels
for those questions: it follows seeded RE chains of demonstration drives
with the controller (its C_WP and an RE that steers the follower, as
:func:`topodrake.learning.onpolicy.states.collect_visited` does), draws visited
states, and rolls C_WP alone out from each toward the anchor the follower
was aiming at (or, for ``next_share`` of them, the anchor after it, which
Follow's advance rule and Dead reckoning ask about), under the labels'
rules (:func:`topodrake.learning.reachability.labels.rollout_to_targets`).

The folder has the format of :mod:`topodrake.learning.reachability.labels` (one
chunk per house, resumable; :func:`~topodrake.learning.reachability.labels.load_reach_labels`
reads it), and its manifest records the steering RE's fingerprint and the
follower's settings beside the controller's. ``src_traj``/``src`` name the
drive and its frame nearest the visited state; ``same`` is true. A house
whose followed chains visit fewer states than its share of ``n`` gives
all it has.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.learning.onpolicy.states import OnPolicyConfig, collect_visited, pick_drives
from topodrake.learning.reachability.labels import (
    ReachLabelConfig,
    open_label_folder,
    rollout_to_targets,
    target_contexts,
    write_label_chunk,
)
from topodrake.montecarlo import trial_seeds
from topodrake.navigation.follower import FollowerConfig


@dataclass
class FollowerStateLabels:
    """Training pairs from the follower's own states (``labels.follower``
    of a reach training config), in ``worlds`` (default: the config's
    ``data.train_worlds``), with their own ``seed``. ``reach``: the RE
    checkpoint that steers the follower while the states are collected
    (default: the config's ``init`` when that is an RE checkpoint)."""

    train_pairs: int = 20000
    seed: int = 30
    worlds: list[str] | None = None
    reach: str | None = None
    drives_per_world: int = 20      # chains followed per house (half with actuation noise)
    next_share: float = 0.3         # share of pairs aimed at the anchor after the active one
    rollout: ReachLabelConfig = field(default_factory=ReachLabelConfig)

    def validate(self, where: str) -> "FollowerStateLabels":
        if self.train_pairs < 1 or self.drives_per_world < 1:
            raise TopodrakeError(f"{where}: labels.follower needs train_pairs >= 1 and "
                                 "drives_per_world >= 1")
        if not 0.0 <= self.next_share <= 1.0:
            raise TopodrakeError(f"{where}: labels.follower next_share must be in [0, 1], got "
                                 f"{self.next_share}")
        self.rollout.validate()
        return self


def label_follower_states(trajs, policy, reach, out_dir, n: int, *, seed: int,
                          controller: dict, reach_identity: dict, drives_per_world: int = 20,
                          next_share: float = 0.3, config: ReachLabelConfig | None = None,
                          follower=None, load_world=None, progress: bool = True) -> Path:
    """Label about ``n`` visited states (spread evenly over the worlds of
    ``trajs``) of ``policy`` steered by ``reach`` into ``out_dir``
    (resumable by house; a folder made for other settings is refused)."""
    from tqdm import tqdm


    if load_world is None:
        from topodrake.world import load_world
    cfg = (config or ReachLabelConfig()).validate()
    follower = follower or FollowerConfig()
    out = Path(out_dir)
    worlds = trajs.worlds
    per = np.full(len(worlds), n // len(worlds))
    per[: n % len(worlds)] += 1
    manifest = open_label_folder(
        out, trajs, n, seed, cfg, controller, "follower-state labels",
        follower_states={"reach": reach_identity, "drives_per_world": drives_per_world,
                         "next_share": next_share, "follower": asdict(follower)})
    done = set(manifest["chunks"])
    world_seeds = trial_seeds(seed, len(worlds))
    on_policy = OnPolicyConfig(drives_per_world=drives_per_world, next_anchor=True)
    bar = tqdm(total=len(worlds), desc="follower-state labels", unit="house",
               disable=not progress)
    for w, name in enumerate(worlds):
        chunk_name = f"{w:03d}-00000.npz"
        if chunk_name in done or per[w] == 0:
            bar.update(1)
            continue
        world = load_world(name)
        drives = pick_drives(trajs, w, drives_per_world, world_seeds[w])
        visited = collect_visited(world, trajs, drives, policy, reach, on_policy,
                                  seed=world_seeds[w], follower=follower)
        rng = np.random.default_rng(world_seeds[w])
        vs = visited.subset(rng.permutation(len(visited))[:int(per[w])])
        m = len(vs)
        if m == 0:
            raise TopodrakeError(f"the followed chains of {name!r} visited no states to label")
        ahead = (vs.next_anchor >= 0) & (rng.random(m) < next_share)
        tgt = np.where(ahead, vs.next_anchor, vs.anchor).astype(np.int64)
        src = np.empty(m, np.int64)
        for i in range(m):
            drive = trajs.poses[trajs.rows(int(vs.traj[i]))]
            src[i] = int(np.argmin(np.hypot(*(drive[:, :2] - vs.state[i, :2]).T)))
        tgt_pose = trajs.poses[trajs.traj_offsets[vs.traj] + tgt]
        seeds = np.array(trial_seeds(world_seeds[w] + 1, m), np.int64)
        labels = rollout_to_targets(
            world, policy, vs.state[:, :3], tgt_pose,
            lambda sl: target_contexts(world, policy, trajs, vs.traj[sl], tgt[sl]), seeds, cfg)
        chunk = {"src_traj": vs.traj.astype(np.int64), "src": src,
                 "src_pose": vs.state[:, :3].copy(), "traj": vs.traj.astype(np.int64),
                 "tgt": tgt, "same": np.ones(m, bool), **labels, "seed": seeds}
        write_label_chunk(out, chunk_name, chunk, manifest)
        bar.update(1)
        bar.set_postfix(success=f"{np.mean(labels['label']):.2f}", states=m)
    bar.close()
    return out
