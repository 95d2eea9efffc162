"""Maps of part of a house's drives: does a plan know what its map covers?

A map built from the drives between a seeded subset of a house's places
(4-7 of 10 places: 13-47 % of the drives) covers part of the house, as a
user's map of the rooms they drove does. Every ordered pair of places is
queried on it (starts jittered as the planning study's) and each plan
driven by its method's networks
(:func:`~topodrake.experiments.plan_study.run_method`). Each
query is judged in truth (privileged geometry, evaluation only):

- *covered in truth*: both its start and its goal lie within the
  controller's reach of a vertex of the map
  (:func:`~topodrake.experiments.link_truth.within_reach`);
- a plan's start or goal link is *false* where its two ends are not within
  reach of each other (:func:`~topodrake.experiments.plan_study.plan_notes`).

Per coverage bin (the number of places the map's drives join; the
figures name the fraction of the drives it is) and pooled:
``covered_link_false`` (among the plans the map makes, the share whose
start or goal link is false: the plan called the query covered and was
wrong), ``refused`` (queries refused because an end is not covered, as
``topodrake map plan`` exits 1), ``uncovered_refused`` (of the queries not
covered in truth, the share that got no plan), ``covered_refused`` (of the
queries covered in truth, the share refused as uncovered), success and
the plans' ECE (calibrated chance of success against success).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.experiments.link_truth import within_reach
from topodrake.experiments.map_cache import get_map, house_drives, house_key
from topodrake.experiments.plan_methods import (
    METHODS,
    attach_success_probability,
    check_map_methods,
)
from topodrake.experiments.plan_scenario import PlanningScenario, Setting, map_config
from topodrake.experiments.plan_study import house_seed, run_method
from topodrake.experiments.plan_trials import jittered_starts, plans_ece
from topodrake.experiments.scenarios import option
from topodrake.topomap.sources import drives_between
from topodrake.validate import check_count, check_seed
from topodrake.world import load_world

#: a plan's links whose falsehood means the plan misjudged coverage
END_LINKS = ("start", "goal", "direct")


@dataclass
class PartialMapsStudy:
    """Which houses, map methods and partial maps a run covers."""

    houses: list[str] = option(["test-0"], "houses (catalogue names or map YAMLs)")
    methods: list[str] = option(["lidar_reg"], "map methods (of the planning study's)")
    places: list[int] = option([4, 5, 6, 7], "places each map's drives join (a map per "
                                             "count: the drives between that many places)")
    maps_per_count: int = option(2, "maps per count of places, each of its own seeded places")
    seed: int = option(0, "base seed of the trials and the place subsets")
    map: dict[str, Setting] = option({}, "map settings to change (MapConfig fields), e.g. "
                                         "{link_cover: 0} for plans without the coverage "
                                         "check", flag="")
    batch: int = option(32, "cars per navigation-engine batch")
    data: str = option("data", "cache of demonstrations and maps")

    def validate(self) -> "PartialMapsStudy":
        """Check every field; a bad one raises a one-line TopodrakeError."""
        check_map_methods("partial maps", self.methods)
        if not self.houses:
            raise TopodrakeError("partial maps: houses names no house")
        if not self.places or any(isinstance(k, bool) or not isinstance(k, int) or k < 2
                                  for k in self.places):
            raise TopodrakeError(f"partial maps: places must be counts >= 2, got {self.places}")
        check_count("partial maps: maps_per_count", self.maps_per_count)
        check_count("partial maps: batch", self.batch)
        check_seed("partial maps: seed", self.seed)
        map_config(self.map)
        return self


def all_pairs(n: int) -> np.ndarray:
    """(n (n - 1), 2) every ordered pair of distinct places."""
    return np.array([(a, b) for a in range(n) for b in range(n) if a != b], np.int64)


def covered_in_truth(world, vertex_poses: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """(N,) whether each pose lies within the controller's reach of a map
    vertex (the nearest few by distance are tried)."""
    out = np.zeros(len(poses), bool)
    for i, p in enumerate(np.asarray(poses, np.float64)):
        d = np.hypot(*(vertex_poses[:, :2] - p[:2]).T)
        out[i] = any(within_reach(world, vertex_poses[j], p) for j in np.argsort(d)[:8])
    return out


def house_records(study: PartialMapsStudy, spec: str, method: str, progress: bool) -> list:
    """Every query's record on each partial map of one house for one method."""
    from tqdm import tqdm

    world = load_world(spec)
    drives = house_drives(spec, Path(study.data), progress)
    places = np.asarray(world.places, np.float64)
    seed = house_seed(study.seed, house_key(spec))
    pairs = all_pairs(len(places))
    starts = jittered_starts(world, places, pairs, seed)
    sc = PlanningScenario(houses=[spec], methods=[method], seed=study.seed, batch=study.batch,
                          data=study.data, pruned_fractions=[], map=dict(study.map)).resolved()
    records = []
    jobs = [(k, r) for k in study.places for r in range(study.maps_per_count)]
    for k, r in tqdm(jobs, desc=f"partial maps {house_key(spec)} {method}", unit="map",
                     disable=not progress, leave=False):
        chosen = place_subset(len(places), k, seed, r)
        idx = drives_between(world, drives, chosen)
        if not idx:
            raise TopodrakeError(f"{house_key(spec)}: no drive runs between places "
                                 f"{','.join(map(str, chosen))}")
        tag = f"all-p{'.'.join(map(str, chosen))}"
        _, recs = run_method(method, spec, world, drives, idx, pairs, starts, sc, tag=tag)
        m, _ = get_map(spec, world, METHODS[method].map, drives, idx, Path(study.data), tag,
                       False, sc.map_config())
        vertices = m.pose(sorted(m.graph.nodes)).reshape(-1, 3)
        start_ok = covered_in_truth(world, vertices, starts)
        place_ok = covered_in_truth(world, vertices, places)
        for t, rec in enumerate(recs):
            rec.update(map_places=chosen, place_count=k, drives=len(idx),
                       drive_fraction=round(len(idx) / len(drives), 4),
                       covered_in_truth=bool(start_ok[t] and place_ok[pairs[t, 1]]))
        records += recs
    return records


def place_subset(n: int, k: int, seed: int, index: int) -> list[int]:
    """``k`` of ``n`` places, sorted, drawn from the house's seed and the
    map's index (a map's places do not depend on the other maps)."""
    if not 2 <= k <= n:
        raise TopodrakeError(f"a partial map joins 2..{n} places, not {k}")
    rng = np.random.default_rng(np.random.SeedSequence([seed, k, index]))
    return sorted(int(p) for p in rng.choice(n, k, replace=False))


def coverage_figures(records: list[dict]) -> dict:
    """The module's figures over some queries' records (with
    ``success_probability`` attached)."""
    planned = [r for r in records if r["planned"]]
    truly = [r for r in records if r["covered_in_truth"]]
    outside = [r for r in records if not r["covered_in_truth"]]

    def share(xs, of):
        return round(sum(xs) / len(of), 4) if of else None

    ece = plans_ece(planned)
    return {"queries": len(records), "planned": share([True] * len(planned), records),
            "covered_in_truth": share([True] * len(truly), records),
            "covered_link_false": share([r.get("false_link_kind") in END_LINKS
                                         for r in planned], planned),
            "false_link_plans": share([(r.get("false_link_m") or 0) > 0 for r in planned],
                                      planned),
            "refused": share(["uncovered" in r for r in records], records),
            "uncovered_refused": share([not r["planned"] for r in outside], outside),
            "covered_refused": share(["uncovered" in r for r in truly], truly),
            "success": share([r["success"] for r in records], records),
            "success_planned": share([r["success"] for r in planned], planned),
            "ece": None if ece is None else round(float(ece), 4)}


def partial_maps_study(study: PartialMapsStudy, command: str, quiet: bool = False) -> dict:
    """The study's result document: per method the figures per coverage bin
    and pooled, per house and bin, and every query's record."""
    study.validate()
    for h in study.houses:
        load_world(h)                                     # unknown houses fail here, first
    t0 = time.perf_counter()
    records = []
    for method in study.methods:
        for h in study.houses:
            records += house_records(study, h, method, not quiet)
    attach_success_probability(records)
    summary, per_house = {}, {}
    for method in study.methods:
        mine = [r for r in records if r["method"] == method]
        summary[method] = {"pooled": coverage_figures(mine), "by_places": _bins(
            mine, study.places)}
        for h in study.houses:
            key = house_key(h)
            per_house.setdefault(key, {})[method] = _bins(
                [r for r in mine if r["house"] == key], study.places)
    return {"command": command, "seed": study.seed, "houses": study.houses,
            "places": study.places, "wall_time_s": round(time.perf_counter() - t0, 1),
            "summary": summary, "per_house": per_house, "trials": records}


def _bins(records: list[dict], counts: list[int]) -> dict:
    """:func:`coverage_figures` per count of places (with the maps' mean
    fraction of the drives)."""
    out = {}
    for k in counts:
        mine = [r for r in records if r["place_count"] == k]
        out[str(k)] = {"drive_fraction": round(float(np.mean([r["drive_fraction"]
                                                              for r in mine])), 4)
                       if mine else None, **coverage_figures(mine)}
    return out


def paired_runs(before_path, after_path) -> dict:
    """Two recorded runs (``partial_maps.json``) set side by side on their
    common queries, per method: success, plans with a false start or goal
    link (of all queries: a query without a plan has none) and refusals,
    each before, after and the paired difference (95 % interval resampled
    within houses)."""
    import json

    from topodrake.montecarlo import paired_difference

    runs = []
    for path in (before_path, after_path):
        try:
            with open(path, encoding="utf-8") as f:
                trials = json.load(f)["trials"]
            runs.append({(r["method"], r["house"], tuple(r["map_places"]), r["trial"]): r
                         for r in trials})
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise TopodrakeError(f"--paired: {path} is not a partial-maps result ({e})") from None
    keys = sorted(set(runs[0]) & set(runs[1]))
    if not keys:
        raise TopodrakeError("--paired: the two runs share no queries")
    measures = {"success": lambda r: r["success"],
                "covered_link_false": lambda r: r.get("false_link_kind") in END_LINKS,
                "refused": lambda r: "uncovered" in r}
    out = {}
    for method in dict.fromkeys(k[0] for k in keys):
        mine = [k for k in keys if k[0] == method]
        houses = np.array([k[1] for k in mine])
        row = {"queries": len(mine)}
        for name, of in measures.items():
            a = np.array([float(of(runs[0][k])) for k in mine])
            b = np.array([float(of(runs[1][k])) for k in mine])
            row[name] = {"before": round(float(a.mean()), 4), "after": round(float(b.mean()), 4),
                         "difference": paired_difference(a, b, houses)}
        out[method] = row
    return out
