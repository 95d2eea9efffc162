"""Batched closed-loop engine: N expert cars stepped together in one world.

The same functions as the Drake diagram (``topodrake.systems``), in the same
order per control period ``k``::

    ranges_k   = lidar(pose_k)                 (and image_k = camera(pose_k))
    waypoint_k = expert(progress, memory, pose_k, ranges_k)   (updates progress, memory)
    u_k        = rmp(state_k, waypoint_k, ranges_k) * (1 + noise_std * w_k)
    state_k+1  = vehicle_step(state_k, u_k)    (RK2 + clamp)
    stop when |xy - goal| < tolerance (success), the body touches a wall
    (collision) or t >= t_max (timeout)

so a Drake run and a batched run from the same start with the same noise
sequence ``w`` drive the same path (see ``tests/test_parity.py``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from topodrake.control import controls_toward
from topodrake.expert import ExpertConfig, PackedPaths, expert_waypoints, initial_memory
from topodrake.rmp import RmpConfig
from topodrake.sensing.camera import Camera
from topodrake.sensing.config import CameraConfig, LidarConfig
from topodrake.sensing.lidar import Lidar
from topodrake.sensing.scene import scene_of
from topodrake.vehicle import VehicleConfig, in_collision, vehicle_step

SUCCESS, COLLISION, TIMEOUT, RUNNING = 0, 1, 2, 3
OUTCOMES = ("success", "collision", "timeout", "running")


@dataclass
class RolloutConfig:
    noise_std: float = 0.0
    t_max_s: float = 120.0
    goal_tolerance_m: float = 0.27
    render_camera: bool = False
    vehicle: VehicleConfig = field(default_factory=VehicleConfig)
    lidar: LidarConfig = field(default_factory=LidarConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    rmp: RmpConfig = field(default_factory=RmpConfig)
    expert: ExpertConfig = field(default_factory=ExpertConfig)


@dataclass
class RolloutResult:
    """Per-car trajectories; rows after a car stopped repeat its last pose."""

    poses: np.ndarray      # (N, T + 1, 3)
    controls: np.ndarray   # (N, T, 2) applied (noisy) controls
    waypoints: np.ndarray  # (N, T, 2) expert waypoints, world frame
    steps: np.ndarray      # (N,) control periods driven
    outcome: np.ndarray    # (N,) SUCCESS / COLLISION / TIMEOUT
    paths: list[np.ndarray]  # A* paths

    @property
    def success(self) -> np.ndarray:
        return self.outcome == SUCCESS

    def trajectory(self, i: int) -> dict:
        k = int(self.steps[i])
        return {"poses": self.poses[i, :k + 1], "controls": self.controls[i, :k],
                "waypoints": self.waypoints[i, :k], "outcome": OUTCOMES[int(self.outcome[i])]}


def standard_normal_noise(seeds, steps: int) -> np.ndarray:
    """(N, steps, 2) per-car standard-normal noise, one generator per seed."""
    return np.stack([np.random.default_rng(int(s)).standard_normal((steps, 2)) for s in seeds])


class ExpertRollout:
    """Steps many expert cars in one world with the shared batched functions."""

    def __init__(self, world, config: RolloutConfig | None = None):
        self.world = world
        self.config = config or RolloutConfig()
        self.lidar = Lidar(world, self.config.lidar)
        self.scene = scene_of(world)
        self.camera = Camera(world, self.config.camera) if self.config.render_camera else None

    def run(self, starts: np.ndarray, goals: np.ndarray, *, seeds=None,
            noise: np.ndarray | None = None,
            on_images: Callable[[int, np.ndarray, np.ndarray], None] | None = None,
            paths: list[np.ndarray] | None = None) -> RolloutResult:
        """Drive cars from ``starts`` (N, 3) to ``goals`` (N, 2).

        Noise: give ``noise`` (N, T, 2) standard normals, or ``seeds`` (N,)
        to draw them; neither means no noise. ``on_images(step, car_index,
        images)`` receives the camera images of the cars still driving.
        """
        cfg = self.config
        veh = cfg.vehicle
        starts = np.asarray(starts, np.float64).reshape(-1, 3)
        goals = np.asarray(goals, np.float64).reshape(-1, 2)
        n = len(starts)
        t_steps = int(round(cfg.t_max_s / veh.dt))
        if noise is None and seeds is not None and cfg.noise_std > 0:
            noise = standard_normal_noise(seeds, t_steps)
        if paths is None:
            paths = [self.world.astar(s, g) for s, g in zip(starts, goals)]
        packed = PackedPaths.pack(paths)
        progress = packed.offsets[:-1].copy()
        memory = initial_memory(starts)
        state = np.zeros((n, 5))
        state[:, :3] = starts
        poses = np.repeat(starts[:, None], t_steps + 1, axis=1)
        controls = np.zeros((n, t_steps, 2))
        waypoints = np.zeros((n, t_steps, 2))
        outcome = np.full(n, RUNNING)
        steps = np.zeros(n, np.int64)
        clearance = self.world.grid.clearance_at
        self._classify(state, goals, outcome, clearance, np.arange(n))
        for k in range(t_steps):
            active = np.flatnonzero(outcome == RUNNING)
            if active.size == 0:
                break
            st = state[active]
            ranges = self.lidar.scan(st[:, :3])
            if self.camera is not None:
                images = self.camera.render(st[:, :3])
                if on_images is not None:
                    on_images(k, active, images)
            wp, progress[active] = expert_waypoints(self.world.grid, packed, progress,
                                                    st[:, :3], cfg.expert, cars=active,
                                                    memory=memory, ranges=ranges,
                                                    lidar=cfg.lidar, scene=self.scene,
                                                    rmp=cfg.rmp, vehicle=veh)
            u = controls_toward(st, wp, ranges, cfg.lidar, cfg.rmp, veh)
            if noise is not None and cfg.noise_std > 0:
                u = u * (1.0 + cfg.noise_std * noise[active, k])
            state[active] = vehicle_step(st, u, veh)
            controls[active, k] = u
            waypoints[active, k] = wp
            steps[active] = k + 1
            poses[active, k + 1:] = state[active, None, :3]
            self._classify(state[active], goals[active], outcome, clearance, active)
        outcome[outcome == RUNNING] = TIMEOUT
        return RolloutResult(poses, controls, waypoints, steps, outcome, paths)

    def _classify(self, state, goals, outcome, clearance, idx) -> None:
        cfg = self.config
        reached = np.hypot(*(state[:, :2] - goals).T) < cfg.goal_tolerance_m
        hit = in_collision(state, clearance, cfg.vehicle)
        outcome[idx[reached]] = SUCCESS
        outcome[idx[~reached & hit]] = COLLISION
