"""RE calibrated on the states the follower visits.

The follower acts on RE's probability toward the anchors it aims at. The
calibrations fitted after training hold for the pairs they were fitted on:
the temperature for jittered demonstration pairs, ``anchor_platt`` for hops
between frames of one drive (which places the anchors). A following car
asks from elsewhere: off the drive, at other headings, toward the active
anchor from wherever it got to. There the anchor-hop calibration is
over-confident (in eight training houses the on-policy lidar pair predicts
0.74 on average where 0.63 of the rollouts succeed; the camera pair 0.85
against 0.69).

This module follows seeded chains with the controller (its C_WP and RE)
in training houses that neither network saw, rolls C_WP alone out from a
sample of the visited states toward the anchor aimed at (the RE labels'
rules: :func:`topodrake.learning.reachability.labels.rollout_to_targets`),
fits a Platt scaling of RE's logit to the outcomes and writes it beside
the RE checkpoint as ``follower_calibration.json`` (with the checkpoint's
SHA-1: a calibration of another file is refused).
:meth:`~topodrake.learning.reachability.estimator.Reachability.from_checkpoint`
loads it, and the follower's queries
(:func:`~topodrake.navigation.evaluate.route_calibrated`) use it; the
anchor placement (sparsification) keeps ``anchor_platt``.

    topodrake train follower-calibration --cwp checkpoints/lidar_k5_dagger/checkpoint.pt \
        --re checkpoints/reach_lidar_k5_dagger/checkpoint.pt

A calibration changes where the follower goes (its thresholds act on these
probabilities), so it is shipped only where the follower measured no worse
with it.

The same state labels score RE in ``topodrake bench follower``
(:func:`label_visited_reach`).
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_json, file_sha1
from topodrake.learning.onpolicy.platt import FORMAT, SIDECAR
from topodrake.learning.onpolicy.states import OnPolicyConfig, collect_visited, pick_drives
from topodrake.learning.reachability.calibration import auroc, ece, fit_platt
from topodrake.learning.reachability.controllers import controller_identity, controller_policy
from topodrake.learning.reachability.labels import (
    ReachLabelConfig,
    rollout_to_targets,
    target_contexts,
)
from topodrake.learning.samples import collect_trajectories
from topodrake.world import load_world


@dataclass(frozen=True)
class FollowerCalibrationConfig:
    """Where and how many states are labelled."""

    worlds: tuple[str, ...] = tuple(f"train-{i:02d}" for i in range(84, 92))
    drives_per_world: int = 8        # chains followed per house (noise on half of them)
    states_per_world: int = 100      # visited states rolled out per house
    seed: int = 0

    def check(self) -> "FollowerCalibrationConfig":
        if not self.worlds:
            raise TopodrakeError("follower calibration needs at least one world")
        if self.drives_per_world < 1 or self.states_per_world < 1:
            raise TopodrakeError("follower calibration drives_per_world and states_per_world "
                                 "must be >= 1")
        return self


@dataclass
class StateLabels:
    """RE's logit toward the anchor aimed at from visited states, and
    whether C_WP alone reached it."""

    logit: np.ndarray = field(default_factory=lambda: np.zeros(0))
    label: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def extend(self, other: "StateLabels") -> "StateLabels":
        return StateLabels(np.concatenate([self.logit, other.logit]),
                           np.concatenate([self.label, other.label]))


def label_visited_reach(world, trajs, visited, policy, reach, n: int, rng,
                        seed: int, *, ahead: bool = False, config=None) -> StateLabels:
    """RE's logits and C_WP rollout outcomes for ``n`` random states of
    ``visited`` (:class:`~topodrake.learning.onpolicy.states.VisitedStates`),
    toward the anchor each aimed at (``ahead``: the one after it, where
    there is one), under the labels' rules ``config`` (default
    :class:`~topodrake.learning.reachability.labels.ReachLabelConfig`)."""
    pick = rng.permutation(len(visited))[:n]
    if len(pick) == 0:
        return StateLabels()
    vs = visited.subset(pick)
    tgt = np.where(vs.next_anchor >= 0, vs.next_anchor, vs.anchor) if ahead else vs.anchor
    tgt_pose = trajs.poses[trajs.traj_offsets[vs.traj] + tgt]
    lab = rollout_to_targets(
        world, policy, vs.state[:, :3], tgt_pose,
        lambda sl: target_contexts(world, policy, trajs, vs.traj[sl], tgt[sl]),
        np.arange(len(pick)) + 10_000 * seed, config or ReachLabelConfig())
    feats = reach.encode_target(target_contexts(world, reach, trajs, vs.traj, tgt))
    z = reach.logit(reach.observe(world, vs.state[:, :3]), feats)
    return StateLabels(np.asarray(z, np.float64), np.asarray(lab["label"], np.float64))


def platt_probability(logit: np.ndarray, platt: tuple[float, float]) -> np.ndarray:
    """``sigmoid(a * logit + b)`` for ``platt`` = (a, b)."""
    return 1.0 / (1.0 + np.exp(-(platt[0] * np.asarray(logit, np.float64) + platt[1])))


def follower_probability(reach, logit: np.ndarray) -> np.ndarray:
    """The probability the follower acts on for RE logits (its follower
    calibration, else the anchor-hop one)."""
    return platt_probability(logit, reach.follower_platt or reach.anchor_platt)


def collect_state_labels(policy, reach, config: FollowerCalibrationConfig, data="data",
                         progress: bool = False) -> tuple[StateLabels, dict]:
    """Follow chains in ``config.worlds`` with ``policy`` and ``reach`` (as
    loaded: a calibration already beside the RE steers the follower) and
    label visited states; also returns the followed chains' cover per
    world."""
    trajs = collect_trajectories(list(config.worlds), Path(data) / "demos" / "pairs-s0",
                                 progress=progress)
    cfg = OnPolicyConfig(drives_per_world=config.drives_per_world, next_anchor=False)
    rng = np.random.default_rng([config.seed, 11])
    labels, covers = StateLabels(), {}
    for w, name in enumerate(trajs.worlds):
        world = load_world(name)
        drives = pick_drives(trajs, w, config.drives_per_world, config.seed)
        visited = collect_visited(world, trajs, drives, policy, reach, cfg,
                                  seed=config.seed * 100 + w)
        labels = labels.extend(label_visited_reach(world, trajs, visited, policy, reach,
                                                   config.states_per_world, rng,
                                                   config.seed * 100 + w))
        covers[name] = round(float(visited.cover.mean()), 4)
        if progress:
            print(f"follower calibration: {name}: {len(visited)} states, {len(labels.label)} "
                  f"labels, success {labels.label.mean():.3f}", flush=True, file=sys.stderr)
    return labels, covers


def calibrate_follower(cwp_path, re_path, config: FollowerCalibrationConfig | None = None,
                       data="data", progress: bool = False, command: str | None = None) -> dict:
    """Fit the follower calibration of the RE ``re_path``, followed with
    the C_WP it was trained for (``cwp_path``: a checkpoint or
    ``"registration"``), and write it beside the RE checkpoint. Returns
    what was written."""
    from topodrake.learning.reachability.estimator import Reachability

    config = (config or FollowerCalibrationConfig()).check()
    if not Path(re_path).is_file():
        raise TopodrakeError(f"checkpoint {re_path} does not exist")
    reach = Reachability.from_checkpoint(re_path, cwp_path)     # refuses another controller's RE
    start = time.time()
    labels, covers = collect_state_labels(controller_policy(cwp_path), reach, config, data,
                                          progress)
    y = labels.label
    if len(y) < 20 or y.min() == y.max():
        raise TopodrakeError(f"follower calibration needs both outcomes among at least 20 "
                             f"labels; got {len(y)} with success rate "
                             f"{y.mean() if len(y) else float('nan'):.2f}")
    a, b = fit_platt(labels.logit, y)
    before = platt_probability(labels.logit, reach.anchor_platt)
    after = platt_probability(labels.logit, (a, b))
    out = {
        "format": FORMAT, "checkpoint_sha1": file_sha1(re_path),
        "controller": controller_identity(cwp_path),
        "follower_platt": [round(a, 5), round(b, 5)],
        "anchor_platt": [round(v, 5) for v in reach.anchor_platt],
        "states": int(len(y)), "success_rate": round(float(y.mean()), 4),
        "ece_anchor_platt": round(ece(before, y), 4), "ece_fitted": round(ece(after, y), 4),
        "auroc": round(auroc(after, y), 4), "mean_p_anchor_platt": round(float(before.mean()), 4),
        "followed_cover": covers, "config": {"worlds": list(config.worlds),
                                             "drives_per_world": config.drives_per_world,
                                             "states_per_world": config.states_per_world,
                                             "seed": config.seed},
        "wall_time_s": round(time.time() - start, 1),
        "command": command or "",
    }
    atomic_write_json(Path(re_path).parent / SIDECAR, out)
    return out
