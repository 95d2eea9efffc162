"""The planning study's trials: one method in one house, every method in a house, pruned maps.

:func:`house_job` runs every method of a study's scenario
(:class:`~topodrake.experiments.plan_scenario.PlanningScenario`) in one house on
the same trials (a Monte Carlo runner job, one per house): each method's
plans are made on its map (:func:`plan_routes`; maps cached by
:mod:`topodrake.experiments.map_cache`) and followed by its networks
(:func:`run_method`, the methods of
:mod:`topodrake.experiments.plan_methods`). :func:`pruned_job` does the
same for maps of fractions of one house's drives. Trial seeds come from
the base seed and the house's name (:func:`house_seed`), so a house's trials
do not depend on which other houses run.
"""

from __future__ import annotations

import time
import zlib
from pathlib import Path

import numpy as np

from topodrake.experiments.map_cache import DEMO_SEED, get_map, house_drives, house_key
from topodrake.experiments.plan_methods import METHODS, networks
from topodrake.experiments.plan_scenario import PlanningScenario
from topodrake.experiments.plan_trials import (
    FALSE_LINK_M,
    SUCCESS_M,
    FollowResult,
    follow_routes,
    jittered_starts,
    longest_link_m,
    pruned_subset,
    render_pose_route,
    route_paths,
    trial_pairs,
)
from topodrake.navigation.engine import NavigationConfig, NavigationEngine
from topodrake.navigation.replan import NEAREST, nearest_seen_vertex, route_traversals
from topodrake.odometry import odometry_model
from topodrake.topomap.plan import plan_from_vertex, plan_path
from topodrake.topomap.sources import drive_observations, view_scans
from topodrake.world import load_world
from topodrake.world.blockage import blocked_world
from topodrake.world.changes import place_changes

SPTM_CHECKPOINT = "checkpoints/sptm_retrieval/checkpoint.pt"


def navigation_config(sc: PlanningScenario):
    """The NavigationConfig the study's cars drive with: the scenario's
    follower and odometry model (:data:`ODOMETRY`)."""
    return NavigationConfig(follower=sc.follower_config(), odometry=odometry_model(sc.odometry))


def odometry_seeds(sc: PlanningScenario, spec: str, n: int) -> list[int]:
    """Each trial's odometry seed in a house: from the base seed, the
    house's name and the trial's index (apart from the trials' own seeds)."""
    key = zlib.crc32(house_key(spec).encode())
    return [int(np.random.SeedSequence([sc.seed, key, t, 1]).generate_state(1)[0])
            for t in range(n)]


def plan_routes(method: str, spec: str, world, drives, indices, starts, places, goal_idx,
                sc: PlanningScenario, tag: str = "all", experience=None, limits=None,
                progress: bool = False):
    """(plans' routes (None = no plan), plan probabilities, map size dict,
    ``replan(trial, pose, excluded_edges, vertex=None)`` on our maps (``vertex``:
    plan from that map vertex, or from the one the oracle locates the car at
    where it is :data:`~topodrake.navigation.replan.NEAREST`; None
    for SPTM)).
    ``experience``: ``(passed, failed)`` map edges of earlier drives, folded
    into the map's edges before planning
    (:func:`topodrake.topomap.recalibrate.record_traversals`).
    ``limits``: each trial's time limit where the caller has them
    (:func:`trial_time_limits`, computed here otherwise); ``progress``:
    progress bars while a map is built."""
    data = Path(sc.data)
    meth = METHODS[method]
    if meth.map == "sptm":
        from topodrake.baselines.retrieval_net import RetrievalScorer
        from topodrake.baselines.sptm import build_sptm_graph, plan_sptm
        from topodrake.sensing.observe import observe
        from topodrake.topomap.sources import resolve_checkpoint

        net = RetrievalScorer.from_checkpoint(resolve_checkpoint(SPTM_CHECKPOINT))
        t0 = time.perf_counter()
        trajs = [(observe(world, "camera", drives[i].poses, net.sensor), drives[i].poses,
                  f"pairs-s{DEMO_SEED}/{i}") for i in indices]
        m = build_sptm_graph(trajs, net, progress=progress)
        s = m.summary()
        size = {"vertices": s["vertices"], "edges": s["directed_edges"],
                "undirected_edges": s["edges"], "shortcuts": s["shortcuts"],
                "build_s": round(time.perf_counter() - t0, 1)}
        so = observe(world, "camera", starts, net.sensor)
        go = observe(world, "camera", places, net.sensor)
        plans = [plan_sptm(m, so[t], go[g], starts[t], places[g], net)
                 for t, g in enumerate(goal_idx)]
    else:
        modality = meth.map
        m, build_s = get_map(spec, world, modality, drives, indices, data, tag, progress,
                             sc.map_config())
        if experience is not None:
            from topodrake.topomap.recalibrate import record_traversals

            record_traversals(m, *experience, prior_weight=sc.experience_prior_weight)
        metres = sum(float(np.hypot(*np.diff(drives[i].poses[:, :2], axis=0).T).sum())
                     for i in indices)
        size = {"vertices": len(m), "edges": m.n_edges, "build_s": round(build_s, 1),
                "anchors_per_m": round(len(m) / max(metres, 1e-9), 4)}
        so = drive_observations(world, m.scorer, starts)
        go = drive_observations(world, m.scorer, places)
        s_scans, g_scans = view_scans(world, m, starts), view_scans(world, m, places)

        if plan_time_limit(sc) is None:
            limits = [None] * len(starts)
        elif limits is None:
            limits = trial_time_limits(sc, world, starts, places[goal_idx])

        def replan(t, pose, excluded, vertex=None):
            limit = limits[t]
            if vertex == NEAREST:       # the oracle locates the car at a vertex it sees
                vs = np.array(sorted(m.graph.nodes), np.int64)
                k = nearest_seen_vertex(m.pose(vs), pose, world.grid.clearance_at)
                if k is None:
                    return None
                vertex = int(vs[k])
            if vertex is not None:      # the car returns to a vertex of its route
                p = plan_from_vertex(m, vertex, go[goal_idx[t]], goal_pose=places[goal_idx[t]],
                                     goal_scan=None if g_scans is None else g_scans[goal_idx[t]],
                                     excluded_edges=excluded, time_limit_s=limit)
                return p.route if p.reachable else None
            pose = np.asarray(pose)[None]
            obs = drive_observations(world, m.scorer, pose)[0]
            here = view_scans(world, m, pose)
            p = plan_path(m, obs, go[goal_idx[t]], start_pose=pose[0],
                          goal_pose=places[goal_idx[t]], excluded_edges=excluded,
                          time_limit_s=limit, view_scans=None if here is None else
                          (here[0], g_scans[goal_idx[t]]))
            return p.route if p.reachable else None
        plans = [plan_path(m, so[t], go[g], start_pose=starts[t], goal_pose=places[g],
                           time_limit_s=limits[t], view_scans=None if s_scans is None else
                           (s_scans[t], g_scans[g]))
                 for t, g in enumerate(goal_idx)]
    routes = [p.route if p.reachable else None for p in plans]
    links = plan_notes(world, m, plans, starts, places[goal_idx]) if meth.map != "sptm" \
        else [{}] * len(plans)
    if meth.renders_routes:      # the learned camera RE reads images
        policy, _ = networks("camera")
        routes = [None if r is None else render_pose_route(world, r, getattr(policy, "sensor", None))
                  for r in routes]
    prob = np.array([p.probability if p.reachable else 0.0 for p in plans])
    if meth.map == "sptm":
        prob[:] = np.nan
        replan = None
    return routes, prob, size, replan, links


def plan_notes(world, topomap, plans, starts, goals) -> list[dict]:
    """What each plan's record tells of it beside its outcome: a plan's
    false link in truth (``false_link_m``, 0 for none, and its kind; links
    into look-alike places or hops through them, :func:`plan_links`); for
    no plan, the end the map does not cover (``uncovered``), where that was
    the reason."""
    from topodrake.experiments.joining import plan_links

    out = []
    for p, s, g in zip(plans, starts, goals):
        if p.reachable:
            links = plan_links(world, topomap, p, s, g)
            out.append({"false_link_m": round(links["false_link_m"], 3),
                        **({"false_link_kind": links["false_link_kind"]}
                           if links["false_link_kind"] else {})})
        else:
            out.append({"uncovered": p.uncovered} if p.uncovered else {})
    return out


def trial_time_limits(sc: PlanningScenario, world, starts, goals) -> np.ndarray:
    """(n,) seconds each trial may drive: the scenario's ``time_limit``,
    or by the 'route' time rule the longer of it and the trial's A* length
    from start to goal at the RE labels' least speed (A* / v_min,
    :func:`topodrake.learning.reachability.labels.time_limits`), so that a
    building's long routes get the time their length needs."""
    out = np.full(len(starts), float(sc.time_limit))
    if sc.route_time and len(starts):
        from topodrake.learning.reachability.labels import ReachLabelConfig, time_limits

        out = np.maximum(out, time_limits(world, np.asarray(starts, np.float64),
                                          np.asarray(goals, np.float64)[:, :2],
                                          ReachLabelConfig()))
    return out


def detour_time_limits(sc: PlanningScenario, world, starts, goals, limits, placed) -> np.ndarray:
    """Each trial's time limit in its changed world: where a passage of its
    route is closed, at least the A* length of the way left open at the RE
    labels' least speed (the replanned way is longer by construction)."""
    from topodrake.learning.reachability.labels import ReachLabelConfig, time_limits

    out = np.array(limits, np.float64)
    for t, p in enumerate(placed):
        if p is not None and p.get("block") is not None:
            open_way = blocked_world(world, np.asarray(p["block"]))
            need = time_limits(open_way, np.asarray(starts)[[t]], np.asarray(goals)[[t], :2],
                               ReachLabelConfig())[0]
            out[t] = max(out[t], need)
    return out


def plan_time_limit(sc: PlanningScenario) -> float | None:
    """The time limit the plans are made for: the trials' own, or None for
    the paper's most probable paths (``paper_plans``)."""
    return None if sc.paper_plans else float(sc.time_limit)


def run_method(method: str, spec: str, world, drives, indices, pairs, starts,
               sc: PlanningScenario, tag: str = "all", bar=None, progress: bool = False,
               changed: bool = False) -> tuple[dict, list[dict]] | list[tuple]:
    """One method's trials in one house: (stats, per-trial records). With
    ``changed`` (and the scenario's ``changes``), the same plans driven
    twice, as the world was mapped and as it changed: a list of
    ``(name, stats, records)``, ``<method>_unchanged`` and ``<method>``."""
    places = np.asarray(world.places, np.float64)
    meth = METHODS[method]
    rounds = 1 if changed else experience_rounds(method, sc)
    first = len(pairs) if rounds == 1 else round_bounds(len(pairs), rounds)[1]
    round_of = None
    t0 = time.perf_counter()
    limits = trial_time_limits(sc, world, starts, places[pairs[:, 1]])
    routes, prob, size, replan, notes = plan_routes(
        method, spec, world, drives, indices, starts[:first], places, pairs[:first, 1], sc, tag,
        limits=limits[:first], progress=progress)
    plan_s = time.perf_counter() - t0
    policy, reach = networks(meth.follower, world)
    odo_seeds = odometry_seeds(sc, spec, len(pairs))
    engine = NavigationEngine(world, policy, reach, navigation_config(sc))
    goals = places[pairs[:, 1]]
    if meth.drive == "replan":
        res = follow_routes(engine, starts, routes, goals, limits, sc.batch, SUCCESS_M,
                            replan=replan, schedule=sc.replan.check(), odometry_seeds=odo_seeds)
        if bar is not None:
            bar.update(len(pairs))
    else:
        res = follow_routes(engine, starts[:first], routes, goals[:first], limits[:first],
                            sc.batch, SUCCESS_M, progress=None if bar is None else bar.update,
                            odometry_seeds=odo_seeds[:first])
        if rounds > 1:
            routes, prob, notes, res, round_of = _later_rounds(
                method, spec, world, drives, indices, pairs, starts, places, sc, tag, engine,
                routes, prob, notes, res, rounds, bar, odo_seeds, limits, progress)
    follow_s = time.perf_counter() - t0 - plan_s

    def records_of(res, placed=None, limits=limits):
        key = house_key(spec)
        return [{"house": key, "method": method, "map": tag, "trial": t,
                 "start_place": int(a), "goal_place": int(b),
                 "start_pose": [round(float(v), 4) for v in starts[t]],
                 "planned": routes[t] is not None,
                 "plan_probability": None if not np.isfinite(prob[t]) else
                 round(float(prob[t]), 5),
                 "on_time_probability": None if routes[t] is None else
                 round(float(getattr(routes[t], "on_time", 1.0)), 5),
                 "plan_anchors": 0 if routes[t] is None else len(routes[t]),
                 "longest_link_m": None if routes[t] is None else
                 round(longest_link_m(starts[t], routes[t], places[b]), 3),
                 "false_link_m": notes[t].get("false_link_m"),
                 **{k: notes[t][k] for k in ("false_link_kind", "uncovered")
                    if k in notes[t]},
                 "outcome": res.outcome[t], "success": bool(res.success[t]),
                 "final_distance_m": round(float(res.final_distance_m[t]), 3),
                 "steps": int(res.steps[t]), "time_limit_s": round(float(limits[t]), 1),
                 **({"plan_vertices": [int(v) for v in routes[t].vertices],
                     "visited": int(res.visited[t]), "active": int(res.active[t])}
                    if routes[t] is not None and meth.map != "sptm" else {}),
                 **({"round": int(round_of[t])} if round_of is not None else {}),
                 **({"plans": int(res.plans[t]), "returns": int(res.returns[t])}
                    if getattr(res, "plans", None) is not None else {}),
                 **({"changes": placed[t]} if placed is not None else {})}
                for t, (a, b) in enumerate(pairs)]

    def stats_of(records, seconds):
        rated = [r for r in records if r["outcome"] != "no_room"]
        return {**size, **_rates(rated or records), "no_room": len(records) - len(rated),
                "map_and_plan_s": round(plan_s, 1), "follow_s": round(seconds, 1)}

    records = records_of(res)
    if not (changed and sc.changes.any):
        return stats_of(records, follow_s), records
    t1 = time.perf_counter()
    seeds = [np.random.SeedSequence([sc.seed, zlib.crc32(house_key(spec).encode()), t])
             for t in range(len(pairs))]
    changes, placed = place_changes(world, route_paths(starts, routes, goals), sc.changes,
                                    seeds, starts)
    drive = [r if p is not None else None for r, p in zip(routes, placed)]
    replans = (meth.drive == "replan" or sc.changes.blocked) and replan is not None
    changed_limits = detour_time_limits(sc, world, starts, goals, limits, placed)
    after = follow_routes(engine, starts, drive, goals, changed_limits, sc.batch, SUCCESS_M,
                          progress=None if bar is None or replans else bar.update,
                          replan=replan if replans else None,
                          schedule=sc.replan.check() if replans else None,
                          odometry_seeds=odo_seeds, changes=changes)
    if bar is not None and replans:
        bar.update(len(pairs))
    for t, p in enumerate(placed):
        if routes[t] is not None and p is None:
            after.outcome[t] = "no_room"
    changed_records = records_of(after, placed, changed_limits)
    for r in records:
        r["method"] = f"{method}_unchanged"
    for r, c in zip(records, changed_records):       # the same trials as the changed ones
        if c["outcome"] == "no_room":
            r["outcome"] = "no_room"
    return [(f"{method}_unchanged", stats_of(records, follow_s), records),
            (method, stats_of(changed_records, time.perf_counter() - t1), changed_records)]


def experience_rounds(method: str, sc: PlanningScenario) -> int:
    """Rounds a method's trials run in, each planned on its map with the
    edges driven in the rounds before folded in (``experience_rounds``;
    1: every trial on the map as built). Plainly driven map methods only."""
    rounds = int(sc.experience_rounds)
    if rounds < 1:
        raise ValueError(f"experience rounds must be >= 1, got {rounds}")
    meth = METHODS[method]
    return rounds if meth.drive == "plain" and meth.map != "sptm" else 1


def round_bounds(n: int, rounds: int) -> np.ndarray:
    """(rounds + 1,) trial indices where each round starts (and the end)."""
    return np.linspace(0, n, rounds + 1).round().astype(np.int64)


def _later_rounds(method, spec, world, drives, indices, pairs, starts, places, sc, tag, engine,
                  routes, prob, notes, res, rounds, bar, odo_seeds, limits, progress):
    """Rounds 2.. of a method's trials: each planned with every earlier
    round's drives folded into the map's edges (``odo_seeds``, ``limits``:
    every trial's odometry seed and time limit). Returns the whole run's
    routes, probabilities, false links, follow result and each trial's round."""
    bounds = round_bounds(len(pairs), rounds)
    passed, failed = [], []
    routes, prob, notes = list(routes), list(prob), list(notes)
    parts = [res]

    def learn(rs, result):
        for t, route in enumerate(rs):
            if route is not None:
                p, f = route_traversals(route.vertices, result.visited[t], result.active[t],
                                        bool(result.success[t]), result.outcome[t] == "timeout")
                passed.extend(p)
                failed.extend(f)

    learn(routes, res)
    for r in range(1, rounds):
        sl = slice(int(bounds[r]), int(bounds[r + 1]))
        rs, pr, _, _, links = plan_routes(method, spec, world, drives, indices, starts[sl],
                                          places, pairs[sl, 1], sc, tag,
                                          experience=(passed, failed), limits=limits[sl],
                                          progress=progress)
        out = follow_routes(engine, starts[sl], rs, places[pairs[sl, 1]], limits[sl], sc.batch,
                            SUCCESS_M, progress=None if bar is None else bar.update,
                            odometry_seeds=odo_seeds[sl])
        learn(rs, out)
        routes += rs
        prob += list(pr)
        notes += links
        parts.append(out)
    whole = FollowResult([o for p in parts for o in p.outcome],
                         *(np.concatenate([getattr(p, k) for p in parts])
                           for k in ("final_distance_m", "success", "steps")),
                         visited=np.concatenate([p.visited for p in parts]),
                         active=np.concatenate([p.active for p in parts]))
    round_of = np.repeat(np.arange(rounds), np.diff(bounds))
    return routes, np.asarray(prob, np.float64), notes, whole, round_of


def success_by_round(records: list[dict]) -> dict:
    """Per method run in experience rounds: each round's success over all
    houses (rounded to 4 places)."""
    out: dict[str, dict[int, list[bool]]] = {}
    for r in records:
        if "round" in r:
            out.setdefault(r["method"], {}).setdefault(int(r["round"]), []).append(r["success"])
    return {m: [round(float(np.mean(rounds[k])), 4) for k in sorted(rounds)]
            for m, rounds in out.items()}


def _rates(records: list[dict]) -> dict:
    """Success, plan and outcome counts of some trials' records; the share
    of plans with a false link (a link or a hop whose ends are not within
    the controller's reach in truth, :func:`plan_notes`; SPTM: any step
    longer than FALSE_LINK_M), of plans with any step that long
    (``long_step_plans``: also the lidar maps' long anchor hops) and of
    trials refused because the map does not cover the start or goal
    (``uncovered``)."""
    outcomes = [r["outcome"] for r in records]
    planned = [r for r in records if r["planned"]]
    probs = [r["plan_probability"] for r in planned if r["plan_probability"] is not None]
    links = [r["longest_link_m"] for r in planned if r.get("longest_link_m") is not None]
    false = [r["false_link_m"] > 0 if r.get("false_link_m") is not None
             else r["longest_link_m"] > FALSE_LINK_M
             for r in planned if r.get("longest_link_m") is not None]
    return {"trials": len(records),
            "success": round(float(np.mean([r["success"] for r in records])), 4),
            "planned": round(len(planned) / len(records), 4),
            "mean_plan_probability": round(float(np.mean(probs)), 4) if probs else None,
            "false_link_plans": round(float(np.mean(false)), 4) if false else None,
            "uncovered": round(sum("uncovered" in r for r in records) / len(records), 4),
            "long_step_plans": (round(float(np.mean(np.array(links) > FALSE_LINK_M)), 4)
                                if links else None),
            "outcomes": {o: outcomes.count(o) for o in sorted(set(outcomes))}}


def house_seed(base: int, key: str) -> int:
    """A house's trial seed: from the base seed and the house's name (so a
    house's trials do not depend on which other houses run)."""
    return int(np.random.SeedSequence([base, zlib.crc32(key.encode())]).generate_state(1)[0])


def _house(seed: int, jobs: dict, sc: PlanningScenario, quiet: bool = True):
    """(spec, world, drives, drives used) of a job's house, torch on one thread."""
    import torch


    torch.set_num_threads(1)
    spec = jobs[seed]
    world = load_world(spec)
    drives = house_drives(spec, Path(sc.data), not quiet)
    return spec, world, drives, min(sc.trajectories or len(drives), len(drives))


def house_job(seed: int, jobs: dict, scenario: PlanningScenario, quiet: bool = True) -> dict:
    """Every method's trials in one house (a Monte Carlo runner job):
    ``jobs`` maps the job's seed to the house, ``scenario`` is the study's."""
    from tqdm import tqdm


    sc = scenario
    spec, world, drives, n = _house(seed, jobs, sc, quiet)
    indices = list(range(n))
    places = np.asarray(world.places, np.float64)
    # trial i is the same for every count (a prefix), so the oracles' longer
    # runs hold the learned methods' trials
    n_trials = {m: sc.oracle_trials if METHODS[m].oracle else sc.trials for m in sc.methods}
    pairs = trial_pairs(len(places), max(n_trials.values()), seed)
    starts = jittered_starts(world, places, pairs, seed)
    out = {"house": house_key(spec), "world": spec, "seed": seed, "drives": n, "methods": {},
           "records": []}
    tag = "all" if n == len(drives) else f"first{n}"
    with tqdm(total=sum(n_trials.values()), desc=f"trials {house_key(spec)}",
              disable=quiet, unit="trial", leave=False) as bar:
        for method in sc.methods:
            t = n_trials[method]
            ran = run_method(method, spec, world, drives, indices, pairs[:t], starts[:t], sc,
                             tag=tag, bar=bar, progress=not quiet, changed=sc.changes.any)
            for name, stats, records in ran if sc.changes.any else [(method, *ran)]:
                out["methods"][name] = stats
                out["records"].extend(records)
    if any(METHODS[m].map == "oracle" for m in sc.methods):
        out["oracle_unplanned_pairs"] = unplanned_pairs(spec, world, drives, indices, sc, tag,
                                                        not quiet)
    return out


def unplanned_pairs(spec: str, world, drives, indices, sc: PlanningScenario, tag: str,
                    progress: bool = False) -> list:
    """The ordered pairs of places (start place, goal place) that get no plan
    on the oracle map, from the start place's own pose."""
    m, _ = get_map(spec, world, "oracle", drives, indices, Path(sc.data), tag, progress,
                   sc.map_config())
    places = np.asarray(world.places, np.float64)
    obs = drive_observations(world, m.scorer, places)
    return [[a, b] for a in range(len(places)) for b in range(len(places))
            if a != b and not plan_path(m, obs[a], obs[b], start_pose=places[a],
                                        goal_pose=places[b]).reachable]


def pruned_job(seed: int, jobs: dict, scenario: PlanningScenario, quiet: bool = True,
               full: dict | None = None) -> dict:
    """Our maps from fractions of one house's drives (the scenario's
    ``pruned_*`` fields), and their trials. ``full``: the main study's stats
    and records of the house's map from all drives (``{"stats": ...,
    "records": [...]}``), reused for the fraction 1 where they are enough."""
    from tqdm import tqdm


    sc = scenario
    spec, world, drives, n = _house(seed, jobs, sc, quiet)
    places = np.asarray(world.places, np.float64)
    pairs = trial_pairs(len(places), sc.pruned_trials, seed)
    starts = jittered_starts(world, places, pairs, seed)
    out = {"house": house_key(spec), "method": sc.pruned_method, "fractions": {},
           "records": []}
    fractions = sc.pruned_fractions
    with tqdm(total=len(fractions) * len(pairs), desc=f"pruned {house_key(spec)}",
              disable=quiet, unit="trial", leave=False) as bar:
        for f in fractions:
            idx = pruned_subset(n, f, sc.pruned_seed)
            base = "all" if n == len(drives) else f"first{n}"
            tag = base if len(idx) == n else f"{base}-f{f:g}-r{sc.pruned_seed}"
            if len(idx) == n and full is not None and len(full["records"]) >= len(pairs):
                # the whole map with the main study's trials (same seed: the same trials)
                records = [dict(r) for r in full["records"][:len(pairs)]]
                stats = {**full["stats"], **_rates(records), "reused_main_trials": True}
                bar.update(len(pairs))
            else:
                stats, records = run_method(sc.pruned_method, spec, world, drives,
                                            idx.tolist(), pairs, starts, sc, tag=tag, bar=bar,
                                            progress=not quiet)
            out["fractions"][f"{f:g}"] = {**stats, "drives": len(idx)}
            out["records"].extend(records)
    return out

