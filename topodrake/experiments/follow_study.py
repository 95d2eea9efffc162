"""The trajectory-following study as a whole: its scenario checked, every controller run, the result.

:func:`following` checks a study's scenario
(:class:`~topodrake.experiments.follow_scenario.FollowingScenario`: p values,
follower settings, odometry, runs, controllers with their C_WP and RE
replacements, the REs that place a controller's anchors instead of its own,
and the sensitivity sweep: :func:`parse_sensitivity`), follows each
controller's chains of the test drives
(:func:`topodrake.experiments.follow_trials.run_controller`) and assembles
the result document: per-controller figures, the summary at the headline p
and the sensitivity tables.
"""

from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.experiments.bench_onpolicy import parse_controllers
from topodrake.experiments.follow_scenario import FollowingScenario
from topodrake.experiments.follow_trials import (
    CHAIN_REACH,
    CONTROLLERS,
    load_trajectories,
    run_controller,
    trajectories_name,
)
from topodrake.learning.waypoint.noisy_oracle import OracleError
from topodrake.navigation.chains import DIVERGE_M, TOLERANCE_M, path_length
from topodrake.world import load_world


def parse_sensitivity(text: str | None) -> tuple[str, list[str]] | None:
    """``--sensitivity KEY=V1,V2,...`` as (KEY, values), each checked as an oracle spec value."""
    if not text:
        return None
    key, sep, values = text.partition("=")
    items = [v for v in values.split(",") if v]
    if not sep or not items:
        raise TopodrakeError(f"--sensitivity {text!r} is not KEY=V1,V2,... (keys: anchor, fresh, "
                             f"tail, seed)")
    for v in items:
        OracleError().with_value(key, v)
    return key, items


def parse_chain_reach(items: list[str] | None, specs: dict, reach: list[str] | None = None
                      ) -> dict:
    """``--chain-re NAME=CHECKPOINT`` options as {NAME: checkpoint}: the RE
    (trained for NAME's C_WP) whose sparsification makes NAME's chains, while
    NAME's own RE answers the follower (the two roles of RE apart). A
    controller of :data:`CHAIN_REACH` keeps its own placing RE unless
    ``--re`` (``reach``) replaces its RE, which then does both."""
    replaced = {o.partition("=")[0] for o in reach or []}
    out = {n: p for n, p in CHAIN_REACH.items() if n in specs and n not in replaced}
    for o in items or []:
        name, sep, path = o.partition("=")
        if not sep or name not in specs:
            raise TopodrakeError(f"--chain-re {o!r} is not NAME=CHECKPOINT with NAME one of "
                                 f"{list(specs)}")
        if not Path(path).is_file():
            raise TopodrakeError(f"--chain-re: checkpoint {path} does not exist")
        out[name] = path
    return out


def following(scenario: FollowingScenario, command: str, out: str | Path = "results",
              quiet: bool = False) -> dict:
    """The study's result document for ``scenario`` (checked here; the
    follows are cached in ``OUT/trajectory_following_runs/``); ``command``
    is recorded. The printed summary is its ``summary`` with its
    ``sensitivity`` tables, where there are any."""
    from tqdm import tqdm


    sc = scenario.validate()
    ps, runs = list(sc.p), set(sc.runs)
    pairs = lambda d: [f"{k}={v}" for k, v in d.items()]   # noqa: E731  (NAME=CHECKPOINT)
    specs = parse_controllers(",".join(sc.controllers), pairs(sc.cwp), pairs(sc.re),
                              table=CONTROLLERS, must_exist=True)
    table = parse_sensitivity(sc.sensitivity)
    chain_reach = parse_chain_reach(pairs(sc.chain_re), specs, pairs(sc.re))
    worlds = [w for w in sc.worlds if w]
    t0 = time.perf_counter()
    trajs = load_trajectories(Path(sc.data), worlds, sc.trajectories, sc.seed)
    cache: dict = {}
    world_of = lambda n: cache.setdefault(n, load_world(n))   # noqa: E731
    lengths = [path_length(t["poses"])[-1] for t in trajs]
    headline = any(abs(p - sc.headline_p) < 1e-9 for p in ps)
    per_p = ("re" in runs) + ("subsampled" in runs)
    at_headline = len(runs & {"noisy", "oracle", "oracle_re"}) if headline else 0
    if headline and sc.changes.any:
        at_headline += 1 + ("oracle" in runs)
    steps = len(specs) * (per_p * len(ps) + at_headline + (len(table[1]) if table else 0))
    results = {}
    with tqdm(total=steps, desc="trajectory following", disable=quiet, unit="sweep") as bar:
        for name in specs:
            results[name] = run_controller(
                name, specs[name], trajs, world_of, sc, bar,
                runs_dir=Path(out) / "trajectory_following_runs",
                trajectories_file=trajectories_name(worlds, sc.trajectories, sc.seed),
                chain_path=chain_reach.get(name), sensitivity_of=table)
    summary = {}
    for name, r in results.items():
        q = min(r["points"], key=lambda q: abs(q["p_sparsify"] - sc.headline_p))
        summary[name] = {k: (round(q[k], 4) if k in q else None)
                         for k in ("cover", "cover_noisy", "cover_subsampled", "cover_oracle",
                                   "cover_oracle_re")}
        if sc.changes.any:          # the same drives in the changed world
            summary[name].update({k: (round(q[k], 4) if q.get(k) is not None else None)
                                  for k in ("cover_changed", "cover_changed_oracle")})
            summary[name]["outcomes_changed"] = q.get("outcomes_changed")
        summary[name]["anchors_per_m"] = q["anchors_per_m"]
    tables = {name: r["sensitivity"] for name, r in results.items() if "sensitivity" in r}
    return {
        "command": command, "scenario": asdict(sc),
        "trajectories": len(trajs), "mean_length_m": round(float(np.mean(lengths)), 2),
        "worlds": worlds, "seed": sc.seed, "noise": sc.noise, "p_sparsify": ps,
        "tolerance_m": TOLERANCE_M, "diverge_m": DIVERGE_M,
        "wall_time_s": round(time.perf_counter() - t0, 1),
        "follower": asdict(sc.follower_config()), "odometry": asdict(sc.odometry_config()),
        "summary": summary, **({"sensitivity": tables} if tables else {}), "results": results}
