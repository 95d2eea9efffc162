"""``topodrake demo``: show a house as the robot sees it.

Writes a top-down plan (walls, free space, places, an A* path between two
places) and a strip of camera images with the lidar scan under each one.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def render_house_demo(world_name: str = "test-0", out_dir: str = "out/demo",
                      n_views: int = 6) -> dict[str, Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from topodrake.sensing.camera import Camera
    from topodrake.sensing.lidar import Lidar
    from topodrake.world import load_world
    from topodrake.world.plot import plot_world, save_figure

    world = load_world(world_name)
    out = Path(out_dir)
    places = world.places[:n_views]
    path = world.astar(world.places[0], world.places[1])

    fig, ax = plt.subplots(figsize=(9, 9))
    plot_world(world, ax)
    ax.plot(path[:, 0], path[:, 1], "-", color="tab:blue", lw=1.5, label="A* place 0 -> 1")
    pts, ok = Lidar(world).points(places)
    for i in range(len(places)):
        ax.scatter(pts[i, ok[i], 0], pts[i, ok[i], 1], s=3, color="tab:green", zorder=4)
    ax.legend(loc="upper right", fontsize=8)
    plan_png = out / "plan.png"
    save_figure(fig, plan_png)
    plt.close(fig)

    images = Camera(world).render(places)
    lidar = Lidar(world)
    ranges = lidar.scan(places)
    angles = lidar.config.beam_angles()
    fig, axes = plt.subplots(2, len(places), figsize=(2.2 * len(places), 4.6))
    axes = np.atleast_2d(axes).reshape(2, -1)
    for i in range(len(places)):
        axes[0, i].imshow(images[i])
        axes[0, i].set_title(f"place {i}", fontsize=9)
        axes[0, i].axis("off")
        r = np.where(np.isfinite(ranges[i]), ranges[i], lidar.config.range_m)
        hit = np.isfinite(ranges[i])
        # Car frame, heading up.
        axes[1, i].scatter(-r * np.sin(angles), r * np.cos(angles), s=4,
                           c=np.where(hit, "tab:green", "lightgray"))
        axes[1, i].plot([0], [0], "r^")
        axes[1, i].set_aspect("equal")
        axes[1, i].set_xlim(-6, 6)
        axes[1, i].set_ylim(-4, 8)
        axes[1, i].tick_params(labelsize=6)
    fig.suptitle(f"{world.name}: camera (top) and lidar in the car frame (bottom)", fontsize=10)
    views_png = out / "views.png"
    save_figure(fig, views_png)
    plt.close(fig)
    return {"plan": plan_png, "views": views_png}
