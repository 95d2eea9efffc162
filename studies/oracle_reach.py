"""What the A* oracle controller reaches, and how well the geometric oracles say it.

In each test house, ``--pairs`` (source, target) pairs are drawn on the
house's ordered-pair demonstrations as the learned RE's labels are (jittered
sources; targets on the same drive at -1..8 m of arc, or on another drive
within 8 m) and rolled out with the A* oracle C_WP + RMP under the labels'
rules (:mod:`topodrake.experiments.oracle_reach`; cached in
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
from pathlib import Path

from topodrake.apps import argtypes as at
from topodrake.fileio import atomic_write_json
from topodrake.experiments.oracle_reach import HOUSES, OracleReachStudy, oracle_study


def main(argv=None) -> int:
    from topodrake.apps.study_args import study_main, typed_from_args

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
    return study_main(lambda a: _run(a, typed_from_args(OracleReachStudy, a)), args)


def _run(args, study: OracleReachStudy) -> int:
    doc = oracle_study(study, "python studies/oracle_reach.py " + " ".join(args.argv),
                       quiet=args.quiet)
    out, summary = Path(args.out), doc["summary"]
    atomic_write_json(out / "oracle_reach.json", doc)
    oracles = summary["oracles"]
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"{summary['pairs']} pairs, A* oracle success {summary['success']:.3f}")
        for name, s in oracles.items():
            print(f"{name:<15} ECE {s['ece']:.3f}  AUROC {s['auroc']:.3f}  NLL {s['nll']:.3f}")
        print("fitted:", summary["fitted"])
    print(f"wrote {out / 'oracle_reach.json'} in {doc['wall_time_s'] / 60:.1f} min",
          file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
