"""The planning study as a whole: its scenario checked, the houses run, the result document.

:func:`planning` checks a study's scenario
(:class:`~topodrake.experiments.plan_scenario.PlanningScenario`), runs every house
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
from topodrake.experiments.map_cache import DEMO_SEED, house_key
from topodrake.experiments.plan_methods import (
    METHODS,
    attach_success_probability,
    calibration_houses,
    calibration_table,
)
from topodrake.experiments.plan_scenario import PlanningScenario
from topodrake.experiments.plan_study import house_job, house_seed, pruned_job, success_by_round
from topodrake.experiments.plan_trials import pruned_ratio, summarize
from topodrake.montecarlo import paired_difference, run_trials
from topodrake.navigation.outcomes import SUCCESS_M
from topodrake.topomap.plan_calibration import read_trial_records


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


def _calibration_summary(cal: dict) -> dict:
    return {"plan_probability_ece_by_method": {m: c["ece"] for m, c in cal.items()},
            "raw_plan_probability_ece": {m: c["ece_raw"] for m, c in cal.items()}}


def rescore(files_text: str, command: str) -> dict:
    """The shipped plan calibrations against the trials recorded in the
    comma-separated planning.json files (no new trials): the document of
    ``plan_calibration.json``, with ``command`` recorded."""
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


def planning(scenario: PlanningScenario, command: str, quiet: bool = False) -> dict:
    """The study's result document for ``scenario`` (checked and resolved
    here; recorded as ``scenario``, with the follower and map settings it
    gives in full under ``config``); ``command`` is recorded; ``quiet``: no
    progress bars."""
    from topodrake.learning.checkpoint import git_revision

    t0 = time.perf_counter()
    code = {"git_revision": git_revision(), "local_changes": local_changes()}   # what runs
    sc = scenario.resolved()
    keys = sc.check_worlds()
    methods, specs = sc.methods, sc.specs
    jobs = {house_seed(sc.seed, k): s for k, s in zip(keys, specs)}
    results = run_trials(house_job, list(jobs), workers=sc.workers, ray_address=sc.ray,
                         progress=not quiet and len(jobs) > 1, desc="houses",
                         jobs=jobs, scenario=sc, quiet=quiet)
    houses = {r["house"]: r for r in results}
    pruned = None
    if sc.pruned_fractions:
        pkey = house_key(sc.pruned_house)
        pjobs = {house_seed(sc.seed, pkey): sc.pruned_house}
        full = None
        if pkey in houses and sc.pruned_method in houses[pkey]["methods"]:
            full = {"stats": houses[pkey]["methods"][sc.pruned_method],
                    "records": [r for r in houses[pkey]["records"]
                                if r["method"] == sc.pruned_method]}
        pruned = run_trials(pruned_job, list(pjobs), workers=1, ray_address=sc.ray,
                            progress=False, jobs=pjobs, scenario=sc, quiet=quiet, full=full)[0]
    # calibration: ours (the headline) and every map method, planned trials only
    attach_success_probability([r for h in houses.values() for r in h["records"]])
    cal = calibration_table(methods, [r for h in houses.values() for r in h["records"]])
    ece = cal["ours"]["ece"] if "ours" in cal else None
    ratio = pruned_ratio({f: v["success"] for f, v in pruned["fractions"].items()}) \
        if pruned else None
    summary = summarize(houses, ece, ratio)
    summary.update(_calibration_summary(cal))
    summary["calibration_houses"] = calibration_houses(methods)
    if sc.experience_rounds > 1:
        summary["success_by_round"] = success_by_round(
            [r for h in houses.values() for r in h["records"]])
    wall = time.perf_counter() - t0
    records = [r for h in houses.values() for r in h.pop("records")]
    pruned_records = pruned.pop("records") if pruned else []
    return {
        "command": command, **code, "seed": sc.seed, "scenario": asdict(sc),
        "config": {"follower": asdict(sc.follower_config()), "map": sc.map_config().flat(),
                   "success_m": SUCCESS_M, "speed_cap_mps": 0.5,
                   "jitter": "0.3 m to a random side, 9 deg to a random side",
                   "demo_seed": DEMO_SEED,
                   "followers": {m: METHODS[m].followed_by for m in methods},
                   "calibration": "planned trials only; unplanned trials count as failures in "
                                  "the success rates"},
        "wall_time_s": round(wall, 1), "summary": summary,
        "houses": houses, "calibration": cal, "pruned": pruned,
        "trials": records, "pruned_trials": pruned_records}
