"""The trajectory-following study as a whole: its options checked, every controller run, the result.

:func:`following` checks a study's options (p values, follower thresholds,
odometry, runs, controllers with their ``--cwp``/``--re`` replacements, the
``--chain-re`` REs that place a controller's anchors instead of its own, and
the ``--sensitivity`` sweep: :func:`parse_sensitivity`), follows each
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
from topodrake.navigation.chains import DIVERGE_M, TOLERANCE_M, path_length
from topodrake.experiments.follow_trials import (CONTROLLERS, load_trajectories, run_controller,
                                                trajectories_name)

RUNS = ("re", "subsampled", "noisy", "oracle", "oracle_re")


def parse_sensitivity(text: str | None) -> tuple[str, list[str]] | None:
    """``--sensitivity KEY=V1,V2,...`` as (KEY, values), each checked as an oracle spec value."""
    from topodrake.learning.waypoint.noisy_oracle import OracleError

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
    from topodrake.experiments.follow_trials import CHAIN_REACH

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


def _p_values(text: str) -> list[float]:
    try:
        ps = [float(x) for x in text.split(",") if x]
    except ValueError:
        raise TopodrakeError(f"--p must be comma-separated numbers, got {text!r}") from None
    if not ps or any(not 0 < p < 1 for p in ps):
        raise TopodrakeError("--p values must be in (0, 1)")
    return ps


def _check(args) -> list[float]:
    """The p values; sets ``args.follower_config``, ``args.odometry_config``,
    ``args.runs`` (a set) and ``args.sensitivity`` (parsed)."""
    from topodrake.navigation.follower import FollowerConfig, follower_fields
    from topodrake.odometry import OdometryConfig

    if args.trajectories < 1:
        raise TopodrakeError("--trajectories must be >= 1")
    if args.batch < 1:
        raise TopodrakeError("--batch must be >= 1")
    if args.seed < 0:
        raise TopodrakeError("--seed must be >= 0")
    if not (np.isfinite(args.noise) and args.noise >= 0):
        raise TopodrakeError("--noise must be finite and >= 0")
    ps = _p_values(args.p)
    args.follower_config = FollowerConfig(**follower_fields(args.follower)).check()
    args.odometry_config = getattr(OdometryConfig, args.odometry)()
    args.runs = {r for r in args.runs.split(",") if r}
    if not args.runs or args.runs - set(RUNS):
        raise TopodrakeError(f"--runs takes {', '.join(RUNS)}, got "
                             f"{','.join(sorted(args.runs)) or 'none'}")
    return ps


def following(args, command: str) -> dict:
    """The study's result document for its options ``args`` (the study's
    command line, parsed); ``command`` is recorded. The printed summary is
    its ``summary`` with its ``sensitivity`` tables, where there are any."""
    from tqdm import tqdm

    from topodrake.experiments.bench_onpolicy import parse_controllers
    from topodrake.world import load_world

    ps = _check(args)
    specs = parse_controllers(args.controllers, args.cwp, args.re, table=CONTROLLERS,
                              must_exist=True)
    args.sensitivity = parse_sensitivity(args.sensitivity)
    args.chain_reach = parse_chain_reach(getattr(args, "chain_re", None), specs,
                                         getattr(args, "re", None))
    worlds = [w for w in args.worlds.split(",") if w]
    t0 = time.perf_counter()
    trajs = load_trajectories(Path(args.data), worlds, args.trajectories, args.seed)
    args.trajectories_file = trajectories_name(worlds, args.trajectories, args.seed)
    cache: dict = {}
    world_of = lambda n: cache.setdefault(n, load_world(n))   # noqa: E731
    lengths = [path_length(t["poses"])[-1] for t in trajs]
    headline = any(abs(p - args.headline_p) < 1e-9 for p in ps)
    per_p = ("re" in args.runs) + ("subsampled" in args.runs)
    at_headline = len(args.runs & {"noisy", "oracle", "oracle_re"}) if headline else 0
    steps = len(specs) * (per_p * len(ps) + at_headline
                          + (len(args.sensitivity[1]) if args.sensitivity else 0))
    results = {}
    with tqdm(total=steps, desc="trajectory following", disable=args.quiet, unit="sweep") as bar:
        for name in specs:
            results[name] = run_controller(name, specs[name], trajs, world_of, ps, args, bar)
    summary = {}
    for name, r in results.items():
        q = min(r["points"], key=lambda q: abs(q["p_sparsify"] - args.headline_p))
        summary[name] = {k: (round(q[k], 4) if k in q else None)
                         for k in ("cover", "cover_noisy", "cover_subsampled", "cover_oracle",
                                   "cover_oracle_re")}
        summary[name]["anchors_per_m"] = q["anchors_per_m"]
    tables = {name: r["sensitivity"] for name, r in results.items() if "sensitivity" in r}
    return {
        "command": command,
        "trajectories": len(trajs), "mean_length_m": round(float(np.mean(lengths)), 2),
        "worlds": worlds, "seed": args.seed, "noise": args.noise, "p_sparsify": ps,
        "tolerance_m": TOLERANCE_M, "diverge_m": DIVERGE_M,
        "wall_time_s": round(time.perf_counter() - t0, 1),
        "follower": asdict(args.follower_config), "odometry": asdict(args.odometry_config),
        "summary": summary, **({"sensitivity": tables} if tables else {}), "results": results}
