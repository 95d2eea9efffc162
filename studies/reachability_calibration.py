"""Is RE calibrated? Predicted reachability against closed-loop outcomes in Drake.

For each RE (default: camera k=5 and lidar k=5, each with the C_WP it was
trained for) and for clean and noisy actuation, ``--pairs`` seeded trials
(``topodrake.systems.trials.reach_trial``): a fresh pair in the test houses
drawn as for the RE labels, RE's probability from the source observation,
and the outcome of the C_WP + RMP diagram driving it (success within
0.27 m or both overlaps > 0.7 before A*/v_min; failure on timeout,
collision or both overlaps < 0.05). Also ``keep_ratio``: the fraction of
test-house expert frames kept as anchors at ``--p`` (0.99), with RE's
calibration for anchor hops (the JSON file adds the ratio under the
temperature, ``keep_ratio_temperature``).

    python studies/reachability_calibration.py --pairs 1000 --json

prints ``{"camera_k5": {"ece", "brier", "auroc", "keep_ratio"}, ...}`` with
the noisy runs' figures (RE is trained on noisy rollouts) and writes
``results/reachability_calibration.json`` (both settings, reliability bins,
the command) and ``results/reachability_calibration.png`` (binned predicted
probability against the empirical success rate, like the paper's
path-probability figure).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from topodrake import argtypes as at
from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_json
from topodrake.learning.reachability.estimator import parse_estimators
from topodrake.montecarlo import add_study_arguments, study_main

DEFAULT = ("camera_k5=checkpoints/reach_camera_k5/checkpoint.pt:checkpoints/camera_k5/checkpoint.pt,"
           "lidar_k5=checkpoints/reach_lidar_k5/checkpoint.pt:checkpoints/lidar_k5/checkpoint.pt")
WORLDS = ("test-0", "test-1", "test-2", "test-3", "test-4")


def keep_ratios(reach: str, controller: str, data_dir: str, p: float,
                drives: int | None) -> tuple[float, float]:
    """Anchors kept / frames over the test houses' successful expert drives,
    with RE's anchor-hop calibration and with its temperature (as for any
    other pair), from one pass over the drives."""
    from topodrake.learning.reachability.estimator import Reachability
    from topodrake.topomap.hops import sparsify_houses

    re = Reachability.from_checkpoint(reach, controller)
    out = sparsify_houses(re, list(WORLDS), Path(data_dir) / "demos" / "pairs-s0", p,
                          drives=drives,
                          other_calibrations={"temperature": (1.0 / re.temperature, 0.0)})
    return out["keep_ratio"] or 0.0, out["keep_ratios"]["temperature"] or 0.0


def summarise_trials(res: list[dict]) -> dict:
    """ECE, Brier, AUROC and reliability bins of trial records (``p``,
    ``success``, ``start_overlap``), and AUROC split by the pairs' start.

    Pairs that see nothing of each other at the start fail at once (both
    overlaps < 0.05): ``auroc_reached_vs_not_overlapping`` says how well RE
    tells the reached pairs from those, ``auroc_overlapping`` how well it
    ranks the pairs that are actually driven."""
    from topodrake.learning.reachability.calibration import calibration_summary, reliability
    from topodrake.learning.reachability.labels import ReachLabelConfig

    p = np.array([r["p"] for r in res], float)
    y = np.array([r["success"] for r in res], int)
    seeing = np.array([max(r["start_overlap"]) >= ReachLabelConfig().overlap_lost for r in res])

    def auroc_of(sel):
        return calibration_summary(p[sel], y[sel])["auroc"] if sel.any() else None

    s = calibration_summary(p, y)
    s["share_not_overlapping"] = float(1 - seeing.mean())
    s["auroc_overlapping"] = auroc_of(seeing)
    s["auroc_reached_vs_not_overlapping"] = auroc_of(~seeing | (y == 1))
    rel = reliability(p, y)
    s["reliability"] = {"edges": rel.edges.tolist(), "count": rel.count.tolist(),
                        "rate": [None if np.isnan(v) else float(v) for v in rel.rate],
                        "mean_pred": [None if np.isnan(v) else float(v) for v in rel.mean_pred]}
    return s


def plot(details: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from topodrake.world.plot import save_figure

    names = list(details)
    fig, axes = plt.subplots(1, len(names), figsize=(5 * len(names), 4.2), dpi=110, squeeze=False)
    for ax, name in zip(axes[0], names):
        for off, cond, colour in ((-0.02, "clean", "#3b75af"), (0.02, "noisy", "#ef8636")):
            r = details[name][cond]["reliability"]
            centres = (np.array(r["edges"][:-1]) + np.array(r["edges"][1:])) / 2
            rate = np.array([np.nan if v is None else v for v in r["rate"]], float)
            ax.bar(centres + off, np.nan_to_num(rate), 0.04, color=colour, label=f"{cond} actuation")
        ax.plot([0, 1], [0, 1], "k--", lw=1, label="calibrated")
        s = details[name]["noisy"]
        ax.set_title(f"{name}: ECE {s['ece']:.3f}, AUROC {s['auroc'] or float('nan'):.3f}")
        ax.set_xlabel("predicted reachability (bin)")
        ax.set_ylabel("empirical success rate")
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1.05)
        ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)


def main(argv=None) -> int:
    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    ap.add_argument("--pairs", type=at.count, default=1000, help="labelled pairs per estimator")
    ap.add_argument("--estimators", default=DEFAULT, help="name=RE.pt:CWP.pt, comma-separated")
    ap.add_argument("--p", type=at.probability, default=0.99, help="p_sparsify for keep_ratio")
    ap.add_argument("--keep-drives", type=at.count, help="drives per house for keep_ratio (default all)")
    add_study_arguments(ap, "cache of demonstrations (test houses)")
    return study_main(_run, ap.parse_args(argv))


def _run(args) -> int:
    from topodrake.learning.samples import collect_trajectories
    from topodrake.montecarlo import run_trials, trial_seeds
    from topodrake.systems.trials import reach_trial

    if args.pairs < 1:
        raise TopodrakeError("--pairs must be >= 1")
    estimators = parse_estimators(args.estimators)
    # make sure the test houses' demonstrations exist before the workers start
    collect_trajectories(list(WORLDS), Path(args.data) / "demos" / "pairs-s0",
                         progress=not args.quiet)
    seeds = trial_seeds(args.seed, args.pairs)
    summary, details = {}, {}
    t0 = time.perf_counter()
    for name, (reach, controller) in estimators.items():
        details[name] = {}
        for cond, noise in (("clean", 0.0), ("noisy", args.noise)):
            res = run_trials(reach_trial, seeds, workers=args.workers, ray_address=args.ray,
                             progress=not args.quiet, desc=f"{name} {cond}", reach=reach,
                             controller=controller, noise_std=noise, data_dir=args.data,
                             worlds=WORLDS)
            details[name][cond] = summarise_trials(res)
    # The keep ratios run RE in this process, so they come after every
    # forked Monte Carlo block (a fork after torch has started its OpenMP
    # threads can hang the children).
    for name, (reach, controller) in estimators.items():
        ratio, under_t = keep_ratios(reach, controller, args.data, args.p, args.keep_drives)
        details[name]["keep_ratio_temperature"] = round(under_t, 4)
        n = details[name]["noisy"]
        summary[name] = {"ece": round(n["ece"], 4), "brier": round(n["brier"], 4),
                         "auroc": None if n["auroc"] is None else round(n["auroc"], 4),
                         "keep_ratio": round(ratio, 4)}
    out = Path(args.out)
    atomic_write_json(out / "reachability_calibration.json", {
        "command": "python studies/reachability_calibration.py " + " ".join(sys.argv[1:]),
        "pairs": args.pairs, "seed": args.seed, "noise_std": args.noise, "p_sparsify": args.p,
        "estimators": {k: {"reach": r, "controller": c} for k, (r, c) in estimators.items()},
        "wall_time_s": round(time.perf_counter() - t0, 1), "summary": summary, "details": details})
    plot(details, out / "reachability_calibration.png")
    if args.json:
        print(json.dumps(summary))
    else:
        for name, s in summary.items():
            print(f"{name:<10} ECE {s['ece']:.3f}  Brier {s['brier']:.3f}  AUROC {s['auroc']}  "
                  f"keep ratio {s['keep_ratio']:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
