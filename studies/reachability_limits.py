"""What limits RE? The outcomes' own noise, the blind starts, and the controller.

Three measurements per RE (default: camera k=5 and lidar k=5, each with its
C_WP), in the test houses, with the batched engine
(:func:`topodrake.learning.reachability.labels.rollout_pairs`, actuation noise on):

* **noise ceiling**: ``--pairs`` fresh pairs drawn as for the RE labels, each
  driven ``--runs`` times with different noise seeds. ``oracle_auroc`` ranks
  each run's outcome by the pair's success rate over the other runs: the
  AUROC an estimator that knew every pair's true success probability would
  reach. ``re_auroc`` is RE's AUROC on the same runs (mean over runs).
* **blind starts**: pairs whose two views share nothing at the start
  (both overlaps < 0.05) fail at once. ``re_auroc_blind_known`` is RE's AUROC
  with those pairs scored 0 (what RE would reach if it recognised them
  perfectly and ranked the rest as it does), ``blind_detection_auroc`` how
  well RE's probability tells them from the rest.
* **anchor hops**: ``--hop-pairs`` pairs in the regime of sparsification
  (source on an expert frame, target up to 3 m ahead on the same drive), one
  run each: the controller's success rate by hop length.
* **keep ratio the controller allows**: ``--keep-drives`` expert drives per
  house sparsified with the controller's own outcomes in RE's place
  (:func:`topodrake.topomap.hops.controller_sparsify`: a frame passes when
  all ``--keep-runs`` noisy runs toward it are made, hops capped at 2 m),
  each resulting hop then driven ``--keep-runs`` more times with fresh
  seeds (``hop_success``, which should be about p_sparsify) and RE's own
  keep ratio on the same drives: how far RE is from the keep ratio a perfect
  estimator of this controller would reach.

    python studies/reachability_limits.py --json

prints ``{"camera_k5": {"oracle_auroc", "re_auroc", "re_auroc_blind_known",
"share_blind", ..., "controller_keep": {...}}, ...}`` and writes
``results/reachability_limits.json``.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from topodrake import argtypes as at
from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_json

DEFAULT = ("camera_k5=checkpoints/reach_camera_k5/checkpoint.pt:checkpoints/camera_k5/checkpoint.pt,"
           "lidar_k5=checkpoints/reach_lidar_k5/checkpoint.pt:checkpoints/lidar_k5/checkpoint.pt")
WORLDS = ("test-0", "test-1", "test-2", "test-3", "test-4")
HOP_BINS_M = (0.0, 0.25, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0)
MAX_HOP_FRAMES = 40     # 2 m of expert drive: the controller-sparsified hops' cap


def oracle_auroc(outcomes: np.ndarray) -> float:
    """Leave-one-run-out AUROC of the pairs' success rates: ``outcomes``
    (pairs, runs) 0/1; each run's outcomes ranked by the other runs' mean."""
    from topodrake.learning.reachability.calibration import auroc

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
    from topodrake.learning.reachability.calibration import auroc

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
    from topodrake.learning.reachability.labels import target_contexts

    ctx = target_contexts(world, re, trajs, pairs["traj"], pairs["tgt"])
    return re.probability(re.observe(world, pairs["src_pose"]), re.encode_target(ctx))


def controller_keep(re, policy, trajs, drives_per_house: int, runs: int, seed: int,
                    progress: bool = True) -> dict:
    """Keep ratio of the first ``drives_per_house`` drives of each house of
    ``trajs`` sparsified by the controller's own outcomes, the success of
    those hops on fresh seeds, and RE's keep ratio on the same drives."""
    from tqdm import tqdm

    from topodrake.topomap.hops import (anchor_hop_success, controller_sparsify, keep_ratio,
                                        share_made)
    from topodrake.world import load_world

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
    from tqdm import tqdm

    from topodrake.learning.reachability.calibration import auroc
    from topodrake.learning.reachability.estimator import Reachability
    from topodrake.learning.reachability.labels import ReachLabelConfig, draw_pairs, rollout_pairs
    from topodrake.learning.reachability.train import AnchorCalibration
    from topodrake.learning.samples import _arclength
    from topodrake.learning.waypoint.policy import LearnedWaypointPolicy
    from topodrake.montecarlo import trial_seeds
    from topodrake.sensing.overlap import mutual_overlap
    from topodrake.world import load_world

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


def main(argv=None) -> int:
    from topodrake.montecarlo import study_main

    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    ap.add_argument("--estimators", default=DEFAULT, help="name=RE.pt:CWP.pt, comma-separated")
    ap.add_argument("--pairs", type=at.count, default=1000, help="pairs for the noise ceiling")
    ap.add_argument("--runs", type=at.count, default=8, help="noisy runs per pair")
    ap.add_argument("--hop-pairs", type=at.count, default=2000, help="anchor hops (one run each)")
    ap.add_argument("--keep-drives", type=at.count0, default=1,
                    help="drives per house sparsified by the controller's own outcomes (0: skip)")
    ap.add_argument("--keep-runs", type=at.count, default=16,
                    help="noisy runs per candidate frame (all must be made) and per hop")
    ap.add_argument("--seed", type=at.seed, default=0, help="base seed of the pairs and runs")
    ap.add_argument("--data", default="data", help="cache of demonstrations (test houses)")
    ap.add_argument("--out", default="results", help="folder of the JSON and PNG results")
    ap.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    args = ap.parse_args(argv)
    return study_main(_run, args)


def _run(args) -> int:
    import torch

    from topodrake.learning.reachability.estimator import parse_estimators
    from topodrake.learning.samples import collect_trajectories

    if args.pairs < len(WORLDS) or args.runs < 2 or args.hop_pairs < 0:
        raise TopodrakeError(f"need --pairs >= {len(WORLDS)}, --runs >= 2 and --hop-pairs >= 0")
    if args.keep_drives < 0 or args.keep_runs < 1:
        raise TopodrakeError("need --keep-drives >= 0 and --keep-runs >= 1")
    estimators = parse_estimators(args.estimators)
    torch.set_num_threads(1)
    trajs = collect_trajectories(list(WORLDS), Path(args.data) / "demos" / "pairs-s0",
                                 progress=not args.quiet)
    t0 = time.perf_counter()
    summary = {name: measure(reach, controller, trajs, args.pairs // len(WORLDS), args.runs,
                             args.hop_pairs // len(WORLDS), args.seed, args.keep_drives,
                             args.keep_runs, progress=not args.quiet)
               for name, (reach, controller) in estimators.items()}
    atomic_write_json(Path(args.out) / "reachability_limits.json", {
        "command": "python studies/reachability_limits.py " + " ".join(sys.argv[1:]),
        "seed": args.seed, "estimators": {k: {"reach": r, "controller": c}
                                          for k, (r, c) in estimators.items()},
        "wall_time_s": round(time.perf_counter() - t0, 1), "summary": summary})
    if args.json:
        print(json.dumps(summary))
    else:
        for name, s in summary.items():
            print(f"{name:<10} oracle AUROC {s['oracle_auroc']:.3f}  RE {s['re_auroc']:.3f}  "
                  f"RE with blind starts known {s['re_auroc_blind_known']:.3f}  "
                  f"blind {s['share_blind']:.0%}")
            if "controller_keep" in s:
                k = s["controller_keep"]
                print(f"{'':<10} keep ratio: controller's own outcomes {k['keep_ratio']:.3f} "
                      f"(hops made {k['hop_success']:.3f}), RE {k['re_keep_ratio']:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
