"""Do drives that share a place join? Maps of the drives a -> b and b -> c plan a -> c.

For seeded ordered triples of places (a, b, c) of each house, a learned
map (camera and lidar, the shipped RE and place embedding) is built from
only the expert drive a -> b and the drive b -> c, and a plan is made from
the view at place a to the view at place c
(:func:`topodrake.topomap.joining.join_trial`). A triple is joined when the
plan exists without a false step: no link (a start, goal or direct link,
a cross or junction edge; not the drives' own hops) longer than 5 m in
truth; ``strict_`` figures hold every link to 2 m.

    python studies/map_joining.py --json

prints ``{"camera": {"joined_triples": r, "false_steps": r}, "lidar": {...}}``
and writes ``results/map_joining.json`` (per house and per triple, with
the command). ``--config map.yaml`` builds with other map settings (for
the ablations: ``join_ends: false``, ``link_consensus: false``).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from topodrake import argtypes as at
from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_json

MODALITIES = ("camera", "lidar", "lidar_reg")


def house_results(spec: str, modality: str, triples, config, progress: bool) -> list:
    """The :class:`~topodrake.topomap.joining.JoinResult` of each triple in one house."""
    import numpy as np
    from tqdm import tqdm

    from topodrake.topomap.graph import TopoMap
    from topodrake.topomap.joining import join_trial
    from topodrake.topomap.retrieval import default_embedding
    from topodrake.topomap.sources import demo_drives, drive_observations, make_scorer, place_of
    from topodrake.world import load_world

    world = load_world(spec)
    _, drives = demo_drives(spec, None, progress=progress)
    by_places = {}
    for d in drives:
        by_places.setdefault((place_of(world, d.poses[0]), place_of(world, d.poses[-1])), d)
    scorer = make_scorer(modality, world)
    embedding = default_embedding(scorer.observation)
    seen: dict[bytes, np.ndarray] = {}

    def observe(poses):
        key = np.asarray(poses, np.float64).tobytes()
        if key not in seen:
            seen[key] = drive_observations(world, scorer, poses)
        return seen[key]

    def make_map():
        return TopoMap(scorer, embedding, config, world=spec)

    out = []
    for triple in tqdm(triples, desc=f"{spec} {modality}", unit="triple", disable=not progress):
        out.append(join_trial(world, make_map, lambda s, g: by_places.get((s, g)),
                              observe, triple))
    return out


def main(argv=None) -> int:
    from topodrake.montecarlo import study_main

    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    ap.add_argument("--houses", default="test-0,test-1,test-2,test-3,test-4",
                    help="comma-separated houses (their demonstrations are collected once)")
    ap.add_argument("--modalities", default="camera,lidar",
                    help=f"comma-separated map kinds of {', '.join(MODALITIES)}")
    ap.add_argument("--triples", type=at.count, default=40, help="ordered place triples per house")
    ap.add_argument("--seed", type=at.seed, default=0, help="seed of the triples")
    ap.add_argument("--config", help="map config YAML (default: the library's defaults)")
    ap.add_argument("--out", default="results", help="folder of map_joining.json")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    ap.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    args = ap.parse_args(argv)
    return study_main(_run, args)


def _run(args) -> int:
    from dataclasses import asdict

    from topodrake.montecarlo import trial_seeds
    from topodrake.topomap.joining import joining_triples, summarize
    from topodrake.topomap.map_cli import load_map_config
    from topodrake.world import load_world

    houses = [h for h in args.houses.split(",") if h]
    modalities = [m for m in args.modalities.split(",") if m]
    bad = [m for m in modalities if m not in MODALITIES]
    if bad or not modalities:
        raise TopodrakeError(f"--modalities takes {', '.join(MODALITIES)}, got {args.modalities!r}")
    if not houses:
        raise TopodrakeError("--houses names no house")
    config = load_map_config(args.config)
    worlds = {h: load_world(h) for h in houses}             # unknown houses fail here, first
    out = Path(args.out) / "map_joining.json"
    t0 = time.perf_counter()
    per_house, records, summary = {}, [], {}
    for modality in modalities:
        every = []
        for h, seed in zip(houses, trial_seeds(args.seed, len(houses))):
            triples = joining_triples(len(worlds[h].places), args.triples, seed)
            results = house_results(h, modality, triples, config, not args.quiet)
            every += results
            per_house.setdefault(h, {})[modality] = summarize(results)
            records += [{"house": h, "modality": modality, **r.record()} for r in results]
        summary[modality] = summarize(every)
    atomic_write_json(out, {
        "command": "python studies/map_joining.py " + " ".join(sys.argv[1:]),
        "seed": args.seed, "triples_per_house": args.triples, "houses": houses,
        "config": asdict(config), "wall_time_s": round(time.perf_counter() - t0, 1),
        "summary": summary, "per_house": per_house, "trials": records})
    if args.json:
        print(json.dumps(summary))
    else:
        for modality, s in summary.items():
            print(f"{modality:<10} joined {s['joined_triples']:.3f} of {s['triples']} triples, "
                  f"false steps in {s['false_steps']} of the plans, planned {s['planned']}")
        print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
