"""The paper's Table I: success rate of each local controller, in Drake.

For every controller (C_WP camera k=0/2/5, lidar k=5, the registration
C_WP ``lidar_reg`` (lidar teach and repeat, no network), the direct-control
baseline; optionally the A* oracle as a protocol check) and for clean and
noisy actuation, run ``--trials`` seeded Monte Carlo trials of the C_WP + RMP
diagram (``topodrake.systems.trials.controller_trial``): source on a
test-house expert trajectory, target 1 m behind to 3 m ahead, success =
within 0.27 m of the target or both image overlaps > 0.7 within the time
limit, collision = failure. The pairs depend only on the trial seeds, so all
controllers and both noise settings are scored on the same pairs.

    python studies/controller_success.py --trials 400 --json

prints ``{"camera_k0": {"clean": p, "noisy": p}, ...}`` and writes
``results/controller_success.json`` (the same object),
``results/controller_success_details.json`` (outcome counts, Wilson 95 %
intervals, the command) and ``results/controller_success.png``.

Each (controller, noise) block of trials is kept in
``results/controller_success_runs/`` with the checkpoint's hash; a rerun with
the same settings reuses finished blocks, so the study can be run as the
checkpoints arrive (``--controllers camera_k2``) and resumed after a stop.
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
from topodrake.experiments.success_table import PAPER, SuccessTableStudy, success_table
from topodrake.fileio import atomic_write_json

SCENARIOS = Path(__file__).resolve().parent / "scenarios" / "controller_success.yaml"


def plot(summary: dict, details: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from topodrake.world.plot import save_figure

    names = list(summary)
    x = np.arange(len(names))
    fig, ax = plt.subplots(figsize=(7.5, 3.6), dpi=120)
    for off, cond, colour in ((-0.2, "clean", "#3b75af"), (0.2, "noisy", "#ef8636")):
        vals = [summary[n][cond] for n in names]
        ci = np.array([details[n][cond]["ci95"] for n in names]).T
        ax.bar(x + off, vals, 0.38, color=colour, label=f"{cond} actuation")
        ax.errorbar(x + off, vals, yerr=[np.array(vals) - ci[0], ci[1] - np.array(vals)],
                    fmt="none", ecolor="k", capsize=3, lw=0.8)
    for i, n in enumerate(names):
        if n in PAPER:
            ax.plot([i - 0.4, i + 0.4], [PAPER[n]] * 2, "k--", lw=1,
                    label="paper (Table I)" if i == 0 else None)
    ax.set_xticks(x, [n.replace("_", " ") for n in names])
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("success rate")
    ax.set_title(f"Local controller success, {details[names[0]]['clean']['trials']} trials each")
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)


def main(argv=None) -> int:
    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    add_scenario_arguments(ap, SuccessTableStudy, SCENARIOS, "default",
                           {"trials": at.count, "workers": at.count})
    add_output_arguments(ap)
    args = ap.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    return study_main(_run, args)


def _run(args) -> int:
    study = scenario_of(SuccessTableStudy, args, SCENARIOS)
    if printed_config(study, args):
        return 0
    summary, details = success_table(
        study, "python studies/controller_success.py " + " ".join(args.argv), args.out,
        quiet=args.quiet)
    names = list(summary)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "controller_success.json", summary)
    atomic_write_json(out / "controller_success_details.json", details)
    details = details["results"]
    plot(summary, details, out / "controller_success.png")
    if args.json:
        print(json.dumps(summary))
    else:
        for name in names:
            c, n = details[name]["clean"], details[name]["noisy"]
            print(f"{name:<10} clean {c['success']:.3f} {c['ci95']}  noisy {n['success']:.3f} "
                  f"{n['ci95']}  (collisions {c['collisions']}/{n['collisions']})")
        print(f"wrote {out / 'controller_success.json'} and {out / 'controller_success.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
