"""Anchors of sparsified trajectories on the floor plan."""

from __future__ import annotations

import numpy as np


def draw_anchors(ax, world, poses: np.ndarray, anchors: np.ndarray, title: str = "") -> None:
    """The drive (grey) and its anchors (red, with their headings) on ``ax``."""
    from topodrake.world.plot import plot_world

    plot_world(world, ax, places=False)
    ax.plot(poses[:, 0], poses[:, 1], color="0.4", lw=1.0)
    a = poses[np.asarray(anchors)]
    ax.quiver(a[:, 0], a[:, 1], np.cos(a[:, 2]), np.sin(a[:, 2]), color="tab:red",
              scale=30, width=0.004)
    ax.plot(a[:, 0], a[:, 1], "o", color="tab:red", ms=4)
    ax.set_title(title)


def plot_anchors(world, poses, anchors, out, title: str = "") -> None:
    """One drive's anchors as a PNG at ``out``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from topodrake.world.plot import save_figure

    fig, ax = plt.subplots(figsize=(8, 8))
    draw_anchors(ax, world, poses, anchors, title)
    save_figure(fig, out)
