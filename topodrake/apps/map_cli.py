"""``topodrake map``: build, inspect, plot and plan on topological maps.

    topodrake map build test-0 --modality camera --trajectories 90 --out t0.tdmap
    topodrake map build test-0 --modality camera --add --out t0.tdmap   (grow it)
    topodrake map info t0.tdmap --json
    topodrake map plot t0.tdmap --out t0.png
    topodrake map plan t0.tdmap --start 1.0,2.0,0 --goal 8.5,3.0,1.57 --json
    topodrake map plan t0.tdmap --start-place 1 --goal-place 4
    topodrake map export t0.tdmap --format graphml --out t0.graphml

A plan that finds no path prints why and exits with status 1; a bad map
file, pose or option exits with status 2.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from topodrake.apps import argtypes as at
from topodrake.apps.endpoints import add_endpoint_options, resolve_endpoints
from topodrake.apps.outputs import (
    add_force_option,
    check_output,
    check_output_folder,
    lock_output,
    write_kept,
)
from topodrake.errors import TopodrakeError
from topodrake.experiments.map_cache import house_key
from topodrake.experiments.plan_methods import plan_calibration_path
from topodrake.navigation.replan import traversals_of_records
from topodrake.topomap.export import FORMATS, WRITERS
from topodrake.topomap.graph import EDGE_KINDS, TopoMap, load_map_config
from topodrake.topomap.mapfile import read_map_arrays, save_map
from topodrake.topomap.plan import plan_path
from topodrake.topomap.plan_calibration import fit_from_records, read_trial_records
from topodrake.topomap.plot import plot_map_file
from topodrake.topomap.recalibrate import PRIOR_WEIGHT, experience_summary, record_traversals
from topodrake.topomap.resumable import (
    MapBuild,
    build_key,
    interrupted_build,
    other_partials,
    resume_file,
)
from topodrake.topomap.retrieval import default_embedding
from topodrake.topomap.sources import (
    OBSERVES,
    demo_drives,
    demo_folder,
    drive_observations,
    drives_between,
    make_scorer,
    open_map,
    view_scans,
)
from topodrake.world import load_world


class Unreachable(TopodrakeError):
    """The goal cannot be reached on the map (exit status 1)."""

    exit_code = 1


def cmd_map_build(args) -> None:
    wall = time.perf_counter()
    out = check_output(args.out, "map", force=args.force, replace=args.add, grow="--add")
    if args.add and not out.is_file():
        raise TopodrakeError(f"--add grows an existing map, and {out} does not exist")
    lock_output(out)          # the map and its interrupted builds beside it, before reading it
    if args.add:
        modality = read_map_arrays(out)[0]["modality"]
        if OBSERVES.get(args.modality, modality) != modality:
            raise TopodrakeError(f"{out} is a {modality} map: --add grows it with {modality} "
                                 f"observations, not --modality {args.modality}")
    args.modality = args.modality or "camera"
    folder = demo_folder(args.world, args.demos)
    collect_into = None
    if not (folder / "manifest.json").is_file():
        if args.demos:
            raise TopodrakeError(f"no demonstrations in {folder}")
        collect_into = check_output_folder(folder, option="demonstrations")
    build = _start_build(args, out, collect_into)
    stats = build.run(progress=not args.quiet)
    write_kept(out, build.save, "the map")
    build.resume.unlink(missing_ok=True)
    info = build.topomap.info()
    times = build.drive_s
    summary = {"out": str(out), "demos": str(build.folder), "vertices": info["vertices"],
               "edges": info["edges"], "trajectories": info["trajectories"],
               "raw_frames": info["raw_frames"], "keep_ratio": info["keep_ratio"],
               "added": stats.trajectories + build.resumed, "resumed": build.resumed,
               "reused": stats.reused, "re_pairs": stats.re_pairs,
               "drive_s_first10": round(float(np.mean(times[:10])), 2) if times else None,
               "drive_s_last10": round(float(np.mean(times[-10:])), 2) if times else None,
               "drive_s": [round(t, 2) for t in times],
               "wall_s": round(time.perf_counter() - wall, 1)}
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"wrote {out}: {summary['vertices']} vertices, {summary['edges']} edges from "
              f"{summary['trajectories']} trajectories ({summary['raw_frames']} frames, keep "
              f"ratio {summary['keep_ratio']:.4f}) in {summary['wall_s']} s"
              + (f"; s per drive: first 10 {summary['drive_s_first10']}, last 10 "
                 f"{summary['drive_s_last10']}" if times else ""))


def _start_build(args, out: Path, collect_into: Path | None):
    """The map to grow (new, ``--add``'s, or an interrupted build's) and the
    drives to add (collected first into ``collect_into`` when given)."""
    world = load_world(args.world)
    config = load_map_config(args.config)
    base = set()
    if args.add:
        loaded = open_map(out, args.reach, args.controller)
        scorer, topomap = loaded.scorer, loaded.topomap
        if topomap.world != args.world:
            raise TopodrakeError(f"{out} is a map of {topomap.world!r}, not of {args.world!r}")
        base = {t.name for t in topomap.trajectories}
    else:
        scorer = make_scorer(args.modality, world, args.reach, args.controller)
        topomap = TopoMap(scorer, default_embedding(scorer.observation), config, world=args.world)
    if args.places is not None:
        drives_between(world, [], args.places)          # checks the place indices first
    if collect_into is not None:
        print(f"topodrake: no demonstrations of {args.world} yet: collecting them into "
              f"{collect_into} first (--demos DIR reads others)", file=sys.stderr, flush=True)
    folder, drives = demo_drives(args.world, args.demos, progress=not args.quiet)
    resume = resume_file(out, build_key(args.places, topomap, folder))
    resumed = interrupted_build(resume, scorer, topomap)
    kept = other_partials(out, resume)
    if kept and not args.quiet:
        print(f"topodrake: {len(kept)} interrupted build(s) of other places or settings stay "
              f"beside {out}, kept for their own rerun: {', '.join(p.name for p in kept)}",
              file=sys.stderr, flush=True)
    names = [f"{folder.name}/{i}" for i in range(len(drives))]
    todo = [i for i, n in enumerate(names) if n not in base]
    if args.places is not None:
        between = set(drives_between(world, drives, args.places))
        if not between:
            raise TopodrakeError(f"no drive of {folder} runs between places "
                                 f"{','.join(map(str, args.places))}")
        todo = [i for i in todo if i in between]
    if args.trajectories is not None:
        todo = todo[:args.trajectories]
    if not todo:
        raise TopodrakeError(f"every drive of {folder} is in the map already")
    if resumed is not None and not {t.name for t in resumed.trajectories} <= \
            base | {names[i] for i in todo}:
        resumed = None                  # an interrupted build of other drives: start anew
    if resumed is not None:
        have = {t.name for t in resumed.trajectories}
        n_before = len(todo)
        todo = [i for i in todo if names[i] not in have]
        topomap = resumed
        if not args.quiet:
            print(f"topodrake: resuming the interrupted build in {resume}: "
                  f"{n_before - len(todo)} of {n_before} drives done", file=sys.stderr, flush=True)
    return MapBuild(topomap, world, folder, drives, names, todo, resume,
                    0 if resumed is None else n_before - len(todo))


def _place_list(text: str) -> list[int]:
    import argparse

    try:
        places = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected place indices like 0,4,9, got {text!r}") from None
    if len(places) < 2:
        raise argparse.ArgumentTypeError(f"expected at least two places, got {text!r}")
    return places


def map_info(path) -> dict:
    meta, z = read_map_arrays(path)
    v, e = len(z["vertex_id"]), len(z["edge_src"])
    kinds = np.bincount(z["edge_kind"], minlength=len(EDGE_KINDS))
    return {"file": str(path), "version": meta["version"], "world": meta["world"],
            "modality": meta["modality"], "vertices": v, "edges": e,
            **{f"{kind}_edges": int(n) for kind, n in zip(EDGE_KINDS, kinds)},
            "trajectories": len(meta["trajectories"]), "raw_frames": meta["raw_frames"],
            "keep_ratio": round(v / meta["raw_frames"], 5) if meta["raw_frames"] else 0.0,
            "kept_frames": len(z["observations"]), "checkpoints": meta["identity"],
            "embedding": meta["embedding"]["name"], "config": meta["config"]}


def cmd_map_info(args) -> None:
    info = map_info(args.file)
    if args.json:
        print(json.dumps(info))
        return
    for key, value in info.items():
        print(f"{key:<17} {json.dumps(value) if isinstance(value, dict) else value}")


def cmd_map_plot(args) -> None:
    check_output(args.out, "image", force=args.force)
    lock_output(args.out)
    plot_map_file(args.file, args.out)
    print(f"wrote {args.out}")


def cmd_map_plan(args) -> None:
    check_output(args.plot, "image", force=args.force, option="--plot")
    start, goal = resolve_endpoints(args, args.file)
    lock_output(args.plot, "--plot")
    loaded = open_map(args.file, args.reach, args.controller)
    world, topomap = loaded.world, loaded.topomap
    world.check_pose(start, "start")
    world.check_pose(goal, "goal")
    obs = drive_observations(world, topomap.scorer, np.stack([start, goal]))
    scans = view_scans(world, topomap, np.stack([start, goal]))
    wall = time.perf_counter()
    result = plan_path(topomap, obs[0], obs[1], start_pose=start, goal_pose=goal,
                       view_scans=scans)
    query_s = time.perf_counter() - wall
    out = {"path": [int(v) for v in result.vertices], "anchors": anchor_count(result),
           "probability": round(result.probability, 6), "reachable": result.reachable,
           "query_s": round(query_s, 3)}
    if not result.reachable:
        out["reason"] = result.reason
        if result.uncovered:
            out["uncovered"] = result.uncovered
    calib = loaded.calibration
    if calib is not None and result.reachable:
        out["success_probability"] = round(float(calib.predict(result.probability,
                                                               out["anchors"])[0]), 4)
    if args.json:
        print(json.dumps(out))
    elif result.reachable:
        chance = (f" (chance of success {out['success_probability']:.2f}, calibrated)"
                  if "success_probability" in out else "")
        print(f"plan of {out['anchors']} anchors ({len(result.vertices)} map vertices and the "
              f"goal), probability {result.probability:.4f}{chance}: "
              f"{' '.join(map(str, result.vertices))}")
    if args.plot:
        from topodrake.topomap.plot import plot_plan

        write_kept(args.plot, lambda p: plot_plan(topomap, result, start, goal, p), "the plot")
    if not result.reachable:
        raise Unreachable(f"no plan: {result.reason}")


def cmd_map_export(args) -> None:
    """The map for other tools (GraphML: networkx, Gephi, yEd, ...; MCAP:
    Foxglove, ROS 2)."""
    if args.format is None:         # from --out's ending, else GraphML
        args.format = next((f for f in FORMATS if str(args.out).lower().endswith(f".{f}")),
                           "graphml")
    out = check_output(args.out, args.format, force=args.force)
    lock_output(out)
    loaded = open_map(args.file, args.reach, args.controller)
    topomap = loaded.topomap
    write = WRITERS[args.format]
    write_kept(out, lambda p: write(topomap, p, source=str(args.file)), "the export")
    summary = {"out": str(out), "format": args.format, "vertices": len(topomap),
               "edges": topomap.n_edges, **{f"{k}_edges": n for k, n in
                                             topomap.edge_counts().items()}}
    print(json.dumps(summary) if args.json else
          f"wrote {out}: {summary['vertices']} vertices, {summary['edges']} edges "
          f"({', '.join(f'{n} {k}' for k, n in topomap.edge_counts().items())})")


#: the planning study's methods as ``--method`` names them (camera: the study's "ours")
STUDY_METHODS = {"camera": "ours", "lidar": "lidar", "lidar_reg": "lidar_reg",
                 "lidar_scale": "lidar_scale", "camera_scale": "ours_scale"}


def cmd_map_calibrate(args) -> None:
    name = STUDY_METHODS[args.method]
    if args.out is None:
        args.out = str(plan_calibration_path(name))
    check_output(args.out, "json", force=args.force)
    lock_output(args.out)
    records, commands = read_trial_records(args.records)
    cal = fit_from_records(records, name, source=", ".join(map(str, args.records)),
                           command=" ; ".join(commands))
    cal.save(args.out)
    out = {"out": str(args.out), "method": name, **cal.fitted_on,
           "coef": [round(c, 4) for c in cal.coef], "intercept": round(cal.intercept, 4)}
    if args.json:
        print(json.dumps(out))
    else:
        print(f"fitted the plan calibration of {name} on {cal.fitted_on['trials']} planned trials of "
              f"{', '.join(cal.fitted_on['houses'])}: ECE {cal.fitted_on['ece_raw']} -> "
              f"{cal.fitted_on['ece_fitted']}; wrote {args.out}")


def cmd_map_refit(args) -> None:
    """Fold a planning study's recorded drives on a map into its edges."""
    out = check_output(args.out, "map", force=args.force)
    lock_output(out)
    loaded = open_map(args.file)
    house = house_key(loaded.topomap.world)
    records, _ = read_trial_records(args.records)
    name = STUDY_METHODS[args.method]
    mine = [r for r in records if r.get("method") == name and r.get("house") == house]
    if not mine:
        have = sorted({f"{r.get('method')} in {r.get('house')}" for r in records})
        raise TopodrakeError(f"no trials of {name} in {house} in the records (they hold "
                             f"{', '.join(have) or 'none'})")
    passed, failed = traversals_of_records(mine)
    graph = loaded.topomap.graph
    missing = [e for e in passed + failed if not graph.has_edge(*e)]
    if missing:
        raise TopodrakeError(f"the recorded plans drive edges {args.file} does not hold "
                             f"({len(missing)}, e.g. {missing[0][0]} -> {missing[0][1]}): they "
                             f"were planned on another map")
    changed = record_traversals(loaded.topomap, passed, failed, args.prior_weight)
    save_map(loaded.topomap, out)
    summary = {"out": str(out), "trials": len(mine), "edges_changed": len(changed),
               **experience_summary(loaded.topomap)}
    print(json.dumps(summary) if args.json else
          f"folded {len(mine)} trials of {name} into {len(changed)} edges "
          f"({len(passed)} hops passed, {len(failed)} failed); the map has now driven "
          f"{summary['edges_driven']} edges; wrote {out}")


def anchor_count(plan) -> int:
    """The anchors a car follows on a plan: its map vertices and the goal."""
    return len(plan.route) if plan.route is not None else 0


def _checkpoint_options(p) -> None:
    p.add_argument("--reach", help="RE checkpoint (default: the shipped RE of the modality, or "
                                   "the one the map was built for)")
    p.add_argument("--controller", help="the C_WP checkpoint that RE was trained for, or "
                                        "'registration' (default: as --reach)")


def add_map_parser(sub) -> None:
    mp = sub.add_parser("map", help="build, inspect, plot and plan on topological maps")
    msub = at.subcommands(mp, dest="map_command")

    b = msub.add_parser("build", help="build a map from a world's demonstrations (or grow one)")
    b.add_argument("world", help="catalogue name or ROS map YAML")
    b.add_argument("--modality", choices=["camera", "lidar", "lidar_reg", "oracle"],
                   help="observations and RE: the shipped camera k=5 or lidar k=5 RE, the RE "
                        "of the registration C_WP (lidar_reg), or the geometric oracle "
                        "(default: camera; with --add the map's own)")
    b.add_argument("--demos", help="demonstration folder (default: data/demos/pairs-s0/WORLD, "
                                   "collected first when missing)")
    b.add_argument("--trajectories", type=at.count,
                   help="add at most this many drives, in order (default: all)")
    b.add_argument("--places", type=_place_list,
                   help="only the drives between these places, comma-separated (default: all)")
    b.add_argument("--out", required=True, help="map file to write (.tdmap)")
    b.add_argument("--add", action="store_true",
                   help="grow the map in --out with drives it does not hold yet")
    b.add_argument("--config", help="map settings YAML (MapConfig: nested groups such as "
                                    "'reuse: {p: 0.9}' or flat names such as 'p_reuse: 0.9'; "
                                    "docs/map.md; default: the library's)")
    _checkpoint_options(b)
    b.add_argument("--json", action="store_true", help="print the summary (with each drive's "
                                                      "time) as one JSON object")
    b.add_argument("--quiet", action="store_true", help="no progress bars")
    add_force_option(b)
    b.set_defaults(func=cmd_map_build)

    i = msub.add_parser("info", help="vertices, edges, keep ratio, checkpoints and config of a map")
    i.add_argument("file", help="map file")
    i.add_argument("--json", action="store_true", help="print one JSON object")
    i.set_defaults(func=cmd_map_info)

    pl = msub.add_parser("plot", help="the map over the floor plan, edges coloured by probability")
    pl.add_argument("file", help="map file")
    pl.add_argument("--out", required=True, help="image to write (PNG, PDF or SVG)")
    add_force_option(pl)
    pl.set_defaults(func=cmd_map_plot)

    pn = msub.add_parser("plan", help="plan between two poses or places (their observations) "
                                      "on a map")
    pn.add_argument("file", help="map file")
    add_endpoint_options(pn)
    pn.add_argument("--plot", metavar="PNG", help="also draw the plan over the map into this image")
    _checkpoint_options(pn)
    add_force_option(pn)
    pn.add_argument("--json", action="store_true",
                    help='print {"path": [...], "probability": p, ...}')
    pn.set_defaults(func=cmd_map_plan)

    ex = msub.add_parser("export", help="write the map for other tools (GraphML for networkx, "
                                        "Gephi, yEd: vertex poses, p and -log p on edges; MCAP "
                                        "for Foxglove: a ROS 2 bag of markers)")
    ex.add_argument("file", help="map file")
    ex.add_argument("--format", choices=FORMATS, default=None,
                    help="the file format; formats accepted: graphml, mcap (default: as "
                         "--out ends, else graphml)")
    ex.add_argument("--out", required=True, help="file to write (.graphml or .mcap, as --format)")
    _checkpoint_options(ex)
    ex.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    add_force_option(ex)
    ex.set_defaults(func=cmd_map_export)

    c = msub.add_parser("calibrate", help="fit a method's plan calibration (chance of success "
                                          "of a plan) on a planning study's trials")
    c.add_argument("records", nargs="+",
                   help="the planning study's planning.json files, run on the calibration "
                        "houses calib-0..4 (or training houses the follower never saw)")
    c.add_argument("--method", required=True, choices=list(STUDY_METHODS),
                   help="the planning study's method (camera: its 'ours')")
    c.add_argument("--out", help="calibration file to write (default: plan_calibration.json "
                                 "beside the method's shipped RE; lidar_scale, camera_scale: beside "
                                 "their C_WP)")
    c.add_argument("--json", action="store_true", help="print the fit as one JSON object")
    add_force_option(c)
    c.set_defaults(func=cmd_map_calibrate)

    rf = msub.add_parser("refit", help="fold a planning study's recorded drives on a map into "
                                       "its edges (passed and failed hops against RE's rating)")
    rf.add_argument("file", help="map file the drives were planned on")
    rf.add_argument("records", nargs="+", help="the planning study's planning.json files")
    rf.add_argument("--method", required=True, choices=list(STUDY_METHODS),
                    help="the planning study's method whose trials to fold in (camera: 'ours')")
    rf.add_argument("--out", required=True, help="map file to write (the same as the input "
                                                 "with --force)")
    rf.add_argument("--prior-weight", type=float, default=PRIOR_WEIGHT,
                    help=f"drives RE's rating of an edge counts for (default: {PRIOR_WEIGHT:g})")
    rf.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    add_force_option(rf)
    rf.set_defaults(func=cmd_map_refit)


def cmd_bench_map(args) -> None:
    """Plan queries between every ordered pair of a world's places on a map."""
    from collections import Counter

    from tqdm import tqdm


    path = Path(args.map)
    say = (lambda text: None) if args.quiet else \
        (lambda text: print(f"bench map: {text}", file=sys.stderr, flush=True))
    say(f"loading {path} and its estimators")
    wall = time.perf_counter()
    loaded = open_map(path)
    load_s = time.perf_counter() - wall
    world, topomap = loaded.world, loaded.topomap
    places = world.places
    say(f"rendering the observations at {len(places)} places")
    obs = drive_observations(world, topomap.scorer, places)
    scans = view_scans(world, topomap, places)      # a camera map checks its links by them
    pairs = [(i, j) for i in range(len(places)) for j in range(len(places)) if i != j]
    times, reached, probs, why = [], 0, [], Counter()
    for i, j in tqdm(pairs[:args.queries], desc="plan queries", unit="query",
                     disable=args.quiet):
        t = time.perf_counter()
        r = plan_path(topomap, obs[i], obs[j],
                      view_scans=None if scans is None else (scans[i], scans[j]))
        times.append(time.perf_counter() - t)
        reached += r.reachable
        probs.append(r.probability)
        if not r.reachable:
            why[r.reason.split(" (")[0]] += 1
    times = np.array(times)
    out = {"map": str(path), "vertices": len(topomap), "edges": topomap.n_edges,
           "queries": len(times), "reachable": reached, "unreachable_why": dict(why),
           "load_s": round(load_s, 2),
           "query_mean_s": round(float(times.mean()), 4),
           "query_p95_s": round(float(np.percentile(times, 95)), 4),
           "query_max_s": round(float(times.max()), 4),
           "mean_probability": round(float(np.mean(probs)), 4)}
    print(json.dumps(out) if args.json else
          "\n".join(f"{k:<18} {v}" for k, v in out.items()))


def add_map_bench_parser(bsub) -> None:
    b = bsub.add_parser("map", help="plan-query time on a map (every ordered pair of places)")
    b.add_argument("map", help="map file, e.g. one 'topodrake map build' wrote")
    b.add_argument("--queries", type=at.count, default=90, help="plan queries")
    b.add_argument("--json", action="store_true", help="print one JSON object")
    b.add_argument("--quiet", action="store_true", help="no progress lines")
    b.set_defaults(func=cmd_bench_map)
