"""``topodrake sparsify``: anchors of one expert drive under a trained RE.

    topodrake sparsify test-0 --reach checkpoints/reach_camera_k5/checkpoint.pt \\
        --controller checkpoints/camera_k5/checkpoint.pt --drive 3 --plot anchors.png --json

Reads the world's demonstrations (``topodrake collect``; default folder
``data/demos/pairs-s0/WORLD``), renders the drive's observations, keeps
anchors greedily while RE > ``--p`` and prints the anchor count and keep
ratio (and plots them on the floor plan with ``--plot``). ``--hop-runs N``
also drives every anchor hop N times with the controller and actuation
noise (:mod:`topodrake.experiments.hops`) and prints the share it made.
"""

from __future__ import annotations

import json

from topodrake.apps import argtypes as at
from topodrake.apps.outputs import add_force_option, check_output, lock_output
from topodrake.demonstrations import load_demos
from topodrake.errors import TopodrakeError
from topodrake.topomap.sources import check_controller, demo_folder
from topodrake.world import load_world


def cmd_sparsify(args) -> None:
    check_output(args.plot, "image", force=args.force, option="--plot")
    check_controller(args.controller, args.reach)
    from topodrake.learning.reachability.estimator import Reachability

    world = load_world(args.world)
    folder = demo_folder(args.world, args.demos)
    if not (folder / "manifest.json").is_file():
        raise TopodrakeError(f"no demonstrations in {folder}; make them with "
                             f"'topodrake collect {args.world} --out {folder}'")
    _, demos = load_demos(folder, successful_only=True)
    if not 0 <= args.drive < len(demos):
        raise TopodrakeError(f"--drive must be in 0..{len(demos) - 1} ({folder} has "
                             f"{len(demos)} successful drives)")
    poses = demos[args.drive].poses
    lock_output(args.plot, "--plot")
    re = Reachability.from_checkpoint(args.reach, args.controller)
    anchors = re.sparsify(re.observe(world, poses), p=args.p)
    result = {"world": args.world, "drive": args.drive, "frames": len(poses),
              "anchors": len(anchors), "keep_ratio": round(len(anchors) / len(poses), 4),
              "p_sparsify": args.p, "anchor_frames": anchors.tolist()}
    if args.hop_runs:
        from topodrake.experiments.hops import anchor_hop_success, share_made
        from topodrake.learning.waypoint.policy import LearnedWaypointPolicy

        ok = anchor_hop_success(world, LearnedWaypointPolicy.from_checkpoint(args.controller),
                                poses, anchors, runs=args.hop_runs, seed=args.seed)
        result["hop_success"] = share_made(ok)
    if args.json:
        print(json.dumps(result), flush=True)
    else:
        hops = (f", hops made {result['hop_success']:.3f}"
                if result.get("hop_success") is not None else "")
        print(f"{len(anchors)} anchors of {len(poses)} frames "
              f"(keep ratio {result['keep_ratio']:.3f}{hops})", flush=True)
    if args.plot:
        from topodrake.apps.outputs import write_kept
        from topodrake.topomap.plot import plot_anchors

        title = f"{re.name or 'RE'}: {len(anchors)} anchors of {len(poses)} frames (p = {args.p})"
        write_kept(args.plot, lambda p: plot_anchors(world, poses, anchors, p, title=title),
                   "the plot")
        if not args.json:
            print(f"wrote {args.plot}")


def add_sparsify_parser(sub) -> None:
    sp = sub.add_parser("sparsify", help="anchors of one expert drive under a trained RE")
    sp.add_argument("world", help="catalogue name or map file")
    sp.add_argument("--reach", required=True, help="RE checkpoint")
    sp.add_argument("--controller", required=True, help="the C_WP checkpoint RE was trained for")
    sp.add_argument("--demos", help="demonstration folder (default data/demos/pairs-s0/WORLD)")
    sp.add_argument("--drive", type=at.count0, default=0, help="index among the successful drives")
    sp.add_argument("--p", type=at.probability, default=0.99,
                    help="p_sparsify: a hop extends while RE stays above it")
    sp.add_argument("--hop-runs", type=at.count0, default=0,
                    help="check each anchor hop with N noisy closed-loop rollouts")
    sp.add_argument("--seed", type=at.seed, default=0, help="noise seeds of the hop rollouts")
    sp.add_argument("--plot", "--out", dest="plot", metavar="PNG",
                    help="draw the anchors on the floor plan into this image")
    sp.add_argument("--json", action="store_true", help="print the result as one JSON object")
    add_force_option(sp)
    sp.set_defaults(func=cmd_sparsify)
