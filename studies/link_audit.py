"""Plans judged in truth without driving them: false links and coverage per building.

For each building and map method the planning study's trials (same seeds)
are planned on the map of the building's drives and each plan's links
judged in truth (:mod:`topodrake.experiments.link_audit`): the share of
plans with a false link (ends out of the controller's reach), their kinds,
and the share of trials refused as not covered. No car drives, so a folder
of buildings takes minutes once its maps are built.

    python studies/link_audit.py --worlds ../shared/maps --json

writes ``results/link_audit.json``.
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
from topodrake.experiments.link_audit import LinkAuditStudy, link_audit
from topodrake.fileio import atomic_write_json
from topodrake.world.catalogue import map_files

SCENARIOS = Path(__file__).resolve().parent / "scenarios" / "link_audit.yaml"


def main(argv=None) -> int:
    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    add_scenario_arguments(ap, LinkAuditStudy, SCENARIOS, "default", {"trials": at.count})
    ap.add_argument("--worlds", metavar="FOLDER|MAP.yaml,...",
                    help="every */map.yaml of a folder (or the maps given) instead of --houses")
    add_output_arguments(ap)
    args = ap.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    return study_main(_run, args)


def _run(args) -> int:
    study = scenario_of(LinkAuditStudy, args, SCENARIOS)
    if args.worlds:
        study.houses = map_files(args.worlds)
    if printed_config(study, args):
        return 0
    doc = link_audit(study, "python studies/link_audit.py " + " ".join(args.argv),
                     quiet=args.quiet)
    out = Path(args.out) / "link_audit.json"
    atomic_write_json(out, doc)
    if args.json:
        print(json.dumps(doc["summary"]))
    else:
        for name, rows in doc["summary"]["by_building"].items():
            for method, r in rows.items():
                print(f"{name:<28} {method:<10} plans {r['planned']:.2f}  false links "
                      f"{r['false_link_plans']}  {r['false_link_kinds']}  uncovered "
                      f"{r['uncovered']}")
        for method, r in doc["summary"]["pooled"].items():
            print(f"{'pooled':<28} {method:<10} false links {r['false_link_plans']} of "
                  f"{r['plans']} plans, worst building {r['worst_building']}, uncovered "
                  f"{r['uncovered']}")
        print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
