"""Benchmarks that print the figures the issues ask for.

Each ``bench_*`` function returns a flat dict of numbers; the CLI prints it as
one JSON object (``--json``) or as aligned lines.
"""

from __future__ import annotations

import time

import numpy as np


def _rate(fn, n_items: int, min_seconds: float = 1.0) -> float:
    """Items per second of ``fn()`` (which handles ``n_items``), after a warm-up call."""
    fn()
    calls, start = 0, time.perf_counter()
    while True:
        fn()
        calls += 1
        elapsed = time.perf_counter() - start
        if elapsed >= min_seconds:
            return calls * n_items / elapsed


def bench_sensors(world_name: str = "test-0", batch: int = 4096, vtk_poses: int = 60,
                  seed: int = 0) -> dict:
    """Camera and lidar throughput, Drake VTK throughput, depth parity."""
    from topodrake.sensing.camera import Camera
    from topodrake.sensing.lidar import Lidar
    from topodrake.sensing.parity import depth_errors, parity_summary
    from topodrake.world import load_world
    from topodrake.world.scenegraph import vtk_depth_renderer

    world = load_world(world_name)
    rng = np.random.default_rng(seed)
    poses = world.sample_free_pose(rng, batch)
    camera, lidar = Camera(world), Lidar(world)
    out = {"world": world_name, "batch": batch,
           "camera_images_per_s": _rate(lambda: camera.render(poses), batch),
           "lidar_scans_per_s": _rate(lambda: lidar.scan(poses), batch)}
    vtk = vtk_depth_renderer(world, camera.config)
    few = poses[:vtk_poses]
    out["vtk_images_per_s"] = _rate(lambda: vtk.render_rgb(few), len(few))
    out.update(parity_summary(depth_errors(world, few, camera.config, vtk=vtk)))
    out["parity_poses"] = len(few)
    return out
