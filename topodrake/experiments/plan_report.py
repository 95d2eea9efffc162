"""The planning study's figures and printed reports.

The figures of a run (:func:`plot_table`: success per house and method;
:func:`plot_calibration`: plan probability and calibrated chance against
empirical success; :func:`plot_pruned`: success with a fraction of the
drives) and the lines printed for a run, a rescoring, a paired comparison, a
driving-time fit and trial traces (:func:`run_lines`, :func:`rescore_lines`,
:func:`paired_lines`, :func:`fit_lines`, :func:`trace_lines`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from topodrake.experiments.plan_methods import METHODS
from topodrake.world.plot import save_figure


def plot_table(houses: dict, methods: list[str], path: Path, trials: int) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    names = list(houses)
    fig, ax = plt.subplots(figsize=(max(6.0, 1.8 * len(names) + 2), 4.8))
    w = 0.8 / max(len(methods), 1)
    x = np.arange(len(names))
    for i, m in enumerate(methods):
        s = [houses[h]["methods"][m]["success"] for h in names]
        bars = ax.bar(x + (i - (len(methods) - 1) / 2) * w, s, w, label=m, color=f"C{i}")
        for b, v in zip(bars, s):
            ax.annotate(f"{v:.2f}", (b.get_x() + b.get_width() / 2, v), ha="center",
                        va="bottom", fontsize=7)
    labels = []
    for h in names:
        o = houses[h]["methods"].get("ours")
        labels.append(f"{h}\n{o['vertices']} V / {o['edges']} E" if o else h)
    ax.set_xticks(x, labels, fontsize=8)
    ax.set_ylim(0, 1.08)
    ax.set_ylabel("success rate")
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8, ncol=len(methods), loc="upper center")
    ax.set_title(f"Planning success per house ({trials} trials per method and house; "
                 f"labels: our map's size)", fontsize=10)
    save_figure(fig, path)


def plot_calibration(cal: dict, path: Path) -> None:
    """One panel per map method: the plan probability and, where calibrated,
    the chance of success against empirical success, with trials per bin."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    names = list(cal)
    fig, axes = plt.subplots(1, len(names), figsize=(4.6 * len(names), 4.8), squeeze=False)
    for ax, m in zip(axes[0], names):
        c = cal[m]
        ax.plot([0, 1], [0, 1], "--", color="gray", lw=1, label="perfect calibration")
        curves = [("plan probability", c["bins_raw"], c["ece_raw"], "C1")]
        if c["calibrated"]:
            curves.append(("calibrated chance", c["bins"], c["ece"], "C0"))
        for label, rows, ece, colour in curves:
            full = [r for r in rows if r["count"]]
            ax.plot([r["predicted"] for r in full], [r["observed"] for r in full], "o-",
                    color=colour, label=f"{label} (ECE {ece:.3f})" if ece is not None else label)
            for r in full:
                ax.annotate(f"{r['count']}", (r["predicted"], r["observed"]), fontsize=7,
                            color=colour, xytext=(3, 3), textcoords="offset points")
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1.05)
        ax.set_xlabel("predicted (numbers: planned trials per bin)")
        ax.set_ylabel("empirical success")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
        ax.set_title(f"{m} ({c['planned_trials']} planned trials)", fontsize=10)
    save_figure(fig, path)


def plot_pruned(pruned: dict | None, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    fig, ax = plt.subplots(figsize=(6, 4.5))
    if pruned and pruned["fractions"]:
        fr = sorted(pruned["fractions"], key=float)
        s = [pruned["fractions"][f]["success"] for f in fr]
        ax.plot([float(f) for f in fr], s, "o-", color="C0", label="success")
        ax2 = ax.twinx()
        ax2.plot([float(f) for f in fr], [pruned["fractions"][f]["vertices"] for f in fr], "s--",
                 color="C1", alpha=0.7, label="vertices")
        ax2.set_ylabel("map vertices", color="C1")
        n = pruned["fractions"][fr[0]]["trials"]
        ax.set_title(f"{pruned['house']}: success with a fraction of the drives "
                     f"({pruned['method']}, {n} trials each)", fontsize=10)
    else:
        ax.set_title("pruned maps: not run")
    ax.set_xlim(0, 1.05)
    ax.set_ylim(0, 1.05)
    ax.set_xlabel("fraction of the drives in the map")
    ax.set_ylabel("success rate", color="C0")
    ax.grid(alpha=0.3)
    save_figure(fig, path)


def run_lines(summary: dict) -> list[str]:
    """A run's summary: each house's success per method and map size, the headline figures."""
    out = []
    for name, h in summary["houses"].items():
        out.append(f"{name:<10} " + ", ".join(f"{m} {h[m]:.3f}" for m in METHODS
                                               if h.get(m) is not None)
                   + (f"; {h['vertices']} vertices, {h['edges']} edges" if "vertices" in h else ""))
    out.append(f"min ours {summary['min_ours']}, min margin over SPTM "
               f"{summary['min_margin_over_sptm']}, plan ECE {summary['plan_probability_ece']}, "
               f"pruned 60%/peak {summary['pruned_60_over_peak']}")
    return out


def rescore_lines(cal: dict) -> list[str]:
    """Each method's plan-probability ECE, raw and calibrated."""
    return [f"{m:<20} ECE {c['ece_raw']} raw, {c['ece']} "
            f"{'calibrated' if c['calibrated'] else '(no calibration)'} over "
            f"{c['planned_trials']} planned trials" for m, c in cal.items()]


def paired_lines(doc: dict) -> list[str]:
    """Two runs side by side: success before and after, the paired difference."""
    out = []
    for name, p in doc.items():
        d = p["difference"]
        out.append(f"{name}: {p['before']:.3f} -> {p['after']:.3f}, paired {d['mean']:+.3f} "
                   f"({d['ci95'][0]:+.3f}..{d['ci95'][1]:+.3f}) over {d['pairs']} trials; "
                   + ", ".join(f"{h} {a:.2f}->{b:.2f}" for h, (a, b) in p["houses"].items()))
    return out


def fit_lines(doc: dict) -> list[str]:
    """The driving-time fits, per method and over all."""
    return [f"{name:<20} {f['start_s']:.1f} s + {f['per_m_s']:.2f} s/m + {f['per_hop_s']:.2f} "
            f"s/hop, spread {f['spread']:.2f}; {f['timeouts']} time-outs of {f['trials']} "
            f"trials, {f['predicted_timeouts']} predicted" for name, f in doc["fits"].items()]


def trace_lines(traces: list[dict]) -> list[str]:
    """Each traced trial's timeline, one line per span of one follower mode."""
    out = []
    for t in traces:
        out.append(f"trial {t['trial']}: place {t['start_place']} -> {t['goal_place']}, "
                   f"{len(t['plan_vertices'])} anchors (p {t['plan_probability']:.3f}), "
                   f"{t['outcome']} {t['final_distance_m']:.2f} m from the goal after "
                   f"{t['driven_s']} s")
        for seg in t["segments"]:
            a0, a1 = seg["anchors"]
            x, y, th = seg["end_pose"]
            out.append(f"  {seg['from_s']:6.1f}-{seg['to_s']:6.1f} s  {seg['mode']:<15} anchors "
                       f"{a0:>3}..{a1:<3} ends at ({x:.2f}, {y:.2f}, {th:+.2f})")
    return out
