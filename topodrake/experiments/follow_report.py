"""The trajectory-following study's figure and printed summary.

:func:`plot`: cover against anchors per metre for each controller, its RE
chains beside its every-n-th-frame chains; :func:`summary_lines`: the
summary at the headline p and the sensitivity tables, as printed.
"""

from __future__ import annotations

from pathlib import Path

from topodrake.world.plot import save_figure


def plot(results: dict, path: Path, n_traj: int) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    fig, ax = plt.subplots(figsize=(8, 5.5))
    for i, (name, r) in enumerate(results.items()):
        color = f"C{i}"
        pts = r["points"]
        nan = float("nan")
        ax.plot([q["anchors_per_m"] for q in pts], [q.get("cover", nan) for q in pts], "o-",
                color=color,
                label=f"{name}, RE anchors")
        for q in pts:
            ax.annotate(f"{q['p_sparsify']}", (q["anchors_per_m"], q.get("cover", nan)), fontsize=7,
                        xytext=(3, 3), textcoords="offset points", color=color)
        ax.plot([q["subsampled_anchors_per_m"] for q in pts],
                [q.get("cover_subsampled", nan) for q in pts],
                "s--", color=color, alpha=0.7, label=f"{name}, every n-th frame")
    ax.set_xlabel("anchors per metre")
    ax.set_ylabel("cover rate")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title(f"Trajectory following, {n_traj} test trajectories (points marked with p_sparsify)")
    save_figure(fig, path)


def summary_lines(summary: dict, tables: dict) -> list[str]:
    """Each controller's covers at the headline p, then each sensitivity table."""
    out = []
    for name, s in summary.items():
        f = {k: "-" if v is None else f"{v:.3f}" for k, v in s.items()
             if not isinstance(v, dict)}
        out.append(f"{name:<10} cover {f['cover']}, oracle {f['cover_oracle']}, "
                   f"oracle RE {f['cover_oracle_re']}, noisy {f['cover_noisy']}, every n-th "
                   f"{f['cover_subsampled']} at {s['anchors_per_m']:.2f} anchors/m")
        if "cover_changed" in s:
            out.append(f"{'':<10} changed world: cover {f['cover_changed']}, oracle "
                       f"{f['cover_changed_oracle']}")
    for name, t in tables.items():
        out.append(f"{name} RE chains at p = {t['p_sparsify']}, oracle C_WP with {t['key']}:")
        for row in t["rows"]:
            out.append(f"  {t['key']}={row[t['key']]:<6g} cover {row['cover']:.3f} "
                       f"({row['trajectories']} trajectories, {row['spec']})")
    return out
