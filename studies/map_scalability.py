"""How big do maps get? Vertices and edges as drives are added, per test house.

The paper's scalability figure: for every test house, a map is built from
its demonstrations (all ordered pairs of its 10 places, 90 drives) one drive
at a time with the shipped RE (``--modality``, camera k=5 by default), and
its vertices and edges are recorded after each drive against the raw frames
seen so far, with the 10x and 20x temporal subsampling lines for reference.
Also measured:

* ``edge_ratio``: the map's edges over a dense graph's (every raw frame a
  vertex, an edge wherever RE passes ``p_edge``), whose edge count is
  estimated from ``--dense-samples`` source frames scored by RE against
  every frame within 4 m and 100 degrees of them (poses pick the candidates;
  pairs farther apart count as no edge, so the estimate is low and the
  ratio high);
* ``growth_last_over_first``: vertices added by the last 30 drives over
  those added by the first 30 (below 1: sublinear growth). Drives are added
  in a seeded random order (``--order shuffled``): the pairs protocol
  collects them by start place, so in collection order (``--order
  collected``) the last 30 drives all leave from places no earlier drive
  left from, which is new experience rather than more of the same;
* ``retrieval_recall``: in ``--recall-world``, while its first
  ``--recall-trajectories`` drives are added, every new vertex is also
  scored against every vertex of the map: the share of the cross edges that
  exhaustive pass makes which the retrieval pass (top ``retrieval_k``)
  makes too;
* ``hop_success``: ``--hop-samples`` trajectory edges of each map driven
  ``--hop-runs`` times by C_WP + RMP with actuation noise (the RE labels'
  rules, as the sparsification study checks anchor hops).

    python studies/map_scalability.py --json

prints ``{"houses": {...}, "keep_ratio_max", "edge_ratio_max",
"growth_last_over_first", "retrieval_recall", "hop_success"}`` and writes
``results/map_scalability.json`` and ``results/map_scalability.png``. Each
house's map is cached in ``DATA/maps/`` and its figures in
``OUT/map_scalability_runs/``, so an interrupted run resumes.
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
from topodrake.experiments.map_scalability import ScalabilityStudy, scalability
from topodrake.fileio import atomic_write_json

SCENARIOS = Path(__file__).resolve().parent / "scenarios" / "map_scalability.yaml"


def plot(houses: dict, path: Path, modality: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from topodrake.world.plot import save_figure

    fig, axes = plt.subplots(1, 2, figsize=(12, 5))
    top = max(h["raw_frames"] for h in houses.values())
    ref = np.array([0, top])
    for ax, col, what in ((axes[0], 1, "vertices"), (axes[1], 2, "edges")):
        for name, h in houses.items():
            c = np.array(h["curve"])
            ax.plot(c[:, 0], c[:, col], label=f"{name} ({c[-1, col]:.0f})")
        ax.plot(ref, ref / 10, ":", color="0.4", label="10x subsampling")
        ax.plot(ref, ref / 20, "--", color="0.6", label="20x subsampling")
        ax.set_xlabel("raw frames")
        ax.set_ylabel(what)
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    axes[0].set_title(f"map vertices ({modality} RE) against raw frames")
    dense = np.mean([h["dense"]["edges"] for h in houses.values()])
    axes[1].set_title(f"map edges (dense graphs: ~{dense:,.0f} edges)")
    save_figure(fig, path)


def main(argv=None) -> int:
    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    add_scenario_arguments(ap, ScalabilityStudy, SCENARIOS, "default",
                           {"trajectories": at.count, "recall_trajectories": at.count0,
                            "dense_samples": at.count, "hop_samples": at.count0,
                            "hop_runs": at.count})
    add_output_arguments(ap)
    args = ap.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    return study_main(_run, args)


def _run(args) -> int:
    study = scenario_of(ScalabilityStudy, args, SCENARIOS)
    if printed_config(study, args):
        return 0
    doc = scalability(study, "python studies/map_scalability.py " + " ".join(args.argv),
                      args.out, quiet=args.quiet)
    out, summary = Path(args.out), doc["summary"]
    atomic_write_json(out / "map_scalability.json", doc)
    plot(doc["houses"], out / "map_scalability.png", study.modality)
    if args.json:
        print(json.dumps(summary))
    else:
        for name, h in summary["houses"].items():
            print(f"{name}: {h['vertices']} vertices, {h['edges']} edges of {h['raw_frames']} "
                  f"frames (keep {h['keep_ratio']:.4f}, edge ratio {h['edge_ratio']:.5f}, "
                  f"growth {h['growth_last_over_first']}, hops made {h['hop_success']}, "
                  f"built in {h['build_s']} s)")
        print(f"retrieval recall {summary['retrieval_recall']}, hop success "
              f"{summary['hop_success']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
