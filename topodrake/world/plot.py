"""Top-down plots of worlds: walls, free space, places, paths, lidar hits."""

from __future__ import annotations

import numpy as np

from topodrake.world.textures import texture_bank


def plot_world(world, ax=None, *, places: bool = True, show_free: bool = True):
    """Draw a world on a matplotlib axis (created if not given); returns the axis."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection, PolyCollection


    if ax is None:
        w, h = world.bbox[1] - world.bbox[0]
        _, ax = plt.subplots(figsize=(min(14, 2 + 8 * w / max(w, h)), min(14, 2 + 8 * h / max(w, h))))
    g = world.grid
    (x0, y0), (x1, y1) = g.bbox()
    if show_free:
        shade = np.where(g.reachable, 1.0, np.where(g.occupied, 0.55, 0.85))
        ax.imshow(shade, origin="lower", extent=(x0, x1, y0, y1), cmap="gray",
                  vmin=0, vmax=1, interpolation="nearest")
    bank = texture_bank()
    colours = bank.mean(axis=(1, 2))
    if world.faces_override is not None:
        # a map read from an image: its walls are the occupied cells, drawn as such
        colours = np.full_like(colours, 0.3)
    if len(world.walls) <= 5000:
        polys = world.walls.corners()
        ax.add_collection(PolyCollection(polys, facecolors=colours[world.walls.texture],
                                         edgecolors="k", linewidths=0.3))
    else:
        f = world.faces
        ax.add_collection(LineCollection(np.stack([f.a, f.b], axis=1),
                                         colors=colours[f.texture], linewidths=0.8))
    if places and len(world.places):
        p = world.places
        ax.quiver(p[:, 0], p[:, 1], np.cos(p[:, 2]), np.sin(p[:, 2]), color="tab:red",
                  scale=25, width=0.004, zorder=5)
        ax.scatter(p[:, 0], p[:, 1], c="tab:red", s=18, zorder=6)
        for i, (x, y, _) in enumerate(p):
            ax.annotate(str(i), (x, y), xytext=(3, 3), textcoords="offset points",
                        color="tab:red", fontsize=8, zorder=7)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{world.name}: {world.free_area_m2:.0f} m$^2$ free, {len(world.walls)} walls")
    return ax


def save_figure(fig, path) -> None:
    """Write a figure atomically (temporary file, then rename) and close it."""
    import os
    from pathlib import Path

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}{path.suffix}")
    import matplotlib.pyplot as plt

    try:
        fig.savefig(tmp, dpi=120, bbox_inches="tight")
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
        plt.close(fig)


def legend_below(ax, handles=None, ncol: int = 4) -> None:
    """The legend under the axes, where it covers nothing of the floor plan."""
    kwargs = {"handles": handles} if handles is not None else {}
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.08), ncol=ncol, fontsize=8,
              frameon=False, **kwargs)
