"""Expert demonstrations: generate, store, resume, load.

On disk a demonstration set is a folder::

    manifest.json       {"format": "topodrake-demos", "version": 2, "world": ...,
                         "config": {...}, "jobs": J, "chunk_size": C, "chunks": [...]}
    chunk-00000.npz     the drives of jobs [0, C)
    chunk-00001.npz     ...

Each chunk holds, for its drives concatenated along time, ``poses`` (sum K_i + 1, 3),
``controls`` and ``waypoints`` (sum K_i, 2), ``offsets`` (n + 1,) into the pose rows
(drive i has poses ``offsets[i]:offsets[i+1]``; its controls/waypoints are the
same rows minus i), plus per drive ``starts`` (n, 3), ``goals`` (n, 3),
``outcome`` (n,) (0 success, 1 collision, 2 timeout) and ``seeds`` (n,), and
``format``/``version`` tags. Images are not stored: render them from the poses
with :class:`topodrake.sensing.camera.Camera` (cheaper than disk).

Places are poses: the ``pairs`` protocol drives from one place's pose to
another's *pose* (the expert's final Reeds-Shepp approach,
:mod:`topodrake.expert.approach`, arrives at the place's heading), so a
drive's last views are its goal place's view. The ``random`` protocol's
goals are positions (heading NaN). Version 1 sets (goals were positions
everywhere) are refused.

Every file is written atomically, so an interrupted run resumes from the last
complete chunk; a folder of another format or version is refused.
"""

from __future__ import annotations

import io
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_bytes, atomic_write_json, read_tagged_npz
from topodrake.fileio import read_manifest as _read_manifest
from topodrake.montecarlo import trial_seeds
from topodrake.rollout import ExpertRollout, RolloutConfig
from topodrake.world import load_world
from topodrake.world.catalogue import same_world

FORMAT = "topodrake-demos"
VERSION = 2
#: the arrays every chunk holds
CHUNK_ARRAYS = ("poses", "controls", "waypoints", "offsets", "starts", "goals", "outcome", "seeds")


@dataclass
class CollectConfig:
    protocol: str = "pairs"       # "pairs": all ordered pairs of the places; "random"
    count: int = 100              # drives for the random protocol
    seed: int = 0
    noise_std: float = 0.0
    min_distance_m: float = 2.0   # random protocol: start-goal distance at least this
    t_max_s: float = 150.0
    chunk_size: int = 32


def plan_jobs(world, config: CollectConfig) -> tuple[np.ndarray, np.ndarray]:
    """Deterministic (starts (J, 3), goals) for a protocol: goal poses (J, 3)
    for ``pairs``, goal positions (J, 2) for ``random``."""
    if config.protocol == "pairs":
        p = world.places
        pairs = [(i, j) for i in range(len(p)) for j in range(len(p)) if i != j]
        return (np.array([p[i] for i, _ in pairs]).reshape(-1, 3),
                np.array([p[j] for _, j in pairs]).reshape(-1, 3))
    if config.protocol == "random":
        rng = np.random.default_rng(config.seed)
        starts, goals = [], []
        while len(starts) < config.count:
            s = world.sample_free_pose(rng)
            g = world.sample_free_pose(rng)
            if np.hypot(*(s[:2] - g[:2])) >= config.min_distance_m:
                starts.append(s)
                goals.append(g[:2])
        return np.array(starts), np.array(goals)
    raise TopodrakeError(f"unknown protocol {config.protocol!r} (pairs or random)")


def collect(world_spec: str, out_dir, config: CollectConfig | None = None,
            progress: bool = True) -> Path:
    """Generate (or resume) a demonstration set; returns its folder."""
    from tqdm import tqdm


    config = config or CollectConfig()
    out = Path(out_dir)
    world = load_world(world_spec)
    starts, goals = plan_jobs(world, config)
    seeds = np.array(trial_seeds(config.seed, len(starts)), np.int64)
    manifest = {"format": FORMAT, "version": VERSION, "world": world_spec,
                "world_name": world.name, "config": asdict(config), "jobs": len(starts),
                "chunk_size": config.chunk_size, "chunks": []}
    if (out / "manifest.json").exists():
        old = read_manifest(out)
        if _comparable(old["config"]) != _comparable(manifest["config"]) \
                or not same_world(old["world"], world_spec):
            raise TopodrakeError(
                f"{out} holds demonstrations of another world or config; use a new folder")
        manifest["chunks"] = old["chunks"]
    engine = ExpertRollout(world, RolloutConfig(noise_std=config.noise_std, t_max_s=config.t_max_s))
    n_chunks = -(-len(starts) // config.chunk_size)
    done = set(manifest["chunks"])
    bar = tqdm(total=len(starts), desc=f"collect {world.name}", disable=not progress, unit="drive")
    bar.update(sum(min(config.chunk_size, len(starts) - c * config.chunk_size)
                   for c in range(n_chunks) if _chunk_name(c) in done))
    outcomes = []
    for c in range(n_chunks):
        name = _chunk_name(c)
        if name in done:
            continue
        sl = slice(c * config.chunk_size, min((c + 1) * config.chunk_size, len(starts)))
        res = engine.run(starts[sl], goals[sl], seeds=seeds[sl])
        _write_chunk(out / name, res, starts[sl], goals[sl], seeds[sl])
        outcomes.append(res.outcome)
        manifest["chunks"].append(name)
        atomic_write_json(out / "manifest.json", manifest)
        bar.update(sl.stop - sl.start)
    bar.close()
    if not manifest["chunks"]:
        atomic_write_json(out / "manifest.json", manifest)
    return out


def _comparable(config: dict) -> dict:
    """The settings that make two collections the same (``count`` means
    nothing to the pairs protocol)."""
    return {k: v for k, v in config.items() if not (k == "count" and config.get("protocol") == "pairs")}


def _chunk_name(c: int) -> str:
    return f"chunk-{c:05d}.npz"


def _write_chunk(path: Path, res, starts, goals, seeds) -> None:
    trajs = [res.trajectory(i) for i in range(len(starts))]
    offsets = np.zeros(len(trajs) + 1, np.int64)
    offsets[1:] = np.cumsum([len(t["poses"]) for t in trajs])
    buf = io.BytesIO()
    np.savez_compressed(
        buf, format=np.array(FORMAT), version=np.array(VERSION),
        poses=np.concatenate([t["poses"] for t in trajs]).astype(np.float64),
        controls=np.concatenate([t["controls"] for t in trajs]).reshape(-1, 2),
        waypoints=np.concatenate([t["waypoints"] for t in trajs]).reshape(-1, 2),
        offsets=offsets, starts=starts, goals=_goal_poses(goals), outcome=res.outcome.astype(np.int8),
        seeds=np.asarray(seeds, np.int64))
    atomic_write_bytes(path, buf.getvalue())


def _goal_poses(goals) -> np.ndarray:
    """Goals as (n, 3) poses; position goals get a NaN heading."""
    goals = np.asarray(goals, np.float64)
    if goals.shape[1] == 3:
        return goals
    return np.column_stack([goals, np.full(len(goals), np.nan)])


def read_manifest(folder) -> dict:
    return _read_manifest(folder, FORMAT, VERSION, "a demonstration set",
                          ("world", "config", "jobs", "chunks"))


@dataclass
class Demonstration:
    poses: np.ndarray      # (K + 1, 3)
    controls: np.ndarray   # (K, 2)
    waypoints: np.ndarray  # (K, 2)
    start: np.ndarray
    goal: np.ndarray       # (3,) pose; heading NaN where the goal was a position
    outcome: int
    seed: int

    @property
    def success(self) -> bool:
        return self.outcome == 0


def load_demos(folder, successful_only: bool = False) -> tuple[dict, list[Demonstration]]:
    """(manifest, drives) of a demonstration folder; bad files are refused."""
    folder = Path(folder)
    m = read_manifest(folder)
    drives: list[Demonstration] = []
    for name in m["chunks"]:
        path = folder / name
        if not path.is_file():
            raise TopodrakeError(f"{path} is listed in the manifest but missing")
        d = read_tagged_npz(path, FORMAT, VERSION, "demonstration chunk")
        lacking = set(CHUNK_ARRAYS) - set(d)
        if lacking:
            raise TopodrakeError(f"{path} is corrupt or not a demonstration chunk (no "
                                 f"{', '.join(sorted(lacking))})")
        off = d["offsets"]
        for i in range(len(off) - 1):
            a, b = off[i], off[i + 1]
            drive = Demonstration(d["poses"][a:b], d["controls"][a - i:b - i - 1],
                                  d["waypoints"][a - i:b - i - 1], d["starts"][i], d["goals"][i],
                                  int(d["outcome"][i]), int(d["seeds"][i]))
            if drive.success or not successful_only:
                drives.append(drive)
    return m, drives


def demo_poses(world_name: str, data_dir, protocol: str = "pairs", seed: int = 0,
               progress: bool = False) -> list[np.ndarray]:
    """Pose arrays of every drive of a house's demonstrations (collected into
    ``data_dir/demos/<protocol>-s<seed>/<world>`` once, reused afterwards)."""
    folder = Path(data_dir) / "demos" / f"{protocol}-s{seed}" / world_name
    collect(world_name, folder, CollectConfig(protocol=protocol, seed=seed), progress=progress)
    return [d.poses for d in load_demos(folder)[1]]
