"""On-policy states: where the follower actually drives, labelled by the expert.

A controller trained on jittered demonstration poses meets other states when
it drives: the follower's car drifts off the path and aims at anchors farther
away than the training targets. This module follows chains of anchors with a
learned follower (C_WP + RE in the batched navigation engine), records every
state it drives through with the anchor it was aiming at
(:func:`collect_visited`), and labels those states with the A* expert toward
that anchor and the one after it (:func:`onpolicy_samples`), as C_WP samples
of the usual format (:class:`~topodrake.learning.samples.SampleSet`).

The follower benchmark (:mod:`topodrake.experiments.bench_onpolicy`) scores a
controller on such states; on-policy training (DAgger,
:mod:`topodrake.learning.onpolicy.dagger`) aggregates them round after round.

A chain is a demonstration drive sparsified by the follower's RE at
``p_sparsify``; its car starts 0.3 m / 9 deg off the drive's first pose and
stops where it strays more than 1 m from the drive
(:func:`topodrake.navigation.chains.follow_chains_once`), so the states are
those of the trajectory-following study.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.learning.samples import (
    _DTYPES,
    _SAMPLE_FIELDS,
    _SHAPES,
    SampleConfig,
    SampleSet,
    TrajectorySet,
    _arclength,
    label_samples,
)
from topodrake.montecarlo import trial_seeds
from topodrake.navigation.chains import follow_chains_once
from topodrake.navigation.engine import NAV_OUTCOMES, NavigationConfig, NavigationEngine
from topodrake.navigation.follower import FollowerConfig
from topodrake.rollout import RolloutConfig


def _onpolicy_sample_config() -> SampleConfig:
    # the follower aims at anchors it barely sees; keep those states
    return SampleConfig(min_overlap=0.02)


@dataclass
class OnPolicyConfig:
    """How on-policy states are collected and labelled."""

    drives_per_world: int = 20      # chains followed per world
    p_sparsify: float = 0.99        # RE threshold that makes the chains
    noisy_share: float = 0.5        # share of chains followed with actuation noise
    noise_std: float = 0.33
    every: int = 2                  # keep the state of every n-th control period
    next_anchor: bool = True        # label toward the anchor after the active one too
    batch: int = 48                 # cars per engine batch
    samples: SampleConfig = field(default_factory=_onpolicy_sample_config)

    def validate(self) -> "OnPolicyConfig":
        if self.drives_per_world < 1 or self.every < 1 or self.batch < 1:
            raise TopodrakeError("drives_per_world, every and batch must be >= 1")
        if not 0.0 < self.p_sparsify < 1.0:
            raise TopodrakeError(f"p_sparsify must be in (0, 1), got {self.p_sparsify}")
        if not 0.0 <= self.noisy_share <= 1.0:
            raise TopodrakeError(f"noisy_share must be in [0, 1], got {self.noisy_share}")
        if not (np.isfinite(self.noise_std) and self.noise_std >= 0):
            raise TopodrakeError(f"noise_std must be finite and >= 0, got {self.noise_std}")
        return self


@dataclass
class VisitedStates:
    """States one world's followed chains drove through (one row a period).

    ``traj`` indexes the :class:`TrajectorySet` the chains came from;
    ``anchor`` and ``next_anchor`` are frames of that drive (the active
    anchor and the one after it, -1 at the route's end); ``off_path_m`` is
    the distance to the drive."""

    traj: np.ndarray          # (M,) int
    state: np.ndarray         # (M, 5) x, y, theta, speed, steering
    anchor: np.ndarray        # (M,) int
    next_anchor: np.ndarray   # (M,) int
    off_path_m: np.ndarray    # (M,)
    noisy: np.ndarray         # (M,) bool
    cover: np.ndarray         # (chains,) cover of each followed chain
    outcomes: list            # (chains,) engine outcome names

    def __len__(self) -> int:
        return len(self.traj)

    def subset(self, idx) -> "VisitedStates":
        return VisitedStates(self.traj[idx], self.state[idx], self.anchor[idx],
                             self.next_anchor[idx], self.off_path_m[idx], self.noisy[idx],
                             self.cover, self.outcomes)


def pick_drives(trajs: TrajectorySet, world: int, n: int, seed: int) -> np.ndarray:
    """``n`` drives of world index ``world`` (all when fewer), seeded."""
    ids = np.flatnonzero(trajs.traj_world == world)
    if len(ids) == 0:
        raise TopodrakeError(f"no drives of world {trajs.worlds[world]!r}")
    rng = np.random.default_rng([seed, world])
    return np.sort(rng.permutation(ids)[:n])


def collect_visited(world, trajs: TrajectorySet, drives: np.ndarray, policy, reach,
                    cfg: OnPolicyConfig | None = None, seed: int = 0, follower=None,
                    progress=None, chain_reach=None) -> VisitedStates:
    """Follow the RE chains of ``drives`` (indices into ``trajs``, all of
    ``world``) with ``policy`` and ``reach`` and record the states.
    ``chain_reach``: the RE that makes the chains when another than
    ``reach`` (e.g. the learned RE's chains followed by pose oracles)."""
    cfg = (cfg or OnPolicyConfig()).validate()
    drives = np.asarray(drives, np.int64)
    chain_reach = chain_reach or reach
    wide = max((policy, reach, chain_reach), key=lambda n: n.k)
    refs = [trajs.poses[trajs.rows(int(t))] for t in drives]
    obs = [chain_reach.observe(world, r) for r in refs]
    chains = [chain_reach.sparsify(o, p=cfg.p_sparsify) for o in obs]
    if {policy.observation, reach.observation} == {"pose"}:
        obs = refs                       # pose oracles read the anchors' poses
    seeds = trial_seeds(seed, len(drives))
    noisy = np.random.default_rng([seed, 1]).random(len(drives)) < cfg.noisy_share
    rows: dict[str, list] = {k: [] for k in ("traj", "state", "anchor", "next", "off", "noisy")}
    cover = np.zeros(len(drives))
    outcomes = [""] * len(drives)
    for is_noisy in (False, True):
        members = np.flatnonzero(noisy == is_noisy)
        if members.size == 0:
            continue
        engine = NavigationEngine(world, policy, reach, NavigationConfig(
            follower=follower or FollowerConfig(),
            rollout=RolloutConfig(noise_std=cfg.noise_std if is_noisy else 0.0)))
        for lo in range(0, len(members), cfg.batch):
            part = members[lo:lo + cfg.batch]
            speed_steer: dict[int, np.ndarray] = {}

            def record(k, cars, states, _store=speed_steer, _n=len(part)):
                a = _store.setdefault(k + 1, np.zeros((_n, 2)))
                a[cars] = states[:, 3:5]

            res, watch = follow_chains_once(engine, [refs[m] for m in part],
                                            [obs[m] for m in part], [chains[m] for m in part],
                                            wide.k, wide.frame_step, [seeds[m] for m in part],
                                            noisy=bool(is_noisy), record=record)
            for j, m in enumerate(part):
                cover[m] = watch.cover(j)
                outcomes[m] = NAV_OUTCOMES[int(res.outcome[j])]
                periods = np.arange(0, int(res.steps[j]), cfg.every)
                act = res.active[j, periods]
                keep = act >= 0
                periods, act = periods[keep], act[keep]
                if periods.size == 0:
                    continue
                chain = chains[m]
                pose = res.poses[j, periods]
                ss = np.array([speed_steer[k][j] if k in speed_steer else (0.0, 0.0)
                               for k in periods])
                nxt = np.where(act + 1 < len(chain), chain[np.minimum(act + 1, len(chain) - 1)], -1)
                d = np.hypot(pose[:, None, 0] - refs[m][None, :, 0],
                             pose[:, None, 1] - refs[m][None, :, 1]).min(axis=1)
                rows["traj"].append(np.full(len(periods), drives[m]))
                rows["state"].append(np.column_stack([pose, ss]))
                rows["anchor"].append(chain[act])
                rows["next"].append(nxt)
                rows["off"].append(d)
                rows["noisy"].append(np.full(len(periods), bool(is_noisy)))
            if progress is not None:
                progress(len(part))
    if not rows["traj"]:
        return VisitedStates(np.zeros(0, np.int64), np.zeros((0, 5)), np.zeros(0, np.int64),
                             np.zeros(0, np.int64), np.zeros(0), np.zeros(0, bool), cover, outcomes)
    return VisitedStates(np.concatenate(rows["traj"]).astype(np.int64),
                         np.concatenate(rows["state"]), np.concatenate(rows["anchor"]),
                         np.concatenate(rows["next"]), np.concatenate(rows["off"]),
                         np.concatenate(rows["noisy"]), cover, outcomes)


def label_visited(world, trajs: TrajectorySet, visited: VisitedStates,
                  cfg: OnPolicyConfig | None = None) -> dict:
    """C_WP sample fields of ``visited``: the A* expert's labels toward each
    state's active anchor and, with ``cfg.next_anchor``, toward the anchor
    after it. ``src`` holds the drive frame nearest the state."""
    cfg = (cfg or OnPolicyConfig()).validate()
    traj, tgt, src_pose, ss = [visited.traj], [visited.anchor], [visited.state[:, :3]], \
        [visited.state[:, 3:5]]
    if cfg.next_anchor:
        has = visited.next_anchor >= 0
        traj.append(visited.traj[has])
        tgt.append(visited.next_anchor[has])
        src_pose.append(visited.state[has, :3])
        ss.append(visited.state[has, 3:5])
    traj, tgt, src_pose, ss = (np.concatenate(a) for a in (traj, tgt, src_pose, ss))
    src = np.zeros(len(traj), np.int64)
    dist = np.zeros(len(traj))      # signed arc length from the nearest drive frame to the target
    for t in np.unique(traj):
        sel = np.flatnonzero(traj == t)
        ref = trajs.poses[trajs.rows(int(t))]
        d = np.hypot(src_pose[sel, None, 0] - ref[None, :, 0], src_pose[sel, None, 1] - ref[None, :, 1])
        src[sel] = d.argmin(axis=1)
        s = _arclength(ref)
        dist[sel] = s[tgt[sel]] - s[src[sel]]
    return label_samples(world, trajs, traj, src, tgt, src_pose, ss, dist, cfg.samples)


def samples_from_fields(trajs: TrajectorySet, parts: list[dict], meta: dict) -> SampleSet:
    """A :class:`SampleSet` over ``trajs`` from labelled field dicts."""
    fields = {}
    for name in _SAMPLE_FIELDS:
        arrs = [p[name] for p in parts if len(p["traj"])] or [np.zeros(_SHAPES.get(name, (0,)))]
        fields[name] = np.concatenate(arrs).astype(_DTYPES[name])
    return SampleSet(trajs, meta=meta, **fields)


def concat_samples(sets: list[SampleSet], meta: dict | None = None) -> SampleSet:
    """Sample sets over different trajectory sets as one (trajectories
    concatenated, each set's ``traj`` shifted)."""
    if not sets:
        raise TopodrakeError("no sample sets to concatenate")
    trajs = TrajectorySet.concat([s.trajectories for s in sets])
    shift = np.concatenate([[0], np.cumsum([s.trajectories.count for s in sets])])[:-1]
    fields = {}
    for name in _SAMPLE_FIELDS:
        parts = [getattr(s, name) for s in sets]
        if name == "traj":
            parts = [p + off for p, off in zip(parts, shift)]
        fields[name] = np.concatenate(parts).astype(_DTYPES[name])
    return SampleSet(trajs, meta=meta or {}, **fields)
