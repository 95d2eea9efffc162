"""A map build that times each drive and keeps its progress.

:class:`MapBuild` adds drives to a map one by one, times each (rendering
and adding), and saves the map so far beside the output (:func:`resume_file`)
at most every :attr:`MapBuild.save_every_s` seconds;
:func:`interrupted_build` reads such a file back when a build of the same
map starts again, so that it resumes where it stopped. Each build keeps its
own file, named by the places it maps, its world, settings, estimators and
demonstrations (:func:`build_key`): a build of other places or settings
leaves another's interrupted build where it is (:func:`other_partials`).
"""

from __future__ import annotations

import glob
import hashlib
import json
import time
from pathlib import Path

from topodrake.errors import TopodrakeError
from topodrake.sensing.observe import camera_scans
from topodrake.topomap.build import BuildStats, build_map
from topodrake.topomap.mapfile import identity_essence, load_map, read_map_meta, save_map
from topodrake.topomap.sources import drive_observations


def resume_file(out, key: str = "") -> Path:
    """Where the build of map file ``out`` keyed ``key`` (:func:`build_key`)
    keeps its progress: ``.NAME.KEY.partial`` beside it."""
    out = Path(out)
    return out.with_name(f".{out.name}.{key}.partial" if key else f".{out.name}.partial")


def build_key(places, topomap, demos) -> str:
    """A build's key: the places it maps (``all``, or ``places-4-5-9``) and a
    hash of the map's world, settings, estimators and the demonstrations
    folder, so that builds of other drives keep their own progress."""
    where = "all" if places is None else "places-" + "-".join(map(str, sorted(set(places))))
    what = json.dumps({"world": topomap.world, "config": topomap.config.flat(),
                       "identity": identity_essence(topomap.identity),
                       "demos": str(Path(demos).resolve())}, sort_keys=True, default=str)
    return f"{where}.{hashlib.sha1(what.encode()).hexdigest()[:8]}"


def other_partials(out, mine: Path) -> list[Path]:
    """The interrupted builds beside map file ``out`` other than ``mine``."""
    out = Path(out)
    return sorted(p for p in out.parent.glob(f".{glob.escape(out.name)}.*partial")
                  if p.name != Path(mine).name)


def interrupted_build(resume: Path, scorer, fresh):
    """The interrupted build in ``resume`` when it is one of the same world,
    config and estimators as ``fresh`` and holds its drives; else None."""
    if not resume.is_file():
        return None
    try:
        meta = read_map_meta(resume)
        if meta.get("world") != fresh.world or meta.get("config") != fresh.config.flat():
            return None
        partial = load_map(resume, scorer)
    except TopodrakeError:
        return None
    have = {t.name for t in partial.trajectories}
    return partial if {t.name for t in fresh.trajectories} <= have else None


class MapBuild:
    """Drives added to a map one by one; each drive's time (rendering and
    adding) is kept, and the map so far is saved beside the output at most
    every :attr:`save_every_s` seconds, so that an interrupted build resumes."""
    save_every_s = 30.0

    def __init__(self, topomap, world, folder, drives, names, todo, resume: Path, resumed: int):
        self.topomap, self.world, self.folder = topomap, world, folder
        self.drives, self.names, self.todo = drives, names, todo
        self.resume, self.resumed = resume, resumed
        self.drive_s: list[float] = []

    def save(self, path) -> None:
        save_map(self.topomap, path)

    def _items(self):
        saved = time.perf_counter()
        scorer = self.topomap.scorer
        for i in self.todo:
            t = time.perf_counter()
            poses = self.drives[i].poses
            yield (drive_observations(self.world, scorer, poses), poses, self.names[i],
                   camera_scans(self.world, scorer.observation, poses))
            self.drive_s.append(time.perf_counter() - t)    # resumed once the drive is added
            if time.perf_counter() - saved >= self.save_every_s and i != self.todo[-1]:
                try:
                    self.save(self.resume)
                except OSError:
                    pass                                    # the final write says what failed
                saved = time.perf_counter()

    def run(self, progress: bool = True):
        """Add the drives; returns the build's stats."""
        if not self.todo:
            return BuildStats()
        return build_map(self.topomap, _Sized(self._items(), len(self.todo)), progress=progress,
                         desc=f"map {self.world.name}")


class _Sized:
    """An iterator with a length (for the progress bar)."""
    def __init__(self, items, n):
        self.items, self.n = items, n

    def __iter__(self):
        return iter(self.items)

    def __len__(self):
        return self.n
