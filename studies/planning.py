"""Planning on topological maps against SPTM (the paper's Table II).

Every method (``topodrake.experiments.plan_methods``; docs/studies.md) builds
its map of each house from the house's 90 expert drives (cached in
``DATA/planning/``) and drives the same trials: a start jittered at one
place, the view at another as the goal. A run is a typed scenario
(``PlanningScenario``) named in ``studies/scenarios/planning.yaml``:

    python studies/planning.py --scenario table2 --json        (the default run)
    python studies/planning.py --scenario paper_protocol
    python studies/planning.py --scenario real_buildings --scenario-text '{trials: 20}'
    python studies/planning.py --houses test-2 --methods oracle_full --trace 7,68
    python studies/planning.py --changes boxes=3 --methods ours,lidar_reg,oracle_full

and writes ``OUT/planning.json`` (command, scenario, per-trial records),
``planning.png``, ``plan_calibration.png`` and ``pruned_maps.png``.
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
from topodrake.errors import TopodrakeError
from topodrake.experiments import plan_report as report
from topodrake.experiments.plan_scenario import PlanningScenario
from topodrake.fileio import atomic_write_json
from topodrake.world.catalogue import map_files

SCENARIOS = Path(__file__).resolve().parent / "scenarios" / "planning.yaml"


def main(argv=None) -> int:
    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    add_scenario_arguments(ap, PlanningScenario, SCENARIOS, "table2")
    ap.add_argument("--changes", metavar="SPEC",
                    help="drive every method also in a changed world, on the same trials: "
                         "boxes=N unmapped boxes on the route, people=N walkers, blocked=1 a "
                         "closed passage (replanning); e.g. boxes=3,people=2 (default: none)")
    ap.add_argument("--worlds", metavar="FOLDER|MAP.yaml,...",
                    help="several buildings at once: every */map.yaml under a folder (e.g. "
                         "../shared/maps), or map YAMLs and catalogue names, comma-separated; "
                         "each timed by its route, no pruned maps; a per-building table and a "
                         "pooled block")
    ap.add_argument("--route-time", action="store_true", help="the same as --time-rule route")
    ap.add_argument("--map-config", metavar="YAML", help="map settings (a MapConfig YAML)")
    ap.add_argument("--follower", metavar="JSON", help="follower settings to change, as JSON")
    ap.add_argument("--replan", metavar="JSON", help="replanning schedule fields to change, as "
                                                     "JSON, or 'paper' for the paper's schedule")
    ap.add_argument("--out", default="results", help="folder of the JSON and PNG results")
    ap.add_argument("--rescore", metavar="PLANNING_JSON[,...]",
                    help="run no trials: set the shipped plan calibrations against the trials "
                         "recorded in these planning.json files")
    ap.add_argument("--paired", metavar="BEFORE.json[:METHOD],AFTER.json[:METHOD]",
                    help="run no trials: two recorded runs' paired difference (95 %% interval)")
    ap.add_argument("--fit-driving-time", metavar="PLANNING_JSON[,...]",
                    help="run no trials: fit the follower's driving time to recorded trials")
    ap.add_argument("--trace", type=at.indices, metavar="TRIALS",
                    help="drive these trials of the one method and house given, each alone, and "
                         "write their timelines (trace.json) and paths (trace-<trial>.png)")
    ap.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    args = ap.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    return study_main(_run, args)


def _scenario(args) -> PlanningScenario:
    """The scenario of the command line: the named one, the text, the flags."""
    from topodrake.navigation.replan import ReplanSchedule
    from topodrake.topomap.graph import load_map_config
    from topodrake.world.changes import WorldChanges

    changes: dict = {}
    if args.worlds:
        if hasattr(args, "world") or hasattr(args, "houses"):
            raise TopodrakeError("give --worlds, --world or --houses, not two of them")
        changes.update({"houses": building_specs(args.worlds), "world": None,
                        "time_rule": "route", "pruned_fractions": []})
    elif hasattr(args, "world") != hasattr(args, "houses"):      # one replaces the other
        changes.update({"houses": []} if hasattr(args, "world") else {"world": None})
    elif hasattr(args, "world"):
        raise TopodrakeError("give --world or --houses, not both")
    if args.route_time:
        if getattr(args, "time_rule", "route") != "route":
            raise TopodrakeError("--route-time and --time-rule fixed contradict each other")
        changes["time_rule"] = "route"
    if args.map_config:       # the file's settings where they are not the defaults
        base, given = load_map_config(None).flat(), load_map_config(args.map_config).flat()
        changes["map"] = {k: v for k, v in given.items() if base[k] != v}
    if args.changes is not None:
        changes["changes"] = asdict(WorldChanges.parse(args.changes))
    if args.follower:
        changes["follower"] = json_object("--follower", args.follower)
    if args.replan:
        changes["replan"] = asdict(ReplanSchedule.paper()) if args.replan == "paper" else \
            json_object("--replan", args.replan)
    return scenario_of(PlanningScenario, args, SCENARIOS, changes)


def building_specs(text: str) -> list[str]:
    """The worlds ``--worlds`` names (:func:`topodrake.world.catalogue.map_files`)."""
    try:
        return map_files(text)
    except TopodrakeError as e:
        raise TopodrakeError(f"--worlds {e}") from None


def _run(args) -> int:
    from topodrake.experiments import plan_results, plan_timing

    out, command = Path(args.out), "python studies/planning.py " + " ".join(args.argv)
    if args.rescore:          # the shipped plan calibrations against recorded trials
        doc = plan_results.rescore(args.rescore, command)
        atomic_write_json(out / "plan_calibration.json", doc)
        if doc["calibration"]:
            report.plot_calibration(doc["calibration"], out / "plan_calibration.png")
        return _print(args, doc["summary"], report.rescore_lines(doc["calibration"]))
    if args.paired:           # two recorded runs compared trial by trial
        doc = plan_results.paired_runs(args.paired)
        return _print(args, doc, report.paired_lines(doc))
    if args.fit_driving_time:   # the planner's driving-time model fitted to recorded trials
        doc = plan_timing.driving_time_fit(args.fit_driving_time, command)
        return _print(args, doc, report.fit_lines(doc))
    sc = _scenario(args)
    if args.print_config:
        from topodrake.experiments.scenarios import to_yaml

        print(to_yaml(sc.resolved()), end="")
        return 0
    if args.trace:
        return _trace(args, sc.resolved(), out, command)
    doc = plan_results.planning(sc, command, quiet=args.quiet)
    summary, houses, cal = doc["summary"], doc["houses"], doc["calibration"]
    atomic_write_json(out / "planning.json", doc)
    report.plot_table(houses, sc.methods, out / "planning.png", sc.trials)
    if cal:
        report.plot_calibration(cal, out / "plan_calibration.png")
    report.plot_pruned(doc["pruned"], out / "pruned_maps.png")
    _print(args, summary, report.run_lines(summary))
    print(f"{len(houses)} houses x {len(sc.methods)} methods x {sc.trials} trials in "
          f"{doc['wall_time_s'] / 60:.1f} min; wrote {out / 'planning.json'}", file=sys.stderr)
    return 0


def _trace(args, sc: PlanningScenario, out: Path, command: str) -> int:
    """Some trials of one method in one house driven alone, their timelines written."""
    from topodrake.experiments.plan_trace import plot_trace, trace_trials
    from topodrake.world import load_world

    if len(sc.specs) != 1 or len(sc.methods) != 1:
        raise TopodrakeError("--trace needs one house (--houses H or --world W) and one method "
                             f"(--methods M), got {len(sc.specs)} and {len(sc.methods)}")
    traces = trace_trials(sc.specs[0], sc.methods[0], args.trace, sc)
    world = load_world(sc.specs[0])
    doc = {"command": command, "scenario": asdict(sc), "traces": [t.to_json() for t in traces]}
    atomic_write_json(out / "trace.json", doc)
    for t in traces:
        plot_trace(world, t, out / f"trace-{t.trial}.png")
    _print(args, doc["traces"], report.trace_lines(doc["traces"]))
    if not args.json:
        print(f"wrote {out / 'trace.json'} and {len(traces)} plots", file=sys.stderr)
    return 0


def _print(args, doc, lines: list[str]) -> int:
    print(json.dumps(doc) if args.json else "\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
