"""Does the controller make the hops a sparsified trajectory promises?

Sparsification keeps an anchor only where RE trusts the controller to get
there from the previous one (RE > p_sparsify). :func:`anchor_hop_success`
checks that promise in the batched engine: C_WP starts at rest on each
anchor's pose, with actuation noise, and drives toward the next anchor
(its context from the same trajectory) under the RE labels' rules
(:func:`topodrake.learning.reachability.labels.rollout_pairs`: success within
0.27 m or both overlaps > 0.7 before A*/v_min). :func:`sparsify_houses`
sparsifies the expert drives of several houses, for their keep ratio and,
optionally, that check of every hop.

:func:`controller_sparsify` sparsifies a drive with the controller's own
outcomes in RE's place (a frame passes when the noisy runs toward it are
made): the keep ratio an RE that knew the controller perfectly would reach,
the floor the controller itself sets under the keep ratio.
"""

from __future__ import annotations

import numpy as np

from topodrake.demonstrations import load_demos
from topodrake.errors import TopodrakeError
from topodrake.learning.reachability.labels import (
    ReachLabelConfig,
    rollout_pairs,
    rollout_to_targets,
)
from topodrake.learning.reachability.sparsify import sparsify
from topodrake.learning.samples import TrajectorySet
from topodrake.montecarlo import trial_seeds
from topodrake.world import load_world


def anchor_hop_success(world, policy, poses: np.ndarray, anchors: np.ndarray, runs: int = 4,
                       seed: int = 0, config=None) -> np.ndarray:
    """(H, runs) successes of the H = len(anchors) - 1 hops, each run with
    its own noise seed."""
    poses = np.asarray(poses, np.float64)
    anchors = np.asarray(anchors, np.int64)
    if runs < 1:
        raise TopodrakeError("need at least one run per hop")
    if len(anchors) < 2:
        return np.zeros((0, runs), bool)
    if anchors.min() < 0 or anchors.max() >= len(poses) or np.any(np.diff(anchors) <= 0):
        raise TopodrakeError("anchors must be increasing frame indices of the trajectory")
    src, tgt = np.repeat(anchors[:-1], runs), np.repeat(anchors[1:], runs)
    seeds = np.array(trial_seeds(seed, len(src)), np.int64)
    return _drive_hops(world, policy, poses, src, tgt, seeds, config).reshape(-1, runs)


def _drive_hops(world, policy, poses: np.ndarray, src: np.ndarray, tgt: np.ndarray,
                seeds: np.ndarray, config=None) -> np.ndarray:
    """Outcomes (bool) of driving from frame ``src[m]`` of one trajectory
    (``poses``) toward its frame ``tgt[m]``, one noise seed each."""
    # one trajectory; the rollouts read its poses only (no replayed states needed)
    trajs = TrajectorySet([world.name], np.zeros(1, np.int32), np.array([0, len(poses)]), poses,
                          np.column_stack([poses, np.zeros((len(poses), 2))]))
    pairs = {"src_traj": np.zeros(len(src), np.int64), "src": src, "src_pose": poses[src],
             "traj": np.zeros(len(src), np.int64), "tgt": tgt, "same": np.ones(len(src), bool)}
    out = rollout_pairs(world, policy, trajs, pairs, seeds, config or ReachLabelConfig())
    return out["label"].astype(bool)


def controller_sparsify(world, policy, poses: np.ndarray, runs: int = 16, failures: int = 0,
                        max_hop: int = 40, seed: int = 0, config=None) -> tuple[np.ndarray, int]:
    """Anchors of one drive (``poses`` (T, 3)) sparsified with the
    controller's outcomes in RE's place, and the number of rollouts run.

    From anchor i, frame j passes when at most ``failures`` of ``runs`` noisy
    runs from frame i toward frame j fail (the runs of one anchor share
    their noise seeds, so one unlucky seed does not stop the scan at random)
    and j - i <= ``max_hop`` (which bounds the cost; the keep ratio cannot
    fall below 1 / max_hop). The greedy scan is RE's
    (:func:`topodrake.learning.reachability.sparsify.sparsify`)."""
    poses = np.asarray(poses, np.float64)
    if runs < 1 or not 0 <= failures < runs or max_hop < 1:
        raise TopodrakeError(f"need runs >= 1, 0 <= failures < runs and max_hop >= 1 "
                             f"(got {runs}, {failures}, {max_hop})")
    rollouts = 0

    def reach(i: int, js: np.ndarray) -> np.ndarray:
        nonlocal rollouts
        near = js[js - i <= max_hop]
        passed = np.zeros(len(js))
        if len(near):
            seeds = np.tile(np.array(trial_seeds(seed * 100003 + i, runs), np.int64), len(near))
            ok = _drive_hops(world, policy, poses, np.full(len(seeds), i), np.repeat(near, runs),
                             seeds, config).reshape(len(near), runs)
            rollouts += ok.size
            passed[:len(near)] = (~ok).sum(axis=1) <= failures
        return passed

    # any p in (0, 1) separates passed (1) from failed (0)
    return sparsify(len(poses), reach, p=0.5, window=4, max_window=16), rollouts


def sparsify_houses(re, worlds: list[str], demo_root, p: float = 0.99, drives: int | None = None,
                    policy=None, runs: int = 0, seed: int = 0,
                    other_calibrations: dict[str, tuple[float, float]] | None = None) -> dict:
    """Sparsify the first ``drives`` (default all) successful expert drives
    of each house in ``worlds`` (demonstrations in ``demo_root/<house>``)
    with RE ``re``: ``{"drives", "frames", "anchors", "keep_ratio",
    "one_frame_hops"}`` (the share of hops that advance a single frame: where
    RE doubts even the next frame, the scan stalls and keeps every frame); with
    ``policy`` and ``runs`` > 0 every hop is also driven ``runs`` times with
    noise (``"hops"``, ``"hop_success"``, ``"failed_runs"``).
    ``other_calibrations`` ({name: Platt (a, b)}): also the keep ratio under
    each of them, from the same observations and features
    (``"keep_ratios": {name: ratio}``)."""
    from pathlib import Path


    check = policy is not None and runs > 0
    others = other_calibrations or {}
    kept = frames = n = single = 0
    kept_other = dict.fromkeys(others, 0)
    oks = [np.zeros(0, bool)]
    for name in worlds:
        world = load_world(name)
        _, demos = load_demos(Path(demo_root) / name, successful_only=True)
        for d in demos[:drives]:
            observations = re.observe(world, d.poses)
            feats = re.frame_features(observations)
            anchors = re.sparsify(observations, p=p, feats=feats)
            for key, platt in others.items():
                kept_other[key] += len(re.sparsify(observations, p=p, feats=feats, platt=platt))
            kept, frames, n = kept + len(anchors), frames + len(d.poses), n + 1
            single += int(np.sum(np.diff(anchors) == 1))
            if check:
                oks.append(anchor_hop_success(world, policy, d.poses, anchors, runs=runs,
                                              seed=seed + n).ravel())
    out = {"drives": n, "frames": frames, "anchors": kept, "keep_ratio": keep_ratio(kept, frames),
           "one_frame_hops": round(single / (kept - n), 4) if kept > n else None}
    if others:
        out["keep_ratios"] = {key: keep_ratio(k, frames) for key, k in kept_other.items()}
    if check:
        ok = np.concatenate(oks)
        out.update(hops=len(ok) // runs, hop_success=share_made(ok), failed_runs=int((~ok).sum()))
    return out


def keep_ratio(anchors: int, frames: int) -> float | None:
    """Anchors kept per frame (4 decimals), None when there are no frames."""
    return round(anchors / frames, 4) if frames else None


def share_made(ok: np.ndarray) -> float | None:
    """The share of hop runs made (4 decimals), None when there are no hops."""
    return round(float(np.mean(ok)), 4) if np.size(ok) else None


def map_hop_success(world, policy, topomap, hops: int = 200, runs: int = 2, seed: int = 0,
                    config=None) -> dict:
    """Drive ``hops`` trajectory edges u -> v of a built map, drawn at
    random (seeded), ``runs`` times each with actuation noise: C_WP starts
    at rest on u's pose toward v's stored context, under the RE labels'
    rules. Returns ``{"hops", "runs", "hop_success"}`` (the share of runs
    made). Poses are the map's metadata: this is an evaluation."""
    edges = [(u, v) for u, v, kind in topomap.graph.edges(data="kind") if kind == "trajectory"]
    if not edges or runs < 1 or hops < 1:
        return {"hops": 0, "runs": 0, "hop_success": None}
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(edges), size=min(hops, len(edges)), replace=False)
    us = np.repeat([edges[i][0] for i in pick], runs)
    vs = np.repeat([edges[i][1] for i in pick], runs)
    contexts = topomap.bank.observations[topomap.contexts(vs)]
    if policy.observation == "pose":
        contexts = topomap.bank.poses[topomap.contexts(vs)]
    out = rollout_to_targets(world, policy, topomap.pose(us), topomap.pose(vs),
                             lambda sl: contexts[sl],
                             np.array(trial_seeds(seed, len(us)), np.int64),
                             config or ReachLabelConfig())
    return {"hops": len(pick), "runs": len(us), "hop_success": float(out["label"].mean())}
