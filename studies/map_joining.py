"""Do drives that share a place join? Maps of the drives a -> b and b -> c plan a -> c.

For seeded ordered triples of places (a, b, c) of each house, a learned
map (camera and lidar, the shipped RE and place embedding; a camera map
keeps the lidar scans its drives took, as ``topodrake map build`` makes
it) is built from only the expert drive a -> b and the drive b -> c, and a
plan is made from the view at place a to the view at place c
(:func:`topodrake.experiments.joining.join_trial`). A triple is joined when the
plan exists without a false step: no link (a start, goal or direct link,
a cross or junction edge; not the drives' own hops) whose ends are out of
the controller's reach of each other in truth
(:mod:`topodrake.experiments.link_truth`); ``strict_`` figures hold every
link to 2 m.

    python studies/map_joining.py --json

prints ``{"camera": {"joined_triples": r, "false_steps": r}, "lidar": {...}}``
and writes ``results/map_joining.json`` (per house and per triple, with
the command). ``--config map.yaml`` builds with other map settings (for
the ablations: ``join_ends: false``, ``link_consensus: false``).
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
from topodrake.experiments.joining import JoiningStudy, joining_study
from topodrake.fileio import atomic_write_json

SCENARIOS = Path(__file__).resolve().parent / "scenarios" / "map_joining.yaml"


def main(argv=None) -> int:
    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    add_scenario_arguments(ap, JoiningStudy, SCENARIOS, "default",
                           {"triples": at.count})
    add_output_arguments(ap)
    args = ap.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    return study_main(_run, args)


def _run(args) -> int:
    study = scenario_of(JoiningStudy, args, SCENARIOS)
    if printed_config(study, args):
        return 0
    doc = joining_study(study, "python studies/map_joining.py " + " ".join(args.argv),
                        quiet=args.quiet)
    out, summary = Path(args.out) / "map_joining.json", doc["summary"]
    atomic_write_json(out, doc)
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
