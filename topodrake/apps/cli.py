"""The ``topodrake`` command line.

Every bad input ends in one line on stderr (``topodrake: error: ...``) and
exit status 2; see :mod:`topodrake.errors`. Numbers are checked where they
enter (:mod:`topodrake.apps.argtypes`, :mod:`topodrake.validate`).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from topodrake import __version__
from topodrake.apps import argtypes as at
from topodrake.apps.demo import add_demo_parser
from topodrake.apps.map_cli import add_map_bench_parser, add_map_parser
from topodrake.apps.navigate_cli import add_navigate_parser
from topodrake.apps.outputs import (
    add_force_option,
    check_output,
    check_output_folder,
    lock_output,
    release_locks,
)
from topodrake.apps.sparsify_cli import add_sparsify_parser
from topodrake.apps.train_cli import add_bench_parser, add_train_parser
from topodrake.demonstrations import CollectConfig, collect, load_demos
from topodrake.errors import TopodrakeError
from topodrake.experiments.bench_sim import bench_expert, bench_sensors
from topodrake.montecarlo import run_trials, trial_seeds
from topodrake.navigation.outcomes import drive_outcome, exit_status
from topodrake.systems.scenario import load_scenario
from topodrake.systems.trials import expert_trial
from topodrake.world import load_world
from topodrake.world.catalogue import catalogue_names, map_files
from topodrake.world.plot import plot_world, save_figure

DESCRIPTION = ("topodrake: visual topological navigation on Drake. Drive, collect "
               "demonstrations, train, sparsify, inspect worlds and benchmark.")

WORKFLOW = """\
Start with:  topodrake demo     (the learned follower drives test-0; writes out/demo/)

The workflow, in order:
  topodrake world list                       the houses (or a ROS map YAML)
  topodrake collect WORLD --out DIR          expert drives between its places
  topodrake map build WORLD --out M.tdmap    sparsify them by RE into a map
  topodrake map plan M.tdmap --start X,Y,YAW --goal X,Y,YAW   (or --start-place N ...)
  topodrake navigate M.tdmap --start X,Y,YAW --goal X,Y,YAW --plot run.png
  topodrake train waypoint|reachability ...  your own C_WP and RE

Exit status: 0 done (a drive reached its goal), 1 no plan, 2 bad input or an
output that cannot be written, 3 a drive that did not reach its goal.
topodrake COMMAND --help for a command; docs/cli.md for the whole picture."""


LOG_LEVELS = ("debug", "info", "warning", "error")


class _StderrHandler(logging.StreamHandler):
    """To whatever ``sys.stderr`` is when a record is logged."""

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value):
        pass


def configure_logging(level: str) -> None:
    """Python's ``logging`` for the ``topodrake`` loggers: ``level`` and up
    to stderr as ``topodrake LEVEL name: message``."""
    logger = logging.getLogger("topodrake")
    for handler in [h for h in logger.handlers if getattr(h, "_topodrake_cli", False)]:
        logger.removeHandler(handler)
    handler = _StderrHandler()
    handler._topodrake_cli = True
    handler.setFormatter(logging.Formatter("topodrake %(levelname)s %(name)s: %(message)s"))
    logger.addHandler(handler)
    logger.setLevel(level.upper())


def _print_result(result: dict, as_json: bool) -> None:
    if as_json:
        print(json.dumps(result))
        return
    width = max(len(k) for k in result)
    for k, v in result.items():
        if isinstance(v, float):
            v = f"{v:,.4g}"
        print(f"{k:<{width}}  {v}")


def cmd_drive(args) -> int:
    from topodrake.systems.run import run_scenario

    summary = run_scenario(load_scenario(args.scenario)).summary()
    summary["outcome"] = drive_outcome(summary["outcome"], summary["distance_to_goal_m"])
    print(json.dumps(summary))
    return exit_status(summary["outcome"])


def cmd_trials(args) -> None:
    world = load_world(args.world)          # its places, checked before the trials start
    world.place_pose(args.start_place, "--start-place")
    world.place_pose(args.goal_place, "--goal-place")
    seeds = trial_seeds(args.seed, args.trials)
    results = run_trials(expert_trial, seeds, workers=args.workers, ray_address=args.ray,
                         desc="expert trials", world=args.world, start_place=args.start_place,
                         goal_place=args.goal_place, noise_std=args.noise, camera=args.camera)

    outcomes = [drive_outcome(r["outcome"], r["distance_to_goal_m"]) for r in results]
    n = len(results)
    summary = {"world": args.world, "trials": n, "seed": args.seed,
               "reached_rate": outcomes.count("reached") / n,
               "collision_rate": outcomes.count("collision") / n,
               "mean_time_s": sum(r["time_s"] for r in results) / n,
               "mean_distance_to_goal_m": sum(r["distance_to_goal_m"] for r in results) / n}
    _print_result(summary, args.json)


def cmd_collect(args) -> None:
    check_output_folder(args.out, marker="manifest.json", what="demonstrations (manifest.json)",
                        force=args.force)
    lock_output(args.out)

    config = CollectConfig(protocol=args.protocol, count=args.count, seed=args.seed,
                           noise_std=args.noise, chunk_size=args.chunk_size)
    out = collect(args.world, args.out, config, progress=not args.quiet)
    manifest, drives = load_demos(out)
    ok = sum(d.success for d in drives)
    print(f"{out}: {len(drives)} drives, {ok} successful, "
          f"{sum(len(d.controls) for d in drives)} control steps")


def cmd_world_list(args) -> None:
    if args.maps and not Path(args.maps).is_dir():
        raise TopodrakeError(f"--maps {args.maps}: no such folder")
    names = catalogue_names() + (map_files(args.maps) if args.maps else [])
    if args.json:
        print(json.dumps(names))
    else:
        print("\n".join(names))


def cmd_world_info(args) -> None:
    world = load_world(args.world)
    info = world.info()
    if args.json:
        print(json.dumps(info))
        return
    for k, v in info.items():
        if k not in ("places", "place_names"):
            print(f"{k:<14} {v}")
    places = world.place_list()
    print(f"{'places':<14} {len(places)} (index: x m, y m, yaw rad; --start-place/--goal-place "
          f"take the index)")
    for row in places:
        name = f"  {row['name']}" if "name" in row else ""
        print(f"  {row['index']:>3}: {row['x']:8.3f} {row['y']:8.3f} {row['yaw']:7.3f}{name}")


def cmd_world_plot(args) -> None:
    check_output(args.out, "image", force=args.force)
    lock_output(args.out)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    world = load_world(args.world)
    fig, ax = plt.subplots(figsize=(9, 9))
    plot_world(world, ax)
    if args.astar:
        i, j = args.astar
        n = len(world.places)
        if not (0 <= i < n and 0 <= j < n):
            raise TopodrakeError(f"--astar places must be in 0..{n - 1}, got {i} {j}")
        path = world.astar(world.places[i], world.places[j])
        ax.plot(path[:, 0], path[:, 1], color="tab:blue", lw=1.5)
    save_figure(fig, args.out)
    print(f"wrote {args.out}")


def cmd_bench_expert(args) -> None:
    _print_result(bench_expert(args.pairs, args.seed, args.batch), args.json)


def cmd_bench_sensors(args) -> None:
    _print_result(bench_sensors(args.world, args.batch, args.vtk_poses, args.seed), args.json)


def build_parser() -> argparse.ArgumentParser:
    p = at.Parser(prog="topodrake", description=DESCRIPTION, epilog=WORKFLOW,
                  formatter_class=at.RawEpilogFormatter)
    p.add_argument("--version", action="version", version=f"topodrake {__version__}",
                   help="print the version and exit")
    p.add_argument("--log-level", choices=LOG_LEVELS, default="warning",
                   help="the diagnostics the library logs to stderr (default: warning)")
    sub = at.subcommands(p, dest="command", metavar="COMMAND")
    p.set_defaults(func=lambda args: _welcome(p))


    add_demo_parser(sub)
    add_navigate_parser(sub)

    drive = sub.add_parser("drive", help="run one expert scenario from a YAML file")
    drive.add_argument("scenario", help="Scenario YAML (its keys: docs/cli.md)")
    drive.set_defaults(func=cmd_drive)

    tr = sub.add_parser("trials", help="seeded Monte Carlo expert drives in the Drake diagram")
    tr.add_argument("--world", default="test-0", help="catalogue name or map YAML/JSON")
    tr.add_argument("--start-place", type=at.count0, default=0, help="index of the start place")
    tr.add_argument("--goal-place", type=at.count0, default=5, help="index of the goal place")
    tr.add_argument("--trials", type=at.count, default=20, help="number of seeded drives")
    tr.add_argument("--seed", type=at.seed, default=0, help="base seed of the trial seeds")
    tr.add_argument("--noise", type=at.nonnegative, default=0.33,
                    help="actuation noise std (0 = off)")
    tr.add_argument("--camera", action="store_true", help="render the camera too")
    tr.add_argument("--workers", type=at.count, help="local processes (default: all cores)")
    tr.add_argument("--ray", metavar="ADDRESS",
                    help="run on a Ray cluster ('auto', 'local' or ray://host:port)")
    tr.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    tr.set_defaults(func=cmd_trials)

    col = sub.add_parser("collect", help="generate expert demonstrations (resumable)")
    col.add_argument("world", help="catalogue name or map YAML/JSON")
    col.add_argument("--out", required=True, help="output folder")
    col.add_argument("--protocol", choices=["pairs", "random"], default="pairs",
                     help="pairs: all ordered pairs of the 10 places; random: --count pairs")
    col.add_argument("--count", type=at.count, default=100,
                     help="number of drives for --protocol random")
    col.add_argument("--seed", type=at.seed, default=0, help="seed of the pairs and the noise")
    col.add_argument("--noise", type=at.nonnegative, default=0.0,
                     help="actuation noise std (0 = off)")
    col.add_argument("--chunk-size", type=at.count, default=32, help="drives per file")
    col.add_argument("--quiet", action="store_true", help="no progress bar")
    add_force_option(col)
    col.set_defaults(func=cmd_collect)

    world = sub.add_parser("world", help="list, inspect and plot worlds")
    wsub = at.subcommands(world, dest="world_command")
    wl = wsub.add_parser("list", help="the catalogue of procedural houses, and the ROS maps "
                                      "of a folder")
    wl.add_argument("--maps", metavar="FOLDER", help="also every */map.yaml under this folder "
                                                     "(e.g. a folder of building maps); each "
                                                     "works wherever a world is asked for")
    wl.add_argument("--json", action="store_true", help="print the names as one JSON list")
    wl.set_defaults(func=cmd_world_list)
    wi = wsub.add_parser("info", help="summary of a world (catalogue name or map file)")
    wi.add_argument("world", help="catalogue name or map YAML/JSON")
    wi.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    wi.set_defaults(func=cmd_world_info)
    wp = wsub.add_parser("plot", help="top-down plot of a world")
    wp.add_argument("world", help="catalogue name or map YAML/JSON")
    wp.add_argument("--out", required=True, help="output image (PNG, PDF or SVG)")
    wp.add_argument("--astar", nargs=2, type=at.count0, metavar=("I", "J"),
                    help="also draw the A* path from place I to place J")
    add_force_option(wp)
    wp.set_defaults(func=cmd_world_plot)


    add_train_parser(sub)
    add_sparsify_parser(sub)

    add_map_parser(sub)

    bench = sub.add_parser("bench", help="speed and accuracy benchmarks of the components")
    bsub = at.subcommands(bench, dest="bench_command", metavar="BENCHMARK")
    bs = bsub.add_parser("sensors", help="camera/lidar throughput, VTK, depth parity")
    bs.add_argument("--world", default="test-0", help="catalogue name or map YAML/JSON")
    bs.add_argument("--batch", type=at.count, default=4096, help="poses per rendering batch")
    bs.add_argument("--vtk-poses", type=at.count, default=60,
                    help="poses rendered by Drake's VTK for the comparison")
    bs.add_argument("--seed", type=at.seed, default=0, help="seed of the random poses")
    bs.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    bs.set_defaults(func=cmd_bench_sensors)
    be = bsub.add_parser("expert", help="expert success, Drake real-time factor, batched speed, parity")
    be.add_argument("--pairs", type=at.count, default=500,
                    help="start-goal pairs for the success rates")
    be.add_argument("--batch", type=at.count, default=256, help="cars in the batched engine run")
    be.add_argument("--seed", type=at.seed, default=0, help="seed of the pairs and the noise")
    be.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    be.set_defaults(func=cmd_bench_expert)
    add_bench_parser(bsub)

    add_map_bench_parser(bsub)
    return p


def _welcome(parser) -> int:
    """Bare ``topodrake``: what it is, where to start and the workflow."""
    print(f"{parser.format_usage()}\n{DESCRIPTION}\n\n{WORKFLOW}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Run one command; returns its exit status (see :data:`WORKFLOW`)."""
    args = build_parser().parse_args(argv)
    configure_logging(args.log_level)
    try:
        return _run(args)
    finally:
        release_locks()        # the outputs this command locked


def _run(args) -> int:
    try:
        return args.func(args) or 0
    except TopodrakeError as e:
        print(f"topodrake: error: {e}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print("topodrake: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader went away (``topodrake world list | head``): stop quietly.
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except OSError as e:
        # a file that could not be read or written after the checks
        where = f"{e.filename}: " if e.filename else ""
        print(f"topodrake: error: {where}{e.strerror or e}", file=sys.stderr)
        return 2

if __name__ == "__main__":
    sys.exit(main())
