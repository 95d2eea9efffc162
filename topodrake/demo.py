"""``topodrake demo``: the expert drives between two places in the Drake diagram.

Writes a top-down plan (walls, places, the A* path, the driven path, lidar
hits along the way), a strip of camera frames re-rendered from the logged
poses (the same renderer the CameraSensor runs), and with Meshcat a static
HTML recording of the run.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np


def run_demo(world_name: str = "test-0", start_place: int = 0, goal_place: int = 5,
             out_dir: str = "out/demo", seed: int = 0, noise_std: float = 0.33,
             meshcat: bool = False, n_frames: int = 8) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from topodrake.fileio import atomic_write_bytes
    from topodrake.sensing.camera import Camera
    from topodrake.sensing.lidar import Lidar
    from topodrake.systems.diagram import build_expert_diagram
    from topodrake.systems.run import ExpertRunner
    from topodrake.systems.scenario import Scenario
    from topodrake.world import load_world
    from topodrake.world.plot import plot_world, save_figure

    wall = time.perf_counter()
    world = load_world(world_name)
    scenario = Scenario(world=world_name, start_place=start_place, goal_place=goal_place,
                        noise_std=noise_std, seed=seed, t_max_s=150.0)
    viewer = None
    if meshcat:
        from pydrake.geometry import Meshcat

        viewer = Meshcat()
        viewer.StartRecording(frames_per_second=10.0, set_visualizations_while_recording=False)
    built = build_expert_diagram(scenario, world=world, meshcat=viewer)
    result = ExpertRunner(built).run()
    out = Path(out_dir)
    files: dict[str, Path] = {}

    start, goal = scenario.start_pose(world), scenario.goal_xy(world)
    astar_path = world.astar(start, goal)
    frames_at = np.linspace(0, len(result.poses) - 1, n_frames).round().astype(int)
    lidar = Lidar(world, scenario.lidar)
    hits, ok = lidar.points(result.poses[::10])

    fig, ax = plt.subplots(figsize=(9, 9))
    plot_world(world, ax)
    ax.scatter(hits[ok][:, 0], hits[ok][:, 1], s=2, color="tab:green", label="lidar hits", zorder=4)
    ax.plot(astar_path[:, 0], astar_path[:, 1], "--", color="tab:blue", lw=1.2, label="A* path")
    ax.plot(result.poses[:, 0], result.poses[:, 1], color="tab:orange", lw=2.0, label="driven")
    for n, k in enumerate(frames_at):
        ax.annotate(chr(ord("a") + n), result.poses[k, :2], color="tab:orange", fontsize=9,
                    xytext=(4, -10), textcoords="offset points", zorder=8)
    ax.set_title(f"{world.name}: place {start_place} -> {goal_place}, {result.outcome} "
                 f"in {result.time_s:.1f} s (noise {noise_std})")
    ax.legend(loc="upper right", fontsize=8)
    files["plan"] = out / "plan.png"
    save_figure(fig, files["plan"])

    images = Camera(world, scenario.camera).render(result.poses[frames_at])
    fig, axes = plt.subplots(1, n_frames, figsize=(2 * n_frames, 2.4))
    for n, (axi, k) in enumerate(zip(np.atleast_1d(axes), frames_at)):
        axi.imshow(images[n])
        axi.set_title(f"{chr(ord('a') + n)}: t={k * scenario.vehicle.dt:.1f} s", fontsize=8)
        axi.axis("off")
    files["camera"] = out / "camera.png"
    save_figure(fig, files["camera"])

    if viewer is not None:
        viewer.StopRecording()
        viewer.PublishRecording()
        files["meshcat"] = out / "meshcat.html"
        atomic_write_bytes(files["meshcat"], viewer.StaticHtml().encode())
    summary = result.summary()
    summary.update({"world": world.name, "start_place": start_place, "goal_place": goal_place,
                    "seed": seed, "realtime_factor": round(result.time_s / max(result.wall_time_s, 1e-9), 1),
                    "demo_wall_s": round(time.perf_counter() - wall, 2)})
    return {"files": files, "summary": summary}
