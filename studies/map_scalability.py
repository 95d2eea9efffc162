"""How big do maps get? Vertices and edges as drives are added, per test house.

The paper's scalability figure: for every test house, a map is built from
its demonstrations (all ordered pairs of its 10 places, 90 drives) one drive
at a time with the shipped RE (``--modality``, camera k=5 by default), and
its vertices and edges are recorded after each drive against the raw frames
seen so far, with the 10x and 20x temporal subsampling lines for reference.
Also measured:

* ``edge_ratio``: the map's edges over a dense graph's (every raw frame a
  vertex, an edge wherever RE passes ``p_edge``), whose edge count is
  estimated from ``--dense-samples`` source frames scored by RE against
  every frame within 4 m and 100 degrees of them (poses pick the candidates;
  pairs farther apart count as no edge, so the estimate is low and the
  ratio high);
* ``growth_last_over_first``: vertices added by the last 30 drives over
  those added by the first 30 (below 1: sublinear growth). Drives are added
  in a seeded random order (``--order shuffled``): the pairs protocol
  collects them by start place, so in collection order (``--order
  collected``) the last 30 drives all leave from places no earlier drive
  left from, which is new experience rather than more of the same;
* ``retrieval_recall``: in ``--recall-world``, while its first
  ``--recall-trajectories`` drives are added, every new vertex is also
  scored against every vertex of the map: the share of the cross edges that
  exhaustive pass makes which the retrieval pass (top ``retrieval_k``)
  makes too;
* ``hop_success``: ``--hop-samples`` trajectory edges of each map driven
  ``--hop-runs`` times by C_WP + RMP with actuation noise (the RE labels'
  rules, as the sparsification study checks anchor hops).

    python studies/map_scalability.py --json

prints ``{"houses": {...}, "keep_ratio_max", "edge_ratio_max",
"growth_last_over_first", "retrieval_recall", "hop_success"}`` and writes
``results/map_scalability.json`` and ``results/map_scalability.png``. Each
house's map is cached in ``DATA/maps/`` and its figures in
``OUT/map_scalability_runs/``, so an interrupted run resumes.
"""

from __future__ import annotations

import hashlib
import json
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from topodrake import argtypes as at
from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_json

HOUSES = "test-0,test-1,test-2,test-3,test-4"


def dense_edges(scorer, world, drives, p_edge: float, samples: int, seed: int,
                radius_m: float = 4.0, turn_rad: float = np.radians(100)) -> dict:
    """Estimated edges of the dense graph over all frames of ``drives``."""
    from topodrake.learning.frames import context_frames
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
    from topodrake.demonstrations import load_demos
    from topodrake.learning.samples import collect_trajectories
    from topodrake.topomap.build import BuildStats, add_trajectory
    from topodrake.topomap.graph import TopoMap
    from topodrake.topomap.hops import map_hop_success
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


def plot(houses: dict, path: Path, modality: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from topodrake.world.plot import save_figure

    fig, axes = plt.subplots(1, 2, figsize=(12, 5))
    top = max(h["raw_frames"] for h in houses.values())
    ref = np.array([0, top])
    for ax, col, what in ((axes[0], 1, "vertices"), (axes[1], 2, "edges")):
        for name, h in houses.items():
            c = np.array(h["curve"])
            ax.plot(c[:, 0], c[:, col], label=f"{name} ({c[-1, col]:.0f})")
        ax.plot(ref, ref / 10, ":", color="0.4", label="10x subsampling")
        ax.plot(ref, ref / 20, "--", color="0.6", label="20x subsampling")
        ax.set_xlabel("raw frames")
        ax.set_ylabel(what)
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    axes[0].set_title(f"map vertices ({modality} RE) against raw frames")
    dense = np.mean([h["dense"]["edges"] for h in houses.values()])
    axes[1].set_title(f"map edges (dense graphs: ~{dense:,.0f} edges)")
    save_figure(fig, path)


def main(argv=None) -> int:
    from topodrake.montecarlo import study_main

    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    ap.add_argument("--worlds", default=HOUSES, help="comma-separated houses")
    ap.add_argument("--modality", choices=["camera", "lidar", "oracle"], default="camera",
                    help="the shipped RE the maps are built with")
    ap.add_argument("--trajectories", type=at.count, default=90, help="drives per house")
    ap.add_argument("--order", choices=["shuffled", "collected"], default="shuffled",
                    help="the order drives are added in (shuffled: seeded by --seed)")
    ap.add_argument("--recall-world", default="test-0", help="house where retrieval is audited")
    ap.add_argument("--recall-trajectories", type=at.count0, default=30,
                    help="drives audited against the exhaustive pass")
    ap.add_argument("--dense-samples", type=at.count, default=20,
                    help="source frames for the dense graph's edge estimate")
    ap.add_argument("--hop-samples", type=at.count0, default=200,
                    help="trajectory edges driven per map (0: no check)")
    ap.add_argument("--hop-runs", type=at.count, default=2, help="noisy runs per hop")
    ap.add_argument("--seed", type=at.seed, default=0, help="seed of every sample and noise")
    ap.add_argument("--config", default=None,
                    help="MapConfig YAML (default: the paper's settings, retrieval_k 64)")
    ap.add_argument("--data", default="data", help="cache of demonstrations and maps")
    ap.add_argument("--out", default="results", help="folder of the JSON and PNG results")
    ap.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    args = ap.parse_args(argv)
    return study_main(_run, args)


def _run(args) -> int:
    import torch

    from topodrake.learning.waypoint.policy import AStarOracle, LearnedWaypointPolicy
    from topodrake.topomap.graph import MapConfig
    from topodrake.topomap.map_cli import load_map_config
    from topodrake.topomap.sources import SHIPPED, shipped_checkpoint

    torch.set_num_threads(1)
    args.map_config = load_map_config(args.config)
    changed = asdict(args.map_config) != asdict(MapConfig())
    config_hash = hashlib.sha1(json.dumps(asdict(args.map_config), sort_keys=True)
                               .encode()).hexdigest()[:8]
    # map files: tagged only off the defaults (the planning study adopts the default ones);
    # cached results: always, so a change of the defaults is never served stale figures
    args.config_tag = "-c" + config_hash if changed else ""
    worlds = [w for w in args.worlds.split(",") if w]
    if not worlds:
        raise TopodrakeError("--worlds names no house")

    def policy_for():
        if args.modality == "oracle":
            from topodrake.world import load_world
            return AStarOracle(load_world(house), k=5)
        return LearnedWaypointPolicy.from_checkpoint(shipped_checkpoint(SHIPPED[args.modality][1]))

    out = Path(args.out)
    runs = out / "map_scalability_runs"
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
    growth = [h["growth_last_over_first"] for h in houses.values() if "growth_last_over_first" in h]
    recall = next((h["retrieval"]["recall"] for h in houses.values() if "retrieval" in h), None)
    hops = [h["hops"] for h in houses.values() if h["hops"]["runs"]]
    summary = {
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
    atomic_write_json(out / "map_scalability.json", {
        "command": "python studies/map_scalability.py " + " ".join(sys.argv[1:]),
        "modality": args.modality, "seed": args.seed, "order": args.order,
        "map_config": asdict(args.map_config),
        "summary": summary, "houses": houses})
    plot(houses, out / "map_scalability.png", args.modality)
    if args.json:
        print(json.dumps(summary))
    else:
        for name, h in summary["houses"].items():
            print(f"{name}: {h['vertices']} vertices, {h['edges']} edges of {h['raw_frames']} "
                  f"frames (keep {h['keep_ratio']:.4f}, edge ratio {h['edge_ratio']:.5f}, "
                  f"growth {h['growth_last_over_first']}, hops made {h['hop_success']}, "
                  f"built in {h['build_s']} s)")
        print(f"retrieval recall {summary['retrieval_recall']}, hop success "
              f"{summary['hop_success']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
