"""Anchors of sparsified trajectories, maps and plans on the floor plan."""

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


def draw_map(ax, world, vertex_poses: np.ndarray, edges: np.ndarray, edge_p: np.ndarray,
             title: str = "") -> None:
    """A map over its floor plan: edges as lines coloured by their
    probability (dark = certain), vertices as dots; poses are metadata."""
    from matplotlib import colormaps
    from matplotlib.collections import LineCollection
    from matplotlib.colors import Normalize

    from topodrake.world.plot import plot_world

    plot_world(world, ax, places=True)
    if len(edges):
        segs = np.stack([vertex_poses[edges[:, 0], :2], vertex_poses[edges[:, 1], :2]], axis=1)
        norm = Normalize(0.9, 1.0)
        lc = LineCollection(segs, cmap=colormaps["viridis_r"], norm=norm, linewidths=0.6,
                            zorder=3)
        lc.set_array(np.clip(edge_p, 0.9, 1.0))
        ax.add_collection(lc)
        ax.figure.colorbar(lc, ax=ax, shrink=0.6, label="edge probability")
    ax.plot(vertex_poses[:, 0], vertex_poses[:, 1], ".", color="tab:orange", ms=2.5, zorder=4)
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

    from topodrake.topomap.mapfile import read_map_arrays
    from topodrake.world import load_world
    from topodrake.world.plot import save_figure

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
    """A plan over its map: the anchor path in red from the start to the goal."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from topodrake.world import load_world
    from topodrake.world.plot import save_figure

    world = load_world(topomap.world)
    fig, ax = plt.subplots(figsize=(10, 9))
    poses, edges, p = _map_layers(topomap)
    state = f"probability {result.probability:.3f}" if result.reachable else "no path"
    draw_map(ax, world, poses, edges, p, f"plan of {len(result.vertices)} anchors, {state}")
    path = np.vstack([np.asarray(start)[None, :2], topomap.pose(result.vertices)[:, :2].reshape(-1, 2),
                      np.asarray(goal)[None, :2]])
    if result.reachable:
        ax.plot(path[:, 0], path[:, 1], "-o", color="tab:red", lw=2, ms=4, zorder=6, label="plan")
    ax.plot(*np.asarray(start)[:2], "s", color="tab:green", ms=9, zorder=7, label="start")
    ax.plot(*np.asarray(goal)[:2], "*", color="tab:red", ms=14, zorder=7, label="goal")
    ax.legend(loc="upper right", fontsize=8)
    save_figure(fig, out)
