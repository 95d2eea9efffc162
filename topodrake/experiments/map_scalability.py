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
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from topodrake.contract.frames import context_frames
from topodrake.demonstrations import load_demos
from topodrake.errors import TopodrakeError
from topodrake.experiments.hops import map_hop_success
from topodrake.experiments.map_cache import config_tag
from topodrake.experiments.scenarios import option
from topodrake.fileio import atomic_write_json
from topodrake.learning.samples import collect_trajectories
from topodrake.topomap.build import BuildStats, add_trajectory
from topodrake.topomap.graph import TopoMap, load_map_config
from topodrake.topomap.mapfile import save_map
from topodrake.topomap.retrieval import default_embedding
from topodrake.topomap.sources import SHIPPED, drive_observations, make_scorer, shipped_checkpoint
from topodrake.validate import check_count, check_seed
from topodrake.world import load_world

HOUSES = "test-0,test-1,test-2,test-3,test-4"
#: the shipped REs a map can be built with, and the orders its drives are added in
MODALITIES = ("camera", "lidar", "oracle")
ORDERS = ("shuffled", "collected")


def dense_edges(scorer, world, drives, p_edge: float, samples: int, seed: int,
                radius_m: float = 4.0, turn_rad: float = np.radians(100)) -> dict:
    """Estimated edges of the dense graph over all frames of ``drives``."""
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


@dataclass
class ScalabilityStudy:
    """The map-scalability study's settings: its houses, the shipped RE the
    maps are built with (camera, lidar or oracle), drives per house and
    their order (shuffled by the seed, or as collected), the house where
    retrieval is audited and its drives audited, the dense graph's source
    frames, the trajectory edges driven per map and the noisy runs of each,
    the seed of every sample and noise, the map settings (a MapConfig YAML;
    None: the defaults) and the cache of demonstrations and maps."""
    worlds: list[str] = option(HOUSES.split(","), "comma-separated houses")
    modality: str = option("camera", "the shipped RE the maps are built with",
                           choices=MODALITIES)
    trajectories: int = option(90, "drives per house")
    order: str = option("shuffled", "the order drives are added in (shuffled: seeded by --seed)",
                        choices=ORDERS)
    recall_world: str = option("test-0", "house where retrieval is audited")
    recall_trajectories: int = option(30, "drives audited against the exhaustive pass")
    dense_samples: int = option(20, "source frames for the dense graph's edge estimate")
    hop_samples: int = option(200, "trajectory edges driven per map (0: no check)")
    hop_runs: int = option(2, "noisy runs per hop")
    seed: int = option(0, "seed of every sample and noise")
    config: str | None = option(None, "MapConfig YAML (default: the paper's settings, "
                                      "retrieval_k 64)")
    data: str = option("data", "cache of demonstrations and maps")

    def validate(self) -> "ScalabilityStudy":
        """Check every field but the houses and files (read as the study
        runs); a bad one raises a one-line TopodrakeError."""
        where = "map-scalability scenario"
        if self.modality not in MODALITIES:
            raise TopodrakeError(f"{where}: modality takes {', '.join(MODALITIES)}, got "
                                 f"{self.modality!r}")
        if self.order not in ORDERS:
            raise TopodrakeError(f"{where}: order takes {', '.join(ORDERS)}, got {self.order!r}")
        check_count(f"{where}: trajectories", self.trajectories)
        check_count(f"{where}: recall_trajectories", self.recall_trajectories, 0)
        check_count(f"{where}: dense_samples", self.dense_samples)
        check_count(f"{where}: hop_samples", self.hop_samples, 0)
        check_count(f"{where}: hop_runs", self.hop_runs)
        check_seed(f"{where}: seed", self.seed)
        return self


def run_house(house: str, study: ScalabilityStudy, policy_for, map_config, config_tag: str,
              quiet: bool = False) -> dict:
    """One house's map built drive by drive with ``map_config`` (saved in
    ``DATA/maps/``, its name tagged with ``config_tag``) and its figures."""
    from tqdm import tqdm

    root = Path(study.data) / "demos" / "pairs-s0"
    collect_trajectories([house], root, progress=not quiet)
    _, drives = load_demos(root / house, successful_only=True)
    order = np.arange(len(drives))
    if study.order == "shuffled":
        order = np.random.default_rng(study.seed).permutation(len(drives))
    order = order[:study.trajectories]
    names = [f"pairs-s0/{i}" for i in order]
    drives = [drives[i] for i in order]
    world = load_world(house)
    scorer = make_scorer(study.modality, world)
    m = TopoMap(scorer, default_embedding(scorer.observation), map_config, world=house)
    audit = house == study.recall_world
    stats, audit_stats = BuildStats(), BuildStats()
    curve = []
    wall = time.perf_counter()
    for i, d in enumerate(tqdm(drives, desc=f"map {house}", disable=quiet, unit="traj")):
        checking = audit and i < study.recall_trajectories
        add_trajectory(m, drive_observations(world, scorer, d.poses), d.poses, names[i],
                       audit_stats if checking else stats, audit=checking)
        curve.append([m.raw_frames, len(m), m.n_edges])
    build_s = time.perf_counter() - wall
    save_map(m, Path(study.data) / "maps"
             / f"{house}-{study.modality}{config_tag}{tag_of_order(study.order)}.tdmap")
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
    dense = dense_edges(scorer, world, drives, m.config.cross.p, study.dense_samples, study.seed)
    out["dense"] = dense
    out["edge_ratio"] = round(m.n_edges / max(dense["edges"], 1.0), 6)
    out["hops"] = map_hop_success(world, policy_for(), m, study.hop_samples, study.hop_runs, study.seed)
    return out


def scalability(study: ScalabilityStudy, command: str, out="results",
                quiet: bool = False) -> dict:
    """The study's result document for ``study``: per-house figures (cached
    in ``OUT/map_scalability_runs/``) and the summary; ``command`` is
    recorded; ``quiet``: no progress bars."""
    import torch

    from topodrake.learning.waypoint.policy import AStarOracle, LearnedWaypointPolicy

    torch.set_num_threads(1)
    map_config = load_map_config(study.config)
    config_hash = hashlib.sha1(json.dumps(map_config.flat(), sort_keys=True)
                               .encode()).hexdigest()[:8]
    # map files: tagged only off the defaults (the planning study adopts the default ones);
    # cached results: always, so a change of the defaults is never served stale figures
    tag = config_tag("", map_config)
    worlds = [w for w in study.worlds if w]
    if not worlds:
        raise TopodrakeError("--worlds names no house")

    def policy_for():
        if study.modality == "oracle":
            from topodrake.world import load_world
            return AStarOracle(load_world(house), k=5)
        return LearnedWaypointPolicy.from_checkpoint(shipped_checkpoint(SHIPPED[study.modality][1]))

    runs = Path(out) / "map_scalability_runs"
    key = f"{study.modality}-t{study.trajectories}-r{study.recall_trajectories}-d{study.dense_samples}" \
          f"-h{study.hop_samples}x{study.hop_runs}-s{study.seed}-c{config_hash}" \
          + tag_of_order(study.order)
    houses = {}
    for house in worlds:
        cached = runs / f"{house}-{key}.json"
        if cached.is_file():
            houses[house] = json.loads(cached.read_text())
            continue
        houses[house] = run_house(house, study, policy_for, map_config, tag, quiet)
        atomic_write_json(cached, houses[house])
    return {"command": command, "modality": study.modality, "seed": study.seed,
            "order": study.order, "map_config": map_config.flat(),
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
