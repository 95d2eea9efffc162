"""Plans judged in truth without driving them: false links and coverage per building.

For each building (a catalogue house or a ROS map) and map method, the
planning study's trials (the same seeds, starts and goals) are planned on
the map of the building's drives (:func:`~topodrake.experiments.plan_study.plan_routes`)
and each plan's links judged in truth (:func:`~topodrake.experiments.plan_study.plan_notes`):
``false_link_plans`` (plans holding a link whose ends are out of the
controller's reach), the false links' kinds, ``uncovered`` (trials refused
as not covered) and ``planned``. Planning is seconds where driving is
minutes, so links can be checked in every building of a folder.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.experiments.map_cache import house_drives, house_key
from topodrake.experiments.plan_methods import check_map_methods
from topodrake.experiments.plan_scenario import PlanningScenario, Setting, map_config
from topodrake.experiments.plan_study import house_seed, plan_routes
from topodrake.experiments.plan_trials import jittered_starts, trial_pairs
from topodrake.experiments.scenarios import option
from topodrake.validate import check_count, check_seed
from topodrake.world import load_world


@dataclass
class LinkAuditStudy:
    """Which buildings, map methods and trials a link audit plans."""

    houses: list[str] = option(["test-0", "test-1", "test-2", "test-3", "test-4"],
                               "buildings (catalogue names or map YAMLs)")
    methods: list[str] = option(["lidar_reg"], "map methods (of the planning study's)")
    trials: int = option(100, "the planning study's trials per building")
    seed: int = option(0, "the planning study's base seed")
    map: dict[str, Setting] = option({}, "map settings to change (MapConfig fields)", flag="")
    data: str = option("data", "cache of demonstrations and maps")

    def validate(self) -> "LinkAuditStudy":
        """Check every field; a bad one raises a one-line TopodrakeError."""
        check_map_methods("link audit", self.methods)
        if not self.houses:
            raise TopodrakeError("link audit: houses names no building")
        check_count("link audit: trials", self.trials)
        check_seed("link audit: seed", self.seed)
        map_config(self.map)
        return self


def audit_building(study: LinkAuditStudy, spec: str, method: str, progress: bool) -> dict:
    """One building's plans for one method, judged."""
    t0 = time.perf_counter()
    world = load_world(spec)
    drives = house_drives(spec, Path(study.data), progress)
    places = np.asarray(world.places, np.float64)
    seed = house_seed(study.seed, house_key(spec))
    pairs = trial_pairs(len(places), study.trials, seed)
    starts = jittered_starts(world, places, pairs, seed)
    sc = PlanningScenario(houses=[spec], methods=[method], seed=study.seed, data=study.data,
                          map=dict(study.map), pruned_fractions=[]).resolved()
    routes, _, size, _, notes = plan_routes(method, spec, world, drives,
                                            list(range(len(drives))), starts, places,
                                            pairs[:, 1], sc, progress=progress)
    planned = [n for r, n in zip(routes, notes) if r is not None]
    kinds = Counter(n.get("false_link_kind") for n in planned if n.get("false_link_m", 0) > 0)
    return {"trials": len(pairs), "drives": len(drives), "vertices": size["vertices"],
            "planned": round(len(planned) / len(pairs), 4),
            "false_link_plans": round(sum(kinds.values()) / len(planned), 4) if planned else None,
            "false_link_kinds": dict(kinds),
            "uncovered": round(sum("uncovered" in n for n in notes) / len(pairs), 4),
            "wall_s": round(time.perf_counter() - t0, 1)}


def link_audit(study: LinkAuditStudy, command: str, quiet: bool = False) -> dict:
    """The audit's result document: per building and method, and pooled
    per method (every plan counted once)."""
    study.validate()
    t0 = time.perf_counter()
    per, pooled = {}, {}
    for method in study.methods:
        for spec in study.houses:
            row = audit_building(study, spec, method, not quiet)
            per.setdefault(house_key(spec), {})[method] = row
        rows = [per[house_key(h)][method] for h in study.houses]
        plans = sum(r["planned"] * r["trials"] for r in rows)
        false = sum(sum(r["false_link_kinds"].values()) for r in rows)
        pooled[method] = {"buildings": len(rows), "trials": sum(r["trials"] for r in rows),
                          "plans": int(round(plans)),
                          "false_link_plans": round(false / plans, 4) if plans else None,
                          "worst_building": max((r["false_link_plans"] or 0.0) for r in rows),
                          "uncovered": round(sum(r["uncovered"] * r["trials"] for r in rows)
                                             / sum(r["trials"] for r in rows), 4)}
    return {"command": command, "seed": study.seed, "trials": study.trials,
            "wall_time_s": round(time.perf_counter() - t0, 1),
            "summary": {"pooled": pooled, "by_building": per}}
