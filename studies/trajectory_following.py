"""Trajectory following: cover rate against anchors per metre (the paper's cover-rate figure).

Seeded expert drives of the test houses (10-20 m) are each reduced to a
chain of anchors by RE sparsification at every p and by keeping every n-th
frame at the same density, and followed by each controller's follower from a
jittered start; cover is the share of the drive's length the car followed
(docs/studies.md says what each run measures). A run is a typed scenario
(``FollowingScenario``) named in ``studies/scenarios/trajectory_following.yaml``:

    python studies/trajectory_following.py --json                    (the default run)
    python studies/trajectory_following.py --scenario paper_protocol
    python studies/trajectory_following.py --trajectories 60 --controllers lidar_reg --p 0.99

Finished follows are kept in ``OUT/trajectory_following_runs/`` with the
settings that made them (a rerun resumes); ``OUT/trajectory_following.json``
and ``.png`` are written.
"""

from __future__ import annotations

import json
import sys
from dataclasses import asdict
from pathlib import Path

from topodrake.apps import argtypes as at
from topodrake.apps.study_args import (
    add_scenario_arguments,
    json_object,
    scenario_of,
    study_main,
)
from topodrake.experiments.follow_scenario import FollowingScenario
from topodrake.experiments.follow_study import following
from topodrake.fileio import atomic_write_json
from topodrake.world.changes import WorldChanges

SCENARIOS = Path(__file__).resolve().parent / "scenarios" / "trajectory_following.yaml"


def main(argv=None) -> int:
    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    add_scenario_arguments(ap, FollowingScenario, SCENARIOS, "default")
    for flag, what in (("--cwp", "follow NAME's chains with another C_WP (NAME's RE stays); "
                                 "oracle:KEY=VALUE[:...]: the A* oracle with a controlled error"),
                       ("--re", "with another RE under NAME, trained for NAME's C_WP"),
                       ("--chain-re", "place NAME's anchors with this RE while NAME's RE "
                                      "answers the follower")):
        ap.add_argument(flag, action="append", metavar="NAME=CHECKPOINT", help=what + "; repeatable")
    ap.add_argument("--follower", metavar="JSON", help="follower settings to change, as JSON")
    ap.add_argument("--changes", metavar="SPEC",
                    help="also follow each drive in a changed world: boxes=N, people=N, "
                         "blocked=1 (e.g. boxes=3; default: none)")
    ap.add_argument("--out", default="results", help="output folder")
    ap.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    return study_main(_run, args)


def _scenario(args) -> FollowingScenario:
    """The scenario of the command line: the named one, the text, the flags."""
    changes: dict = {}
    for key in ("cwp", "re", "chain_re"):       # NAME=CHECKPOINT items
        items = getattr(args, key) or []
        if items:
            changes[key] = dict(o.partition("=")[::2] for o in items)
    if args.follower:
        changes["follower"] = json_object("--follower", args.follower)
    if args.changes is not None:
        changes["changes"] = asdict(WorldChanges.parse(args.changes))
    return scenario_of(FollowingScenario, args, SCENARIOS, changes)


def _run(args) -> int:
    from topodrake.experiments.follow_report import plot, summary_lines

    sc = _scenario(args)
    if args.print_config:
        from topodrake.experiments.scenarios import to_yaml

        print(to_yaml(sc), end="")
        return 0
    out = Path(args.out)
    doc = following(sc, "python studies/trajectory_following.py " + " ".join(args.argv), out,
                    quiet=args.quiet)
    results, summary, tables = doc["results"], doc["summary"], doc.get("sensitivity", {})
    atomic_write_json(out / "trajectory_following.json", doc)
    plot(results, out / "trajectory_following.png", doc["trajectories"])
    if args.json:
        print(json.dumps({**summary, **({"sensitivity": tables} if tables else {})}))
    else:
        print("\n".join(summary_lines(summary, tables)))
    print(f"{doc['trajectories']} trajectories (mean {doc['mean_length_m']:.1f} m), "
          f"{len(results)} controllers, {len(doc['p_sparsify'])} p values in "
          f"{doc['wall_time_s'] / 60:.1f} min", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
