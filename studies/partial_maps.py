"""Maps of part of a house's drives: do plans know what their map covers?

For seeded subsets of a house's places (4-7 of 10 by default: 13-47 % of
its drives) a map is built from the drives between them, every ordered
pair of places is queried on it and each plan is driven by its method's
networks (:mod:`topodrake.experiments.partial_maps`). Per coverage bin
(the map's count of places, with its fraction of the drives) and pooled
it prints ``covered_link_false`` (plans whose start or
goal link is false in truth: the plan called the query covered and was
wrong), ``refused`` (queries refused as not covered), ``uncovered_refused``
(queries not covered in truth that got no plan), ``covered_refused``
(queries covered in truth refused as not covered), success and ECE (the
plans' calibrated chance of success against success).

    python studies/partial_maps.py --json

writes ``results/partial_maps.json`` (per house, per count of places, every
query's record, the command); ``--paired BEFORE.json,AFTER.json`` compares
two runs query by query (e.g. with and without the coverage check,
``--scenario-text '{map: {link_cover: 0}}'``).
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
from topodrake.errors import TopodrakeError
from topodrake.experiments.partial_maps import (
    PartialMapsStudy,
    paired_runs,
    partial_maps_study,
)
from topodrake.fileio import atomic_write_json

SCENARIOS = Path(__file__).resolve().parent / "scenarios" / "partial_maps.yaml"


def main(argv=None) -> int:
    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    add_scenario_arguments(ap, PartialMapsStudy, SCENARIOS, "default",
                           {"maps_per_count": at.count, "batch": at.count})
    add_output_arguments(ap)
    ap.add_argument("--paired", metavar="BEFORE.json,AFTER.json",
                    help="run no queries: two recorded runs' paired differences (95 %% interval)")
    args = ap.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    return study_main(_run, args)


def _run(args) -> int:
    if args.paired:
        sides = [p for p in args.paired.split(",") if p]
        if len(sides) != 2:
            raise TopodrakeError(f"--paired {args.paired!r}: give BEFORE.json,AFTER.json")
        doc = paired_runs(*sides)
        print(json.dumps(doc) if args.json else "\n".join(
            f"{m:<10} {name:<19} {v['before']} -> {v['after']}  {v['difference']['mean']:+.4f} "
            f"[{v['difference']['ci95'][0]:+.4f}, {v['difference']['ci95'][1]:+.4f}]"
            for m, row in doc.items() for name, v in row.items() if name != "queries"))
        return 0
    study = scenario_of(PartialMapsStudy, args, SCENARIOS)
    if printed_config(study, args):
        return 0
    doc = partial_maps_study(study, "python studies/partial_maps.py " + " ".join(args.argv),
                             quiet=args.quiet)
    out, summary = Path(args.out) / "partial_maps.json", doc["summary"]
    atomic_write_json(out, doc)
    if args.json:
        print(json.dumps(summary))
    else:
        for method, s in summary.items():
            for name, f in [("pooled", s["pooled"]), *s["by_places"].items()]:
                print(f"{method:<10} {name:<7} queries {f['queries']:>4}  planned {f['planned']}  "
                      f"false start/goal links {f['covered_link_false']}  refused "
                      f"{f['refused']} (uncovered in truth refused {f['uncovered_refused']}, "
                      f"covered refused {f['covered_refused']})  success {f['success']}  "
                      f"ECE {f['ece']}")
        print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
