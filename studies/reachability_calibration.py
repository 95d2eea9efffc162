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
from pathlib import Path

import numpy as np

from topodrake.apps import argtypes as at
from topodrake.apps.study_args import (
    add_output_arguments,
    add_scenario_arguments,
    printed_config,
    scenario_of,
    study_main,
)
from topodrake.experiments.calibration_trials import CalibrationStudy, calibration_trials
from topodrake.fileio import atomic_write_json

SCENARIOS = Path(__file__).resolve().parent / "scenarios" / "reachability_calibration.yaml"


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
    add_scenario_arguments(ap, CalibrationStudy, SCENARIOS, "default",
                           {"pairs": at.count, "p": at.probability, "keep_drives": at.count,
                            "workers": at.count})
    add_output_arguments(ap)
    args = ap.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    return study_main(_run, args)


def _run(args) -> int:
    study = scenario_of(CalibrationStudy, args, SCENARIOS)
    if printed_config(study, args):
        return 0
    doc = calibration_trials(
        study, "python studies/reachability_calibration.py " + " ".join(args.argv),
        quiet=args.quiet)
    out, summary = Path(args.out), doc["summary"]
    atomic_write_json(out / "reachability_calibration.json", doc)
    plot(doc["details"], out / "reachability_calibration.png")
    if args.json:
        print(json.dumps(summary))
    else:
        for name, s in summary.items():
            print(f"{name:<10} ECE {s['ece']:.3f}  Brier {s['brier']:.3f}  AUROC {s['auroc']}  "
                  f"keep ratio {s['keep_ratio']:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
