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
from topodrake.fileio import atomic_write_json
from topodrake.experiments.sparsify_compare import (DEFAULT_ESTIMATORS, SparsifyStudy,
                                                    compare_estimators, summarize)


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
    from topodrake.apps.study_args import study_main, typed_from_args

    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    ap.add_argument("--world", default="test-0", help="test house (its demonstrations must exist)")
    ap.add_argument("--drive", type=at.count0, help="index among its successful drives (default: longest)")
    ap.add_argument("--estimators", default=DEFAULT_ESTIMATORS, help="name=RE.pt:CWP.pt, comma-separated")
    ap.add_argument("--p", type=at.probability, default=0.99, help="p_sparsify")
    ap.add_argument("--hop-runs", type=at.count0, default=4,
                    help="noisy rollouts of each anchor hop (0: do not check the hops)")
    ap.add_argument("--seed", type=at.seed, default=0, help="noise seeds of the hop rollouts")
    ap.add_argument("--check-drives", type=at.count0, default=0,
                    help="also check the hops of the first N drives of every --check-worlds house")
    ap.add_argument("--check-worlds", default="test-0,test-1,test-2,test-3,test-4",
                    help="comma-separated houses for --check-drives")
    ap.add_argument("--data", default="data", help="cache of demonstrations")
    ap.add_argument("--demos", help="demonstration folder of the world (default: DATA/demos/pairs-s0/WORLD)")
    ap.add_argument("--out", default="results", help="folder of the JSON and PNG results")
    ap.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    args = ap.parse_args(argv)
    return study_main(lambda a: _run(a, typed_from_args(SparsifyStudy, a)), args)


def _run(args, study: SparsifyStudy) -> int:
    doc, world, poses = compare_estimators(
        study, "python studies/sparsification.py " + " ".join(sys.argv[1:]))
    out, results, check_worlds = Path(args.out), doc["results"], doc["check_worlds"]
    atomic_write_json(out / "sparsification.json", doc)
    plot(world, poses, results, out / "sparsification.png", args.p)
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
