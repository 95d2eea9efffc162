"""The ``topodrake`` command line.

Every bad input ends in one line on stderr (``topodrake: error: ...``) and
exit status 2; see :mod:`topodrake.errors`.
"""

from __future__ import annotations

import argparse
import json
import sys

from topodrake.errors import TopodrakeError


def _print_result(result: dict, as_json: bool) -> None:
    if as_json:
        print(json.dumps(result))
        return
    width = max(len(k) for k in result)
    for k, v in result.items():
        if isinstance(v, float):
            v = f"{v:,.4g}"
        print(f"{k:<{width}}  {v}")


def cmd_demo(args) -> None:
    from topodrake.demo import render_house_demo

    files = render_house_demo(args.world, args.out)
    for what, path in files.items():
        print(f"wrote {what}: {path}")


def cmd_world_list(args) -> None:
    from topodrake.world.catalogue import catalogue_names

    names = catalogue_names()
    if args.json:
        print(json.dumps(names))
    else:
        print("\n".join(names))


def cmd_world_info(args) -> None:
    from topodrake.world import load_world

    info = load_world(args.world).info()
    if args.json:
        print(json.dumps(info))
    else:
        for k, v in info.items():
            print(f"{k:<14} {v}")


def cmd_world_plot(args) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from topodrake.world import load_world
    from topodrake.world.plot import plot_world, save_figure

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


def cmd_bench_sensors(args) -> None:
    from topodrake.bench import bench_sensors

    _print_result(bench_sensors(args.world, args.batch, args.vtk_poses, args.seed), args.json)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="topodrake", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="render a house: plan, camera and lidar views")
    demo.add_argument("--world", default="test-0")
    demo.add_argument("--out", default="out/demo", help="output folder")
    demo.set_defaults(func=cmd_demo)

    world = sub.add_parser("world", help="list, inspect and plot worlds")
    wsub = world.add_subparsers(dest="world_command", required=True)
    wl = wsub.add_parser("list", help="the catalogue of procedural houses")
    wl.add_argument("--json", action="store_true")
    wl.set_defaults(func=cmd_world_list)
    wi = wsub.add_parser("info", help="summary of a world (catalogue name or map file)")
    wi.add_argument("world")
    wi.add_argument("--json", action="store_true")
    wi.set_defaults(func=cmd_world_info)
    wp = wsub.add_parser("plot", help="top-down plot of a world")
    wp.add_argument("world")
    wp.add_argument("--out", required=True)
    wp.add_argument("--astar", nargs=2, type=int, metavar=("I", "J"),
                    help="also draw the A* path from place I to place J")
    wp.set_defaults(func=cmd_world_plot)

    bench = sub.add_parser("bench", help="benchmarks that print the issues' figures")
    bsub = bench.add_subparsers(dest="bench_command", required=True)
    bs = bsub.add_parser("sensors", help="camera/lidar throughput, VTK, depth parity")
    bs.add_argument("--world", default="test-0")
    bs.add_argument("--batch", type=int, default=4096)
    bs.add_argument("--vtk-poses", type=int, default=60)
    bs.add_argument("--seed", type=int, default=0)
    bs.add_argument("--json", action="store_true")
    bs.set_defaults(func=cmd_bench_sensors)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except TopodrakeError as e:
        print(f"topodrake: error: {e}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print("topodrake: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
