"""Command-line pieces of the learning package, for :mod:`topodrake.apps.cli` to mount.

``add_train_parser(sub)`` adds ``train waypoint`` / ``train reachability`` and ``add_bench_parser(bsub)``
adds ``networks`` under ``bench``::

    topodrake train waypoint --config configs/waypoint_camera_k5.yaml --out checkpoints/camera_k5
    topodrake train reachability --config configs/reach_camera_k5.yaml --out checkpoints/reach_camera_k5
    topodrake bench networks --json

Both commands raise :class:`~topodrake.errors.TopodrakeError` for bad input
(the CLI prints one line and exits 2).
"""

from __future__ import annotations

import json
from pathlib import Path

from topodrake.apps import argtypes as at
from topodrake.apps.outputs import (
    add_force_option,
    check_folder,
    check_output,
    check_output_folder,
    lock_output,
)
from topodrake.errors import TopodrakeError
from topodrake.experiments.bench_onpolicy import bench_follower, parse_controllers
from topodrake.experiments.waypoint_anatomy import bench_waypoint
from topodrake.learning.onpolicy.calibration import FollowerCalibrationConfig, calibrate_follower
from topodrake.learning.samples import collect_trajectories
from topodrake.learning.trajpack import pack_trajectories
from topodrake.topomap.embedding_eval import bench_place


def _check_folders(args, out=None) -> None:
    """The output folder (``out``, default ``--out``) and the data cache can
    be made and written, before any work."""
    check_output_folder(out or args.out)
    if getattr(args, "data", None):
        check_output_folder(args.data, option="--data")
    lock_output(out or args.out)


def _command(args, verb: str) -> str:
    command = f"topodrake train {verb} --config {args.config} --out {args.out}"
    if args.data != "data":
        command += f" --data {args.data}"
    for flag in ("max_minutes", "max_samples", "threads"):
        if getattr(args, flag) is not None:
            command += f" --{flag.replace('_', '-')} {getattr(args, flag)}"
    return command


def _apply_overrides(cfg, args):
    if args.max_minutes is not None:
        cfg.max_minutes = args.max_minutes
    if args.max_samples is not None:
        cfg.max_samples = args.max_samples
    if args.threads is not None:
        cfg.threads = args.threads
    return cfg


def _print_result(args, result) -> None:
    if args.json:
        print(json.dumps({"checkpoint": str(result.checkpoint), "samples_seen": result.samples_seen,
                          "wall_time_s": round(result.wall_time_s, 1),
                          "train_samples_per_s": round(result.train_samples_per_s, 1),
                          "metrics": result.metrics}))


def cmd_train_reachability(args) -> None:
    from topodrake.learning.reachability.train import load_reach_config, train_reachability

    _check_folders(args)
    cfg = _apply_overrides(load_reach_config(args.config), args)
    result = train_reachability(cfg, args.out, args.data, resume=not args.no_resume,
                                progress=not args.quiet, command=_command(args, "reachability"))
    _print_result(args, result)


def cmd_train_waypoint(args) -> None:
    from topodrake.learning.config import load_train_config
    from topodrake.learning.waypoint.train import train_waypoint

    _check_folders(args)
    cfg = _apply_overrides(load_train_config(args.config), args)
    result = train_waypoint(cfg, args.out, args.data, resume=not args.no_resume,
                            progress=not args.quiet, command=_command(args, "waypoint"))
    _print_result(args, result)


def add_train_parser(sub) -> None:
    """``train waypoint`` under the top-level subparsers ``sub``."""
    train = sub.add_parser("train", help="train the learned components")
    tsub = at.subcommands(train, dest="train_command")
    for verb, helptext, configs, func in (
            ("waypoint", "train C_WP (or the direct-control baseline) from a YAML config",
             "configs/waypoint_*.yaml", cmd_train_waypoint),
            ("reachability", "roll out a C_WP for labels and train its reachability estimator",
             "configs/reach_*.yaml", cmd_train_reachability)):
        tw = tsub.add_parser(verb, help=helptext)
        tw.add_argument("--config", required=True, help=f"training YAML (see {configs})")
        tw.add_argument("--out", required=True, help="output folder: checkpoint.pt and card.json")
        tw.add_argument("--data", default="data",
                        help="cache of demonstrations, sample sets and rollout labels")
        tw.add_argument("--no-resume", action="store_true",
                        help="refuse to continue an existing checkpoint in --out")
        tw.add_argument("--max-minutes", type=at.positive, help="override the config's time budget")
        tw.add_argument("--max-samples", type=at.count, help="override the config's sample budget")
        tw.add_argument("--threads", type=at.count0, help="torch / numba threads (0: all cores)")
        tw.add_argument("--quiet", action="store_true", help="no progress bar")
        tw.add_argument("--json", action="store_true", help="print the result as one JSON object")
        tw.set_defaults(func=func)
    tk = tsub.add_parser("pack-trajectories",
                         help="pack the expert drives of houses into one small file (for train scale)")
    tk.add_argument("--out", required=True, help="packed trajectories file (.npz)")
    tk.add_argument("--worlds", default="train-00..train-95,test-0..test-4",
                    help="houses, comma-separated; NAME-A..NAME-B for a numbered range")
    tk.add_argument("--data", default="data", help="cache of demonstrations (collected when missing)")
    tk.add_argument("--quiet", action="store_true", help="no progress bar")
    add_force_option(tk)
    tk.set_defaults(func=cmd_train_pack)
    tg = tsub.add_parser("scale", help="train a lidar C_WP at scale on a GPU: worker processes make "
                                       "samples while it trains")
    tg.add_argument("--config", required=True, help="scale YAML (see configs/scale_lidar_k5.yaml)")
    tg.add_argument("--out", required=True, help="output folder (resumed when it holds a checkpoint)")
    tg.add_argument("--minutes", type=at.positive, default=8.0, help="wall-time budget of this call")
    tg.add_argument("--quiet", action="store_true", help="no progress bar")
    tg.add_argument("--json", action="store_true", help="print the main network's card as JSON")
    tg.set_defaults(func=cmd_train_scale)
    td = tsub.add_parser("dagger", help="on-policy rounds of C_WP: follow chains, label the "
                                        "visited states with the expert, fine-tune")
    td.add_argument("--config", required=True, help="DAgger YAML (see configs/dagger_*.yaml)")
    td.add_argument("--out", required=True, help="output folder: rounds, dagger.json, best.pt")
    td.add_argument("--data", default="data", help="cache of demonstrations and sample sets")
    td.add_argument("--rounds", type=at.count, help="override the config's number of rounds")
    td.add_argument("--quiet", action="store_true", help="no progress output")
    td.add_argument("--json", action="store_true", help="print the rounds as one JSON object")
    td.set_defaults(func=cmd_train_dagger)
    tf = tsub.add_parser("follower-calibration",
                         help="calibrate RE on rollouts from the states the follower visits")
    tf.add_argument("--controller", "--cwp", dest="cwp", required=True, metavar="CHECKPOINT",
                    help="the C_WP followed, the one RE was trained for (checkpoint or "
                         "'registration')")
    tf.add_argument("--reach", "--re", dest="re", required=True, metavar="CHECKPOINT",
                    help="RE checkpoint; the calibration is written beside it "
                         "(follower_calibration.json)")
    tf.add_argument("--worlds", help="comma-separated training houses to follow chains in "
                                     "(default: train-84..train-91)")
    tf.add_argument("--drives", type=at.count, default=8, help="chains followed per house")
    tf.add_argument("--states", type=at.count, default=100, help="visited states rolled out per house")
    tf.add_argument("--seed", type=at.seed, default=0, help="seed of the chains, starts and states")
    tf.add_argument("--data", default="data", help="cache of demonstrations")
    tf.add_argument("--threads", type=at.count, default=1, help="torch threads")
    tf.add_argument("--quiet", action="store_true", help="no progress lines")
    tf.add_argument("--json", action="store_true", help="print the calibration as one JSON object")
    tf.set_defaults(func=cmd_train_follower_calibration)
    tp = tsub.add_parser("place", help="train the place embedding that ranks map vertices")
    tp.add_argument("config", help="training YAML (see configs/place_*.yaml)")
    tp.add_argument("--out", help="output folder (default: checkpoints/<config name>)")
    tp.add_argument("--data", default="data", help="cache of demonstrations")
    tp.add_argument("--quiet", action="store_true", help="no progress lines")
    tp.set_defaults(func=cmd_train_place)
    ts = tsub.add_parser("sptm", help="train the SPTM baseline's retrieval network")
    ts.add_argument("config", help="training YAML (see configs/sptm_retrieval.yaml)")
    ts.add_argument("--out", help="output folder (default: checkpoints/<config name>)")
    ts.add_argument("--data", default="data", help="cache of demonstrations")
    ts.add_argument("--quiet", action="store_true", help="no progress lines")
    ts.set_defaults(func=cmd_train_sptm)


def expand_worlds(spec: str) -> list[str]:
    """``train-00..train-03,test-0`` -> the named houses (ranges keep the digits' width)."""
    import re


    out = []
    for part in (p.strip() for p in spec.split(",") if p.strip()):
        if ".." not in part:
            out.append(part)
            continue
        a, b = part.split("..", 1)
        ma, mb = re.fullmatch(r"(.*?)(\d+)", a), re.fullmatch(r"(.*?)(\d+)", b)
        if not ma or not mb or ma.group(1) != mb.group(1) or int(mb.group(2)) < int(ma.group(2)):
            raise TopodrakeError(f"--worlds: {part!r} is not a range like train-00..train-95")
        width = len(ma.group(2))
        out += [f"{ma.group(1)}{i:0{width}d}" for i in range(int(ma.group(2)), int(mb.group(2)) + 1)]
    if not out:
        raise TopodrakeError("--worlds names no house")
    return out


def cmd_train_pack(args) -> None:
    check_output(args.out, "npz", force=args.force)
    check_output_folder(args.data, option="--data")
    lock_output(args.out)
    worlds = expand_worlds(args.worlds)
    trajs = collect_trajectories(worlds, Path(args.data) / "demos" / "pairs-s0",
                                 progress=not args.quiet)
    path = pack_trajectories(trajs, args.out)
    print(json.dumps({"file": str(path), "worlds": len(worlds), "drives": int(trajs.count),
                      "frames": int(len(trajs.poses)), "bytes": path.stat().st_size}))


def cmd_train_scale(args) -> None:
    from topodrake.learning.waypoint.scale import load_scale_config, train_at_scale

    _check_folders(args)
    run = load_scale_config(args.config)
    card = train_at_scale(run, args.out, minutes=args.minutes, progress=not args.quiet,
                          command=f"topodrake train scale --config {args.config} --out {args.out} "
                                  f"--minutes {args.minutes}")
    if args.json:
        print(json.dumps(card))


def cmd_train_dagger(args) -> None:
    import json
    import sys

    from topodrake.learning.onpolicy.dagger import load_dagger_config, run_dagger

    _check_folders(args)
    cfg = load_dagger_config(args.config)
    if args.rounds:
        cfg.rounds = args.rounds
        cfg.validate(f"config {args.config}")
    state = run_dagger(cfg, args.out, args.data, progress=not args.quiet,
                       command="topodrake " + " ".join(sys.argv[1:]))
    if args.json:
        print(json.dumps(state["rounds"]))
    else:
        for r in state["rounds"]:
            print(f"round {r['round']}: {r['states']} states in {len(r['worlds'])} houses, "
                  f"followed cover {r['followed_cover']:.3f}, val error "
                  f"{r['val_waypoint_error_m']:.3f} m")


def cmd_train_follower_calibration(args) -> None:
    check_folder(Path(args.re).parent, "--reach")
    check_output_folder(args.data, option="--data")
    import sys

    import torch


    torch.set_num_threads(args.threads)
    worlds = FollowerCalibrationConfig.worlds if args.worlds is None else \
        tuple(w for w in args.worlds.split(",") if w)
    cfg = FollowerCalibrationConfig(worlds, args.drives, args.states, args.seed)
    out = calibrate_follower(args.cwp, args.re, cfg, args.data, progress=not args.quiet,
                             command="topodrake " + " ".join(sys.argv[1:]))
    if args.json:
        print(json.dumps(out))
    else:
        print(f"follower calibration of {args.re}: Platt {out['follower_platt']} on "
              f"{out['states']} states (success {out['success_rate']:.3f}); ECE "
              f"{out['ece_anchor_platt']:.3f} under the anchor-hop calibration, "
              f"{out['ece_fitted']:.3f} fitted")


def cmd_train_place(args) -> None:
    from topodrake.topomap.embedding_train import load_place_config, train_place

    out = args.out or str(Path("checkpoints") / Path(args.config).stem)
    _check_folders(args, out)
    command = f"topodrake train place {args.config}" + (f" --out {args.out}" if args.out else "")
    if args.data != "data":
        command += f" --data {args.data}"
    result = train_place(load_place_config(args.config), out, args.data,
                         progress=not args.quiet, command=command)
    print(json.dumps({"checkpoint": str(result.checkpoint), "steps": result.steps,
                      "wall_time_s": round(result.wall_time_s, 1), "metrics": result.metrics}))


def cmd_train_sptm(args) -> None:
    from topodrake.baselines.train_retrieval import load_retrieval_config, train_retrieval

    out = args.out or str(Path("checkpoints") / Path(args.config).stem)
    _check_folders(args, out)
    command = f"topodrake train sptm {args.config}" + (f" --out {args.out}" if args.out else "")
    if args.data != "data":
        command += f" --data {args.data}"
    result = train_retrieval(load_retrieval_config(args.config), out, args.data,
                             progress=not args.quiet, command=command)
    print(json.dumps({"checkpoint": str(result.checkpoint), "steps": result.steps,
                      "wall_time_s": round(result.wall_time_s, 1), "metrics": result.metrics}))


def cmd_bench_networks(args) -> None:
    from topodrake.experiments.bench_learning import bench_networks

    cfg = None
    if args.config:
        from topodrake.learning.config import load_train_config
        cfg = load_train_config(args.config)
    _print_figures(args, bench_networks(cfg, args.world, args.batch, args.seconds, args.threads,
                                        args.seed))


def _print_figures(args, result: dict) -> None:
    if args.json:
        print(json.dumps(result))
    else:
        width = max(len(k) for k in result)
        for k, v in result.items():
            print(f"{k:<{width}}  {v}")


def cmd_bench_reachability(args) -> None:
    from topodrake.experiments.bench_learning import bench_reachability

    cfg = None
    if args.config:
        from topodrake.learning.reachability.train import load_reach_config
        cfg = load_reach_config(args.config)
    if args.controller:
        from topodrake.topomap.sources import check_controller

        check_controller(args.controller)
    _print_figures(args, bench_reachability(cfg, args.controller, args.world, args.pairs,
                                            args.label_pairs, args.seconds, args.threads, args.seed))


def add_bench_parser(bsub) -> None:
    """``networks`` under the ``bench`` subparsers ``bsub``."""
    bn = bsub.add_parser("networks", help="C_WP training and naive/cached inference throughput")
    bn.add_argument("--config", help="training YAML (default: the camera k=5 default profile)")
    bn.add_argument("--world", default="train-00", help="catalogue name or map YAML/JSON")
    bn.add_argument("--batch", type=at.count, default=64, help="samples per training batch")
    bn.add_argument("--seconds", type=at.positive, default=3.0, help="timing window per figure")
    bn.add_argument("--threads", type=at.count, default=1, help="torch threads")
    bn.add_argument("--seed", type=at.seed, default=0, help="seed of the samples and weights")
    bn.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    bn.set_defaults(func=cmd_bench_networks)
    br = bsub.add_parser("reachability", help="RE pair throughput (naive / cached) and label rollouts")
    br.add_argument("--config", help="RE training YAML (default: the camera k=5 profile)")
    br.add_argument("--controller", help="C_WP checkpoint for the label rollouts "
                                         "(default: an untrained network of the default profile)")
    br.add_argument("--world", default="test-0", help="catalogue name or map YAML/JSON")
    br.add_argument("--pairs", type=at.count, default=256, help="image pairs per RE batch")
    br.add_argument("--label-pairs", type=at.count, default=128,
                    help="pairs rolled out for the label throughput")
    br.add_argument("--seconds", type=at.positive, default=3.0, help="timing window per figure")
    br.add_argument("--threads", type=at.count, default=1, help="torch threads")
    br.add_argument("--seed", type=at.seed, default=0, help="seed of the pairs and weights")
    br.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    br.set_defaults(func=cmd_bench_reachability)
    bf = bsub.add_parser("follower", help="C_WP error and RE calibration on the states the "
                                          "follower visits in the test houses")
    bf.add_argument("--controllers", default="camera_k5,lidar_k5,lidar_k5_scale",
                    help="controllers to bench")
    bf.add_argument("--controller", "--cwp", dest="cwp", action="append",
                    metavar="NAME=CHECKPOINT",
                    help="bench another C_WP under NAME (with NAME's RE); repeatable")
    bf.add_argument("--reach", "--re", dest="re", action="append", metavar="NAME=CHECKPOINT",
                    help="with another RE under NAME, trained for NAME's (--controller) C_WP; "
                         "repeatable")
    bf.add_argument("--drives", type=at.count, default=8, help="chains followed per test house")
    bf.add_argument("--re-states", type=at.count, default=300,
                    help="visited states rolled out to score RE")
    bf.add_argument("--data", default="data", help="cache of demonstrations")
    bf.add_argument("--threads", type=at.count, default=1, help="torch threads")
    bf.add_argument("--seed", type=at.seed, default=0, help="seed of the chains, starts and noise")
    bf.add_argument("--quiet", action="store_true", help="no progress lines")
    bf.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    bf.set_defaults(func=cmd_bench_follower)
    bw = bsub.add_parser("waypoint", help="where C_WPs' validation error lies: by target distance, "
                                          "in the waypoint's length and its direction; paired")
    bw.add_argument("checkpoints", nargs="+", metavar="CHECKPOINT",
                    help="C_WP checkpoints (the first is the reference of the paired differences)")
    bw.add_argument("--worlds", default="test-0..test-4", help="houses the samples come from")
    bw.add_argument("--samples", type=at.count, default=6000, help="validation samples")
    bw.add_argument("--distance-max", type=at.positive, default=3.0,
                    help="farthest target along the drive (m)")
    bw.add_argument("--seed", type=at.seed, default=1, help="sample seed (1: the configs' validation)")
    bw.add_argument("--data", default="data", help="cache of demonstrations")
    bw.add_argument("--threads", type=at.count, default=1, help="torch threads")
    bw.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    bw.set_defaults(func=cmd_bench_waypoint)
    bp = bsub.add_parser("place", help="place-embedding recall@K against a thumbnail baseline, "
                                       "and search time at 100,000 vertices")
    bp.add_argument("--checkpoint", default="checkpoints/place_camera/checkpoint.pt",
                    help="place-embedding checkpoint")
    bp.add_argument("--world", default="test-0", help="catalogue name or map YAML/JSON")
    bp.add_argument("--data", default="data", help="cache of demonstrations")
    bp.add_argument("--reach", help="RE.pt:CWP.pt: also score recall against the vertices this "
                                    "RE passes (slow: exact RE on queries x database)")
    bp.add_argument("--re-queries", type=int, default=60, help="queries scored with --reach")
    bp.add_argument("--threads", type=at.count, default=1, help="torch threads")
    bp.add_argument("--seed", type=at.seed, default=0, help="seed of the sampled frames")
    bp.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    bp.set_defaults(func=cmd_bench_place)


def cmd_bench_follower(args) -> None:
    import json

    import torch


    torch.set_num_threads(args.threads)
    result = bench_follower(parse_controllers(args.controllers, args.cwp, args.re), data=args.data,
                            drives_per_world=args.drives, re_states=args.re_states,
                            seed=args.seed, progress=not args.quiet)
    if args.json:
        print(json.dumps(result))
        return
    for name, r in result.items():
        print(f"{name}: on-policy waypoint error {r['onpolicy_error_m']:.3f} m (validation "
              f"{r['val_error_m']}, ratio {r['error_ratio']}), RE ECE {r['re_ece']:.3f} AUROC "
              f"{r['re_auroc']:.3f} on {r['re_states']} states, followed cover "
              f"{r['followed_cover']:.3f}")
        for band, b in r["bands"].items():
            print(f"    {band:>6}: {b['share']:.2f} of states, error {b['error_m']} m, "
                  f"angle {b['angle_error_deg']} deg")


def cmd_bench_waypoint(args) -> None:
    import json

    import torch


    torch.set_num_threads(args.threads)
    result = bench_waypoint(args.checkpoints, expand_worlds(args.worlds), samples=args.samples,
                            distance_max_m=args.distance_max, seed=args.seed, data=args.data)
    if args.json:
        print(json.dumps(result))
        return
    for path, r in result["checkpoints"].items():
        print(f"{path}: error {r['error_m']} m (median {r['median_m']}, p90 {r['p90_m']}, "
              f"p98 {r['p98_m']}; worst tenth {r['worst_tenth_share']:.0%} of it); direction "
              f"{r['direction_error_m']} m, length {r['length_error_m']} m, angle "
              f"{r['angle_error_deg']} deg")
        for band, b in r["bands"].items():
            print(f"    {band:>9} m: {b['share']:.2f} of samples, error {b['error_m']} m, "
                  f"direction {b['direction_error_m']} m, length {b['length_error_m']} m")
        if "paired_to_first" in r:
            d = r["paired_to_first"]
            print(f"    paired to the first: {d['mean_m']:+.4f} m ({d['ci95_m'][0]:+.4f}.."
                  f"{d['ci95_m'][1]:+.4f})")


def cmd_bench_place(args) -> None:
    reach = None
    if args.reach:
        from topodrake.errors import TopodrakeError
        if ":" not in args.reach:
            raise TopodrakeError(f"--reach {args.reach!r} is not RE.pt:CWP.pt")
        reach = tuple(args.reach.split(":", 1))
    _print_figures(args, bench_place(args.checkpoint, args.world, args.data, args.seed,
                                     args.threads, reach, args.re_queries))
