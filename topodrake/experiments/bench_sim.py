"""Benchmarks that print the figures the issues ask for.

Each ``bench_*`` function returns a flat dict of numbers; the CLI prints it as
one JSON object (``--json``) or as aligned lines.
"""

from __future__ import annotations

import time

import numpy as np

from topodrake.demonstrations import CollectConfig, plan_jobs
from topodrake.experiments.vtk_parity import depth_errors, parity_summary
from topodrake.montecarlo import trial_seeds
from topodrake.rollout import ExpertRollout, RolloutConfig
from topodrake.sensing.camera import Camera
from topodrake.sensing.lidar import Lidar
from topodrake.sensing.scenegraph import vtk_depth_renderer
from topodrake.systems.scenario import Scenario
from topodrake.world import load_world


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


TEST_HOUSES = ("test-0", "test-1", "test-2", "test-3", "test-4")


def expert_success(pairs: int = 500, noise_std: float = 0.0, seed: int = 0,
                   houses=TEST_HOUSES, t_max_s: float = 150.0) -> dict:
    """Success rate of the A* + RMP expert on random start/goal pairs.

    ``pairs`` are split evenly over ``houses``; in each, starts (any heading)
    and goals are uniform over the free configuration space, at least 2 m
    apart (``plan_jobs`` of the ``random`` protocol); one noise seed per
    drive. Success = within 0.27 m of the goal without touching a wall
    before ``t_max_s``. Runs on the batched engine, which the parity test
    pins to the Drake diagram.
    """
    per_house = [pairs // len(houses) + (i < pairs % len(houses)) for i in range(len(houses))]
    counts = np.zeros(3, np.int64)
    for h, (name, n) in enumerate(zip(houses, per_house)):
        world = load_world(name)
        starts, goals = plan_jobs(world, CollectConfig(protocol="random", count=n, seed=seed + h))
        engine = ExpertRollout(world, RolloutConfig(noise_std=noise_std, t_max_s=t_max_s))
        res = engine.run(starts, goals, seeds=trial_seeds(seed + 1000 + h, n))
        counts += np.bincount(res.outcome, minlength=3)[:3]
    total = int(counts.sum())
    return {"success": counts[0] / total, "collision": counts[1] / total,
            "timeout": counts[2] / total, "pairs": total}


def drive_parity(world, starts, goals, noise_std: float = 0.33, seed: int = 0,
                 t_max_s: float = 20.0) -> float:
    """Largest distance (m) between the Drake diagram's path and the batched
    engine's for the same starts, goals and noise sequence."""
    from topodrake.systems.diagram import build_expert_diagram
    from topodrake.systems.run import ExpertRunner

    scenario = Scenario(world=world.name, noise_std=noise_std, t_max_s=t_max_s, camera_enabled=False)
    runner = ExpertRunner(build_expert_diagram(scenario, world=world))
    engine = ExpertRollout(world, RolloutConfig(noise_std=noise_std, t_max_s=t_max_s))
    worst = 0.0
    for i, (s, g) in enumerate(zip(starts, goals)):
        drake = runner.run(start=s, goal=g, seed=seed + i)
        noise = np.zeros((1, int(round(t_max_s / scenario.vehicle.dt)), 2))
        noise[0, :len(drake.noise)] = drake.noise[:noise.shape[1]]
        batched = engine.run(s[None], g[None], noise=noise)
        k = min(len(drake.poses), int(batched.steps[0]) + 1)
        worst = max(worst, float(np.linalg.norm(drake.poses[:k, :2] - batched.poses[0, :k, :2], axis=1).max()))
    return worst


def bench_expert(pairs: int = 500, seed: int = 0, batch: int = 256) -> dict:
    """The expert figures of the closed-loop issue (see ``topodrake bench expert``)."""
    import time

    from topodrake.systems.diagram import build_expert_diagram
    from topodrake.systems.run import ExpertRunner

    out = {}
    clean = expert_success(pairs, 0.0, seed)
    noisy = expert_success(pairs, 0.33, seed)
    out["success_rate"] = clean["success"]
    out["success_rate_noise"] = noisy["success"]
    out["collision_rate"] = clean["collision"]
    out["collision_rate_noise"] = noisy["collision"]

    world = load_world("test-0")
    # Full diagram, camera and lidar on, actuation noise on; first run warms up.
    runner = ExpertRunner(build_expert_diagram(Scenario(world="test-0", noise_std=0.33), world=world))
    sim = wall = 0.0
    for i, (a, b) in enumerate([(0, 5), (0, 5), (3, 8), (6, 1)]):
        r = runner.run(start=world.places[a], goal=world.places[b, :2], seed=seed + i)
        if i:
            sim += r.time_s
            wall += r.wall_time_s
    out["drake_realtime_factor"] = sim / wall

    starts, goals = plan_jobs(world, CollectConfig(protocol="random", count=batch, seed=seed))
    paths = [world.astar(s, g) for s, g in zip(starts, goals)]
    engine = ExpertRollout(world, RolloutConfig(noise_std=0.33, t_max_s=30.0, render_camera=True))
    engine.run(starts[:8], goals[:8], seeds=range(8), paths=paths[:8])   # compile
    t0 = time.perf_counter()
    res = engine.run(starts, goals, seeds=range(batch), paths=paths)
    out["batched_car_steps_per_s"] = float(res.steps.sum() / (time.perf_counter() - t0))

    out["parity_max_deviation_m"] = drive_parity(world, starts[:5], goals[:5], 0.33, seed)
    out["pairs"] = clean["pairs"]
    return out
