"""One expert drive sparsified by several REs (the sparsification study).

:func:`compare_estimators` reduces the same test-house drive (the longest,
or the one asked for: :func:`pick_drive`) to anchors once per RE and, where
asked, drives every anchor hop with the RE's controller
(:func:`topodrake.experiments.hops.anchor_hop_success`) and checks the first
drives of every test house (:func:`topodrake.experiments.hops.sparsify_houses`);
it returns the study's result document, with the world and the drive's
poses its figure draws.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from topodrake.errors import TopodrakeError


def pick_drive(lengths, drive: int | None) -> int:
    """``drive`` if given (checked), else the longest of the drives' ``lengths``."""
    if not len(lengths):
        raise TopodrakeError("no successful drives to sparsify")
    if drive is None:
        return int(np.argmax(lengths))
    if not 0 <= drive < len(lengths):
        raise TopodrakeError(f"--drive must be in 0..{len(lengths) - 1}")
    return drive


def _demo_folder(args) -> Path:
    """The demonstration folder of ``args.world``: ``args.demos`` (checked),
    else its standard demonstrations, made once if missing."""
    from topodrake.learning.samples import collect_trajectories

    if args.demos:
        folder = Path(args.demos)
        if not (folder / "manifest.json").is_file():
            raise TopodrakeError(f"no demonstrations in {folder}")
        return folder
    root = Path(args.data) / "demos" / "pairs-s0"
    collect_trajectories([args.world], root, progress=False)
    return root / args.world


def compare_estimators(args, command: str) -> tuple[dict, object, np.ndarray]:
    """(the study's result document, the world, the drive's poses) for its
    options ``args`` (world, drive, estimators, p, hop runs, seed, check
    drives and worlds, data, demos); ``command`` is recorded."""
    from topodrake.demonstrations import load_demos
    from topodrake.learning.reachability.estimator import Reachability, parse_estimators
    from topodrake.learning.samples import collect_trajectories
    from topodrake.learning.waypoint.policy import LearnedWaypointPolicy
    from topodrake.experiments.hops import anchor_hop_success, share_made, sparsify_houses
    from topodrake.world import load_world

    if args.hop_runs < 0 or args.check_drives < 0:
        raise TopodrakeError("--hop-runs and --check-drives must be >= 0")
    if args.check_drives and not args.hop_runs:
        raise TopodrakeError("--check-drives needs --hop-runs >= 1")
    check_worlds = [w for w in args.check_worlds.split(",") if w]
    check_root = Path(args.data) / "demos" / "pairs-s0"
    missing = [w for w in check_worlds if not (check_root / w / "manifest.json").is_file()]
    if args.check_drives and missing:   # the houses' standard demonstrations, made once
        collect_trajectories(missing, check_root, progress=False)
    estimators = parse_estimators(args.estimators)
    world = load_world(args.world)
    folder = _demo_folder(args)
    _, demos = load_demos(folder, successful_only=True)
    drive = pick_drive([len(d.poses) for d in demos], args.drive)
    poses = demos[drive].poses
    results = {}
    for name, (reach, controller) in estimators.items():
        re = Reachability.from_checkpoint(reach, controller)
        anchors = re.sparsify(re.observe(world, poses), p=args.p)
        results[name] = {"anchors": len(anchors), "keep_ratio": round(len(anchors) / len(poses), 4),
                         "anchor_frames": anchors.tolist()}
        if args.hop_runs:
            ok = anchor_hop_success(world, LearnedWaypointPolicy.from_checkpoint(controller), poses,
                                    anchors, runs=args.hop_runs, seed=args.seed)
            results[name]["hop_success"] = share_made(ok)
            results[name]["hop_successes"] = ok.sum(axis=1).tolist()
        if args.check_drives:
            results[name]["test_houses"] = sparsify_houses(
                re, check_worlds, check_root, args.p, drives=args.check_drives,
                policy=LearnedWaypointPolicy.from_checkpoint(controller), runs=args.hop_runs,
                seed=args.seed)
    return {
        "command": command,
        "world": args.world, "demos": str(folder), "drive": drive, "frames": len(poses),
        "p_sparsify": args.p, "hop_runs": args.hop_runs, "seed": args.seed,
        "check_drives": args.check_drives, "check_worlds": check_worlds if args.check_drives else [],
        "estimators": {k: {"reach": r, "controller": c} for k, (r, c) in estimators.items()},
        "results": results}, world, poses


def summarize(results: dict) -> dict:
    """The printed summary: each RE's anchors, keep ratio and hop figures."""
    return {k: {key: r[key] for key in ("anchors", "keep_ratio", "hop_success", "test_houses")
                if key in r} for k, r in results.items()}
