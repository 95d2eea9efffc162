"""Traces of single planning trials: what the car did, period by period.

A planning study's trial ``t`` in a house is fixed by the study's seed and
the house's name (:mod:`topodrake.experiments.plan_study`), so it can be
driven again alone: :func:`trace_trials` plans the same trials of one
method on the same cached map and drives each one in its own engine run,
keeping the car's poses, the follower's mode and active anchor in every
period. :meth:`TrialTrace.segments` reads that as a timeline (which mode,
on which anchors, from when to when) and :func:`plot_trace` draws it over
the floor plan. A trace drives its trial alone; the study drives trials in
batches, whose network numerics differ in the last digits, so a trace's
outcome differs from the study's record in a few trials in a hundred.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.experiments.plan_methods import METHODS, networks
from topodrake.experiments.plan_study import (
    _house,
    house_key,
    house_seed,
    navigation_config,
    odometry_seeds,
    plan_routes,
    trial_time_limits,
)
from topodrake.experiments.plan_trials import follow_routes, jittered_starts, trial_pairs
from topodrake.navigation.engine import NavigationEngine
from topodrake.navigation.follower import MODES
from topodrake.navigation.outcomes import SUCCESS_M
from topodrake.world.plot import plot_world, save_figure

#: the colours of the follower's modes in :func:`plot_trace`
MODE_COLOURS = {"search": "0.5", "follow": "tab:blue", "dead_reckoning": "tab:orange",
                "reached": "tab:green", "failed": "tab:red"}


@dataclass
class TrialTrace:
    """One trial driven alone: the plan it followed and the car's run."""

    house: str
    method: str
    trial: int
    start_place: int
    goal_place: int
    start: np.ndarray          # (3,) the jittered start pose
    goal: np.ndarray           # (3,) the goal place's pose
    plan_probability: float
    route_poses: np.ndarray | None   # (A, 3) the route's anchor poses (None: no plan)
    route_vertices: list[int]
    poses: np.ndarray          # (T + 1, 3) the car's true poses
    modes: np.ndarray          # (T,) follower mode per period (MODES index)
    active: np.ndarray         # (T,) active anchor per period
    outcome: str
    success: bool
    final_distance_m: float
    dt: float = 0.1

    def segments(self) -> list[dict]:
        """The run as spans of one follower mode: {mode, from_s, to_s,
        anchors [first, last] active in the span, pose at its end}."""
        out: list[dict] = []
        for k, (m, a) in enumerate(zip(self.modes, self.active)):
            if out and out[-1]["mode"] == MODES[m]:
                seg = out[-1]
                seg["to_s"] = round((k + 1) * self.dt, 1)
                seg["anchors"][1] = int(a)
            else:
                seg = {"mode": MODES[m], "from_s": round(k * self.dt, 1),
                       "to_s": round((k + 1) * self.dt, 1), "anchors": [int(a), int(a)]}
                out.append(seg)
            seg["end_pose"] = [round(float(v), 3) for v in self.poses[k + 1]]
        return out

    def to_json(self) -> dict:
        return {"house": self.house, "method": self.method, "trial": self.trial,
                "start_place": self.start_place, "goal_place": self.goal_place,
                "start_pose": [round(float(v), 4) for v in self.start],
                "plan_probability": round(float(self.plan_probability), 5),
                "plan_vertices": self.route_vertices,
                "route_poses": None if self.route_poses is None else
                np.round(self.route_poses, 3).tolist(),
                "outcome": self.outcome, "success": self.success,
                "final_distance_m": round(float(self.final_distance_m), 3),
                "driven_s": round(len(self.modes) * self.dt, 1), "segments": self.segments()}


def trace_trials(spec: str, method: str, trials: list[int], scenario) -> list[TrialTrace]:
    """Trials ``trials`` of ``method`` in the house ``spec`` under the
    planning study's ``scenario`` (a
    :class:`~topodrake.experiments.plan_scenario.PlanningScenario`),
    each planned as the study plans it and driven alone. Methods that
    replan or place obstacles are not traced (their drives are not one
    engine run)."""
    if method not in METHODS:
        raise TopodrakeError(f"unknown method {method!r}; known: {', '.join(METHODS)}")
    meth = METHODS[method]
    if meth.drive != "plain" or meth.map == "sptm":
        raise TopodrakeError(f"method {method!r} is not traced: only plainly driven map methods "
                             f"are one engine run per trial")
    if not trials or min(trials) < 0:
        raise TopodrakeError(f"trials to trace are indices >= 0, got {trials}")
    sc = scenario
    seed = house_seed(sc.seed, house_key(spec))
    spec, world, drives, n = _house(seed, {seed: spec}, sc)
    places = np.asarray(world.places, np.float64)
    count = max(trials) + 1
    pairs = trial_pairs(len(places), count, seed)
    starts = jittered_starts(world, places, pairs, seed)
    sel = np.asarray(trials, np.int64)
    tag = "all" if n == len(drives) else f"first{n}"
    limits = trial_time_limits(sc, world, starts[sel], places[pairs[sel, 1]])
    routes, prob, *_ = plan_routes(method, spec, world, drives, list(range(n)), starts[sel],
                                   places, pairs[sel, 1], sc, tag, limits=limits)
    policy, reach = networks(meth.follower, world)
    engine = NavigationEngine(world, policy, reach, navigation_config(sc))
    odo = np.asarray(odometry_seeds(sc, spec, count))[sel]
    runs: list = []
    res = follow_routes(engine, starts[sel], routes, places[pairs[sel, 1]], limits, 1,
                        SUCCESS_M, odometry_seeds=odo, runs=runs)
    driven = {part[0]: run for part, run in runs}
    out = []
    for j, t in enumerate(trials):
        run, route = driven.get(j), routes[j]
        steps = int(run.steps[0]) if run is not None else 0
        out.append(TrialTrace(
            house=house_key(spec), method=method, trial=int(t), start_place=int(pairs[t, 0]),
            goal_place=int(pairs[t, 1]), start=starts[t], goal=places[pairs[t, 1]],
            plan_probability=float(prob[j]),
            route_poses=None if route is None else np.asarray(route.poses, np.float64),
            route_vertices=[] if route is None or route.vertices is None
            else [int(v) for v in route.vertices],
            poses=starts[t][None] if run is None else run.poses[0, :steps + 1],
            modes=np.zeros(0, np.int64) if run is None else run.modes[0, :steps],
            active=np.zeros(0, np.int64) if run is None else run.active[0, :steps],
            outcome=res.outcome[j], success=bool(res.success[j]),
            final_distance_m=float(res.final_distance_m[j]),
            dt=engine.config.rollout.vehicle.dt))
    return out


def plot_trace(world, trace: TrialTrace, out: str | Path) -> None:
    """The trial over the floor plan: the route's anchors (numbered), the
    car's path coloured by the follower's mode, start and goal."""
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib.lines import Line2D


    ax = plot_world(world, places=False)
    if trace.route_poses is not None:
        r = trace.route_poses[np.all(np.isfinite(trace.route_poses), axis=1)]
        ax.plot(r[:, 0], r[:, 1], "--", color="0.3", lw=0.8, zorder=3)
        ax.quiver(r[:, 0], r[:, 1], np.cos(r[:, 2]), np.sin(r[:, 2]), color="k", scale=40,
                  width=0.003, zorder=4)
        for i, (x, y, _) in enumerate(trace.route_poses):
            if np.isfinite(x) and (i % 5 == 0 or i == len(trace.route_poses) - 1):
                ax.annotate(str(i), (x, y), fontsize=7, xytext=(3, 3), textcoords="offset points")
    p = trace.poses
    for k, m in enumerate(trace.modes):
        ax.plot(p[k:k + 2, 0], p[k:k + 2, 1], color=MODE_COLOURS[MODES[m]], lw=2.0, zorder=5)
    ax.plot(*trace.start[:2], "o", color="tab:green", ms=8, zorder=6)
    ax.plot(*trace.goal[:2], "*", color="tab:red", ms=14, zorder=6)
    ax.plot(*p[-1, :2], "x", color="k", ms=9, zorder=6)
    ax.legend([Line2D([], [], color=c, lw=2) for c in MODE_COLOURS.values()],
              list(MODE_COLOURS), fontsize=7, loc="upper right")
    ax.set_title(f"{trace.house} {trace.method} trial {trace.trial}: place {trace.start_place} -> "
                 f"{trace.goal_place}, {trace.outcome} ({trace.final_distance_m:.2f} m from the "
                 f"goal, {len(trace.modes) * trace.dt:.0f} s)", fontsize=9)
    save_figure(ax.figure, out)


__all__ = ["MODE_COLOURS", "TrialTrace", "plot_trace", "trace_trials"]
