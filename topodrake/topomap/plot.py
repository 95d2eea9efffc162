"""Anchors of sparsified trajectories, maps and plans on the floor plan."""

from __future__ import annotations

import numpy as np

from topodrake.topomap.mapfile import read_map_arrays
from topodrake.world import load_world
from topodrake.world.plot import legend_below, plot_world, save_figure


def draw_anchors(ax, world, poses: np.ndarray, anchors: np.ndarray, title: str = "") -> None:
    """The drive (grey) and its anchors (red, with their headings) on ``ax``."""
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


    fig, ax = plt.subplots(figsize=(8, 8))
    draw_anchors(ax, world, poses, anchors, title)
    save_figure(fig, out)


#: the map's colours: vertices and certain edges dark blue, less certain edges lighter
VERTEX_COLOR = "navy"
EDGE_CMAP = "Blues"


def draw_map(ax, world, vertex_poses: np.ndarray, edges: np.ndarray, edge_p: np.ndarray,
             title: str = "") -> None:
    """A map over its floor plan: each edge an arrow from its source to its
    target coloured by its probability (dark = certain), each vertex a dot
    with a tick along its heading; poses are metadata."""
    from matplotlib import colormaps
    from matplotlib.colors import ListedColormap, Normalize


    plot_world(world, ax, places=True)
    cmap = ListedColormap(colormaps[EDGE_CMAP](np.linspace(0.35, 1.0, 256)))   # no white
    v = np.asarray(vertex_poses)
    if len(edges):
        a, b = v[edges[:, 0], :2], v[edges[:, 1], :2]
        d = b - a
        arrows = ax.quiver(a[:, 0], a[:, 1], d[:, 0], d[:, 1], np.clip(edge_p, 0.9, 1.0),
                           cmap=cmap, norm=Normalize(0.9, 1.0), angles="xy",
                           scale_units="xy", scale=1, width=0.002, headwidth=5, headlength=6,
                           headaxislength=5, zorder=3)
        ax.figure.colorbar(arrows, ax=ax, fraction=0.025, pad=0.01, shrink=0.5,
                           label="edge probability")
    if len(v):
        ax.quiver(v[:, 0], v[:, 1], np.cos(v[:, 2]), np.sin(v[:, 2]), color=VERTEX_COLOR,
                  scale=45, width=0.002, headwidth=0, headlength=0, headaxislength=0, zorder=4)
        ax.plot(v[:, 0], v[:, 1], "o", color=VERTEX_COLOR, ms=3.5, mec="white", mew=0.4,
                zorder=4)
    if title:
        ax.set_title(title)


def _map_layers(topomap):
    """(vertex poses (V, 3), edges (E, 2) as vertex positions, edge p (E,)) of a TopoMap."""
    verts = sorted(topomap.graph.nodes)
    where = {v: i for i, v in enumerate(verts)}
    edges = np.array([(where[u], where[v]) for u, v in topomap.graph.edges], np.int64).reshape(-1, 2)
    p = np.array([d for _, _, d in topomap.graph.edges(data="p")], np.float64)
    return topomap.pose(verts).reshape(-1, 3), edges, p


def plot_map_file(path, out) -> None:
    """``topodrake map plot``: a map file drawn over its floor plan."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    meta, z = read_map_arrays(path)
    world = load_world(meta["world"])
    verts = z["vertex_id"]
    where = {int(v): i for i, v in enumerate(verts)}
    edges = np.array([(where[int(u)], where[int(v)]) for u, v in zip(z["edge_src"], z["edge_dst"])],
                     np.int64).reshape(-1, 2)
    fig, ax = plt.subplots(figsize=(10, 9))
    draw_map(ax, world, z["poses"][z["vertex_center"]], edges, z["edge_p"],
             f"{meta['world']} ({meta['modality']}): {len(verts)} vertices, {len(edges)} edges "
             f"from {len(meta['trajectories'])} drives")
    save_figure(fig, out)


def plot_plan(topomap, result, start, goal, out) -> None:
    """A plan over its map: the links from the start through the anchors to
    the goal."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    world = load_world(topomap.world)
    fig, ax = plt.subplots(figsize=(10, 9))
    poses, edges, p = _map_layers(topomap)
    state = (f"plan of {len(result.route)} anchors, probability {result.probability:.3f}"
             if result.reachable else f"no plan: {result.reason}")
    draw_map(ax, world, poses, edges, p, state)
    path = np.vstack([np.asarray(start)[None, :2], topomap.pose(result.vertices)[:, :2].reshape(-1, 2),
                      np.asarray(goal)[None, :2]])
    if result.reachable:
        ax.plot(path[:, 0], path[:, 1], "-o", color="tab:purple", lw=2, ms=4, zorder=6,
                label="plan: start, anchors, goal")
    ax.plot(*np.asarray(start)[:2], "s", color="white", mec="k", ms=9, zorder=7, label="start")
    ax.plot(*np.asarray(goal)[:2], "*", color="tab:red", mec="k", ms=14, zorder=7, label="goal")
    ax.plot([], [], "o", color=VERTEX_COLOR, ms=3.5, label="map vertex")
    legend_below(ax)
    save_figure(fig, out)
