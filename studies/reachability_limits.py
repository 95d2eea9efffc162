"""What limits RE? The outcomes' own noise, the blind starts, and the controller.

Three measurements per RE (default: camera k=5 and lidar k=5, each with its
C_WP), in the test houses, with the batched engine
(:func:`topodrake.learning.reachability.labels.rollout_pairs`, actuation noise on):

* **noise ceiling**: ``--pairs`` fresh pairs drawn as for the RE labels, each
  driven ``--runs`` times with different noise seeds. ``oracle_auroc`` ranks
  each run's outcome by the pair's success rate over the other runs: the
  AUROC an estimator that knew every pair's true success probability would
  reach. ``re_auroc`` is RE's AUROC on the same runs (mean over runs).
* **blind starts**: pairs whose two views share nothing at the start
  (both overlaps < 0.05) fail at once. ``re_auroc_blind_known`` is RE's AUROC
  with those pairs scored 0 (what RE would reach if it recognised them
  perfectly and ranked the rest as it does), ``blind_detection_auroc`` how
  well RE's probability tells them from the rest.
* **anchor hops**: ``--hop-pairs`` pairs in the regime of sparsification
  (source on an expert frame, target up to 3 m ahead on the same drive), one
  run each: the controller's success rate by hop length.
* **keep ratio the controller allows**: ``--keep-drives`` expert drives per
  house sparsified with the controller's own outcomes in RE's place
  (:func:`topodrake.experiments.hops.controller_sparsify`: a frame passes when
  all ``--keep-runs`` noisy runs toward it are made, hops capped at 2 m),
  each resulting hop then driven ``--keep-runs`` more times with fresh
  seeds (``hop_success``, which should be about p_sparsify) and RE's own
  keep ratio on the same drives: how far RE is from the keep ratio a perfect
  estimator of this controller would reach.

    python studies/reachability_limits.py --json

prints ``{"camera_k5": {"oracle_auroc", "re_auroc", "re_auroc_blind_known",
"share_blind", ..., "controller_keep": {...}}, ...}`` and writes
``results/reachability_limits.json``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from topodrake.apps import argtypes as at
from topodrake.fileio import atomic_write_json
from topodrake.experiments.reach_limits import DEFAULT_ESTIMATORS, ReachLimitsStudy, reach_limits


def main(argv=None) -> int:
    from topodrake.apps.study_args import study_main, typed_from_args

    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    ap.add_argument("--estimators", default=DEFAULT_ESTIMATORS, help="name=RE.pt:CWP.pt, comma-separated")
    ap.add_argument("--pairs", type=at.count, default=1000, help="pairs for the noise ceiling")
    ap.add_argument("--runs", type=at.count, default=8, help="noisy runs per pair")
    ap.add_argument("--hop-pairs", type=at.count, default=2000, help="anchor hops (one run each)")
    ap.add_argument("--keep-drives", type=at.count0, default=1,
                    help="drives per house sparsified by the controller's own outcomes (0: skip)")
    ap.add_argument("--keep-runs", type=at.count, default=16,
                    help="noisy runs per candidate frame (all must be made) and per hop")
    ap.add_argument("--seed", type=at.seed, default=0, help="base seed of the pairs and runs")
    ap.add_argument("--data", default="data", help="cache of demonstrations (test houses)")
    ap.add_argument("--out", default="results", help="folder of the JSON and PNG results")
    ap.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    args = ap.parse_args(argv)
    return study_main(lambda a: _run(a, typed_from_args(ReachLimitsStudy, a)), args)


def _run(args, study: ReachLimitsStudy) -> int:
    doc = reach_limits(study, "python studies/reachability_limits.py " + " ".join(sys.argv[1:]),
                       quiet=args.quiet)
    summary = doc["summary"]
    atomic_write_json(Path(args.out) / "reachability_limits.json", doc)
    if args.json:
        print(json.dumps(summary))
    else:
        for name, s in summary.items():
            print(f"{name:<10} oracle AUROC {s['oracle_auroc']:.3f}  RE {s['re_auroc']:.3f}  "
                  f"RE with blind starts known {s['re_auroc_blind_known']:.3f}  "
                  f"blind {s['share_blind']:.0%}")
            if "controller_keep" in s:
                k = s["controller_keep"]
                print(f"{'':<10} keep ratio: controller's own outcomes {k['keep_ratio']:.3f} "
                      f"(hops made {k['hop_success']:.3f}), RE {k['re_keep_ratio']:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
