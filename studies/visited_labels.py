"""Does the controller reach the anchors the follower asks RE about? Labels at visited states.

Follows seeded RE chains of demonstration drives in training houses no
network saw (the follower calibration's), and from a sample of the states
the follower drove through rolls the controller's C_WP out toward the
anchor it aimed at and toward the one after it (what Follow's advance
rule and Dead reckoning ask), under the RE labels' rules: once from a
fresh tracking state (how RE's labels are made) and once tracked
(``ReachLabelConfig.tracked_start``: a tracking C_WP, the registration
controller, starts already tracking the target, as a following car's
tracker holds it). Beside each: the probability the follower acts on.

    python studies/visited_labels.py --json

prints ``{"active_anchor": {...}, "next_anchor": {"success_cold": s,
"success_tracked": s, "mean_re_p": p, ...}}`` and writes
``results/visited_labels.json``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from topodrake.apps import argtypes as at
from topodrake.fileio import atomic_write_json


def main(argv=None) -> int:
    from topodrake.learning.onpolicy.calibration import follower_probability, label_visited_reach
    from topodrake.learning.onpolicy.states import OnPolicyConfig, collect_visited, pick_drives
    from topodrake.learning.reachability.controllers import controller_policy
    from topodrake.learning.reachability.estimator import Reachability
    from topodrake.learning.reachability.labels import ReachLabelConfig
    from topodrake.learning.samples import collect_trajectories
    from topodrake.world import load_world

    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    ap.add_argument("--cwp", default="registration", help="the C_WP (a checkpoint or registration)")
    ap.add_argument("--re", default="checkpoints/reach_lidar_reg/checkpoint.pt",
                    help="the RE that steers the follower (trained for --cwp)")
    ap.add_argument("--houses", default="train-84,train-85,train-86,train-87",
                    help="houses, comma-separated")
    ap.add_argument("--drives", type=at.count, default=8, help="chains followed per house")
    ap.add_argument("--states", type=at.count, default=150, help="visited states labelled per house")
    ap.add_argument("--seed", type=at.seed, default=0, help="seed of the drives, states and noise")
    ap.add_argument("--data", default="data", help="cache of demonstrations")
    ap.add_argument("--out", default="results", help="output folder")
    ap.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    args = ap.parse_args(argv)
    start = time.time()
    policy = controller_policy(args.cwp)
    reach = Reachability.from_checkpoint(args.re, args.cwp)
    worlds = [h for h in args.houses.split(",") if h]
    trajs = collect_trajectories(worlds, Path(args.data) / "demos" / "pairs-s0", progress=False)
    rng = np.random.default_rng([args.seed, 11])
    per = {}
    for w, name in enumerate(trajs.worlds):
        world = load_world(name)
        drives = pick_drives(trajs, w, args.drives, args.seed)
        visited = collect_visited(world, trajs, drives, policy, reach,
                                  OnPolicyConfig(drives_per_world=args.drives), seed=w)
        pick = rng.permutation(len(visited))[:args.states]
        vs = visited.subset(pick)
        for ahead in (False, True):
            got = {}
            for tracked in (False, True):
                got[tracked] = label_visited_reach(
                    world, trajs, vs, policy, reach, len(vs), np.random.default_rng(0),
                    args.seed * 100 + w, ahead=ahead,
                    config=ReachLabelConfig(tracked_start=tracked))
            p = follower_probability(reach, got[False].logit)
            per.setdefault("next_anchor" if ahead else "active_anchor", []).append(
                (got[False].label, got[True].label, p))
        print(f"{name}: {len(visited)} states, cover {visited.cover.mean():.3f}", file=sys.stderr,
              flush=True)
    summary = {}
    for key, parts in per.items():
        cold, tracked, p = (np.concatenate([q[i] for q in parts]) for i in range(3))
        summary[key] = {"states": int(len(cold)), "success_cold": round(float(cold.mean()), 4),
                        "success_tracked": round(float(tracked.mean()), 4),
                        "mean_re_p": round(float(p.mean()), 4),
                        "re_below_0.85_tracked_reached": round(float(np.mean((p < 0.85)
                                                                             & (tracked == 1))), 4)}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "visited_labels.json", {
        "command": "python studies/visited_labels.py " + " ".join(argv or sys.argv[1:]),
        "summary": summary, "config": vars(args), "wall_time_s": round(time.time() - start, 1)})
    if args.json:
        import json

        print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
