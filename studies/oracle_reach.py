"""What the A* oracle controller reaches, and how well the geometric oracles say it.

In each test house, ``--pairs`` (source, target) pairs are drawn on the
house's ordered-pair demonstrations as the learned RE's labels are (jittered
sources; targets on the same drive at -1..8 m of arc, or on another drive
within 8 m) and rolled out with the A* oracle C_WP + RMP under the labels'
rules (:mod:`topodrake.navigation.oracle_reach`; cached in
``DATA/oracle_reach/``). The geometric oracle's parameters are fitted to the
outcomes (maximum likelihood), and every oracle is rated against them:

- ``paper_geometry``: the former fixed oracle (2.5 m, 1.2 rad turn, overlap 0.3);
- ``map``: the map's oracle (:class:`topodrake.topomap.scorer.OracleConfig` defaults);
- ``calibrated``: :data:`~topodrake.topomap.scorer.CALIBRATED_ORACLE`;
- ``trusting``: :data:`~topodrake.topomap.scorer.TRUSTING_ORACLE`;
- ``follower``: the follower's :class:`topodrake.navigation.evaluate.GeometricReachability`;
- ``fitted``: the fit of this run.

    python studies/oracle_reach.py --json

prints ``{"pairs": n, "success": s, "oracles": {name: {"ece": e, "auroc": a,
"nll": l}, ...}, "fitted": {OracleConfig fields}, "success_by_distance": {...}}``
and writes ``results/oracle_reach.json``. 800 pairs in each of the five
houses take about 1.5 min.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from topodrake import argtypes as at
from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_bytes, atomic_write_json

HOUSES = "test-0,test-1,test-2,test-3,test-4"
FIELDS = ("src", "tgt", "same", "outcome", "label")
#: Candidate values of the fit (coordinate descent over the OracleConfig fields).
GRID = {"reach_m": [2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0], "reach_soft_m": [0.1, 0.2, 0.5, 1.0],
        "bearing_rad": [0.8, 1.2, 1.6, 2.0, 2.4, 2.8, 3.2], "bearing_soft_rad": [0.1, 0.2, 0.4, 0.8],
        "turn_rad": [0.8, 1.2, 1.6, 2.0, 2.4], "turn_soft_rad": [0.1, 0.2, 0.4, 0.8],
        "min_overlap": [0.0, 0.02, 0.05, 0.1, 0.2, 0.3], "overlap_soft": [0.01, 0.02, 0.05, 0.1],
        "hidden": [0.0, 0.1, 0.2, 0.3, 0.5]}


def house_pairs(spec: str, n: int, seed: int, data: Path, progress: bool) -> dict:
    """The labelled oracle pairs of one house (cached)."""
    import io

    from topodrake.demonstrations import CollectConfig, collect, load_demos
    from topodrake.navigation.oracle_reach import oracle_reach_pairs
    from topodrake.topomap.sources import demo_folder
    from topodrake.world import load_world

    key = demo_folder(spec).name
    path = data / "oracle_reach" / f"{key}-n{n}-s{seed}.npz"
    if path.is_file():
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in FIELDS}
    folder = data / "demos" / "pairs-s0" / key
    collect(spec, folder, CollectConfig(protocol="pairs", seed=0), progress=progress)
    drives = [d.poses for d in load_demos(folder, successful_only=True)[1]]
    out = oracle_reach_pairs(load_world(spec), drives, n, seed)
    buf = io.BytesIO()
    np.savez_compressed(buf, **{k: out[k] for k in FIELDS})
    atomic_write_bytes(path, buf.getvalue())
    return {k: out[k] for k in FIELDS}


def main(argv=None) -> int:
    from topodrake.montecarlo import study_main

    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    ap.add_argument("--houses", default=HOUSES, help="test houses (catalogue names or map YAMLs)")
    ap.add_argument("--pairs", type=at.count, default=800, help="labelled pairs per house")
    ap.add_argument("--seed", type=at.seed, default=1, help="seed of the pairs and their noise")
    ap.add_argument("--data", default="data", help="cache of demonstrations and pairs")
    ap.add_argument("--out", default="results", help="folder of the JSON result")
    ap.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    args = ap.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    return study_main(_run, args)


def _run(args) -> int:
    from tqdm import tqdm

    from topodrake.navigation.evaluate import GeometricReachability
    from topodrake.navigation.oracle_reach import calibration_scores, fit_oracle
    from topodrake.topomap.scorer import (CALIBRATED_ORACLE, TRUSTING_ORACLE, OracleConfig,
                                          pair_geometry, reach_from_geometry)
    from topodrake.world import load_world

    specs = [h for h in args.houses.split(",") if h]
    if not specs:
        raise TopodrakeError("--houses names no house")
    t0 = time.perf_counter()
    geos, labels, follower = [], [], []
    for spec in tqdm(specs, desc="houses", disable=args.quiet):
        world = load_world(spec)
        pairs = house_pairs(spec, args.pairs, args.seed, Path(args.data), not args.quiet)
        geos.append(pair_geometry(world, pairs["src"], pairs["tgt"]))
        labels.append(pairs["label"])
        follower.append(GeometricReachability(world).probability(pairs["src"], pairs["tgt"]))
    geo = {k: np.concatenate([g[k] for g in geos]) for k in geos[0]}
    y = np.concatenate(labels).astype(np.float64)
    fitted, _ = fit_oracle(geo, y, CALIBRATED_ORACLE, GRID)
    paper = OracleConfig(reach_m=2.5, bearing_rad=float("inf"), turn_rad=1.2, min_overlap=0.3,
                         hidden=0.0)
    oracles = {name: calibration_scores(reach_from_geometry(geo, c), y)
               for name, c in (("paper_geometry", paper), ("map", OracleConfig()),
                               ("calibrated", CALIBRATED_ORACLE), ("trusting", TRUSTING_ORACLE),
                               ("fitted", fitted))}
    oracles["follower"] = calibration_scores(np.concatenate(follower), y)
    by_distance = {}
    for lo in range(8):
        m = geo["sight"] & (geo["distance"] >= lo) & (geo["distance"] < lo + 1)
        if m.any():
            by_distance[f"{lo}-{lo + 1}m"] = {"pairs": int(m.sum()), "success": round(float(y[m].mean()), 3)}
    summary = {"pairs": int(len(y)), "success": round(float(y.mean()), 4), "oracles": oracles,
               "fitted": {k: (None if not np.isfinite(v) else round(float(v), 4))
                          for k, v in asdict(fitted).items()},
               "success_by_distance": by_distance}
    wall = time.perf_counter() - t0
    out = Path(args.out)
    atomic_write_json(out / "oracle_reach.json", {
        "command": "python studies/oracle_reach.py " + " ".join(args.argv), "seed": args.seed,
        "houses": specs, "pairs_per_house": args.pairs, "wall_time_s": round(wall, 1),
        "note": "success_by_distance: pairs with a clear straight line, by straight distance",
        "summary": summary})
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"{len(y)} pairs, A* oracle success {y.mean():.3f}")
        for name, s in oracles.items():
            print(f"{name:<15} ECE {s['ece']:.3f}  AUROC {s['auroc']:.3f}  NLL {s['nll']:.3f}")
        print("fitted:", summary["fitted"])
    print(f"wrote {out / 'oracle_reach.json'} in {wall / 60:.1f} min", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
