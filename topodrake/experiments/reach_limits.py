"""What limits RE (the reachability-limits study): the outcomes' own noise, blind starts, the controller.

:func:`measure` drives fresh pairs of the test houses several times each
(the noise ceiling, :func:`oracle_auroc`, against RE's AUROC,
:func:`mean_auroc`), splits off the blind starts, bins anchor hops' success
by length (:func:`success_by_distance`) and sparsifies drives with the
controller's own outcomes (:func:`controller_keep`); :func:`reach_limits`
does so for every RE of a study's options and assembles the result document.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.experiments.hops import (
    anchor_hop_success,
    controller_sparsify,
    keep_ratio,
    share_made,
)
from topodrake.experiments.scenarios import option
from topodrake.learning.reachability.calibration import auroc
from topodrake.learning.reachability.labels import (
    ReachLabelConfig,
    draw_pairs,
    rollout_pairs,
    target_contexts,
)
from topodrake.learning.samples import _arclength, collect_trajectories
from topodrake.montecarlo import trial_seeds
from topodrake.sensing.overlap import mutual_overlap
from topodrake.validate import check_count, check_seed
from topodrake.world import load_world

WORLDS = ("test-0", "test-1", "test-2", "test-3", "test-4")
#: the REs the study measures by default (name=RE.pt:CWP.pt, comma-separated)
DEFAULT_ESTIMATORS = (
    "camera_k5=checkpoints/reach_camera_k5/checkpoint.pt:checkpoints/camera_k5/checkpoint.pt,"
    "lidar_k5=checkpoints/reach_lidar_k5/checkpoint.pt:checkpoints/lidar_k5/checkpoint.pt")


@dataclass
class ReachLimitsStudy:
    """The reachability-limits study's settings: the REs
    (``name=RE.pt:CWP.pt``, comma-separated), the pairs of the noise ceiling
    and their noisy runs each, the anchor hops (one run each), the drives per
    house sparsified by the controller's own outcomes (0: none) and the runs
    per candidate frame and hop, the base seed and the demonstration cache."""

    estimators: str = option(DEFAULT_ESTIMATORS, "name=RE.pt:CWP.pt, comma-separated")
    pairs: int = option(1000, "pairs for the noise ceiling")
    runs: int = option(8, "noisy runs per pair")
    hop_pairs: int = option(2000, "anchor hops (one run each)")
    keep_drives: int = option(1, "drives per house sparsified by the controller's own outcomes "
                                 "(0: skip)")
    keep_runs: int = option(16, "noisy runs per candidate frame (all must be made) and per hop")
    seed: int = option(0, "base seed of the pairs and runs")
    data: str = option("data", "cache of demonstrations (test houses)")

    def validate(self) -> "ReachLimitsStudy":
        """Check the numbers; a bad one raises a one-line TopodrakeError."""
        where = "reachability-limits scenario"
        for name in ("pairs", "runs", "hop_pairs", "keep_runs"):
            check_count(f"{where}: {name}", getattr(self, name))
        check_count(f"{where}: keep_drives", self.keep_drives, 0)
        check_seed(f"{where}: seed", self.seed)
        return self
HOP_BINS_M = (0.0, 0.25, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0)
MAX_HOP_FRAMES = 40     # 2 m of expert drive: the controller-sparsified hops' cap


def oracle_auroc(outcomes: np.ndarray) -> float:
    """Leave-one-run-out AUROC of the pairs' success rates: ``outcomes``
    (pairs, runs) 0/1; each run's outcomes ranked by the other runs' mean."""
    runs = outcomes.shape[1]
    if runs < 2:
        raise TopodrakeError("the noise ceiling needs at least two runs per pair")
    out = []
    for r in range(runs):
        rest = np.delete(outcomes, r, axis=1).mean(axis=1)
        out.append(auroc(rest, outcomes[:, r]))
    return float(np.mean(out))


def mean_auroc(p: np.ndarray, outcomes: np.ndarray) -> float:
    """AUROC of scores ``p`` against each run's outcomes, averaged over runs."""
    return float(np.mean([auroc(p, outcomes[:, r]) for r in range(outcomes.shape[1])]))


def success_by_distance(distance: np.ndarray, success: np.ndarray,
                        edges=HOP_BINS_M) -> list[dict]:
    """Success rate of hops binned by length (m)."""
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (distance >= lo) & (distance < hi + (1e-9 if hi == edges[-1] else 0.0))
        out.append({"from_m": lo, "to_m": hi, "n": int(sel.sum()),
                    "success": round(float(success[sel].mean()), 4) if sel.any() else None})
    return out


def _re_probabilities(re, world, trajs, pairs) -> np.ndarray:
    ctx = target_contexts(world, re, trajs, pairs["traj"], pairs["tgt"])
    return re.probability(re.observe(world, pairs["src_pose"]), re.encode_target(ctx))


def controller_keep(re, policy, trajs, drives_per_house: int, runs: int, seed: int,
                    progress: bool = True) -> dict:
    """Keep ratio of the first ``drives_per_house`` drives of each house of
    ``trajs`` sparsified by the controller's own outcomes, the success of
    those hops on fresh seeds, and RE's keep ratio on the same drives."""
    from tqdm import tqdm


    frames = kept = kept_re = rollouts = 0
    oks = [np.zeros(0, bool)]
    bar = tqdm(total=len(trajs.worlds) * drives_per_house, desc="controller keep ratio",
               unit="drive", disable=not progress)
    for w, name in enumerate(trajs.worlds):
        world = load_world(name)
        for n, t in enumerate(np.flatnonzero(trajs.traj_world == w)[:drives_per_house]):
            poses = trajs.poses[trajs.rows(int(t))]
            anchors, spent = controller_sparsify(world, policy, poses, runs=runs,
                                                 max_hop=MAX_HOP_FRAMES, seed=seed + 7 * w + n)
            oks.append(anchor_hop_success(world, policy, poses, anchors, runs=runs,
                                          seed=seed + 50_000 + 7 * w + n).ravel())
            kept_re += len(re.sparsify(re.observe(world, poses)))
            frames, kept, rollouts = frames + len(poses), kept + len(anchors), rollouts + spent
            bar.update()
    bar.close()
    return {"drives": len(trajs.worlds) * drives_per_house, "frames": frames, "runs": runs,
            "max_hop_frames": MAX_HOP_FRAMES, "keep_ratio": keep_ratio(kept, frames),
            "hop_success": share_made(np.concatenate(oks)),
            "re_keep_ratio": keep_ratio(kept_re, frames),
            "scan_rollouts": rollouts}


def measure(reach: str, controller: str, trajs, pairs_per_house: int, runs: int,
            hop_pairs_per_house: int, seed: int, keep_drives: int = 0, keep_runs: int = 16,
            progress: bool = True) -> dict:
    """One RE's figures (with its C_WP ``controller``) over ``trajs``: noise
    ceiling, blind starts, anchor hops by length, the controller's keep ratio."""
    from tqdm import tqdm

    from topodrake.learning.reachability.estimator import Reachability
    from topodrake.learning.reachability.train import AnchorCalibration
    from topodrake.learning.waypoint.policy import LearnedWaypointPolicy

    re = Reachability.from_checkpoint(reach, controller)
    policy = LearnedWaypointPolicy.from_checkpoint(controller)
    cfg, hop_cfg = ReachLabelConfig(), AnchorCalibration().rollout
    outcomes, p, blind, hop_d, hop_ok = [], [], [], [], []
    bar = tqdm(total=len(trajs.worlds) * (runs * pairs_per_house + hop_pairs_per_house),
               desc=Path(reach).parent.name, unit="rollout", disable=not progress)
    for w, name in enumerate(trajs.worlds):
        world = load_world(name)
        ids = np.flatnonzero(trajs.traj_world == w)
        rng = np.random.default_rng([seed, w])
        pairs = draw_pairs(world, trajs, ids, pairs_per_house, rng, cfg)
        runs_w = []
        for r in range(runs):
            seeds = np.array(trial_seeds(seed * 1000 + 97 * w + r, pairs_per_house), np.int64)
            runs_w.append(rollout_pairs(world, policy, trajs, pairs, seeds, cfg)["label"])
            bar.update(pairs_per_house)
        outcomes.append(np.stack(runs_w, axis=1))
        p.append(_re_probabilities(re, world, trajs, pairs))
        tgt = trajs.poses[trajs.traj_offsets[pairs["traj"]] + pairs["tgt"]]
        blind.append(mutual_overlap(world, pairs["src_pose"], tgt).max(axis=1) < cfg.overlap_lost)
        if hop_pairs_per_house:
            hops = draw_pairs(world, trajs, ids, hop_pairs_per_house, rng, hop_cfg)
            seeds = np.array(trial_seeds(seed * 1000 + 500 + w, hop_pairs_per_house), np.int64)
            hop_ok.append(rollout_pairs(world, policy, trajs, hops, seeds, hop_cfg)["label"])
            arcs = {int(t): _arclength(trajs.poses[trajs.rows(int(t))])
                    for t in np.unique(hops["traj"])}
            hop_d += [arcs[int(t)][g] - arcs[int(t)][s]
                      for t, s, g in zip(hops["traj"], hops["src"], hops["tgt"])]
            bar.update(hop_pairs_per_house)
    bar.close()
    outcomes, p, blind = np.concatenate(outcomes).astype(int), np.concatenate(p), np.concatenate(blind)
    rate = outcomes.mean(axis=1)
    out = {"pairs": int(len(p)), "runs": runs,
           "success_rate": round(float(rate.mean()), 4),
           "share_mixed_outcomes": round(float(np.mean((rate > 0) & (rate < 1))), 4),
           "oracle_auroc": round(oracle_auroc(outcomes), 4),
           "re_auroc": round(mean_auroc(p, outcomes), 4),
           "share_blind": round(float(blind.mean()), 4),
           "blind_success_rate": round(float(rate[blind].mean()), 4) if blind.any() else None,
           "re_auroc_blind_known": round(mean_auroc(np.where(blind, 0.0, p), outcomes), 4),
           "re_auroc_in_view": round(mean_auroc(p[~blind], outcomes[~blind]), 4),
           "blind_detection_auroc": round(auroc(p, (~blind).astype(int)), 4)
           if 0 < blind.sum() < len(blind) else None}
    if hop_pairs_per_house:
        out["anchor_hops"] = success_by_distance(np.array(hop_d), np.concatenate(hop_ok))
    if keep_drives:
        out["controller_keep"] = controller_keep(re, policy, trajs, keep_drives, keep_runs, seed,
                                                 progress=progress)
    return out


def reach_limits(study: ReachLimitsStudy, command: str, quiet: bool = False) -> dict:
    """The study's result document for ``study``; ``command`` is recorded;
    ``quiet``: no progress bars."""
    import torch

    from topodrake.learning.reachability.estimator import parse_estimators

    if study.pairs < len(WORLDS) or study.runs < 2 or study.hop_pairs < 0:
        raise TopodrakeError(f"need --pairs >= {len(WORLDS)}, --runs >= 2 and --hop-pairs >= 0")
    if study.keep_drives < 0 or study.keep_runs < 1:
        raise TopodrakeError("need --keep-drives >= 0 and --keep-runs >= 1")
    estimators = parse_estimators(study.estimators)
    torch.set_num_threads(1)
    trajs = collect_trajectories(list(WORLDS), Path(study.data) / "demos" / "pairs-s0",
                                 progress=not quiet)
    t0 = time.perf_counter()
    summary = {name: measure(reach, controller, trajs, study.pairs // len(WORLDS), study.runs,
                             study.hop_pairs // len(WORLDS), study.seed, study.keep_drives,
                             study.keep_runs, progress=not quiet)
               for name, (reach, controller) in estimators.items()}
    return {"command": command,
            "seed": study.seed, "estimators": {k: {"reach": r, "controller": c}
                                              for k, (r, c) in estimators.items()},
            "wall_time_s": round(time.perf_counter() - t0, 1), "summary": summary}
