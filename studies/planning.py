"""Planning on topological maps against SPTM (the paper's Table II).

For every test house a map is built from its 90 expert drives between all
ordered pairs of its 10 places (``topodrake collect``; cached in
``DATA/demos/pairs-s0/``), one per method, and cached in ``DATA/planning/``
(keyed by house, modality, scorer, demonstration seed and trajectory
subset; existing maps are reused):

- ``ours``: the camera k=5 map (learned RE), followed by camera k=5 C_WP + RE;
- ``lidar``: the lidar k=5 map, followed by lidar k=5 C_WP + RE;
- ``lidar_reg``: the map built with the RE of the registration C_WP (lidar
  teach and repeat, no network; ``checkpoints/reach_lidar_reg``), followed
  by that controller and its RE; its short reach keeps denser anchors
  (every map method reports ``anchors_per_m``: vertices per metre of the
  drives it was built from);
- ``oracle``: our map built with the geometric oracle RE from the same
  drives (perception errors out of the map); its anchors' contexts are
  rendered as camera images and followed by camera k=5 C_WP with the learned
  camera RE (the navigation engine needs C_WP and RE on one modality);
- ``sptm``: SPTM's graph (every 20th frame, retrieval shortcuts, top-1
  localization, hop-count path), followed by camera k=5 C_WP + RE;
- ``ours_replan``: ``ours`` with replanning on the paper's schedule: a car
  in dead reckoning plans again from where it stands after 5 periods and
  then every 3, without the edge it fails on, and takes the new plan when it
  beats the current one discounted by 0.99 per try, up to 5 new plans
  (:mod:`topodrake.navigation.replan`); ``replanning_gain`` is the
  smallest per-house gain over ``ours`` among the houses where ``ours`` is
  below 0.97;
- ``oracle_full``: perfect perception, the design's ceiling: the oracle map
  followed by the A* oracle C_WP and the geometric oracle RE;
- ``ours_oracle_follow``: our camera map (learned RE) followed by the two
  oracles (reading the route's anchor poses): the map's share of the errors;
- ``oracle_cwp``: the oracle map followed by the A* oracle C_WP and the
  learned camera RE: RE's share of the follower's errors;
- ``ours_obstacles``: ``ours`` on the first ``--obstacle-trials`` trials,
  each alone in a copy of its house with ``--obstacles`` boxes (0.3-0.6 m)
  that the map never saw, placed on its planned route away from its start
  and goal without closing the way; the lidar RMP has to steer around them
  (``unmapped_obstacles``: success over these trials of all houses; a route
  with no room for the boxes is left out and counted as ``no_room``).

The oracle ablations are fast and run ``--oracle-trials`` (100) trials per
house, whose first ones are the learned methods' trials; every house also
reports ``oracle_unplanned_pairs``, the ordered place pairs without a plan
on its oracle map. An outcome ``false_reached`` is a follower that ended its
plan more than 0.54 m from the goal.

A trial starts at one place jittered (0.3 m sideways, 9 deg) and gets the
observation at another place as its goal; it succeeds when the car comes
within 0.54 m of the goal within 150 s (1,500 steps) at <= 0.5 m/s without
colliding. A goal without a plan is a failed trial. Every method of a house
runs the same trials. Plan probabilities are set against empirical success
(10 bins, expected calibration error), and maps built from 10%..100% of
the drives show how success grows with experience (``pruned_60_over_peak``:
success with 60% of the drives over the best over all fractions).

    python studies/planning.py --json                      (default: a few trials)
    python studies/planning.py --trials 1000 --pruned-fractions 0.1,0.2,0.3,0.4,0.5,0.6,0.7,0.8,0.9,1 --pruned-trials 1000   (the paper's protocol)
    python studies/planning.py --world tests/data/maps/willow_full_0.05/map.yaml

The default (20 trials per method and house, 10 of them with obstacles,
pruned fractions 0.3, 0.6, 1 of the first house) took 38 min on 2 cores
beside another study, with the maps cached; building them from an empty
cache took 80 min more beside other jobs (a camera map takes 5-15 min, a
lidar one 0.5-2 min, an oracle one and SPTM's graph a few minutes); the
paper's protocol is ``--trials 1000`` with the ten fractions.

``--json`` prints ``{"houses": {"test-0": {"ours": s, "lidar": s, "lidar_reg": s, "sptm": s,
"oracle": s, "oracle_full": s, ..., "vertices": n, "edges": n, "sptm_vertices": n,
"<method>_anchors_per_m": a, ...}, ...},
"min_ours": s, "min_oracle_full": s, "min_ours_oracle_follow": s,
"min_oracle_cwp": s, "oracle_unplanned_pairs": n, "min_margin_over_sptm": m,
"plan_probability_ece": e, "pruned_60_over_peak": r, "replanning_gain": g,
"false_link_plans": {method: share}, "unmapped_obstacles": s}``
and writes ``results/planning.json`` (command, seed, config, per-trial
records), ``planning.png``, ``plan_calibration.png`` and ``pruned_maps.png``.
"""

from __future__ import annotations

import json
import shutil
import sys
import time
import zlib
from dataclasses import asdict
from pathlib import Path

import numpy as np

from topodrake import argtypes as at
from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_json

METHODS = ("ours", "lidar", "lidar_reg", "sptm", "oracle", "ours_replan", "ours_obstacles",
           "oracle_full", "ours_oracle_follow", "oracle_cwp")
#: the perfect-perception ablations (fast: they run ``--oracle-trials`` trials)
ORACLE_METHODS = ("oracle_full", "ours_oracle_follow", "oracle_cwp")
HOUSES = "test-0,test-1,test-2,test-3,test-4"
#: method -> (map scorer modality, follower's networks: "camera", "lidar", "oracle" (A* C_WP
#: + geometric RE) or "oracle_cwp" (A* C_WP + the learned camera RE))
MAP_OF = {"ours": ("camera", "camera"), "lidar": ("lidar", "lidar"),
          "lidar_reg": ("lidar_reg", "lidar_reg"), "oracle": ("oracle", "camera"),
          "sptm": (None, "camera"), "ours_replan": ("camera", "camera"),
          "ours_obstacles": ("camera", "camera"), "oracle_full": ("oracle", "oracle"),
          "ours_oracle_follow": ("camera", "oracle"), "oracle_cwp": ("oracle", "oracle_cwp")}
FOLLOWERS = {"camera": "camera k5 C_WP + learned camera k5 RE",
             "lidar": "lidar k5 C_WP + learned lidar k5 RE",
             "lidar_reg": "registration C_WP (lidar teach and repeat) + its learned RE",
             "oracle": "A* oracle C_WP + geometric oracle RE",
             "oracle_cwp": "A* oracle C_WP + learned camera k5 RE"}
DEMO_SEED = 0           # the demonstrations: all ordered place pairs, seed 0 (noise-free)
SPTM_CHECKPOINT = "checkpoints/sptm_retrieval/checkpoint.pt"


# ---------------------------------------------------------------- data

def house_key(spec: str) -> str:
    """A world's name in caches and results: the catalogue name, or a map
    file's folder and stem (as ``topodrake collect`` names its demos)."""
    from topodrake.topomap.sources import demo_folder

    return demo_folder(spec).name


def house_drives(spec: str, data: Path, progress: bool) -> list:
    """The successful demonstrations of all ordered place pairs (collected once)."""
    from topodrake.demonstrations import CollectConfig, collect, load_demos

    folder = data / "demos" / f"pairs-s{DEMO_SEED}" / house_key(spec)
    collect(spec, folder, CollectConfig(protocol="pairs", seed=DEMO_SEED), progress=progress)
    _, drives = load_demos(folder, successful_only=True)
    if not drives:
        raise TopodrakeError(f"{folder} holds no successful drive")
    return drives


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
    from topodrake.topomap.graph import MapConfig
    from topodrake.topomap.mapfile import read_map_meta

    try:
        meta = read_map_meta(candidate)
    except TopodrakeError:
        return False
    return (meta.get("world") == world and meta.get("modality") == modality
            and meta.get("config") == asdict(MapConfig())
            and [t["name"] for t in meta.get("trajectories", [])] == names)


def get_map(spec: str, world, modality: str, drives: list, indices, data: Path, tag: str,
            progress: bool):
    """The map of ``drives[indices]`` for ``modality`` (cached; built when missing)."""
    from topodrake.topomap.build import build_map
    from topodrake.topomap.graph import MapConfig, TopoMap
    from topodrake.topomap.mapfile import load_map, read_map_meta, save_map
    from topodrake.topomap.retrieval import default_embedding
    from topodrake.topomap.sources import drive_observations, make_scorer

    key = house_key(spec)
    path = map_path(data, key, modality, tag)
    scorer = make_scorer(modality, world)
    names = [f"pairs-s{DEMO_SEED}/{i}" for i in indices]
    legacy = data / "maps" / f"{key}-{modality}.tdmap"
    if not path.is_file() and modality != "oracle" and legacy.is_file() \
            and _adoptable(legacy, spec, modality, names):
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        shutil.copyfile(legacy, tmp)
        tmp.replace(path)
    if path.is_file():
        m = load_map(path, scorer)
        if [t.name for t in m.trajectories] != names:
            raise TopodrakeError(f"{path} holds other drives than {len(names)} of "
                                 f"{key}; delete it to rebuild")
        # the config as written (a map from before a setting existed reads it as the default)
        if read_map_meta(path).get("config") == asdict(MapConfig()):
            return m, 0.0
        print(f"{path} was built with another map config; rebuilding it", file=sys.stderr)
    t0 = time.perf_counter()
    m = TopoMap(scorer, default_embedding(scorer.observation), world=spec)
    items = [(drive_observations(world, scorer, drives[i].poses), drives[i].poses, n)
             for i, n in zip(indices, names)] if modality == "oracle" else \
        _Lazy(world, scorer, drives, indices, names)
    build_map(m, items, progress=progress, desc=f"map {key} {modality} {tag}")
    save_map(m, path)
    return m, time.perf_counter() - t0


class _Lazy:
    """Drives' observations rendered one at a time (with a length, for tqdm)."""

    def __init__(self, world, scorer, drives, indices, names):
        self.args = world, scorer, drives, list(indices), names

    def __len__(self):
        return len(self.args[3])

    def __iter__(self):
        from topodrake.topomap.sources import drive_observations

        world, scorer, drives, indices, names = self.args
        for i, n in zip(indices, names):
            yield drive_observations(world, scorer, drives[i].poses), drives[i].poses, n


_NETWORKS: dict = {}


def networks(modality: str, world=None):
    """(C_WP, RE) of the shipped k=5 follower of ``modality`` (``lidar_reg``:
    the registration C_WP and its RE; loaded once), or of the oracles in
    ``world`` (``"oracle"``: A* C_WP and geometric RE; ``"oracle_cwp"``: A*
    C_WP and the learned camera RE)."""
    from topodrake.topomap.sources import (SHIPPED, load_networks, shipped_checkpoint,
                                           shipped_controller)

    if modality in ("oracle", "oracle_cwp"):
        from topodrake.learning.policy import AStarOracle
        from topodrake.navigation.evaluate import GeometricReachability

        cwp = AStarOracle(world, k=5)
        return cwp, (GeometricReachability(world, k=5) if modality == "oracle"
                     else networks("camera")[1])
    if modality not in _NETWORKS:
        _NETWORKS[modality] = load_networks(shipped_controller(modality),
                                            shipped_checkpoint(SHIPPED[modality][0]))
    return _NETWORKS[modality]


def plan_calibration_of(method: str):
    """The plan calibration shipped for a method whose map and follower use
    one shipped RE (``ours``, ``lidar``, ``lidar_reg`` and ``ours``' variants), or None."""
    from topodrake.topomap.plan_calibration import calibration_beside
    from topodrake.topomap.sources import ROOT, SHIPPED

    kind, follower = MAP_OF[method]
    if kind != follower or kind not in SHIPPED:
        return None
    return calibration_beside(ROOT / "checkpoints" / SHIPPED[kind][0] / "checkpoint.pt")


def attach_success_probability(records: list[dict]) -> None:
    """Set each planned record's ``success_probability`` from its method's
    shipped plan calibration (None where the method has none or no plan)."""
    calibs = {m: plan_calibration_of(m) for m in {r["method"] for r in records} if m in MAP_OF}
    for r in records:
        c = calibs.get(r["method"])
        r["success_probability"] = (
            None if c is None or not r["planned"] or r["plan_probability"] is None else
            round(float(c.predict(r["plan_probability"], r["plan_anchors"])[0]), 5))


def calibration_table(methods: list[str], records: list[dict]) -> dict:
    """Per map method, over its planned trials: the plan probability against
    success (bins and ECE) and, where a calibration ships, its
    ``success_probability`` against success (``ece``; else the raw ECE)."""
    from topodrake.navigation.plan_trials import calibration

    cal = {}
    for m in methods:
        if m == "sptm":
            continue
        recs = [r for r in records if r["method"] == m and r["planned"]]
        rows, ece_raw = calibration([r["plan_probability"] for r in recs],
                                    [r["success"] for r in recs])
        row = {"bins_raw": rows, "ece_raw": ece_raw, "planned_trials": len(recs),
               "calibrated": False, "bins": rows, "ece": ece_raw}
        if recs and all(r.get("success_probability") is not None for r in recs):
            bins, ece = calibration([r["success_probability"] for r in recs],
                                    [r["success"] for r in recs])
            row.update(calibrated=True, bins=bins, ece=ece)
        cal[m] = row
    return cal


# ---------------------------------------------------------------- one method in one house

def plan_routes(method: str, spec: str, world, drives, indices, starts, places, goal_idx,
                cfg: dict, tag: str = "all"):
    """(plans' routes (None = no plan), plan probabilities, map size dict,
    ``replan(trial, pose, excluded_edges)`` on our maps (None for SPTM))."""
    from topodrake.navigation.plan_trials import render_pose_route
    from topodrake.topomap.plan import plan_path
    from topodrake.topomap.sources import drive_observations

    data, progress = Path(cfg["data"]), not cfg["quiet"]
    if method == "sptm":
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
        modality = MAP_OF[method][0]
        m, build_s = get_map(spec, world, modality, drives, indices, data, tag, progress)
        metres = sum(float(np.hypot(*np.diff(drives[i].poses[:, :2], axis=0).T).sum())
                     for i in indices)
        size = {"vertices": len(m), "edges": m.n_edges, "build_s": round(build_s, 1),
                "anchors_per_m": round(len(m) / max(metres, 1e-9), 4)}
        so = drive_observations(world, m.scorer, starts)
        go = drive_observations(world, m.scorer, places)

        def replan(t, pose, excluded):
            obs = drive_observations(world, m.scorer, np.asarray(pose)[None])[0]
            p = plan_path(m, obs, go[goal_idx[t]], start_pose=pose, goal_pose=places[goal_idx[t]],
                          excluded_edges=excluded)
            return p.route if p.reachable else None
        plans = [plan_path(m, so[t], go[g], start_pose=starts[t], goal_pose=places[g])
                 for t, g in enumerate(goal_idx)]
    routes = [p.route if p.reachable else None for p in plans]
    if method != "sptm":        # each plan's links (not the drives' own hops), judged in truth
        from topodrake.topomap.joining import plan_links

        links = [plan_links(m, p, starts[t], places[g])["false_link_m"] if p.reachable else None
                 for t, (p, g) in enumerate(zip(plans, goal_idx))]
    else:
        links = [None] * len(plans)
    if method in ("oracle", "oracle_cwp"):      # the learned camera RE reads images
        policy, _ = networks("camera")
        routes = [None if r is None else render_pose_route(world, r, getattr(policy, "sensor", None))
                  for r in routes]
    prob = np.array([p.probability if p.reachable else 0.0 for p in plans])
    if method == "sptm":
        prob[:] = np.nan
        replan = None
    return routes, prob, size, replan, links


def run_method(method: str, spec: str, world, drives, indices, pairs, starts, cfg: dict,
               tag: str = "all", bar=None) -> tuple[dict, list[dict]]:
    """One method's trials in one house: (stats, per-trial records)."""
    from topodrake.navigation.engine import NavigationConfig, NavigationEngine
    from topodrake.navigation.plan_trials import (SUCCESS_M, T_MAX_S, follow_routes,
                                                  longest_link_m)

    places = np.asarray(world.places, np.float64)
    t0 = time.perf_counter()
    routes, prob, size, replan, false_links = plan_routes(
        method, spec, world, drives, indices, starts, places, pairs[:, 1], cfg, tag)
    plan_s = time.perf_counter() - t0
    policy, reach = networks(MAP_OF[method][1], world)
    if method == "ours_obstacles":
        from topodrake.navigation.plan_trials import follow_past_obstacles

        n = min(cfg["obstacle_trials"], len(pairs))
        pairs, starts, routes, prob = pairs[:n], starts[:n], routes[:n], prob[:n]
        seeds = [np.random.SeedSequence([cfg["seed"], zlib.crc32(house_key(spec).encode()), t])
                 for t in range(n)]
        res, boxes = follow_past_obstacles(
            world, lambda w: NavigationEngine(w, policy, reach, NavigationConfig()), starts,
            routes, places[pairs[:, 1]], seeds, cfg["obstacles"], T_MAX_S, SUCCESS_M)
        if bar is not None:
            bar.update(n)
    elif method == "ours_replan":
        from topodrake.navigation.replan import ReplanSchedule

        engine = NavigationEngine(world, policy, reach, NavigationConfig())
        res = follow_routes(engine, starts, routes, places[pairs[:, 1]], T_MAX_S, cfg["batch"],
                            SUCCESS_M, replan=replan, schedule=ReplanSchedule(**cfg["replan"]))
        if bar is not None:
            bar.update(len(pairs))
    else:
        engine = NavigationEngine(world, policy, reach, NavigationConfig())
        res = follow_routes(engine, starts, routes, places[pairs[:, 1]], T_MAX_S, cfg["batch"],
                            SUCCESS_M, progress=None if bar is None else bar.update)
    key = house_key(spec)
    records = [{"house": key, "method": method, "map": tag, "trial": t,
                "start_place": int(a), "goal_place": int(b),
                "start_pose": [round(float(v), 4) for v in starts[t]],
                "planned": routes[t] is not None,
                "plan_probability": None if not np.isfinite(prob[t]) else round(float(prob[t]), 5),
                "plan_anchors": 0 if routes[t] is None else len(routes[t]),
                "longest_link_m": None if routes[t] is None else
                round(longest_link_m(starts[t], routes[t], places[b]), 3),
                "false_link_m": None if false_links[t] is None else round(false_links[t], 3),
                "outcome": res.outcome[t], "success": bool(res.success[t]),
                "final_distance_m": round(float(res.final_distance_m[t]), 3),
                "steps": int(res.steps[t]),
                **({"plans": int(res.plans[t])} if getattr(res, "plans", None) is not None
                   else {}),
                **({"boxes": None if boxes[t] is None else np.round(boxes[t], 3).tolist()}
                   if method == "ours_obstacles" else {})}
               for t, (a, b) in enumerate(pairs)]
    rated = [r for r in records if r["outcome"] != "no_room"]
    stats = {**size, **_rates(rated or records), "no_room": len(records) - len(rated),
             "map_and_plan_s": round(plan_s, 1),
             "follow_s": round(time.perf_counter() - t0 - plan_s, 1)}
    return stats, records


def _rates(records: list[dict]) -> dict:
    """Success, plan and outcome counts of some trials' records; the share
    of plans with a false link (a link, not a drive's own hop, longer than
    FALSE_LINK_M in truth; SPTM: any step) and of plans with any step that
    long (``long_step_plans``: also the lidar maps' long anchor hops)."""
    from topodrake.navigation.plan_trials import FALSE_LINK_M

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
            "long_step_plans": (round(float(np.mean(np.array(links) > FALSE_LINK_M)), 4)
                                if links else None),
            "outcomes": {o: outcomes.count(o) for o in sorted(set(outcomes))}}


def house_seed(base: int, key: str) -> int:
    """A house's trial seed: from the base seed and the house's name (so a
    house's trials do not depend on which other houses run)."""
    return int(np.random.SeedSequence([base, zlib.crc32(key.encode())]).generate_state(1)[0])


def house_job(seed: int, jobs: dict, cfg: dict) -> dict:
    """Every method's trials in one house (a Monte Carlo runner job)."""
    import torch
    from tqdm import tqdm

    from topodrake.navigation.plan_trials import jittered_starts, trial_pairs
    from topodrake.world import load_world

    torch.set_num_threads(1)
    spec = jobs[seed]
    world = load_world(spec)
    drives = house_drives(spec, Path(cfg["data"]), not cfg["quiet"])
    n = min(cfg["trajectories"] or len(drives), len(drives))
    indices = list(range(n))
    places = np.asarray(world.places, np.float64)
    # trial i is the same for every count (a prefix), so the oracles' longer
    # runs hold the learned methods' trials
    n_trials = {m: cfg["oracle_trials"] if m in ORACLE_METHODS else cfg["trials"]
                for m in cfg["methods"]}
    pairs = trial_pairs(len(places), max(n_trials.values()), seed)
    starts = jittered_starts(world, places, pairs, seed)
    out = {"house": house_key(spec), "world": spec, "seed": seed, "drives": n, "methods": {},
           "records": []}
    tag = "all" if n == len(drives) else f"first{n}"
    with tqdm(total=sum(n_trials.values()), desc=f"trials {house_key(spec)}",
              disable=cfg["quiet"], unit="trial", leave=False) as bar:
        for method in cfg["methods"]:
            t = n_trials[method]
            stats, records = run_method(method, spec, world, drives, indices, pairs[:t],
                                        starts[:t], cfg, tag=tag, bar=bar)
            out["methods"][method] = stats
            out["records"].extend(records)
    if any(MAP_OF[m][0] == "oracle" for m in cfg["methods"]):
        out["oracle_unplanned_pairs"] = unplanned_pairs(spec, world, drives, indices, cfg, tag)
    return out


def unplanned_pairs(spec: str, world, drives, indices, cfg: dict, tag: str) -> list:
    """The ordered pairs of places (start place, goal place) that get no plan
    on the oracle map, from the start place's own pose."""
    from topodrake.topomap.plan import plan_path
    from topodrake.topomap.sources import drive_observations

    m, _ = get_map(spec, world, "oracle", drives, indices, Path(cfg["data"]), tag,
                   not cfg["quiet"])
    places = np.asarray(world.places, np.float64)
    obs = drive_observations(world, m.scorer, places)
    return [[a, b] for a in range(len(places)) for b in range(len(places))
            if a != b and not plan_path(m, obs[a], obs[b], start_pose=places[a],
                                        goal_pose=places[b]).reachable]


def pruned_job(seed: int, jobs: dict, cfg: dict) -> dict:
    """Our maps from fractions of one house's drives, and their trials."""
    import torch
    from tqdm import tqdm

    from topodrake.navigation.plan_trials import jittered_starts, pruned_subset, trial_pairs
    from topodrake.world import load_world

    torch.set_num_threads(1)
    spec = jobs[seed]
    world = load_world(spec)
    drives = house_drives(spec, Path(cfg["data"]), not cfg["quiet"])
    n = min(cfg["trajectories"] or len(drives), len(drives))
    places = np.asarray(world.places, np.float64)
    pairs = trial_pairs(len(places), cfg["pruned_trials"], seed)
    starts = jittered_starts(world, places, pairs, seed)
    out = {"house": house_key(spec), "method": cfg["pruned_method"], "fractions": {},
           "records": []}
    fractions = cfg["pruned_fractions"]
    with tqdm(total=len(fractions) * len(pairs), desc=f"pruned {house_key(spec)}",
              disable=cfg["quiet"], unit="trial", leave=False) as bar:
        for f in fractions:
            idx = pruned_subset(n, f, cfg["pruned_seed"])
            base = "all" if n == len(drives) else f"first{n}"
            tag = base if len(idx) == n else f"{base}-f{f:g}-r{cfg['pruned_seed']}"
            full = (cfg.get("full") or {}).get(house_key(spec))
            if len(idx) == n and full is not None and len(full["records"]) >= len(pairs):
                # the whole map with the main study's trials (same seed: the same trials)
                records = [dict(r) for r in full["records"][:len(pairs)]]
                stats = {**full["stats"], **_rates(records), "reused_main_trials": True}
                bar.update(len(pairs))
            else:
                stats, records = run_method(cfg["pruned_method"], spec, world, drives,
                                            idx.tolist(), pairs, starts, cfg, tag=tag, bar=bar)
            out["fractions"][f"{f:g}"] = {**stats, "drives": len(idx)}
            out["records"].extend(records)
    return out


# ---------------------------------------------------------------- plots

def plot_table(houses: dict, methods: list[str], path: Path, trials: int) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from topodrake.world.plot import save_figure

    names = list(houses)
    fig, ax = plt.subplots(figsize=(max(6.0, 1.8 * len(names) + 2), 4.8))
    w = 0.8 / max(len(methods), 1)
    x = np.arange(len(names))
    for i, m in enumerate(methods):
        s = [houses[h]["methods"][m]["success"] for h in names]
        bars = ax.bar(x + (i - (len(methods) - 1) / 2) * w, s, w, label=m, color=f"C{i}")
        for b, v in zip(bars, s):
            ax.annotate(f"{v:.2f}", (b.get_x() + b.get_width() / 2, v), ha="center",
                        va="bottom", fontsize=7)
    labels = []
    for h in names:
        o = houses[h]["methods"].get("ours")
        labels.append(f"{h}\n{o['vertices']} V / {o['edges']} E" if o else h)
    ax.set_xticks(x, labels, fontsize=8)
    ax.set_ylim(0, 1.08)
    ax.set_ylabel("success rate")
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8, ncol=len(methods), loc="upper center")
    ax.set_title(f"Planning success per house ({trials} trials per method and house; "
                 f"labels: our map's size)", fontsize=10)
    save_figure(fig, path)


def plot_calibration(cal: dict, path: Path) -> None:
    """One panel per map method: the plan probability and, where calibrated,
    the chance of success against empirical success, with trials per bin."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from topodrake.world.plot import save_figure

    names = list(cal)
    fig, axes = plt.subplots(1, len(names), figsize=(4.6 * len(names), 4.8), squeeze=False)
    for ax, m in zip(axes[0], names):
        c = cal[m]
        ax.plot([0, 1], [0, 1], "--", color="gray", lw=1, label="perfect calibration")
        curves = [("plan probability", c["bins_raw"], c["ece_raw"], "C1")]
        if c["calibrated"]:
            curves.append(("calibrated chance", c["bins"], c["ece"], "C0"))
        for label, rows, ece, colour in curves:
            full = [r for r in rows if r["count"]]
            ax.plot([r["predicted"] for r in full], [r["observed"] for r in full], "o-",
                    color=colour, label=f"{label} (ECE {ece:.3f})" if ece is not None else label)
            for r in full:
                ax.annotate(f"{r['count']}", (r["predicted"], r["observed"]), fontsize=7,
                            color=colour, xytext=(3, 3), textcoords="offset points")
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1.05)
        ax.set_xlabel("predicted (numbers: planned trials per bin)")
        ax.set_ylabel("empirical success")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
        ax.set_title(f"{m} ({c['planned_trials']} planned trials)", fontsize=10)
    save_figure(fig, path)


def _calibration_houses(methods: list[str]) -> dict:
    """The houses each method's shipped plan calibration was fitted on."""
    out = {}
    for m in methods:
        c = plan_calibration_of(m) if m in MAP_OF else None
        if c is not None:
            out[m] = list(c.fitted_on.get("houses", []))
    return out


def plot_pruned(pruned: dict | None, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from topodrake.world.plot import save_figure

    fig, ax = plt.subplots(figsize=(6, 4.5))
    if pruned and pruned["fractions"]:
        fr = sorted(pruned["fractions"], key=float)
        s = [pruned["fractions"][f]["success"] for f in fr]
        ax.plot([float(f) for f in fr], s, "o-", color="C0", label="success")
        ax2 = ax.twinx()
        ax2.plot([float(f) for f in fr], [pruned["fractions"][f]["vertices"] for f in fr], "s--",
                 color="C1", alpha=0.7, label="vertices")
        ax2.set_ylabel("map vertices", color="C1")
        n = pruned["fractions"][fr[0]]["trials"]
        ax.set_title(f"{pruned['house']}: success with a fraction of the drives "
                     f"({pruned['method']}, {n} trials each)", fontsize=10)
    else:
        ax.set_title("pruned maps: not run")
    ax.set_xlim(0, 1.05)
    ax.set_ylim(0, 1.05)
    ax.set_xlabel("fraction of the drives in the map")
    ax.set_ylabel("success rate", color="C0")
    ax.grid(alpha=0.3)
    save_figure(fig, path)


# ---------------------------------------------------------------- main

def _local_changes() -> list[str]:
    """Files of the checkout changed since its revision (the follower may be
    under work while a study runs; the results belong to the code that ran)."""
    import subprocess

    try:
        out = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                             cwd=Path(__file__).resolve().parents[1], capture_output=True,
                             text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return []
    return [line[3:] for line in out.stdout.splitlines()] if out.returncode == 0 else []


def _fractions(text: str) -> list[float]:
    if text.strip().lower() in ("", "none", "off"):
        return []
    try:
        out = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise TopodrakeError(f"--pruned-fractions must be comma-separated numbers in (0, 1] or "
                             f"'none', got {text!r}") from None
    if not out or any(not 0.0 < f <= 1.0 for f in out):
        raise TopodrakeError(f"--pruned-fractions must be numbers in (0, 1], got {text!r}")
    return sorted(set(out))


def main(argv=None) -> int:
    from topodrake.montecarlo import study_main

    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    ap.add_argument("--houses", default=HOUSES, help="test houses (catalogue names or map YAMLs)")
    ap.add_argument("--world", help="one world (catalogue name or ROS map YAML) instead of "
                                    "--houses")
    ap.add_argument("--methods", default=",".join(METHODS), help="methods to run")
    ap.add_argument("--trials", type=at.count, default=20,
                    help="trials per method and house (paper: 1000)")
    ap.add_argument("--oracle-trials", type=at.count, default=100,
                    help="trials per house of the oracle ablations (" + ", ".join(ORACLE_METHODS)
                         + ")")
    ap.add_argument("--trajectories", type=at.count,
                    help="drives per map, in order (default: all 90)")
    ap.add_argument("--obstacle-trials", type=at.count, default=10,
                    help="trials per house of ours_obstacles (the first of the trials)")
    ap.add_argument("--obstacles", type=at.count, default=3,
                    help="unmapped boxes per ours_obstacles trial")
    ap.add_argument("--batch", type=at.count, default=32, help="cars per navigation-engine batch")
    ap.add_argument("--pruned-fractions", default="0.3,0.6,1",
                    help="fractions of the drives for the pruned maps, or 'none' "
                         "(paper: 0.1,0.2,...,1)")
    ap.add_argument("--pruned-house", help="house of the pruned maps (default: the first)")
    ap.add_argument("--pruned-method", choices=["ours", "lidar", "oracle"], default="ours",
                    help="map of the pruned study")
    ap.add_argument("--pruned-trials", type=at.count, default=20,
                    help="trials per pruned map (paper: 1000)")
    ap.add_argument("--pruned-seed", type=at.seed, default=0, help="seed of the drive subsets")
    ap.add_argument("--seed", type=at.seed, default=0, help="base seed of the trials")
    ap.add_argument("--data", default="data", help="cache of demonstrations and maps")
    ap.add_argument("--workers", type=at.count, default=1,
                    help="local worker processes, one house each")
    ap.add_argument("--ray", metavar="ADDRESS", help="run the houses on a Ray cluster")
    ap.add_argument("--out", default="results", help="folder of the JSON and PNG results")
    ap.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    args = ap.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    return study_main(_run, args)


def _run(args) -> int:
    from topodrake.learning.checkpoint import git_revision
    from topodrake.montecarlo import run_trials
    from topodrake.navigation.plan_trials import SUCCESS_M, T_MAX_S, pruned_ratio, summarize
    from topodrake.world import load_world

    t0 = time.perf_counter()
    code = {"git_revision": git_revision(), "local_changes": _local_changes()}   # what runs
    methods = [m for m in args.methods.split(",") if m]
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise TopodrakeError(f"unknown methods {unknown}; choose from {', '.join(METHODS)}")
    if args.world is not None:
        if args.houses != HOUSES:
            raise TopodrakeError("give --world or --houses, not both")
        specs = [args.world]
    else:
        specs = [h for h in args.houses.split(",") if h]
    if not specs:
        raise TopodrakeError("--houses names no house")
    fractions = _fractions(args.pruned_fractions)
    for spec in specs:
        w = load_world(spec)               # a bad name or file fails here, in one line
        if len(w.places) < 2:
            raise TopodrakeError(f"world {spec!r} has {len(w.places)} places; planning trials "
                                 f"need at least 2")
    keys = [house_key(s) for s in specs]
    if len(set(keys)) != len(keys):
        raise TopodrakeError("--houses names a house twice")
    pruned_spec = args.pruned_house or specs[0]
    if fractions:
        load_world(pruned_spec)
    from topodrake.navigation.replan import ReplanSchedule

    cfg = {"data": args.data, "quiet": args.quiet, "trials": args.trials, "methods": methods,
           "oracle_trials": args.oracle_trials,
           "trajectories": args.trajectories, "batch": args.batch, "seed": args.seed,
           "replan": asdict(ReplanSchedule()), "obstacle_trials": args.obstacle_trials,
           "obstacles": args.obstacles,
           "pruned_fractions": fractions, "pruned_method": args.pruned_method,
           "pruned_trials": args.pruned_trials, "pruned_seed": args.pruned_seed}
    jobs = {house_seed(args.seed, k): s for k, s in zip(keys, specs)}
    results = run_trials(house_job, list(jobs), workers=args.workers, ray_address=args.ray,
                         progress=not args.quiet and len(jobs) > 1, desc="houses",
                         jobs=jobs, cfg=cfg)
    houses = {r["house"]: r for r in results}
    pruned = None
    if fractions:
        pjobs = {house_seed(args.seed, house_key(pruned_spec)): pruned_spec}
        pkey = house_key(pruned_spec)
        if pkey in houses and args.pruned_method in houses[pkey]["methods"]:
            cfg["full"] = {pkey: {"stats": houses[pkey]["methods"][args.pruned_method],
                                  "records": [r for r in houses[pkey]["records"]
                                              if r["method"] == args.pruned_method]}}
        pruned = run_trials(pruned_job, list(pjobs), workers=1, ray_address=args.ray,
                            progress=False, jobs=pjobs, cfg=cfg)[0]
        cfg.pop("full", None)
    # calibration: ours (the headline) and every map method, planned trials only
    attach_success_probability([r for h in houses.values() for r in h["records"]])
    cal = calibration_table(methods, [r for h in houses.values() for r in h["records"]])
    ece = cal["ours"]["ece"] if "ours" in cal else None
    ratio = pruned_ratio({f: v["success"] for f, v in pruned["fractions"].items()}) \
        if pruned else None
    summary = summarize(houses, ece, ratio)
    summary["plan_probability_ece_by_method"] = {m: c["ece"] for m, c in cal.items()}
    summary["raw_plan_probability_ece"] = {m: c["ece_raw"] for m, c in cal.items()}
    summary["calibration_houses"] = _calibration_houses(methods)
    out = Path(args.out)
    wall = time.perf_counter() - t0
    records = [r for h in houses.values() for r in h.pop("records")]
    pruned_records = pruned.pop("records") if pruned else []
    atomic_write_json(out / "planning.json", {
        "command": "python studies/planning.py " + " ".join(args.argv),
        **code, "seed": args.seed,
        "config": {**{k: v for k, v in cfg.items() if k != "quiet"}, "houses": specs,
                   "success_m": SUCCESS_M, "t_max_s": T_MAX_S, "speed_cap_mps": 0.5,
                   "jitter": "0.3 m to a random side, 9 deg to a random side",
                   "demo_seed": DEMO_SEED, "workers": args.workers,
                   "followers": {m: FOLLOWERS[MAP_OF[m][1]] for m in methods},
                   "calibration": "planned trials only; unplanned trials count as failures in "
                                  "the success rates"},
        "wall_time_s": round(wall, 1), "summary": summary,
        "houses": houses, "calibration": cal, "pruned": pruned,
        "trials": records, "pruned_trials": pruned_records})
    plot_table(houses, methods, out / "planning.png", args.trials)
    if cal:
        plot_calibration(cal, out / "plan_calibration.png")
    plot_pruned(pruned, out / "pruned_maps.png")
    if args.json:
        print(json.dumps(summary))
    else:
        for name, h in summary["houses"].items():
            print(f"{name:<10} " + ", ".join(f"{m} {h[m]:.3f}" for m in METHODS
                                             if h.get(m) is not None)
                  + (f"; {h['vertices']} vertices, {h['edges']} edges" if "vertices" in h else ""))
        print(f"min ours {summary['min_ours']}, min margin over SPTM "
              f"{summary['min_margin_over_sptm']}, plan ECE {summary['plan_probability_ece']}, "
              f"pruned 60%/peak {summary['pruned_60_over_peak']}")
    print(f"{len(houses)} houses x {len(methods)} methods x {args.trials} trials in "
          f"{wall / 60:.1f} min; wrote {out / 'planning.json'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
