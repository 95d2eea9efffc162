"""Batched closed-loop engine: N cars stepped together in one world.

:class:`ExpertRollout` drives the A* expert to goal positions;
:class:`PolicyRollout` drives a waypoint policy (learned C_WP, the direct-
control baseline or the A* oracle) + RMP toward target poses, as the
``build_waypoint_diagram`` diagram does. The same functions as the Drake
diagram (``topodrake.systems``), in the same order per control period ``k``
(for the expert)::

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
from topodrake.errors import TopodrakeError
from topodrake.expert import ExpertConfig, PackedPaths, expert_waypoints, initial_memory
from topodrake.expert.approach import (
    ApproachConfig,
    PathTracker,
    plan_pose_path,
    pose_reached,
    track_pose_path,
)
from topodrake.rmp import RmpConfig
from topodrake.sensing.camera import Camera
from topodrake.sensing.config import CameraConfig, LidarConfig
from topodrake.sensing.lidar import Lidar
from topodrake.sensing.overlap import mutual_overlap
from topodrake.sensing.scene import scene_of
from topodrake.vehicle import VehicleConfig, car_to_world, in_collision, vehicle_step

SUCCESS, COLLISION, TIMEOUT, RUNNING, LOST = 0, 1, 2, 3, 4
OUTCOMES = ("success", "collision", "timeout", "running", "lost")


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
    approach: ApproachConfig = field(default_factory=ApproachConfig)


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
        """Drive cars from ``starts`` (N, 3) to ``goals``: positions (N, 2),
        or poses (N, 3), which the expert reaches with a final Reeds-Shepp
        approach (:mod:`topodrake.expert.approach`) within the goal
        tolerance and ``approach.heading_tol_deg``.

        Noise: give ``noise`` (N, T, 2) standard normals, or ``seeds`` (N,)
        to draw them; neither means no noise. ``on_images(step, car_index,
        images)`` receives the camera images of the cars still driving.
        """
        cfg = self.config
        veh = cfg.vehicle
        starts = np.asarray(starts, np.float64).reshape(-1, 3)
        goals = np.asarray(goals, np.float64)
        pose_goals = goals.ndim == 2 and goals.shape[1] == 3
        goals = goals.reshape(-1, 3 if pose_goals else 2)
        n = len(starts)
        t_steps = int(round(cfg.t_max_s / veh.dt))
        if noise is None and seeds is not None and cfg.noise_std > 0:
            noise = standard_normal_noise(seeds, t_steps)
        if paths is None:
            paths = [self.world.astar(s, g[:2]) for s, g in zip(starts, goals)]
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
        trackers: dict[int, PathTracker] = {}
        finished = np.zeros(n, bool)           # pose goals: the approach path was driven
        self._classify(state, goals, outcome, clearance, np.arange(n), finished)
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
            if pose_goals:
                self._approach(k, active, st, goals, trackers, finished, u, wp, seeds)
            if noise is not None and cfg.noise_std > 0:
                u = u * (1.0 + cfg.noise_std * noise[active, k])
            state[active] = vehicle_step(st, u, veh)
            controls[active, k] = u
            waypoints[active, k] = wp
            steps[active] = k + 1
            poses[active, k + 1:] = state[active, None, :3]
            self._classify(state[active], goals[active], outcome, clearance, active, finished)
        outcome[outcome == RUNNING] = TIMEOUT
        return RolloutResult(poses, controls, waypoints, steps, outcome, paths)

    def _approach(self, k, active, st, goals, trackers, finished, u, wp, seeds) -> None:
        """Cars near their goal pose drive a Reeds-Shepp path to it instead of
        the A* expert's waypoint (``u`` and ``wp`` rows replaced in place)."""
        cfg = self.config.approach
        veh = self.config.vehicle
        near = np.hypot(*(st[:, :2] - goals[active, :2]).T) < cfg.start_m
        near |= np.isin(active, list(trackers))      # a path once started is driven to its end
        for r in np.flatnonzero(near):
            car = int(active[r])
            tracker = trackers.get(car)
            if tracker is not None:
                u[r], target, done = track_pose_path(tracker, st[r], cfg, veh)
                finished[car] = done
                if not done:
                    wp[r] = target
                    continue
                if tracker.replans >= cfg.replans:
                    wp[r] = target      # out of new paths: stand (the drive times out)
                    continue
            seed = 0 if seeds is None else int(seeds[car])
            path = plan_pose_path(self.world.grid, st[r, :3], goals[car], cfg,
                                  seed=seed + 7919 * k)
            if path is None:
                continue                # the A* expert drives on; try again next period
            trackers[car] = PathTracker(path, replans=0 if tracker is None else tracker.replans + 1)
            u[r], wp[r], _ = track_pose_path(trackers[car], st[r], cfg, veh)

    def _classify(self, state, goals, outcome, clearance, idx, finished=None) -> None:
        cfg = self.config
        if goals.shape[1] == 3:
            # at the end of its approach path (not merely passing through the tolerance)
            reached = finished[idx] & pose_reached(state[:, :3], goals, cfg.goal_tolerance_m,
                                                         cfg.approach.heading_tol_deg)
        else:
            reached = np.hypot(*(state[:, :2] - goals).T) < cfg.goal_tolerance_m
        hit = in_collision(state, clearance, cfg.vehicle)
        outcome[idx[reached]] = SUCCESS
        outcome[idx[~reached & hit]] = COLLISION


@dataclass
class PolicyRolloutResult(RolloutResult):
    """A :class:`RolloutResult` toward target poses; ``overlap`` (N, 2) holds
    the final geometric overlaps (car -> target, target -> car)."""
    overlap: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


class PolicyRollout:
    """Steps many cars, each following its own target with one waypoint policy.

    Per control period, for the cars still driving: lidar scan (and camera
    image for a camera policy); ``policy.predict`` on the batch with each
    car's cached target features; waypoint to world frame with the car's
    state, RMP controls toward it (a direct-control policy's controls are
    used as they are); actuation noise; vehicle step. Then, as the Drake
    ``TargetRunner`` checks after every step: success when within
    ``goal_tolerance_m`` of the target position or both image overlaps above
    ``overlap_success``; collision; ``lost`` when ``overlap_lost`` is set and
    both overlaps fall below it; timeout at the car's ``t_max``.

    A stateful policy (``track_size`` > 0, e.g. the registration C_WP) keeps
    one row of tracking state per car (``policy.initial_track``) and is asked
    through ``policy.predict_tracked`` with the car's target as anchor 0 and
    the car's state as its odometry pose, as the navigation executors do.
    """

    def __init__(self, world, policy, config: RolloutConfig | None = None, *,
                 overlap_success: float = 0.7, overlap_lost: float | None = None):
        self.world = world
        self.policy = policy
        self.config = config or RolloutConfig()
        self.overlap_success = overlap_success
        self.overlap_lost = overlap_lost
        self.lidar = Lidar(world, self.config.lidar)
        self.camera = None
        kind = policy.observation
        if kind == "camera":
            self.camera = Camera(world, getattr(policy, "sensor", None) or self.config.camera)
        elif kind == "lidar":
            sensor = getattr(policy, "sensor", None)
            if sensor is not None and sensor != self.config.lidar:
                raise TopodrakeError("the lidar policy was trained with another lidar config "
                                     "than the engine's (RolloutConfig.lidar)")
        elif kind != "pose":
            raise TopodrakeError(f"unknown policy observation {kind!r}")

    def _observe(self, st: np.ndarray, ranges: np.ndarray) -> np.ndarray:
        kind = self.policy.observation
        if kind == "camera":
            return self.camera.render(st[:, :3])
        return ranges if kind == "lidar" else st[:, :3]

    def run(self, starts: np.ndarray, target_poses: np.ndarray, target_features, *,
            t_max_s=None, seeds=None, noise: np.ndarray | None = None,
            initial_track: np.ndarray | None = None) -> PolicyRolloutResult:
        """Drive cars from ``starts`` (N, 3) toward ``target_poses`` (N, 3).

        ``target_features``: ``policy.encode_target`` of the N targets'
        contexts (row i belongs to car i). ``t_max_s``: scalar or (N,)
        (default: the config's). Noise as in :meth:`ExpertRollout.run`.
        ``initial_track``: a stateful policy's tracking state at the start
        (N, ``track_size``; default ``policy.initial_track``)."""
        cfg = self.config
        veh = cfg.vehicle
        starts = np.asarray(starts, np.float64).reshape(-1, 3)
        targets = np.asarray(target_poses, np.float64).reshape(-1, 3)
        n = len(starts)
        if len(targets) != n or len(target_features) != n:
            raise ValueError(f"{n} starts, {len(targets)} target poses and "
                             f"{len(target_features)} target features")
        t_max = np.broadcast_to(np.asarray(cfg.t_max_s if t_max_s is None else t_max_s,
                                           np.float64), (n,))
        limit = np.rint(t_max / veh.dt).astype(np.int64)
        t_steps = int(limit.max()) if n else 0
        if noise is None and seeds is not None and cfg.noise_std > 0:
            noise = standard_normal_noise(seeds, t_steps)
        is_torch = hasattr(target_features, "index_select")
        state = np.zeros((n, 5))
        state[:, :3] = starts
        poses = np.repeat(starts[:, None], t_steps + 1, axis=1)
        controls = np.zeros((n, t_steps, 2))
        waypoints = np.full((n, t_steps, 2), np.nan)
        outcome = np.full(n, RUNNING)
        steps = np.zeros(n, np.int64)
        overlap = mutual_overlap(self.world, starts, targets, cfg.camera) if n else np.zeros((0, 2))
        clearance = self.world.grid.clearance_at
        direct = bool(getattr(self.policy, "is_direct_control", False))
        feats, feats_cars = target_features, np.arange(n)
        stateful = int(getattr(self.policy, "track_size", 0) or 0) > 0
        track = self.policy.initial_track(n) if stateful else None
        if initial_track is not None:
            from topodrake.errors import TopodrakeError

            if not stateful or np.shape(initial_track) != track.shape:
                width = track.shape[1] if stateful else 0
                raise TopodrakeError(f"initial_track must be ({n}, {width}) for this policy, "
                                     f"got {np.shape(initial_track)}")
            track = np.array(initial_track, np.float64)
        for k in range(t_steps):
            outcome[(outcome == RUNNING) & (limit <= k)] = TIMEOUT
            active = np.flatnonzero(outcome == RUNNING)
            if active.size == 0:
                break
            st = state[active]
            ranges = self.lidar.scan(st[:, :3])
            if active.size != feats_cars.size:
                # cars only ever stop, so the features are gathered again only when some did
                keep = np.searchsorted(feats_cars, active)
                feats = feats.index_select(0, _torch_index(keep)) if is_torch else feats[keep]
                feats_cars = active
            if stateful:
                pred = self.policy.predict_tracked(self._observe(st, ranges), feats, track, active,
                                                   np.zeros(active.size, np.int64), st[:, :3])
            else:
                pred = self.policy.predict(self._observe(st, ranges), feats)
            if direct:
                u = np.asarray(pred.controls, np.float64)
            else:
                wp = car_to_world(np.asarray(pred.waypoint, np.float64)[:, None], st)[:, 0]
                u = controls_toward(st, wp, ranges, cfg.lidar, cfg.rmp, veh)
                waypoints[active, k] = wp
            if noise is not None and cfg.noise_std > 0:
                u = u * (1.0 + cfg.noise_std * noise[active, k])
            state[active] = vehicle_step(st, u, veh)
            controls[active, k] = u
            steps[active] = k + 1
            poses[active, k + 1:] = state[active, None, :3]
            ov = mutual_overlap(self.world, state[active, :3], targets[active], cfg.camera)
            overlap[active] = ov
            reached = ((np.hypot(*(state[active, :2] - targets[active, :2]).T)
                        < cfg.goal_tolerance_m) | (ov.min(axis=1) > self.overlap_success))
            hit = in_collision(state[active], clearance, veh)
            outcome[active[reached]] = SUCCESS
            outcome[active[~reached & hit]] = COLLISION
            if self.overlap_lost is not None:
                lost = ~reached & ~hit & (ov.max(axis=1) < self.overlap_lost)
                outcome[active[lost]] = LOST
        outcome[outcome == RUNNING] = TIMEOUT
        return PolicyRolloutResult(poses, controls, waypoints, steps, outcome, [], overlap=overlap)


def _torch_index(idx: np.ndarray):
    import torch

    return torch.as_tensor(idx, dtype=torch.long)
