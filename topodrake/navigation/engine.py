"""The batched navigation engine: N cars, each following its own route.

Per control period ``k``, for the cars still driving, in the order of the
Drake navigation diagram (``topodrake.systems.navigation``)::

    ranges_k, obs_k  = lidar(pose_k), camera(pose_k)      (the policy's observation)
    follower_k, out  = follower_step(follower_k-1, obs_k)  (C_WP and RE on cached anchors;
                                                            the follower works in the
                                                            odometry frame: odo_k, which
                                                            drifts from state_k when
                                                            config.odometry says so)
    waypoint_k       = manoeuvres(out.waypoint, ranges_k)  (the expert's check and three-point
                                                            turns on the car's own recent
                                                            scans; FollowerConfig.manoeuvres)
    u_k              = rmp(state_k, waypoint_k, ranges_k) * (1 + noise_std * w_k)
    state_k+1        = vehicle_step(state_k, u_k)
    stop: collision; the follower reached the last anchor or gave up (its
    decision of period k ends the run after that period, as FollowerFsm's
    update at t_k+1 does); a ``watch`` callback (e.g. divergence from a
    reference path); timeout.
    replanning (optional): a car whose Dead reckoning reached a try gets a
    new route from the next period, its follower back in Search
    (:class:`topodrake.navigation.replan.Replanner`, as FollowerFsm does).

so the two executors drive the same path for the same start, route and
noise (``tests/test_navigation.py``, ``test_drake_diagram_and_engine_drive_the_same_path``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from topodrake.control import controls_toward
from topodrake.navigation.evaluate import (
    Evaluator,
    RouteFeatures,
    encode_routes,
    initial_track,
    stack_features,
)
from topodrake.navigation.follower import (
    FollowerConfig,
    FollowerState,
    Mode,
    Reason,
    follower_step,
)
from topodrake.navigation.manoeuvre import Manoeuvres
from topodrake.navigation.replan import kept_features, search_would_start
from topodrake.odometry import Odometry, OdometryConfig, odometry_to_world
from topodrake.rollout import RolloutConfig, standard_normal_noise
from topodrake.sensing.camera import Camera
from topodrake.sensing.lidar import Lidar
from topodrake.vehicle import in_collision, vehicle_step
from topodrake.world.changes import CarChanges

RUNNING, NAV_REACHED, NAV_COLLISION, NAV_TIMEOUT, NAV_SEARCH_FAILED, NAV_DR_GAVE_UP, NAV_DIVERGED = \
    range(7)
NAV_OUTCOMES = ("running", "reached", "collision", "timeout", "search_failed",
                "dead_reckoning_gave_up", "diverged")


@dataclass
class NavigationConfig:
    """The follower's thresholds and the closed loop's settings (noise,
    time limit, vehicle, sensors, RMP, odometry)."""

    follower: FollowerConfig = field(default_factory=FollowerConfig)
    rollout: RolloutConfig = field(default_factory=lambda: RolloutConfig(t_max_s=150.0))
    odometry: OdometryConfig = field(default_factory=OdometryConfig.perfect)


@dataclass
class NavigationResult:
    """Per-car runs; rows after a car stopped repeat its last pose, modes -1."""

    poses: np.ndarray        # (N, T + 1, 3)
    modes: np.ndarray        # (N, T) follower mode in each period (-1 after the stop)
    active: np.ndarray       # (N, T) active anchor in each period
    steps: np.ndarray        # (N,) periods driven
    outcome: np.ndarray      # (N,) NAV_* codes
    follower: FollowerState  # final follower states
    distance_to_goal_m: np.ndarray   # (N,) to each route's goal pose (its last anchor's)
    manoeuvres: np.ndarray | None = None   # (N,) manoeuvres started (None: the search was off)

    def outcome_name(self, i: int) -> str:
        return NAV_OUTCOMES[int(self.outcome[i])]

    def distance_driven_m(self, i: int) -> float:
        p = self.poses[i, :int(self.steps[i]) + 1, :2]
        return float(np.hypot(*np.diff(p, axis=0).T).sum())


def follower_outcome(state: FollowerState) -> np.ndarray:
    """NAV_* codes of followers that ended (RUNNING for the others)."""
    out = np.full(len(state), RUNNING)
    out[state.mode == Mode.REACHED] = NAV_REACHED
    failed = state.mode == Mode.FAILED
    out[failed & (state.reason == Reason.SEARCH_FAILED)] = NAV_SEARCH_FAILED
    out[failed & (state.reason == Reason.DEAD_RECKONING_GAVE_UP)] = NAV_DR_GAVE_UP
    return out


class NavigationEngine:
    """Steps many cars, each following its own route, with one C_WP
    (``policy``) and one RE (``reach``), the functions FollowerFsm calls."""
    def __init__(self, world, policy, reach, config: NavigationConfig | None = None):
        self.world = world
        self.policy = policy
        self.reach = reach
        self.config = config or NavigationConfig()
        self.config.follower.check()
        cfg = self.config.rollout
        self.lidar = Lidar(world, cfg.lidar)
        # a pose oracle may stand in for either network (it reads the car's pose)
        kinds = {policy.observation, reach.observation} - {"pose"}
        if len(kinds) > 1:
            raise ValueError(f"C_WP observes {policy.observation}, RE {reach.observation}")
        self.kind = kinds.pop() if kinds else "pose"
        self.camera = None
        if self.kind == "camera":
            self.camera = Camera(world, getattr(policy, "sensor", None) or cfg.camera)

    def observe(self, states: np.ndarray, ranges: np.ndarray,
                extra: np.ndarray | None = None) -> np.ndarray | None:
        if self.kind == "camera":
            return self.camera.render(states[:, :3], extra)
        return ranges if self.kind == "lidar" else None

    def _startable(self, observations, states, odometry, ranges, encoded: dict):
        """``startable(row, route)`` for the replanner: would the follower's
        Search pass on ``route`` for the car in row ``row`` of this period's
        cars (:func:`~topodrake.navigation.replan.search_would_start`; the
        route and its encoding kept in ``encoded`` under ``id(route)``)."""
        def startable(r: int, route) -> bool:
            one = slice(r, r + 1)
            ok, feats = search_would_start(
                self.policy, self.reach, route,
                None if observations is None else observations[one], states[one, :3],
                ranges[one], self.config.rollout.lidar, self.config.follower,
                odometry=odometry[one, :3])
            encoded[id(route)] = (route, feats)      # the route kept: its id stays its own
            return ok
        return startable

    def run(self, starts: np.ndarray, routes, *, features: RouteFeatures | None = None,
            seeds=None, noise: np.ndarray | None = None, t_max_s=None,
            watch: Callable[[int, np.ndarray, np.ndarray], np.ndarray] | None = None,
            progress=None, replanner=None, odometry_seeds=None,
            changes: CarChanges | None = None) -> NavigationResult:
        """Drive cars from ``starts`` (N, 3) along ``routes`` (N routes;
        ``features``: their :func:`encode_routes`, computed if not given).
        Noise as in :meth:`topodrake.rollout.ExpertRollout.run`. ``t_max_s``:
        scalar or (N,). ``watch(k, cars, states)`` may stop cars (returns a
        bool mask over ``cars``; they end ``diverged``). ``replanner``: a
        :class:`~topodrake.navigation.replan.Replanner` over these N cars
        and routes (its bookkeeping is the caller's to read afterwards).
        ``odometry_seeds`` (N,) draw each car's odometry errors (default:
        the car's index). ``changes``: what each car meets that its map
        lacks (boxes, walkers, a closed door), seen by its sensors and
        counted in collisions; the walkers move every period."""
        cfg = self.config.rollout
        veh = cfg.vehicle
        starts = np.asarray(starts, np.float64).reshape(-1, 3)
        n = len(starts)
        if len(routes) != n:
            raise ValueError(f"{n} starts and {len(routes)} routes")
        if replanner is not None:
            replanner.schedule.check_against(self.config.follower.dead_reckoning.dr_max_iterations)
        if features is None:
            features = encode_routes(routes, self.policy, self.reach,
                                     legs_m=self.config.follower.tracker.legs_m)
        n_anchors = features.n_anchors.copy()
        route_of = np.arange(n)
        goals = np.array([r.goal_pose for r in routes]).reshape(n, 3)
        t_max = np.broadcast_to(np.asarray(cfg.t_max_s if t_max_s is None else t_max_s,
                                           np.float64), (n,))
        limit = np.rint(t_max / veh.dt).astype(np.int64)
        t_steps = int(limit.max()) if n else 0
        if noise is None and seeds is not None and cfg.noise_std > 0:
            noise = standard_normal_noise(seeds, t_steps)
        state = np.zeros((n, 5))
        state[:, :3] = starts
        poses = np.repeat(starts[:, None], t_steps + 1, axis=1)
        modes = np.full((n, t_steps), -1, np.int64)
        active_log = np.full((n, t_steps), -1, np.int64)
        outcome = np.full(n, RUNNING)
        steps = np.zeros(n, np.int64)
        follower = FollowerState.initial(n, initial_track(self.policy, n))
        odometry = Odometry(self.config.odometry,
                            np.arange(n) if odometry_seeds is None else odometry_seeds, starts)
        clearance = self.world.grid.clearance_at
        manoeuvres = Manoeuvres(n, odometry.poses, cfg.lidar, self.config.follower.manoeuvre,
                                rmp=cfg.rmp, vehicle=veh) \
            if self.config.follower.manoeuvres else None
        for k in range(t_steps):
            outcome[(outcome == RUNNING) & (limit <= k)] = NAV_TIMEOUT
            cars = np.flatnonzero(outcome == RUNNING)
            if cars.size == 0:
                break
            st = state[cars]
            extra = None if changes is None else changes.faces(cars)
            ranges = self.lidar.scan(st[:, :3], extra)
            fs = follower.take(cars)
            odo = st.copy()
            odo[:, :3] = odometry.poses[cars]
            ev = Evaluator(self.policy, self.reach, features, route_of[cars],
                           self.observe(st, ranges, extra), poses=st[:, :3], track=fs.track,
                           odometry=odo[:, :3], lidar=cfg.lidar, ranges=ranges)
            fs, out = follower_step(fs, n_anchors[cars], odo, ev, self.config.follower)
            if manoeuvres is not None:
                out.waypoint = manoeuvres.step(cars, odo[:, :3], out.waypoint, ranges)
            if not odometry.perfect:        # the waypoint, given in the odometry frame
                out.waypoint = odometry_to_world(out.waypoint[:, None], odo, st)[:, 0]
            fs.track = ev.track
            follower.put(cars, fs)
            if replanner is not None:
                encoded: dict = {}
                startable = self._startable(ev.observations, st, odo, ranges, encoded)
                fresh = lambda: FollowerState.initial(1, initial_track(self.policy, 1))  # noqa: E731
                for i, new, start in replanner.step(cars, fs, st[:, :3], startable=startable,
                                                    fresh=fresh, odometry=odo[:, :3]):
                    feats = kept_features(encoded, new)
                    if feats is None:
                        feats = encode_routes([new], self.policy, self.reach,
                                              legs_m=self.config.follower.tracker.legs_m)
                    features = stack_features(features, feats)
                    route_of[i] = len(features.offsets) - 2
                    n_anchors[i] = len(new)
                    goals[i] = new.goal_pose
                    follower.put(np.array([i]), start)
            u = controls_toward(st, out.waypoint, ranges, cfg.lidar, cfg.rmp, veh)
            if noise is not None and cfg.noise_std > 0:
                u = u * (1.0 + cfg.noise_std * noise[cars, k])
            state[cars] = vehicle_step(st, u, veh)
            odometry.update(cars, state[cars, :3])
            steps[cars] = k + 1
            modes[cars, k] = fs.mode
            active_log[cars, k] = fs.active
            poses[cars, k + 1:] = state[cars, None, :3]
            hit = in_collision(state[cars], clearance, veh)
            if changes is not None:
                hit |= changes.touching(cars, state[cars], veh)
                changes.step(veh.dt, cars, state[cars, :2])
            outcome[cars[hit]] = NAV_COLLISION
            ended = follower_outcome(fs)
            fin = ~hit & (ended != RUNNING)
            outcome[cars[fin]] = ended[fin]
            if watch is not None:
                live = ~hit & ~fin
                stop = np.asarray(watch(k, cars, state[cars]), bool) & live
                outcome[cars[stop]] = NAV_DIVERGED
            if progress is not None:
                progress(k, int((outcome == RUNNING).sum()))
        outcome[outcome == RUNNING] = NAV_TIMEOUT
        dist = np.hypot(*(state[:, :2] - goals[:, :2]).T)
        return NavigationResult(poses, modes, active_log, steps, outcome, follower, dist,
                                None if manoeuvres is None else manoeuvres.started.copy())


__all__ = ["NavigationConfig", "NavigationEngine", "NavigationResult", "NAV_OUTCOMES",
           "follower_outcome"]
