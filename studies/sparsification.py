"""How many anchors does each controller need? One test-house drive, sparsified by several REs.

The paper's sparsification figure: the same expert trajectory of a test
house, reduced to anchors greedily while RE > ``--p`` (0.99), once per
controller (default camera k=2, camera k=5 and lidar k=5, each RE with the
C_WP it was trained for). A controller that reaches farther needs fewer
anchors. Each anchor promises that its controller gets there from the
previous one; ``hop_success`` checks the promise: ``--hop-runs`` noisy
closed-loop rollouts of every hop in the batched engine
(:func:`topodrake.experiments.hops.anchor_hop_success`). ``--check-drives N``
adds the same check over the first N drives of every test house
(``test_houses`` in the output: keep ratio, hops, share made).

    python studies/sparsification.py --check-drives 3 --json

prints ``{"camera_k2": {"anchors": n, "keep_ratio": r, "hop_success": s}, ...}``
and writes ``results/sparsification.json`` (anchor frames, each hop's
successes, the command) and
``results/sparsification.png`` (one floor-plan panel per RE).
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
from topodrake.experiments.sparsify_compare import SparsifyStudy, compare_estimators, summarize
from topodrake.fileio import atomic_write_json

SCENARIOS = Path(__file__).resolve().parent / "scenarios" / "sparsification.yaml"


def plot(world, poses, results: dict, path: Path, p: float) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from topodrake.topomap.plot import draw_anchors
    from topodrake.world.plot import save_figure

    fig, axes = plt.subplots(1, len(results), figsize=(6 * len(results), 6), squeeze=False)
    for ax, (name, r) in zip(axes[0], results.items()):
        hops = f"\nhops made {r['hop_success']:.1%}" if r.get("hop_success") is not None else ""
        draw_anchors(ax, world, poses, r["anchor_frames"],
                     f"{name}: {r['anchors']} anchors of {len(poses)} frames{hops}")
    fig.suptitle(f"{world.name}: one expert drive sparsified at p = {p}")
    save_figure(fig, path)


def main(argv=None) -> int:
    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    add_scenario_arguments(ap, SparsifyStudy, SCENARIOS, "default",
                           {"drive": at.count0, "p": at.probability, "hop_runs": at.count0,
                            "check_drives": at.count0})
    add_output_arguments(ap, quiet=False)
    args = ap.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    return study_main(_run, args)


def _run(args) -> int:
    study = scenario_of(SparsifyStudy, args, SCENARIOS)
    if printed_config(study, args):
        return 0
    doc, world, poses = compare_estimators(
        study, "python studies/sparsification.py " + " ".join(args.argv))
    out, results, check_worlds = Path(args.out), doc["results"], doc["check_worlds"]
    atomic_write_json(out / "sparsification.json", doc)
    plot(world, poses, results, out / "sparsification.png", study.p)
    summary = summarize(results)
    if args.json:
        print(json.dumps(summary))
    else:
        for name, s in summary.items():
            hops = f", hops made {s['hop_success']:.3f}" if s.get("hop_success") is not None else ""
            print(f"{name:<10} {s['anchors']:4d} anchors of {doc['frames']} frames "
                  f"(keep ratio {s['keep_ratio']:.3f}{hops})")
            if "test_houses" in s:
                c = s["test_houses"]
                print(f"{'':<10} {c['drives']} drives of {', '.join(check_worlds)}: keep ratio "
                      f"{c['keep_ratio']}, {c['hops']} hops, made {c['hop_success']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
