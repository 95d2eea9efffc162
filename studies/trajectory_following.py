"""Trajectory following: cover rate against anchors per metre (the paper's cover-rate figure).

Test trajectories (seeded expert drives between random free poses of the
test houses whose A* path is 10-20 m, mean about 15 m; cached in
``DATA/trajectory_following/``) are each reduced to a chain of anchors (a)
by RE sparsification at every ``--p`` and (b) by keeping every n-th frame
(the SPTM way) at the density the RE chains of that ``p`` have. Each chain is
followed by the learned follower (:mod:`topodrake.navigation`, the batched
navigation engine) from a jittered start (0.3 m to a random side, turned
9 deg to a random side), with each controller and its RE; at p = 0.99 the RE
chains are followed again with actuation noise N(1, ``--noise``). The robot
stops when it strays more than 1 m from the reference path (``DIVERGE_M``),
collides, the follower ends, or at 2 x frames + 100 periods. Cover: the
share of the reference path's length up to the farthest reference sample the
robot came within 0.5 m of (in order), averaged over trajectories. At
that ``p`` the RE chains are also followed with perfect perception (the A*
oracle C_WP and the geometric oracle RE: ``cover_oracle``), which separates
the follower's design from the networks' errors, and with ``--runs
oracle_re`` by the controller's own C_WP with the geometric oracle RE in
the follower's place (``cover_oracle_re``: what RE's answers cost the
follower on the same chains).
``--follower`` changes the follower's thresholds (an ablation).
``--chain-re NAME=CHECKPOINT`` places NAME's anchors with another RE while
NAME's own RE answers the follower (the two roles of RE apart).
``--cwp NAME=oracle:anchor=0.3`` follows NAME's chains with the A* oracle
C_WP plus a controlled error and NAME's RE
(:mod:`topodrake.learning.waypoint.noisy_oracle`); ``--sensitivity anchor=0.1,0.3``
follows the RE chains at the headline p with it at each error size (the
``sensitivity`` table: cover against error).

Each controller's chains and each engine batch of follows are kept in
``OUT/trajectory_following_runs/`` with the settings and checkpoint hashes
that made them; a rerun with the same settings reuses them, so a long run
(``--trajectories 500``) resumes after a stop.

camera_k0 has no RE of its own: its chains and its follower's RE are the
camera k=2 ones (the network of the nearest controller).

lidar_reg is the registration controller
(:class:`topodrake.registration.policy.RegistrationPolicy`: no network,
scans registered against the anchors' taught scans) with two REs learnt from
its own rollouts: ``checkpoints/reach_lidar_reg`` (rollouts that start cold)
places its anchors and ``checkpoints/reach_lidar_reg_tracked`` (rollouts that
start the controller tracking its target, as the follower's tracker does)
answers its follower; ``--re lidar_reg=...`` replaces both. Its runs are keyed by
the controller's settings and the registration package's sources instead of
a checkpoint's hash.

    python studies/trajectory_following.py --json

prints at p = 0.99 ``{"camera_k0": {"cover": c, "cover_noisy": c,
"cover_subsampled": c, "cover_oracle": c, "cover_oracle_re": c, "anchors_per_m": a},
...}`` (``cover_oracle_re`` null unless asked for) and writes
``results/trajectory_following.json`` and ``.png``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from topodrake.apps import argtypes as at
from topodrake.fileio import atomic_write_json
from topodrake.experiments.follow_study import following
from topodrake.experiments.follow_trials import CONTROLLERS


def plot(results: dict, path: Path, n_traj: int) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from topodrake.world.plot import save_figure

    fig, ax = plt.subplots(figsize=(8, 5.5))
    for i, (name, r) in enumerate(results.items()):
        color = f"C{i}"
        pts = r["points"]
        nan = float("nan")
        ax.plot([q["anchors_per_m"] for q in pts], [q.get("cover", nan) for q in pts], "o-",
                color=color,
                label=f"{name}, RE anchors")
        for q in pts:
            ax.annotate(f"{q['p_sparsify']}", (q["anchors_per_m"], q.get("cover", nan)), fontsize=7,
                        xytext=(3, 3), textcoords="offset points", color=color)
        ax.plot([q["subsampled_anchors_per_m"] for q in pts],
                [q.get("cover_subsampled", nan) for q in pts],
                "s--", color=color, alpha=0.7, label=f"{name}, every n-th frame")
    ax.set_xlabel("anchors per metre")
    ax.set_ylabel("cover rate")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title(f"Trajectory following, {n_traj} test trajectories (points marked with p_sparsify)")
    save_figure(fig, path)


def main(argv=None) -> int:
    from topodrake.apps.study_args import study_main

    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    ap.add_argument("--trajectories", type=at.count, default=8, help="test trajectories (paper: 500)")
    ap.add_argument("--worlds", default="test-0,test-1,test-2,test-3,test-4", help="test houses")
    ap.add_argument("--p", default="0.9,0.95,0.98,0.99,0.995", help="p_sparsify values")
    ap.add_argument("--headline-p", type=at.probability, default=0.99,
                    help="p_sparsify of the printed summary and of the noisy runs")
    ap.add_argument("--controllers", default=",".join(CONTROLLERS),
                    help="controllers to follow with")
    ap.add_argument("--cwp", action="append", metavar="NAME=CHECKPOINT",
                    help="follow NAME's chains with another C_WP (NAME's RE stays; repeatable); "
                         "oracle:KEY=VALUE[:...]: the A* oracle with a controlled error (keys "
                         "anchor, fresh, tail, seed)")
    ap.add_argument("--sensitivity", metavar="KEY=V1,V2,...",
                    help="also follow each controller's RE chains at the headline p with the "
                         "oracle C_WP (its --cwp oracle spec, else the exact one) with KEY set to "
                         "each value: cover against error size")
    ap.add_argument("--re", action="append", metavar="NAME=CHECKPOINT",
                    help="with another RE under NAME, trained for NAME's C_WP (the --cwp one if "
                         "given): its chains and its answers; repeatable")
    ap.add_argument("--chain-re", action="append", metavar="NAME=CHECKPOINT",
                    help="place NAME's anchors with this RE (trained for NAME's C_WP, the same "
                         "sensor) while NAME's RE answers the follower; repeatable")
    ap.add_argument("--batch", type=at.count, default=48, help="cars per engine batch")
    ap.add_argument("--seed", type=at.seed, default=0, help="seed of the trajectories, starts and noise")
    ap.add_argument("--noise", type=at.nonnegative, default=0.33, help="actuation noise std of the noisy runs")
    ap.add_argument("--data", default="data", help="cache of the test trajectories")
    ap.add_argument("--out", default="results", help="output folder")
    ap.add_argument("--follower", default="{}",
                    help="follower thresholds to change, as JSON (FollowerConfig fields)")
    ap.add_argument("--runs", default="re,subsampled,noisy,oracle",
                    help="which runs to make (comma-separated of re, subsampled, noisy, oracle, "
                         "oracle_re: the controller's C_WP with the geometric oracle RE; noisy, "
                         "oracle and oracle_re at the headline p only); figures of runs left out "
                         "are null")
    ap.add_argument("--odometry", choices=("perfect", "wheel"), default="wheel",
                    help="the cars' and the drives' odometry: the true pose, or wheel odometry "
                         "that drifts (topodrake.odometry.OdometryConfig.wheel)")
    ap.add_argument("--slack", type=at.fraction, default=0.0,
                    help="sparsify slack where RE passes not even the next frame above p (0: the "
                         "paper's rule; maps use MapConfig.sparsify_slack)")
    ap.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    return study_main(_run, args)


def _run(args) -> int:
    doc = following(args, "python studies/trajectory_following.py " + " ".join(sys.argv[1:]))
    out, results, summary = Path(args.out), doc["results"], doc["summary"]
    tables = doc.get("sensitivity", {})
    atomic_write_json(out / "trajectory_following.json", doc)
    plot(results, out / "trajectory_following.png", doc["trajectories"])
    if args.json:
        print(json.dumps({**summary, **({"sensitivity": tables} if tables else {})}))
    else:
        for name, s in summary.items():
            f = {k: "-" if v is None else f"{v:.3f}" for k, v in s.items()}
            print(f"{name:<10} cover {f['cover']}, oracle {f['cover_oracle']}, "
                  f"oracle RE {f['cover_oracle_re']}, "
                  f"noisy {f['cover_noisy']}, every n-th "
                  f"{f['cover_subsampled']} at {s['anchors_per_m']:.2f} anchors/m")
        for name, t in tables.items():
            print(f"{name} RE chains at p = {t['p_sparsify']}, oracle C_WP with {t['key']}:")
            for row in t["rows"]:
                print(f"  {t['key']}={row[t['key']]:<6g} cover {row['cover']:.3f} "
                      f"({row['trajectories']} trajectories, {row['spec']})")
    print(f"{doc['trajectories']} trajectories (mean {doc['mean_length_m']:.1f} m), "
          f"{len(results)} controllers, {len(doc['p_sparsify'])} p values in "
          f"{doc['wall_time_s'] / 60:.1f} min", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
