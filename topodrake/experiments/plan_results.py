"""The planning study as a whole: its options checked, the houses run, the result document.

:func:`planning` checks a study's options (houses or one world, methods,
pruned fractions: :func:`pruned_fractions`), runs every house
(:func:`topodrake.experiments.plan_study.house_job`) and the pruned maps
(:func:`~topodrake.experiments.plan_study.pruned_job`), sets plan
probabilities and calibrated chances against success
(:func:`topodrake.experiments.plan_methods.calibration_table`) and assembles
the result document, with the code that ran (:func:`local_changes`).
:func:`rescore` does the calibration part for trials recorded before.
"""

from __future__ import annotations

import subprocess
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.navigation.follower import follower_fields
from topodrake.experiments.plan_methods import (METHODS, attach_success_probability,
                                               calibration_houses, calibration_table)
from topodrake.experiments.plan_study import house_job, house_seed, pruned_job, success_by_round
from topodrake.experiments.map_cache import DEMO_SEED, house_key
from topodrake.topomap.recalibrate import PRIOR_WEIGHT

HOUSES = "test-0,test-1,test-2,test-3,test-4"


def local_changes() -> list[str]:
    """Files of the checkout changed since its revision (the follower may be
    under work while a study runs; the results belong to the code that ran)."""
    try:
        out = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                             cwd=Path(__file__).resolve().parents[2], capture_output=True,
                             text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return []
    return [line[3:] for line in out.stdout.splitlines()] if out.returncode == 0 else []


def pruned_fractions(text: str) -> list[float]:
    """``--pruned-fractions``: sorted distinct fractions in (0, 1], none for 'none'."""
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


HOUSE_PRUNED_FRACTIONS = "0.3,0.6,1"


def _one_world(args) -> bool:
    return getattr(args, "world", None) is not None


def pruned_fraction_text(args) -> str:
    """``--pruned-fractions`` as given, or its default: the pruned maps of
    the first house for a run of the test houses, none for one ``--world``
    (a building's learned maps are not the pruned study's)."""
    text = getattr(args, "pruned_fractions", None)
    if text is not None:
        return text
    return "none" if _one_world(args) else HOUSE_PRUNED_FRACTIONS


def time_rule(args) -> str:
    """How long each trial may drive: ``--time-rule``, ``--route-time`` for
    'route', or the default: 'fixed' (every trial ``--time-limit``) for the
    test houses, 'route' (each trial at least its A* length at the RE
    labels' least speed) for one ``--world``, whose routes can be longer
    than the limit drives."""
    rule, route = getattr(args, "time_rule", None), getattr(args, "route_time", False)
    if route and rule == "fixed":
        raise TopodrakeError("--route-time and --time-rule fixed contradict each other; give one")
    if route:
        return "route"
    if rule is not None:
        return rule
    return "route" if _one_world(args) else "fixed"


def _calibration_summary(cal: dict) -> dict:
    return {"plan_probability_ece_by_method": {m: c["ece"] for m, c in cal.items()},
            "raw_plan_probability_ece": {m: c["ece_raw"] for m, c in cal.items()}}


def rescore(files_text: str, command: str) -> dict:
    """The shipped plan calibrations against the trials recorded in the
    comma-separated planning.json files (no new trials): the document of
    ``plan_calibration.json``, with ``command`` recorded."""
    from topodrake.topomap.plan_calibration import read_trial_records

    files = [Path(f) for f in files_text.split(",") if f]
    try:
        records, commands = read_trial_records(files)
    except TopodrakeError as e:
        raise TopodrakeError(f"--rescore: {e}") from None
    methods = [m for m in dict.fromkeys(r["method"] for r in records) if m in METHODS]
    attach_success_probability(records)
    cal = calibration_table(methods, records)
    summary = {**_calibration_summary(cal),
               "planned_trials": {m: c["planned_trials"] for m, c in cal.items()},
               "houses": sorted({r["house"] for r in records}),
               "calibration_houses": calibration_houses(methods)}
    return {"command": command,
            "sources": [{"file": str(f), "command": c} for f, c in zip(files, commands)],
            "summary": summary, "calibration": cal}


def paired_runs(spec: str) -> dict:
    """Two recorded runs set side by side on their common trials:
    ``BEFORE.json[:METHOD],AFTER.json[:METHOD]`` (without METHOD: every
    method both ran). Per method: each house's success before and after and
    the paired difference over all common trials, its interval resampled
    within houses (:func:`topodrake.montecarlo.paired_difference`)."""
    from topodrake.montecarlo import paired_difference
    from topodrake.topomap.plan_calibration import read_trial_records

    sides = [part.strip() for part in spec.split(",")]
    if len(sides) != 2 or not all(sides):
        raise TopodrakeError(f"--paired {spec!r}: give BEFORE.json[:METHOD],AFTER.json[:METHOD]")
    runs = []
    for side in sides:
        path, _, method = side.partition(":") if not side.endswith(".json") else (side, "", "")
        try:
            records, _ = read_trial_records([Path(path)])
        except TopodrakeError as e:
            raise TopodrakeError(f"--paired: {e}") from None
        by = {}
        for r in records:
            if r.get("map", "all") == "all":        # the maps built from every drive
                by.setdefault(r["method"], {})[(r["house"], r["trial"])] = bool(r["success"])
        if method and method not in by:
            raise TopodrakeError(f"--paired: {path} has no trials of {method} "
                                 f"(it has {', '.join(by)})")
        runs.append((method, by))
    (m_a, a), (m_b, b) = runs
    pairs = [(m_a, m_b)] if m_a and m_b else \
        [(m_a or m, m_b or m) for m in (b if m_a else a) if (m_a or m) in a and (m_b or m) in b]
    out = {}
    for ma, mb in pairs:
        keys = sorted(set(a[ma]) & set(b[mb]))
        if not keys:
            raise TopodrakeError(f"--paired: {ma} and {mb} share no trials")
        before = np.array([a[ma][k] for k in keys], float)
        after = np.array([b[mb][k] for k in keys], float)
        houses = np.array([k[0] for k in keys])
        name = ma if ma == mb else f"{ma} -> {mb}"
        out[name] = {"houses": {h: [round(float(before[houses == h].mean()), 3),
                                    round(float(after[houses == h].mean()), 3)]
                                for h in dict.fromkeys(houses)},
                     "before": round(float(before.mean()), 4), "after": round(float(after.mean()), 4),
                     "difference": paired_difference(before, after, houses)}
    if not out:
        raise TopodrakeError("--paired: the two runs have no method in common")
    return out


def _check(args) -> tuple[list[str], list[str], list[str], list[float]]:
    """(methods, world specs, their house keys, pruned fractions) of the options, checked."""
    from topodrake.world import load_world

    methods = [m for m in args.methods.split(",") if m]
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise TopodrakeError(f"unknown methods {unknown}; choose from {', '.join(METHODS)}")
    weight = getattr(args, "experience_prior_weight", PRIOR_WEIGHT)
    if not (weight > 0 and weight < float("inf")):
        raise TopodrakeError(f"--experience-prior-weight must be > 0, got {weight}")
    if args.world is not None:
        if args.houses != HOUSES:
            raise TopodrakeError("give --world or --houses, not both")
        specs = [args.world]
    else:
        specs = [h for h in args.houses.split(",") if h]
    if not specs:
        raise TopodrakeError("--houses names no house")
    fractions = pruned_fractions(pruned_fraction_text(args))
    for spec in specs:
        w = load_world(spec)               # a bad name or file fails here, in one line
        if len(w.places) < 2:
            raise TopodrakeError(f"world {spec!r} has {len(w.places)} places; planning trials "
                                 f"need at least 2")
    keys = [house_key(s) for s in specs]
    if len(set(keys)) != len(keys):
        raise TopodrakeError("--houses names a house twice")
    if fractions:
        load_world(args.pruned_house or specs[0])
    return methods, specs, keys, fractions


def study_config(args) -> tuple[dict, list[str], list[str], list[float]]:
    """(the trials' config, house specs, house keys, pruned fractions) of
    the study's options ``args``, checked."""
    from topodrake.experiments.plan_trials import T_MAX_S
    from topodrake.navigation.replan import ReplanSchedule
    from topodrake.topomap.graph import load_map_config

    methods, specs, keys, fractions = _check(args)
    map_config = asdict(load_map_config(getattr(args, "map_config", None)))
    follower = follower_fields(getattr(args, "follower", None))
    cfg = {"data": args.data, "quiet": args.quiet, "trials": args.trials, "methods": methods,
           "oracle_trials": args.oracle_trials,
           "trajectories": args.trajectories, "batch": args.batch, "seed": args.seed,
           "replan": asdict(ReplanSchedule.from_json(getattr(args, "replan", None))),
           "obstacle_trials": args.obstacle_trials,
           "obstacles": args.obstacles,
           "pruned_fractions": fractions, "pruned_method": args.pruned_method,
           "pruned_trials": args.pruned_trials, "pruned_seed": args.pruned_seed,
           "experience_rounds": getattr(args, "experience_rounds", 1),
           "experience_prior_weight": getattr(args, "experience_prior_weight", PRIOR_WEIGHT),
           "map_config": map_config, "follower": follower,
           "odometry": getattr(args, "odometry", "perfect"),
           "t_max_s": getattr(args, "time_limit", None) or T_MAX_S,
           "route_time": time_rule(args) == "route",
           "plan_within_time": not getattr(args, "paper_plans", False)}
    return cfg, specs, keys, fractions


def planning(args, command: str) -> dict:
    """The study's result document for its options ``args`` (the study's
    command line, parsed); ``command`` is recorded."""
    from topodrake.learning.checkpoint import git_revision
    from topodrake.montecarlo import run_trials
    from topodrake.experiments.plan_trials import SUCCESS_M, pruned_ratio, summarize

    t0 = time.perf_counter()
    code = {"git_revision": git_revision(), "local_changes": local_changes()}   # what runs
    cfg, specs, keys, fractions = study_config(args)
    methods = cfg["methods"]
    pruned_spec = args.pruned_house or specs[0]
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
    summary.update(_calibration_summary(cal))
    summary["calibration_houses"] = calibration_houses(methods)
    if cfg["experience_rounds"] > 1:
        summary["success_by_round"] = success_by_round(
            [r for h in houses.values() for r in h["records"]])
    wall = time.perf_counter() - t0
    records = [r for h in houses.values() for r in h.pop("records")]
    pruned_records = pruned.pop("records") if pruned else []
    return {
        "command": command, **code, "seed": args.seed,
        "config": {**{k: v for k, v in cfg.items() if k != "quiet"}, "houses": specs,
                   "success_m": SUCCESS_M, "speed_cap_mps": 0.5,
                   "jitter": "0.3 m to a random side, 9 deg to a random side",
                   "demo_seed": DEMO_SEED, "workers": args.workers,
                   "followers": {m: METHODS[m].followed_by for m in methods},
                   "calibration": "planned trials only; unplanned trials count as failures in "
                                  "the success rates"},
        "wall_time_s": round(wall, 1), "summary": summary,
        "houses": houses, "calibration": cal, "pruned": pruned,
        "trials": records, "pruned_trials": pruned_records}
