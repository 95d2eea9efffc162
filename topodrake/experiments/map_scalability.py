"""Map growth as drives are added (the map-scalability study).

:func:`run_house` builds one house's map from its demonstrations one drive
at a time (in a seeded random order, or as collected: :func:`tag_of_order`),
recording vertices and edges after each drive, auditing retrieval against
the exhaustive pass, estimating the dense graph's edges (:func:`dense_edges`)
and driving sampled trajectory edges. :func:`scalability` runs the houses of
a study's options, each kept in ``OUT/map_scalability_runs/`` under a key of
its settings so an interrupted run resumes, and assembles the summary.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_json

HOUSES = "test-0,test-1,test-2,test-3,test-4"


def dense_edges(scorer, world, drives, p_edge: float, samples: int, seed: int,
                radius_m: float = 4.0, turn_rad: float = np.radians(100)) -> dict:
    """Estimated edges of the dense graph over all frames of ``drives``."""
    from topodrake.contract.frames import context_frames
    from topodrake.topomap.sources import drive_observations

    poses = np.concatenate([d.poses for d in drives])
    starts = np.cumsum([0] + [len(d.poses) for d in drives])
    owner = np.repeat(np.arange(len(drives)), np.diff(starts))
    local = np.arange(len(poses)) - starts[owner]
    ctx = starts[owner][:, None] + context_frames(np.diff(starts)[owner][:, None], local,
                                                  scorer.k, scorer.frame_step)
    rng = np.random.default_rng(seed)
    counts = []
    for i in rng.choice(len(poses), size=min(samples, len(poses)), replace=False):
        d = np.hypot(*(poses[:, :2] - poses[i, :2]).T)
        turn = np.abs((poses[:, 2] - poses[i, 2] + np.pi) % (2 * np.pi) - np.pi)
        cand = np.flatnonzero((d <= radius_m) & (turn <= turn_rad))
        rows = np.unique(np.concatenate([[i], ctx[cand].ravel()]))
        where = np.full(len(poses), -1)
        where[rows] = np.arange(len(rows))
        feats = scorer.features(drive_observations(world, scorer, poses[rows]))
        p = scorer.score(feats, np.full(len(cand), where[i]), where[ctx[cand]])
        counts.append(int((p > p_edge).sum()))
    return {"samples": len(counts), "mean_out_degree": float(np.mean(counts)),
            "edges": float(np.mean(counts) * len(poses)), "vertices": int(len(poses))}


def tag_of_order(order: str) -> str:
    """The file-name tag of a drive order (collected order: none, as the
    planning study's maps)."""
    return "-shuffled" if order == "shuffled" else ""


def run_house(house: str, args, policy_for) -> dict:
    """One house's map built drive by drive (saved in ``DATA/maps/``) and its figures."""
    from topodrake.demonstrations import load_demos
    from topodrake.learning.samples import collect_trajectories
    from topodrake.topomap.build import BuildStats, add_trajectory
    from topodrake.topomap.graph import TopoMap
    from topodrake.experiments.hops import map_hop_success
    from topodrake.topomap.mapfile import save_map
    from topodrake.topomap.retrieval import default_embedding
    from topodrake.topomap.sources import drive_observations, make_scorer
    from topodrake.world import load_world
    from tqdm import tqdm

    root = Path(args.data) / "demos" / "pairs-s0"
    collect_trajectories([house], root, progress=not args.quiet)
    _, drives = load_demos(root / house, successful_only=True)
    order = np.arange(len(drives))
    if args.order == "shuffled":
        order = np.random.default_rng(args.seed).permutation(len(drives))
    order = order[:args.trajectories]
    names = [f"pairs-s0/{i}" for i in order]
    drives = [drives[i] for i in order]
    world = load_world(house)
    scorer = make_scorer(args.modality, world)
    m = TopoMap(scorer, default_embedding(scorer.observation), args.map_config, world=house)
    audit = house == args.recall_world
    stats, audit_stats = BuildStats(), BuildStats()
    curve = []
    wall = time.perf_counter()
    for i, d in enumerate(tqdm(drives, desc=f"map {house}", disable=args.quiet, unit="traj")):
        checking = audit and i < args.recall_trajectories
        add_trajectory(m, drive_observations(world, scorer, d.poses), d.poses, names[i],
                       audit_stats if checking else stats, audit=checking)
        curve.append([m.raw_frames, len(m), m.n_edges])
    build_s = time.perf_counter() - wall
    save_map(m, Path(args.data) / "maps"
             / f"{house}-{args.modality}{args.config_tag}{tag_of_order(args.order)}.tdmap")
    out = {"trajectories": len(drives), "raw_frames": m.raw_frames, "vertices": len(m),
           "edges": m.n_edges, "edge_kinds": m.edge_counts(),
           "keep_ratio": round(len(m) / m.raw_frames, 5), "build_s": round(build_s, 1),
           "re_pairs": stats.re_pairs + audit_stats.re_pairs, "curve": curve}
    v = [c[1] for c in curve]
    if len(v) >= 60:
        out["growth_last_over_first"] = round((v[-1] - v[-31]) / max(v[29], 1), 4)
    if audit:
        out["retrieval"] = {"trajectories": audit_stats.trajectories,
                            "exhaustive_edges": audit_stats.exhaustive_edges,
                            "found_edges": audit_stats.found_edges,
                            "recall": audit_stats.recall, "retrieval_k": m.config.retrieval_k}
    dense = dense_edges(scorer, world, drives, m.config.p_edge, args.dense_samples, args.seed)
    out["dense"] = dense
    out["edge_ratio"] = round(m.n_edges / max(dense["edges"], 1.0), 6)
    out["hops"] = map_hop_success(world, policy_for(), m, args.hop_samples, args.hop_runs, args.seed)
    return out


def scalability(args, command: str) -> dict:
    """The study's result document for its options ``args`` (worlds,
    modality, trajectories, order, recall world and drives, dense and hop
    samples, seed, config, data, out, quiet): per-house figures and the
    summary; ``command`` is recorded. Sets ``args.map_config`` and
    ``args.config_tag`` (the map files' tag) for :func:`run_house`."""
    import torch

    from topodrake.learning.waypoint.policy import AStarOracle, LearnedWaypointPolicy
    from topodrake.experiments.map_cache import config_tag
    from topodrake.topomap.graph import load_map_config
    from topodrake.topomap.sources import SHIPPED, shipped_checkpoint

    torch.set_num_threads(1)
    args.map_config = load_map_config(args.config)
    config_hash = hashlib.sha1(json.dumps(asdict(args.map_config), sort_keys=True)
                               .encode()).hexdigest()[:8]
    # map files: tagged only off the defaults (the planning study adopts the default ones);
    # cached results: always, so a change of the defaults is never served stale figures
    args.config_tag = config_tag("", args.map_config)
    worlds = [w for w in args.worlds.split(",") if w]
    if not worlds:
        raise TopodrakeError("--worlds names no house")

    def policy_for():
        if args.modality == "oracle":
            from topodrake.world import load_world
            return AStarOracle(load_world(house), k=5)
        return LearnedWaypointPolicy.from_checkpoint(shipped_checkpoint(SHIPPED[args.modality][1]))

    runs = Path(args.out) / "map_scalability_runs"
    key = f"{args.modality}-t{args.trajectories}-r{args.recall_trajectories}-d{args.dense_samples}" \
          f"-h{args.hop_samples}x{args.hop_runs}-s{args.seed}-c{config_hash}" \
          + tag_of_order(args.order)
    houses = {}
    for house in worlds:
        cached = runs / f"{house}-{key}.json"
        if cached.is_file():
            houses[house] = json.loads(cached.read_text())
            continue
        houses[house] = run_house(house, args, policy_for)
        atomic_write_json(cached, houses[house])
    return {"command": command, "modality": args.modality, "seed": args.seed,
            "order": args.order, "map_config": asdict(args.map_config),
            "summary": summarize(houses), "houses": houses}


def summarize(houses: dict) -> dict:
    """The study's summary of its houses' figures."""
    growth = [h["growth_last_over_first"] for h in houses.values() if "growth_last_over_first" in h]
    recall = next((h["retrieval"]["recall"] for h in houses.values() if "retrieval" in h), None)
    hops = [h["hops"] for h in houses.values() if h["hops"]["runs"]]
    return {
        "houses": {n: {k: h[k] for k in ("vertices", "edges", "raw_frames", "keep_ratio",
                                          "edge_ratio", "build_s")}
                   | {"growth_last_over_first": h.get("growth_last_over_first"),
                      "hop_success": h["hops"]["hop_success"]} for n, h in houses.items()},
        "keep_ratio_max": max(h["keep_ratio"] for h in houses.values()),
        "edge_ratio_max": max(h["edge_ratio"] for h in houses.values()),
        "growth_last_over_first": max(growth) if growth else None,
        "retrieval_recall": None if recall is None else round(recall, 4),
        "hop_success": (round(sum(h["hop_success"] * h["runs"] for h in hops)
                              / sum(h["runs"] for h in hops), 4) if hops else None)}
