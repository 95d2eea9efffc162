"""Do drives that share a place join? Maps of the drives a -> b and b -> c plan a -> c.

For seeded ordered triples of places (a, b, c) of each house, a learned
map (camera and lidar, the shipped RE and place embedding; a camera map
keeps the lidar scans its drives took, as ``topodrake map build`` makes
it) is built from only the expert drive a -> b and the drive b -> c, and a
plan is made from the view at place a to the view at place c
(:func:`topodrake.experiments.joining.join_trial`). A triple is joined when the
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
from pathlib import Path

from topodrake.apps import argtypes as at
from topodrake.fileio import atomic_write_json
from topodrake.experiments.joining import MODALITIES, JoiningStudy, joining_study


def main(argv=None) -> int:
    from topodrake.apps.study_args import study_main, typed_from_args

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
    return study_main(lambda a: _run(a, typed_from_args(JoiningStudy, a)), args)


def _run(args, study: JoiningStudy) -> int:
    doc = joining_study(study, "python studies/map_joining.py " + " ".join(sys.argv[1:]),
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
