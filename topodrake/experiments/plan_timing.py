"""The follower's driving time fitted to recorded planning trials.

:func:`driving_time_fit` reads planning.json files, measures each planned
trial's route as the planner does (:mod:`topodrake.topomap.route_time`: legs
on the house's cached map, hops) and fits a
:class:`~topodrake.topomap.route_time.DrivingTime` per method and over all
of them to the times of the trials that arrived and the time-outs (the
other failures say nothing of the pace and are left out).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.experiments.map_cache import get_map
from topodrake.experiments.plan_methods import METHODS
from topodrake.experiments.plan_scenario import PlanningScenario
from topodrake.experiments.plan_study import _house
from topodrake.topomap.plan import GOAL, START
from topodrake.topomap.route_time import edge_metres, fit_driving_time, path_metres
from topodrake.vehicle import VehicleConfig


def _route_sizes(doc: dict) -> list[tuple[str, float, int, float, bool]]:
    """(method, metres, hops, seconds, timed out) of a run's planned trials
    that arrived or timed out, on the maps the run planned on."""
    period_s = VehicleConfig().dt          # a trial's steps are the car's control periods
    sc = PlanningScenario.from_record(doc)
    out = []
    for house, h in doc["houses"].items():
        trials = [r for r in doc["trials"] if r["house"] == house and r["planned"]
                  and "plan_vertices" in r and (r["success"] or r["outcome"] == "timeout")
                  and r["method"] in METHODS and METHODS[r["method"]].map != "sptm"]
        if not trials:
            continue
        spec, world, drives, n = _house(h["seed"], {h["seed"]: h["world"]}, sc)
        for modality in dict.fromkeys(METHODS[r["method"]].map for r in trials):
            tag = trials[0]["map"]
            m, _ = get_map(spec, world, modality, drives, list(range(n)), Path(sc.data), tag,
                           False, sc.map_config())
            metres, typical = edge_metres(m.graph)
            for r in trials:
                if METHODS[r["method"]].map != modality:
                    continue
                path = [START, *(v for v in r["plan_vertices"] if v >= 0), GOAL]
                out.append((r["method"], path_metres(path, metres, typical), len(path) - 1,
                            r["steps"] * period_s, r["outcome"] == "timeout"))
    return out


def driving_time_fit(files_text: str, command: str) -> dict:
    """The driving time fitted to the trials of the comma-separated
    planning.json files, per method and over all (``command`` recorded)."""
    import json
    from dataclasses import asdict


    files = [Path(f) for f in files_text.split(",") if f]
    if not files:
        raise TopodrakeError("--fit-driving-time names no planning.json")
    rows, limits = [], set()
    for f in files:
        try:
            doc = json.loads(f.read_text())
            sc = PlanningScenario.from_record(doc)
        except (OSError, ValueError, KeyError, AttributeError, TypeError, TopodrakeError) as e:
            raise TopodrakeError(f"--fit-driving-time: {f}: not a planning.json with trials "
                                 f"({type(e).__name__}: {e})") from None
        if sc.route_time:
            raise TopodrakeError(f"--fit-driving-time: {f} gave each trial its route's own time "
                                 f"(--time-rule route or --route-time, a --world run's default); fit "
                                 f"runs of one time limit (--time-rule fixed)")
        try:
            limits.add(float(sc.time_limit))
            rows += _route_sizes(doc)
        except (OSError, ValueError, KeyError) as e:
            raise TopodrakeError(f"--fit-driving-time: {f}: not a planning.json with trials "
                                 f"({type(e).__name__}: {e})") from None
    if len(limits) != 1:
        raise TopodrakeError(f"--fit-driving-time: the runs drove under different time limits "
                             f"{sorted(limits)}; fit them apart")
    limit = limits.pop()
    fits = {}
    for method in [None, *dict.fromkeys(r[0] for r in rows)]:
        sel = [r for r in rows if method is None or r[0] == method]
        metres, hops, seconds, late = (np.array([r[i] for r in sel]) for i in (1, 2, 3, 4))
        try:
            fit = fit_driving_time(metres, hops, seconds, late, limit)
        except TopodrakeError:
            continue
        predicted_late = 1 - np.array([fit.on_time(a, b, limit) for a, b in zip(metres, hops)])
        fits[method or "all"] = {**asdict(fit), "trials": len(sel), "timeouts": int(late.sum()),
                                 "predicted_timeouts": round(float(predicted_late.sum()), 1)}
    return {"command": command, "sources": [str(f) for f in files], "time_limit_s": limit,
            "fits": fits}
