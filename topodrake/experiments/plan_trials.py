"""Planning trials (the paper's Table II protocol) as functions over batches.

A trial starts at one of a world's places, jittered (0.3 m to a random
side, turned 9 deg to a random side: :func:`topodrake.baselines.sptm.jittered_start`),
and is given the observation at another place as its goal. The planner
(ours on a topological map, or SPTM) turns the two observations into a
:class:`~topodrake.contract.route.Route`, which the batched navigation
engine follows. A trial succeeds when the car comes within ``SUCCESS_M``
(0.54 m, the relaxed radius) of the goal place within ``T_MAX_S``
(150 s = 1,500 steps) without colliding; a :class:`GoalWatch` stops the
car there, as an episode ends at its goal. A goal that has no plan is a
failed trial.

Everything here is seeded by its arguments: the same seed gives the same
place pairs, jitters and map subsets, and trial ``i`` does not depend on
how many trials follow it (the seeds are spawned by
:func:`topodrake.montecarlo.trial_seeds`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from topodrake.contract.route import Route
from topodrake.errors import TopodrakeError
from topodrake.montecarlo import trial_seeds
from topodrake.navigation.engine import NAV_COLLISION, NAV_OUTCOMES
from topodrake.navigation.outcomes import SUCCESS_M, judge_outcome
from topodrake.navigation.replan import Replanner
from topodrake.sensing.observe import observe

T_MAX_S = 150.0         # 1,500 control periods of 0.1 s
FALSE_LINK_M = 5.0      # a plan step longer than this in truth joins look-alike places


# ---------------------------------------------------------------- trials

def trial_pairs(n_places: int, n: int, seed: int) -> np.ndarray:
    """(n, 2) (start place, goal place) indices, never a place with itself;
    trial i is drawn from its own spawned seed, so a prefix of a longer run
    is the same trials."""
    if n_places < 2:
        raise TopodrakeError(f"planning trials need at least 2 places, the world has {n_places}")
    out = np.zeros((n, 2), np.int64)
    for t, s in enumerate(trial_seeds(seed, n)):
        rng = np.random.default_rng(s)
        a = int(rng.integers(n_places))
        b = (a + 1 + int(rng.integers(n_places - 1))) % n_places
        out[t] = a, b
    return out


def jittered_starts(world, places: np.ndarray, pairs: np.ndarray, seed: int) -> np.ndarray:
    """(n, 3) jittered start poses of the trials ``pairs`` (each from its own
    seed, independent of the pairs' own draws)."""
    from topodrake.baselines.sptm import jittered_start

    seeds = trial_seeds(seed + 1, len(pairs))
    return np.array([jittered_start(world, places[a], np.random.default_rng(s))
                     for (a, _), s in zip(pairs, seeds)]).reshape(-1, 3)


def pruned_subset(n_trajectories: int, fraction: float, seed: int) -> np.ndarray:
    """The sorted indices of round(fraction * n) (at least 1) trajectories,
    a seeded random subset; fraction 1 keeps them all. Subsets of one seed
    are nested: a smaller fraction keeps a prefix of the same permutation."""
    if not 0.0 < fraction <= 1.0:
        raise TopodrakeError(f"a map keeps a fraction in (0, 1] of its trajectories, got {fraction}")
    if n_trajectories < 1:
        raise TopodrakeError("no trajectories to choose from")
    keep = max(1, int(round(fraction * n_trajectories)))
    order = np.random.default_rng(seed).permutation(n_trajectories)
    return np.sort(order[:keep])


# ---------------------------------------------------------------- following

class GoalWatch:
    """The engine's ``watch``: stops a car within ``radius`` of its goal
    place (an episode ends at its goal) and remembers that it arrived."""
    def __init__(self, goals: np.ndarray, radius: float = SUCCESS_M):
        self.goals = np.asarray(goals, np.float64).reshape(-1, 3)
        self.radius = radius
        self.arrived = np.zeros(len(self.goals), bool)

    def __call__(self, k: int, cars: np.ndarray, states: np.ndarray) -> np.ndarray:
        d = np.hypot(*(states[:, :2] - self.goals[cars, :2]).T)
        at = d <= self.radius
        self.arrived[cars[at]] = True
        return at


@dataclass
class FollowResult:
    outcome: list[str]           # the engine's outcome ("diverged" = stopped at the goal)
    final_distance_m: np.ndarray  # (n,) from the last pose to the goal place
    success: np.ndarray          # (n,) bool
    steps: np.ndarray            # (n,) control periods driven
    plans: np.ndarray | None = None       # (n,) plans driven (with replanning)
    returns: np.ndarray | None = None     # (n,) of them plans from an anchor the car returned to
    excluded: list | None = None          # per trial, the edges replanning excluded
    visited: np.ndarray | None = None     # (n,) the follower's last visited anchor (-1: none)
    active: np.ndarray | None = None      # (n,) ... and its active anchor at the end

    def __post_init__(self) -> None:
        n = len(self.outcome)
        if self.visited is None:
            self.visited = np.full(n, -1, np.int64)
        if self.active is None:
            self.active = np.full(n, -1, np.int64)

    @classmethod
    def not_driven(cls, starts, goals) -> "FollowResult":
        """Every trial as not driven yet: outcome ``no_plan``, its start's
        distance to its goal, no success, no steps."""
        n = len(starts)
        dist = np.array([float(np.hypot(*(np.asarray(starts[i])[:2] - goals[i][:2])))
                         for i in range(n)])
        return cls(["no_plan"] * n, dist, np.zeros(n, bool), np.zeros(n, np.int64))


def follow_routes(engine, starts: np.ndarray, routes: list, goals: np.ndarray,
                  t_max_s: float = T_MAX_S, batch: int = 32, radius: float = SUCCESS_M,
                  progress=None, replan=None, schedule=None, odometry_seeds=None,
                  runs: list | None = None, changes=None) -> FollowResult:
    """Drive cars from ``starts`` along ``routes`` (None: no plan, a failed
    trial that is not driven) toward the goal places ``goals`` (n, 3), in
    engine batches of ``batch``, each trial within ``t_max_s`` seconds (one
    for all, or (n,) one per trial). ``progress(n_done)`` is called per batch.
    With ``replan(trial, pose, excluded_edges, vertex=None) -> Route | None``
    (``vertex``: plan from that map vertex instead of the view at ``pose``)
    cars replan while dead reckoning (:mod:`topodrake.navigation.replan`, on
    ``schedule``), and the result holds ``plans``, ``returns`` and ``excluded``.
    ``odometry_seeds`` (n,) draw each trial's odometry errors where the
    engine's odometry drifts (default: the trial's index), so a trial's
    odometry does not depend on the batch it drives in. ``runs``: a list
    that gets each batch's (trial indices, engine
    :class:`~topodrake.navigation.engine.NavigationResult`), for traces.
    ``changes``: a :class:`~topodrake.world.changes.CarChanges` of the n
    trials, what each car meets that its map lacks."""
    n = len(starts)
    out = FollowResult.not_driven(starts, goals)
    outcome, dist, success, steps = out.outcome, out.final_distance_m, out.success, out.steps
    if replan is not None:
        out.plans = np.array([int(r is not None) for r in routes], np.int64)
        out.returns = np.zeros(n, np.int64)
        out.excluded = [[] for _ in range(n)]
    todo = [i for i in range(n) if routes[i] is not None]
    for lo in range(0, len(todo), batch):
        part = todo[lo:lo + batch]
        watch = GoalWatch(goals[part], radius)
        replanner = None
        if replan is not None:
            replanner = Replanner(lambda j, pose, ex, part=part, **kw: replan(part[j], pose, ex,
                                                                               **kw),
                                  [routes[i] for i in part], schedule)
        seeds = [int(odometry_seeds[i]) if odometry_seeds is not None else i for i in part]
        limit = t_max_s if np.ndim(t_max_s) == 0 else np.asarray(t_max_s, np.float64)[part]
        res = engine.run(np.asarray(starts)[part], [routes[i] for i in part], t_max_s=limit,
                         watch=watch, replanner=replanner, odometry_seeds=seeds,
                         changes=None if changes is None else changes.take(part))
        if runs is not None:
            runs.append((part, res))
        for j, i in enumerate(part):
            if replanner is not None:
                out.plans[i], out.excluded[i] = replanner.plans[j], replanner.excluded[j]
                out.returns[i] = replanner.returns[j]
            code = int(res.outcome[j])
            out.visited[i], out.active[i] = res.follower.visited[j], res.follower.active[j]
            final = float(np.hypot(*(res.poses[j, int(res.steps[j]), :2] - goals[i][:2])))
            dist[i] = final
            steps[i] = int(res.steps[j])
            success[i] = code != NAV_COLLISION and (watch.arrived[j] or final <= radius)
            outcome[i] = "goal" if watch.arrived[j] else judge_outcome(NAV_OUTCOMES[code], final,
                                                                        radius)
        if progress is not None:
            progress(len(part))
    return out


def route_paths(starts: np.ndarray, routes: list, goals: np.ndarray) -> list:
    """Each planned trial's path in truth (None without a plan): its start,
    its route's anchor poses and its goal place, (K, 2); where the
    changes of a changed world are put."""
    return [None if r is None else
            np.vstack([np.asarray(s)[None, :2], np.asarray(r.poses)[:, :2],
                       np.asarray(g)[None, :2]])
            for s, r, g in zip(starts, routes, goals)]


def longest_link_m(start, route, goal) -> float:
    """The longest straight step of a plan in truth, over the start, the
    route's anchors and the goal place (privileged poses: evaluation only).
    The controller's hops are at most 3 m long, so a step over
    :data:`FALSE_LINK_M` is a link that perception made between places that
    look alike."""
    xy = np.vstack([np.asarray(start, np.float64)[None, :2], np.asarray(route.poses)[:, :2],
                    np.asarray(goal, np.float64)[None, :2]])
    xy = xy[np.all(np.isfinite(xy), axis=1)]
    return float(np.hypot(*np.diff(xy, axis=0).T).max()) if len(xy) > 1 else 0.0


def render_pose_route(world, route, sensor=None):
    """A route planned on an oracle (pose) map, its contexts rendered as
    camera images at their poses, for a camera follower."""
    ctx = np.asarray(route.contexts, np.float64)
    if ctx.ndim != 3 or ctx.shape[-1] != 3:
        raise TopodrakeError(f"a pose route has (A, 2k+1, 3) contexts, got {ctx.shape}")
    images = observe(world, "camera", ctx.reshape(-1, 3), sensor)
    return Route(images.reshape(*ctx.shape[:2], *images.shape[1:]), route.poses,
                 vertices=route.vertices, edge_probability=route.edge_probability,
                 probability=route.probability, modality="camera",
                 start_probability=route.start_probability, legs=route.legs,
                 leg_paths=route.leg_paths, on_time=route.on_time)


# ---------------------------------------------------------------- analysis

def summarize(houses: dict, ece: float | None, pruned_60_over_peak: float | None) -> dict:
    """The study's summary: per house the methods' success rates, our map's
    size and SPTM's, each map method's anchors per metre of drive; ``min_ours`` (our worst house) and
    ``min_margin_over_sptm`` (the smallest per-house ours - sptm)."""
    out: dict = {"houses": {}}
    ours, margins = [], []
    for name, h in houses.items():
        row = {m: st["success"] for m, st in h["methods"].items()}
        row.update({f"{m}_anchors_per_m": st["anchors_per_m"] for m, st in h["methods"].items()
                    if st.get("anchors_per_m") is not None})
        if "ours" in h["methods"]:
            row["vertices"] = h["methods"]["ours"]["vertices"]
            row["edges"] = h["methods"]["ours"]["edges"]
            ours.append(row["ours"])
        if "sptm" in h["methods"]:
            row["sptm_vertices"] = h["methods"]["sptm"]["vertices"]
        if "ours" in row and "sptm" in row:
            margins.append(row["ours"] - row["sptm"])
        out["houses"][name] = row
    out["min_ours"] = round(min(ours), 4) if ours else None
    for m in ("oracle_full", "ours_oracle_follow", "oracle_cwp", "lidar_oracle_follow"):
        rates = [h["methods"][m]["success"] for h in houses.values() if m in h["methods"]]
        out[f"min_{m}"] = round(min(rates), 4) if rates else None
    unplanned = [(name, pair) for name, h in houses.items()
                 for pair in h.get("oracle_unplanned_pairs") or []]
    out["oracle_unplanned_pairs"] = (len(unplanned) if any("oracle_unplanned_pairs" in h
                                                           for h in houses.values()) else None)
    out["min_margin_over_sptm"] = round(min(margins), 4) if margins else None
    out["plan_probability_ece"] = ece
    out["pruned_60_over_peak"] = pruned_60_over_peak
    gains = [h["methods"]["ours_replan"]["success"] - h["methods"]["ours"]["success"]
             for h in houses.values() if {"ours", "ours_replan"} <= set(h["methods"])
             and h["methods"]["ours"]["success"] < 0.97]
    out["replanning_gain"] = round(min(gains), 4) if gains else None
    # every map method run with and without replanning: its smallest per-house gain
    out["replanning_gains"] = {}
    for name in {m[:-len("_replan")] for h in houses.values() for m in h["methods"]
                 if m.endswith("_replan")}:
        pairs = [(h["methods"][name]["success"], h["methods"][f"{name}_replan"]["success"])
                 for h in houses.values() if {name, f"{name}_replan"} <= set(h["methods"])]
        if pairs:
            out["replanning_gains"][name] = {
                "min": round(min(b - a for a, b in pairs), 4),
                "mean": round(float(np.mean([b - a for a, b in pairs])), 4)}
    # planner errors apart from follower errors: plans with a step between look-alike places
    shares: dict = {}
    for h in houses.values():
        for m, st in h["methods"].items():
            if st.get("false_link_plans") is not None:
                shares.setdefault(m, []).append(st["false_link_plans"])
    out["false_link_plans"] = {m: round(float(np.mean(v)), 4) for m, v in shares.items()}
    records = [r for h in houses.values() for r in h.get("records", [])]
    out["pooled"] = pooled(records) if len(houses) > 1 else None
    out["by_house"] = {name: pooled(h.get("records", [])) for name, h in houses.items()} \
        if len(houses) > 1 else None
    out["changed_world"] = changed_world(records) if any(
        r["method"].endswith("_unchanged") for r in records) else None
    for name, row in (out["changed_world"] or {}).items():   # what the changes cost to run
        secs = [sum(h["methods"][m].get("follow_s", 0.0) for h in houses.values()
                    if m in h["methods"]) for m in (name, f"{name}_unchanged")]
        steps = [sum(r.get("steps", 0) for r in records if r["method"] == m)
                 for m in (name, f"{name}_unchanged")]
        row["follow_s"], row["follow_s_unchanged"] = round(secs[0], 1), round(secs[1], 1)
        row["wall_ratio"] = round(secs[0] / secs[1], 3) if min(secs) > 0 else None
        # car-periods driven: failing cars drive longer, apart from what a period costs
        row["periods_ratio"] = round(steps[0] / steps[1], 3) if min(steps) > 0 else None
    return out


def plans_ece(planned: list[dict]) -> float | None:
    """The ECE of some planned trials' records: each plan's calibrated
    chance of success where the record carries one, else its raw plan
    probability, against success (None without trials or probabilities)."""
    from topodrake.topomap.plan_calibration import calibration

    probs = [r.get("success_probability") if r.get("success_probability") is not None
             else r.get("plan_probability") for r in planned]
    if not planned or any(p is None for p in probs):
        return None
    return calibration(probs, [r["success"] for r in planned])[1]


def pooled(records: list[dict]) -> dict:
    """Per method over some trials (all houses' together: each trial counts
    once, ``no_room`` ones left out): ``trials``, ``success``, the share of
    plans with a false link (``false_link_plans``, of the planned trials
    whose links are judged), of trials refused as not covered
    (``uncovered``) and the plans' ECE (``plan_probability_ece``: the
    calibrated chance of success where the records carry one, else the raw
    plan probability, against success)."""
    out: dict = {}
    for m in dict.fromkeys(r["method"] for r in records):
        rs = [r for r in records if r["method"] == m and r["outcome"] != "no_room"]
        if not rs:
            continue
        planned = [r for r in rs if r.get("planned")]
        false = [r["false_link_m"] > 0 for r in planned if r.get("false_link_m") is not None]
        ece = plans_ece(planned)
        out[m] = {"trials": len(rs), "success": round(float(np.mean([r["success"] for r in rs])), 4),
                  "false_link_plans": round(float(np.mean(false)), 4) if false else None,
                  "uncovered": round(sum("uncovered" in r for r in rs) / len(rs), 4),
                  "plan_probability_ece": None if ece is None else round(float(ece), 4)}
    return out


def changed_world(records: list[dict]) -> dict:
    """Per method driven in a changed world and as mapped (``<m>`` and
    ``<m>_unchanged`` records of the same trials, ``no_room`` trials left
    out): its success pooled over the houses both ways, their ratio, the
    paired difference (95 % interval resampled within houses), the changed
    drives' outcome mix and collision share."""
    from topodrake.montecarlo import paired_difference

    out = {}
    for name in sorted({r["method"][:-len("_unchanged")] for r in records
                        if r["method"].endswith("_unchanged")}):
        before = {(r["house"], r["trial"]): r for r in records
                  if r["method"] == f"{name}_unchanged" and r["outcome"] != "no_room"}
        after = {(r["house"], r["trial"]): r for r in records
                 if r["method"] == name and r["outcome"] != "no_room"}
        keys = sorted(set(before) & set(after))
        if not keys:
            continue
        b = np.array([before[k]["success"] for k in keys], float)
        a = np.array([after[k]["success"] for k in keys], float)
        outcomes = [after[k]["outcome"] for k in keys]
        out[name] = {"trials": len(keys), "success": round(float(a.mean()), 4),
                     "unchanged": round(float(b.mean()), 4),
                     "ratio": round(float(a.mean() / b.mean()), 4) if b.mean() > 0 else None,
                     "difference": paired_difference(b, a, np.array([k[0] for k in keys])),
                     "collisions": round(outcomes.count("collision") / len(keys), 4),
                     "outcomes": {o: outcomes.count(o) for o in sorted(set(outcomes))},
                     "no_room": sum(r["method"] == name and r["outcome"] == "no_room"
                                    for r in records)}
    return out


def pruned_ratio(success_by_fraction: dict, at: float = 0.6) -> float | None:
    """Success at ``at`` over the best success over all fractions (None
    when ``at`` was not run or no fraction succeeded at all: 0/0)."""
    if not success_by_fraction:
        return None
    hit = [s for f, s in success_by_fraction.items() if math.isclose(float(f), at, abs_tol=1e-9)]
    if not hit:
        return None
    peak = max(success_by_fraction.values())
    return round(hit[0] / peak, 4) if peak > 0 else None
