"""Planning on topological maps against SPTM (the paper's Table II).

For every test house a map is built from its 90 expert drives between all
ordered pairs of its 10 places (``topodrake collect``; cached in
``DATA/demos/pairs-s0/``), one per method, and cached in ``DATA/planning/``
(keyed by house, modality, scorer, demonstration seed and trajectory
subset; existing maps are reused):

- ``ours``: the camera k=5 map (learned RE), followed by camera k=5 C_WP + RE;
- ``lidar``: the lidar k=5 map, followed by lidar k=5 C_WP + RE;
- ``lidar_scale``: the lidar k=5 map, followed by the lidar C_WP trained at
  scale (``checkpoints/lidar_k5_scale``) with the lidar k=5 RE;
- ``ours_scale``: the camera k=5 map, followed by the camera C_WP trained at
  scale (``checkpoints/camera_k5_scale``) with the camera k=5 RE;
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
- ``ours_replan``: ``ours`` with replanning: a car in dead reckoning plans
  again from where it stands in the last 10 periods before it would give
  up (every 3), without the edge it fails on, and takes any new plan its
  follower can start, up to 5 new plans (``--replan paper``: the paper's
  schedule, from the 5th period; :mod:`topodrake.navigation.replan`);
  ``lidar_replan`` and ``lidar_reg_replan`` the same for those methods;
  ``replanning_gain`` is the
  smallest per-house gain over ``ours`` among the houses where ``ours`` is
  below 0.97;
- ``oracle_full``: perfect perception, the design's ceiling: the oracle map
  followed by the A* oracle C_WP and the geometric oracle RE;
- ``ours_oracle_follow``: our camera map (learned RE) followed by the two
  oracles (reading the route's anchor poses): the map's share of the errors;
- ``oracle_cwp``: the oracle map followed by the A* oracle C_WP and the
  learned camera RE: RE's share of the follower's errors;
- ``lidar_oracle_follow``: the lidar map followed by the two oracles: the
  lidar map's share;
- ``lidar_scale_oracle_re`` and ``lidar_oracle_cwp``: the lidar map
  followed by ``lidar_scale``'s C_WP with the geometric oracle RE, and by
  the A* oracle C_WP with the learned lidar RE: which of the follower's two
  networks loses the routes;
- ``lidar_reg_oracle_follow`` and ``lidar_reg_oracle_re``: ``lidar_reg``'s
  map followed by the two oracles (the map's share), and by the
  registration C_WP with the geometric oracle RE (its RE's share);
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
colliding; in one ``--world`` building each trial gets at least its A* length
at 0.25 m/s (``--time-rule``). A goal without a plan is a failed trial. Every method of a house
runs the same trials. The cars' odometry drifts as a small car's wheel
odometry does (each trial's errors from its seed; ``--odometry perfect``
reads the true pose, an ablation), as the drives' odometry stored on the
maps' edges does. Plan probabilities, and where a plan calibration
ships for the method (``topodrake map calibrate``, fitted on training
houses) each plan's calibrated ``success_probability``, are set against
empirical success (10 bins, expected calibration error; ``--rescore``
does this for recorded trials without running new ones), and maps built from 10%..100% of
the drives show how success grows with experience (``pruned_60_over_peak``:
success with 60% of the drives over the best over all fractions).

    python studies/planning.py --json                      (the default run)
    python studies/planning.py --trials 1000 --pruned-fractions 0.1,0.2,0.3,0.4,0.5,0.6,0.7,0.8,0.9,1 --pruned-trials 1000   (the paper's protocol)
    python studies/planning.py --world tests/data/maps/willow_full_0.05/map.yaml --methods oracle_full
    python studies/planning.py --houses test-2 --methods oracle_full --trace 7,68   (why trials fail)

The default run is 100 trials per method and house of ours, lidar,
lidar_scale, lidar_reg, SPTM, oracle_full, ours_replan and lidar_replan, 10 with
unmapped obstacles (ours_obstacles) and pruned fractions 0.3, 0.6, 1 of the
first house (20 trials each); the other methods (the ablations) run when
named in ``--methods``. Measured with the maps cached, 100 trials a house
over the five test houses take one core 31 min of driving for ours, 17 for
SPTM, 10 for lidar_reg, 9 for oracle_full, 7 for lidar and 6 for
lidar_scale; building the
maps from an empty cache takes about an hour more (a camera map 5-15 min,
a lidar one 0.5-2 min, an oracle one and SPTM's graph a few minutes).
``--workers N`` runs N houses at once; the paper's protocol is
``--trials 1000`` with the ten fractions.

``--json`` prints ``{"houses": {"test-0": {"ours": s, "lidar": s, "lidar_reg": s, "sptm": s,
"oracle": s, "oracle_full": s, ..., "vertices": n, "edges": n, "sptm_vertices": n,
"<method>_anchors_per_m": a, ...}, ...},
"min_ours": s, "min_oracle_full": s, "min_ours_oracle_follow": s,
"min_oracle_cwp": s, "oracle_unplanned_pairs": n, "min_margin_over_sptm": m,
"plan_probability_ece": e, "pruned_60_over_peak": r, "replanning_gain": g,
"false_link_plans": {method: share}, "unmapped_obstacles": s,
"plan_probability_ece_by_method": {method: e}, "raw_plan_probability_ece": {method: e},
"calibration_houses": {method: [house, ...]}}`` (``plan_probability_ece``: ours,
calibrated where a calibration ships; with ``--experience-rounds R``, also
``"success_by_round": {method: [s, ...]}``: each round's success, planned with the
drives of the rounds before folded into the map's edges)
and writes ``results/planning.json`` (command, seed, config, per-trial
records), ``planning.png``, ``plan_calibration.png`` and ``pruned_maps.png``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from topodrake.apps import argtypes as at
from topodrake.fileio import atomic_write_json
from topodrake.experiments.plan_methods import DEFAULT_METHODS, METHODS, ORACLE_METHODS
from topodrake.experiments.plan_results import HOUSES, paired_runs, planning, rescore
from topodrake.experiments.plan_study import ODOMETRY
from topodrake.experiments.plan_trials import T_MAX_S
from topodrake.topomap.recalibrate import PRIOR_WEIGHT


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

def main(argv=None) -> int:
    from topodrake.apps.study_args import study_main

    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    ap.add_argument("--houses", default=HOUSES, help="test houses (catalogue names or map YAMLs)")
    ap.add_argument("--world", help="one world (catalogue name or ROS map YAML) instead of "
                                    "--houses")
    ap.add_argument("--methods", default=",".join(DEFAULT_METHODS),
                    help="methods to run, of " + ", ".join(METHODS))
    ap.add_argument("--trials", type=at.count, default=100,
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
    ap.add_argument("--time-limit", type=at.positive, default=T_MAX_S, metavar="S",
                    help="seconds a trial may drive before it times out (long plans in a "
                         "large building need more)")
    ap.add_argument("--time-rule", choices=["fixed", "route"],
                    help="'fixed': every trial gets --time-limit; 'route': each trial gets the "
                         "longer of --time-limit and its A* length from start to goal at "
                         "0.25 m/s (the RE labels' rule, A* / v_min), for buildings whose routes "
                         "are longer than the limit drives (default: fixed for --houses, route "
                         "for --world)")
    ap.add_argument("--route-time", action="store_true", help="the same as --time-rule route")
    ap.add_argument("--paper-plans", action="store_true",
                    help="plan the most probable path as the paper does, not the path most "
                         "likely to be driven within the time limit")
    ap.add_argument("--pruned-fractions",
                    help="fractions of the drives for the pruned maps, or 'none' "
                         "(paper: 0.1,0.2,...,1; default: 0.3,0.6,1 for --houses, none for "
                         "--world)")
    ap.add_argument("--pruned-house", help="house of the pruned maps (default: the first)")
    ap.add_argument("--pruned-method", choices=["ours", "lidar", "oracle"], default="ours",
                    help="map of the pruned study")
    ap.add_argument("--pruned-trials", type=at.count, default=20,
                    help="trials per pruned map (paper: 1000)")
    ap.add_argument("--pruned-seed", type=at.seed, default=0, help="seed of the drive subsets")
    ap.add_argument("--experience-rounds", type=at.count, default=1,
                    help="run each plainly driven map method's trials in this many rounds, "
                         "each planned with the drives of the rounds before folded into the "
                         "map's edges (1: every trial on the map as built)")
    ap.add_argument("--experience-prior-weight", type=float, default=PRIOR_WEIGHT,
                    help="drives RE's rating of an edge counts for when earlier drives are "
                         "folded in")
    ap.add_argument("--map-config", metavar="YAML",
                    help="map settings (a MapConfig YAML, every key optional) for the maps "
                         "built from the drives; maps of other settings than the library's "
                         "defaults are cached under names of their own (default: the defaults)")
    ap.add_argument("--follower", metavar="JSON",
                    help="follower settings to change, as JSON (FollowerConfig fields; an "
                         "ablation), recorded in planning.json's config")
    ap.add_argument("--odometry", choices=ODOMETRY, default="wheel",
                    help="what the cars' odometry reads: wheel odometry that drifts "
                         "(topodrake.odometry.OdometryConfig.wheel, each trial's errors from "
                         "its seed) or the true pose (an ablation); recorded in "
                         "planning.json's config")
    ap.add_argument("--replan", metavar="JSON",
                    help="replanning schedule of the *_replan methods to change, as JSON "
                         "(ReplanSchedule fields: first, every, discount, max_replans; default: "
                         "tries in the last 10 Dead reckoning periods before giving up), or "
                         "'paper' for the paper's schedule; recorded in planning.json's config")
    ap.add_argument("--seed", type=at.seed, default=0, help="base seed of the trials")
    ap.add_argument("--data", default="data", help="cache of demonstrations and maps")
    ap.add_argument("--workers", type=at.count, default=1,
                    help="local worker processes, one house each")
    ap.add_argument("--ray", metavar="ADDRESS", help="run the houses on a Ray cluster")
    ap.add_argument("--out", default="results", help="folder of the JSON and PNG results")
    ap.add_argument("--rescore", metavar="PLANNING_JSON[,...]",
                    help="run no trials: set the shipped plan calibrations against the trials "
                         "recorded in these planning.json files and write "
                         "plan_calibration.json and plan_calibration.png into --out")
    ap.add_argument("--paired", metavar="BEFORE.json[:METHOD],AFTER.json[:METHOD]",
                    help="run no trials: set two recorded runs side by side on their common "
                         "trials (each method both ran, or the two named) and print each "
                         "house's success and the paired difference with its 95 %% interval")
    ap.add_argument("--fit-driving-time", metavar="PLANNING_JSON[,...]",
                    help="run no trials: fit the follower's driving time (the planner's model "
                         "of how long a plan takes) to the trials recorded in these files, "
                         "per method and over all, and print it")
    ap.add_argument("--trace", type=at.indices, metavar="TRIALS",
                    help="drive these trials (indices, e.g. 7,68) of the one method and house "
                         "given, each alone, and write each one's timeline (trace.json) and "
                         "path (trace-<trial>.png) into --out; prints the timelines")
    ap.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    args = ap.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    return study_main(_run, args)


def _command(args) -> str:
    return "python studies/planning.py " + " ".join(args.argv)


def _rescore(args) -> int:
    """The shipped plan calibrations against recorded trials (no new trials)."""
    doc = rescore(args.rescore, _command(args))
    out, summary, cal = Path(args.out), doc["summary"], doc["calibration"]
    atomic_write_json(out / "plan_calibration.json", doc)
    if cal:
        plot_calibration(cal, out / "plan_calibration.png")
    print(json.dumps(summary) if args.json else
          "\n".join(f"{m:<20} ECE {c['ece_raw']} raw, {c['ece']} "
                    f"{'calibrated' if c['calibrated'] else '(no calibration)'} over "
                    f"{c['planned_trials']} planned trials" for m, c in cal.items()))
    return 0


def _paired(args) -> int:
    """Two recorded runs compared trial by trial (no new trials)."""
    doc = paired_runs(args.paired)
    if args.json:
        print(json.dumps(doc))
        return 0
    for name, p in doc.items():
        d = p["difference"]
        print(f"{name}: {p['before']:.3f} -> {p['after']:.3f}, paired {d['mean']:+.3f} "
              f"({d['ci95'][0]:+.3f}..{d['ci95'][1]:+.3f}) over {d['pairs']} trials; "
              + ", ".join(f"{h} {a:.2f}->{b:.2f}" for h, (a, b) in p["houses"].items()))
    return 0


def _fit_driving_time(args) -> int:
    """The planner's driving-time model fitted to recorded trials (no new trials)."""
    from topodrake.experiments.plan_timing import driving_time_fit

    doc = driving_time_fit(args.fit_driving_time, _command(args))
    if args.json:
        print(json.dumps(doc))
        return 0
    for name, f in doc["fits"].items():
        print(f"{name:<20} {f['start_s']:.1f} s + {f['per_m_s']:.2f} s/m + {f['per_hop_s']:.2f} "
              f"s/hop, spread {f['spread']:.2f}; {f['timeouts']} time-outs of {f['trials']} "
              f"trials, {f['predicted_timeouts']} predicted")
    return 0


def _trace(args) -> int:
    """Some trials of one method in one house driven alone, their timelines
    written and printed."""
    from topodrake.errors import TopodrakeError
    from topodrake.experiments.plan_results import study_config
    from topodrake.experiments.plan_trace import plot_trace, trace_trials
    from topodrake.world import load_world

    cfg, specs, _, _ = study_config(args)
    if len(specs) != 1 or len(cfg["methods"]) != 1:
        raise TopodrakeError("--trace needs one house (--houses H or --world W) and one method "
                             f"(--methods M), got {len(specs)} and {len(cfg['methods'])}")
    traces = trace_trials(specs[0], cfg["methods"][0], args.trace, cfg)
    out, world = Path(args.out), load_world(specs[0])
    doc = {"command": _command(args), "config": {k: v for k, v in cfg.items() if k != "quiet"},
           "traces": [t.to_json() for t in traces]}
    atomic_write_json(out / "trace.json", doc)
    for t in traces:
        plot_trace(world, t, out / f"trace-{t.trial}.png")
    if args.json:
        print(json.dumps(doc["traces"]))
        return 0
    for t in doc["traces"]:
        print(f"trial {t['trial']}: place {t['start_place']} -> {t['goal_place']}, "
              f"{len(t['plan_vertices'])} anchors (p {t['plan_probability']:.3f}), "
              f"{t['outcome']} {t['final_distance_m']:.2f} m from the goal after "
              f"{t['driven_s']} s")
        for seg in t["segments"]:
            a0, a1 = seg["anchors"]
            x, y, th = seg["end_pose"]
            print(f"  {seg['from_s']:6.1f}-{seg['to_s']:6.1f} s  {seg['mode']:<15} anchors "
                  f"{a0:>3}..{a1:<3} ends at ({x:.2f}, {y:.2f}, {th:+.2f})")
    print(f"wrote {out / 'trace.json'} and {len(traces)} plots", file=sys.stderr)
    return 0


def _run(args) -> int:
    if args.trace:
        return _trace(args)
    if args.fit_driving_time:
        return _fit_driving_time(args)
    if args.paired:
        return _paired(args)
    if args.rescore:
        return _rescore(args)
    doc = planning(args, _command(args))
    out, summary, houses, cal = Path(args.out), doc["summary"], doc["houses"], doc["calibration"]
    methods = doc["config"]["methods"]
    atomic_write_json(out / "planning.json", doc)
    plot_table(houses, methods, out / "planning.png", args.trials)
    if cal:
        plot_calibration(cal, out / "plan_calibration.png")
    plot_pruned(doc["pruned"], out / "pruned_maps.png")
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
          f"{doc['wall_time_s'] / 60:.1f} min; wrote {out / 'planning.json'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
