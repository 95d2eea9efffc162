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
from topodrake.apps.study_args import (
    add_output_arguments,
    add_scenario_arguments,
    printed_config,
    scenario_of,
    study_main,
)
from topodrake.experiments.oracle_reach import OracleReachStudy, oracle_study
from topodrake.fileio import atomic_write_json

SCENARIOS = Path(__file__).resolve().parent / "scenarios" / "oracle_reach.yaml"


def main(argv=None) -> int:
    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    add_scenario_arguments(ap, OracleReachStudy, SCENARIOS, "default",
                           {"pairs": at.count})
    add_output_arguments(ap)
    args = ap.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    return study_main(_run, args)


def _run(args) -> int:
    study = scenario_of(OracleReachStudy, args, SCENARIOS)
    if printed_config(study, args):
        return 0
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
