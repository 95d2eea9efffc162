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

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from topodrake.demonstrations import load_demos
from topodrake.errors import TopodrakeError
from topodrake.experiments.hops import anchor_hop_success, share_made, sparsify_houses
from topodrake.experiments.scenarios import option
from topodrake.learning.samples import collect_trajectories
from topodrake.validate import check_count, check_probability, check_seed
from topodrake.world import load_world

#: the shipped REs the study compares by default (name=RE.pt:CWP.pt, comma-separated)
DEFAULT_ESTIMATORS = (
    "camera_k2=checkpoints/reach_camera_k2/checkpoint.pt:checkpoints/camera_k2/checkpoint.pt,"
    "camera_k5=checkpoints/reach_camera_k5/checkpoint.pt:checkpoints/camera_k5/checkpoint.pt,"
    "lidar_k5=checkpoints/reach_lidar_k5/checkpoint.pt:checkpoints/lidar_k5/checkpoint.pt")


@dataclass
class SparsifyStudy:
    """The sparsification study's settings: the test house and its drive
    (None: the longest), the REs (``name=RE.pt:CWP.pt``, comma-separated),
    p_sparsify, the noisy rollouts of each anchor hop (0: no check), their
    seed, the first drives of each of ``check_worlds`` also checked, the
    demonstration cache and the house's demonstration folder (None: its
    standard ones)."""

    world: str = option("test-0", "test house (its demonstrations must exist)")
    drive: int | None = option(None, "index among its successful drives (default: longest)")
    estimators: str = option(DEFAULT_ESTIMATORS, "name=RE.pt:CWP.pt, comma-separated")
    p: float = option(0.99, "p_sparsify")
    hop_runs: int = option(4, "noisy rollouts of each anchor hop (0: do not check the hops)")
    seed: int = option(0, "noise seeds of the hop rollouts")
    check_drives: int = option(0, "also check the hops of the first N drives of every "
                                  "--check-worlds house")
    check_worlds: list[str] = option([f"test-{i}" for i in range(5)],
                                     "comma-separated houses for --check-drives")
    data: str = option("data", "cache of demonstrations")
    demos: str | None = option(None, "demonstration folder of the world (default: "
                                     "DATA/demos/pairs-s0/WORLD)")

    def validate(self) -> "SparsifyStudy":
        """Check every field; a bad one raises a one-line TopodrakeError."""
        where = "sparsification scenario"
        if self.drive is not None:
            check_count(f"{where}: drive", self.drive, 0)
        check_probability(f"{where}: p", self.p)
        check_count(f"{where}: hop_runs", self.hop_runs, 0)
        check_seed(f"{where}: seed", self.seed)
        check_count(f"{where}: check_drives", self.check_drives, 0)
        return self


def pick_drive(lengths, drive: int | None) -> int:
    """``drive`` if given (checked), else the longest of the drives' ``lengths``."""
    if not len(lengths):
        raise TopodrakeError("no successful drives to sparsify")
    if drive is None:
        return int(np.argmax(lengths))
    if not 0 <= drive < len(lengths):
        raise TopodrakeError(f"--drive must be in 0..{len(lengths) - 1}")
    return drive


def _demo_folder(study: SparsifyStudy) -> Path:
    """The demonstration folder of the study's world: its ``demos``
    (checked), else its standard demonstrations, made once if missing."""
    if study.demos:
        folder = Path(study.demos)
        if not (folder / "manifest.json").is_file():
            raise TopodrakeError(f"no demonstrations in {folder}")
        return folder
    root = Path(study.data) / "demos" / "pairs-s0"
    collect_trajectories([study.world], root, progress=False)
    return root / study.world


def compare_estimators(study: SparsifyStudy, command: str) -> tuple[dict, object, np.ndarray]:
    """(the study's result document, the world, the drive's poses) for
    ``study``; ``command`` is recorded."""
    from topodrake.learning.reachability.estimator import Reachability, parse_estimators
    from topodrake.learning.waypoint.policy import LearnedWaypointPolicy

    if study.hop_runs < 0 or study.check_drives < 0:
        raise TopodrakeError("--hop-runs and --check-drives must be >= 0")
    if study.check_drives and not study.hop_runs:
        raise TopodrakeError("--check-drives needs --hop-runs >= 1")
    check_worlds = [w for w in study.check_worlds if w]
    check_root = Path(study.data) / "demos" / "pairs-s0"
    missing = [w for w in check_worlds if not (check_root / w / "manifest.json").is_file()]
    if study.check_drives and missing:   # the houses' standard demonstrations, made once
        collect_trajectories(missing, check_root, progress=False)
    estimators = parse_estimators(study.estimators)
    world = load_world(study.world)
    folder = _demo_folder(study)
    _, demos = load_demos(folder, successful_only=True)
    drive = pick_drive([len(d.poses) for d in demos], study.drive)
    poses = demos[drive].poses
    results = {}
    for name, (reach, controller) in estimators.items():
        re = Reachability.from_checkpoint(reach, controller)
        anchors = re.sparsify(re.observe(world, poses), p=study.p)
        results[name] = {"anchors": len(anchors), "keep_ratio": round(len(anchors) / len(poses), 4),
                         "anchor_frames": anchors.tolist()}
        if study.hop_runs:
            ok = anchor_hop_success(world, LearnedWaypointPolicy.from_checkpoint(controller), poses,
                                    anchors, runs=study.hop_runs, seed=study.seed)
            results[name]["hop_success"] = share_made(ok)
            results[name]["hop_successes"] = ok.sum(axis=1).tolist()
        if study.check_drives:
            results[name]["test_houses"] = sparsify_houses(
                re, check_worlds, check_root, study.p, drives=study.check_drives,
                policy=LearnedWaypointPolicy.from_checkpoint(controller), runs=study.hop_runs,
                seed=study.seed)
    return {
        "command": command,
        "world": study.world, "demos": str(folder), "drive": drive, "frames": len(poses),
        "p_sparsify": study.p, "hop_runs": study.hop_runs, "seed": study.seed,
        "check_drives": study.check_drives, "check_worlds": check_worlds if study.check_drives else [],
        "estimators": {k: {"reach": r, "controller": c} for k, (r, c) in estimators.items()},
        "results": results}, world, poses


def summarize(results: dict) -> dict:
    """The printed summary: each RE's anchors, keep ratio and hop figures."""
    return {k: {key: r[key] for key in ("anchors", "keep_ratio", "hop_success", "test_houses")
                if key in r} for k, r in results.items()}
