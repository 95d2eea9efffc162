"""The planning study's map cache: demonstrations and maps per house.

Every house's expert drives between all ordered pairs of its places
(``topodrake collect``, seed :data:`DEMO_SEED`) are collected once into
``DATA/demos/pairs-s0/`` (:func:`house_drives`); a map of a subset of them
for one map kind is built once and kept in ``DATA/planning/``
(:func:`get_map`), keyed by house, modality, scorer, demonstration seed and
subset (:func:`map_path`). A map built elsewhere from the same drives with
the default config (``topodrake map build``) is adopted instead of rebuilt.
"""

from __future__ import annotations

import json
import shutil
import sys
import time
import zlib
from dataclasses import asdict
from pathlib import Path

from topodrake.demonstrations import CollectConfig, collect, load_demos
from topodrake.errors import TopodrakeError
from topodrake.sensing.observe import camera_scans, lidar_scans
from topodrake.topomap.build import build_map
from topodrake.topomap.graph import PLAN_ONLY, MapConfig, TopoMap, map_settings, same_config
from topodrake.topomap.mapfile import check_identity, load_map, read_map_meta, save_map
from topodrake.topomap.retrieval import default_embedding
from topodrake.topomap.sources import demo_folder, drive_observations, make_scorer

DEMO_SEED = 0           # the demonstrations: all ordered place pairs, seed 0 (noise-free)


def house_key(spec: str) -> str:
    """A world's name in caches and results: the catalogue name, or a map
    file's folder and stem (as ``topodrake collect`` names its demos)."""
    return demo_folder(spec).name


def house_drives(spec: str, data: Path, progress: bool) -> list:
    """The successful demonstrations of all ordered place pairs (collected once)."""
    folder = data / "demos" / f"pairs-s{DEMO_SEED}" / house_key(spec)
    collect(spec, folder, CollectConfig(protocol="pairs", seed=DEMO_SEED), progress=progress)
    _, drives = load_demos(folder, successful_only=True)
    if not drives:
        raise TopodrakeError(f"{folder} holds no successful drive")
    return drives


def config_tag(tag: str, config, modality: str = "lidar") -> str:
    """``tag`` for a map of the default config; with a digest of ``config``
    appended for any other, so that each config keeps its own maps. A map
    of a ``modality`` other than lidar ignores the lidar-only settings, and
    a pose oracle map the ones only maps with scans read."""
    kind = _kind(modality)
    if config is None or same_config(config.flat(), MapConfig(), **kind):
        return tag
    settings = map_settings(config.flat(), **kind)
    return f"{tag}-cfg{zlib.crc32(json.dumps(settings, sort_keys=True).encode()):08x}"


def _kind(modality: str) -> dict:
    """What a map of ``modality`` is, as :func:`~topodrake.topomap.graph.map_settings` asks."""
    return {"lidar": modality in ("lidar", "lidar_reg"), "scans": modality != "oracle"}


def map_path(data: Path, key: str, modality: str, tag: str) -> Path:
    if modality == "oracle":        # keyed by the oracle's parameters, which may change
        from topodrake.topomap.scorer import OracleConfig

        digest = zlib.crc32(json.dumps(asdict(OracleConfig()), sort_keys=True).encode())
        return data / "planning" / f"{key}-pose-oracle{digest:08x}-demos{DEMO_SEED}-{tag}.tdmap"
    return data / "planning" / f"{key}-{modality}-re-demos{DEMO_SEED}-{tag}.tdmap"


def _adoptable(candidate: Path, world: str, modality: str, names: list[str]) -> bool:
    """Whether a map built elsewhere (``topodrake map build`` or the map
    scalability study) is this very map: same world, modality, default
    config and the same drives in the same order."""
    try:
        meta = read_map_meta(candidate)
    except TopodrakeError:
        return False
    return (meta.get("world") == world and meta.get("modality") == modality
            and same_config(meta.get("config"), MapConfig(), **_kind(modality))
            and [t["name"] for t in meta.get("trajectories", [])] == names)


def get_map(spec: str, world, modality: str, drives: list, indices, data: Path, tag: str,
            progress: bool, config=None):
    """The map of ``drives[indices]`` for ``modality`` built with ``config``
    (a MapConfig; default: the library's defaults), cached: built when
    missing, each config under its own name (:func:`config_tag`)."""
    config = config or MapConfig()
    key = house_key(spec)
    path = map_path(data, key, modality, config_tag(tag, config, modality))
    scorer = make_scorer(modality, world)
    names = [f"pairs-s{DEMO_SEED}/{i}" for i in indices]
    legacy = data / "maps" / f"{key}-{modality}.tdmap"
    if not path.is_file() and modality != "oracle" and legacy.is_file() \
            and config_tag(tag, config, modality) == tag \
            and _adoptable(legacy, spec, modality, names):
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        shutil.copyfile(legacy, tmp)
        tmp.replace(path)
    if path.is_file() and not _same_identity(path, scorer):
        print(f"{path} was built for another reachability estimator or controller; rebuilding it",
              file=sys.stderr)
    elif path.is_file():
        m = load_map(path, scorer)
        if [t.name for t in m.trajectories] != names:
            raise TopodrakeError(f"{path} holds other drives than {len(names)} of "
                                 f"{key}; delete it to rebuild")
        # the config as written (settings a map predates read as LATER_DEFAULTS)
        same = same_config(read_map_meta(path).get("config"), config, **_kind(modality))
        scanned = m.modality == "lidar" or m.bank.scans is not None
        if same and scanned:
            # planning settings are the caller's, not the file's
            m.config = m.config.updated(**{k: config.flat()[k] for k in PLAN_ONLY})
            return m, 0.0
        why = "with another map config" if not same else \
            "before camera and pose oracle maps kept their lidar scans"
        print(f"{path} was built {why}; rebuilding it", file=sys.stderr)

    t0 = time.perf_counter()
    m = TopoMap(scorer, default_embedding(scorer.observation), config, world=spec)
    # a pose oracle map keeps its drives' scans too: the route tracker's scan
    # fixes, which the learned maps give it, so perfect perception has them
    items = [(drive_observations(world, scorer, drives[i].poses), drives[i].poses, n,
              lidar_scans(world, drives[i].poses))
             for i, n in zip(indices, names)] if modality == "oracle" else \
        _Lazy(world, scorer, drives, indices, names)
    build_map(m, items, progress=progress, desc=f"map {key} {modality} {tag}")
    save_map(m, path)
    return m, time.perf_counter() - t0


def _same_identity(path: Path, scorer) -> bool:
    """Whether the cached map at ``path`` was built with ``scorer``'s RE and
    controller (a retrained checkpoint under the same path makes it stale)."""
    try:
        check_identity(path, read_map_meta(path), scorer.identity)
    except TopodrakeError:
        return False
    return True


class _Lazy:
    """Drives' observations rendered one at a time (with a length, for tqdm)."""
    def __init__(self, world, scorer, drives, indices, names):
        self.parts = world, scorer, drives, list(indices), names

    def __len__(self):
        return len(self.parts[3])

    def __iter__(self):
        world, scorer, drives, indices, names = self.parts
        for i, n in zip(indices, names):
            poses = drives[i].poses
            yield (drive_observations(world, scorer, poses), poses, n,
                   camera_scans(world, scorer.observation, poses))
