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
from topodrake.apps.study_args import (
    add_output_arguments,
    add_scenario_arguments,
    printed_config,
    scenario_of,
    study_main,
)
from topodrake.experiments.reach_limits import ReachLimitsStudy, reach_limits
from topodrake.fileio import atomic_write_json

SCENARIOS = Path(__file__).resolve().parent / "scenarios" / "reachability_limits.yaml"


def main(argv=None) -> int:
    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    add_scenario_arguments(ap, ReachLimitsStudy, SCENARIOS, "default",
                           {"pairs": at.count, "runs": at.count, "hop_pairs": at.count,
                            "keep_drives": at.count0, "keep_runs": at.count})
    add_output_arguments(ap)
    args = ap.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    return study_main(_run, args)


def _run(args) -> int:
    study = scenario_of(ReachLimitsStudy, args, SCENARIOS)
    if printed_config(study, args):
        return 0
    doc = reach_limits(study, "python studies/reachability_limits.py " + " ".join(args.argv),
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
