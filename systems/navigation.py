"""The navigation diagram (a route followed by FollowerFsm + C_WP + RMP) and its runner.

::

    CarPlant --pose--> LidarSensor, CameraSensor (10 Hz, sample and hold)
    CarPlant --state--> ZeroOrderHold --> FollowerFsm, WaypointNet, RmpController
    CameraSensor (or LidarSensor) --observation--> FollowerFsm, WaypointNet
    FollowerFsm --target--> WaypointNet --waypoint--> WaypointSelect <--held_waypoint-- FollowerFsm
    WaypointSelect --> ManoeuvreGuard --> RmpController <--ranges-- LidarSensor
    (ManoeuvreGuard: the expert's manoeuvres on the car's recent scans; left
    out when the follower's ``manoeuvres`` is off)
    with a changed world (the scenario's ``changes``):
    CarPlant --pose--> WorldChangesSource --faces--> LidarSensor, CameraSensor
    with odometry that drifts (the scenario's ``odometry``):
    ZeroOrderHold --> OdometrySensor --odometry--> FollowerFsm, WaypointNet, ManoeuvreGuard,
    and the waypoint goes through OdometryFrame (odometry frame -> world) to the RmpController
    RmpController --> ActuationNoise <-- RandomSource; ActuationNoise --> CarPlant

FollowerFsm runs RE itself (on the route's cached anchor features), so no
separate ReachabilityEstimator system is wired. :class:`NavigationRunner`
runs it until the follower ends the run (reached, or gave up), a collision
(with the world or with what changed in it) or the time limit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from topodrake.systems.run import DiagramRunner, RunResult
from topodrake.systems.scenario import Scenario

from topodrake.errors import TopodrakeError
from topodrake.navigation.follower import REASONS, FollowerConfig, Mode
from topodrake.odometry import OdometryConfig
from topodrake.vehicle import in_collision
from topodrake.world import load_world, path_length
from topodrake.world.changes import CarChanges, WorldChanges, place_changes


@dataclass
class NavigationScenario(Scenario):
    """A :class:`Scenario` plus the learned follower: C_WP and RE
    checkpoints, the follower's thresholds and what the car's odometry reads
    (YAML keys ``controller``, ``reach``, ``follower``, ``odometry``: an
    :class:`~topodrake.odometry.OdometryConfig`, all zero for the true pose;
    each run's errors come from its odometry seed), and ``changes``: what
    the car meets that its map lacks (a
    :class:`~topodrake.world.changes.WorldChanges`; each run places them on
    its route, from its seed)."""

    controller: str = "checkpoints/camera_k5/checkpoint.pt"
    reach: str = "checkpoints/reach_camera_k5/checkpoint.pt"
    follower: FollowerConfig = field(default_factory=FollowerConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig.perfect)
    t_max_s: float = 150.0
    changes: WorldChanges = field(default_factory=WorldChanges)

    def validate(self, where: str = "scenario") -> "NavigationScenario":
        super().validate(where)
        self.odometry.check()
        self.changes.check(f"{where}: changes")
        return self

    def place_changes(self, world, route, start, seed: int) -> tuple[CarChanges, dict | None]:
        """A run's changes on its planned path (``start``, then the route's
        anchors, the last its goal), drawn from ``seed``
        (:func:`~topodrake.world.changes.place_changes`): the changes of
        the car, and what was placed (None: no room on this route)."""
        start = np.asarray(start, np.float64)
        path = np.vstack([start[None, :2], np.asarray(route.poses, np.float64)[:, :2]])
        changes, placed = place_changes(world, [path], self.changes, [seed], start[None, :3])
        return changes, placed[0]


def load_networks(scenario: NavigationScenario):
    """(C_WP policy, RE) from the scenario's checkpoints."""
    from topodrake.topomap.sources import load_networks

    return load_networks(scenario.controller, scenario.reach)


@dataclass
class NavigationDiagram:
    diagram: object
    car: object
    follower: object
    waypoint_net: object
    pose_logger: object
    noise_logger: object
    mode_logger: object
    world: object
    scenario: object
    route: object
    odometry: object = None     # the OdometrySensor (None: the follower reads the true pose)
    recorder: object = None     # the DriveRecorder (None: the drive's sensors are not kept)
    changes: object = None      # the WorldChangesSource (None: the world as mapped)


def make_navigation_diagram(scenario: NavigationScenario, plan, meshcat=None, *, world=None,
                            policy=None, reach=None, replanner=None,
                            record_sensors: bool = False) -> NavigationDiagram:
    """CarPlant + sensors + FollowerFsm + WaypointNet + RmpController +
    ActuationNoise following ``plan`` (a :class:`~topodrake.contract.route.Route`).
    ``policy`` and ``reach`` default to the scenario's checkpoints (pass
    oracles or loaded networks to skip loading). ``replanner``: a
    :class:`~topodrake.navigation.replan.Replanner` of one car over
    ``[plan]`` (replanning while dead reckoning). Exported outputs: ``pose``,
    ``state``, ``ranges``, ``controls``, ``waypoint``, ``mode`` and (camera)
    ``image``. ``record_sensors``: keep each period's state, odometry,
    ranges, camera image (the camera is added if the policy reads none) and
    mode in a :class:`~topodrake.systems.recorder.DriveRecorder`. With the
    scenario's ``changes``, a
    :class:`~topodrake.systems.changes.WorldChangesSource` feeds the sensors
    (and Meshcat) the car's changed world, which each run places."""
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import LogVectorOutput
    from topodrake.systems.control import ManoeuvreGuard, RmpController
    from topodrake.systems.diagram import add_chassis
    from topodrake.systems.follower import FollowerFsm, WaypointSelect
    from topodrake.systems.odometry import OdometryFrame, OdometrySensor
    from topodrake.systems.waypoint_net import WaypointNet

    if policy is None or reach is None:
        loaded = load_networks(scenario)
        policy = policy or loaded[0]
        reach = reach or loaded[1]
    world = world or load_world(scenario.world)
    dt = scenario.vehicle.dt
    b = DiagramBuilder()
    c = add_chassis(b, scenario, world, camera=policy.observation == "camera" or record_sensors,
                    meshcat=meshcat, changes=scenario.changes.any)
    drifts = not scenario.odometry.is_perfect
    fsm = b.AddNamedSystem("follower", FollowerFsm(plan, policy, reach, scenario.follower, dt,
                                                   scenario.camera, scenario.lidar, replanner,
                                                   odometry_input=drifts))
    net = b.AddNamedSystem("waypoint_net", WaypointNet(policy, dt, scenario.camera, scenario.lidar,
                                                       odometry_input=drifts))
    select = b.AddNamedSystem("waypoint_select", WaypointSelect())
    rmp = b.AddNamedSystem("rmp", RmpController(scenario.lidar, scenario.rmp, scenario.vehicle))
    b.Connect(c.hold.get_output_port(), fsm.state_port)
    b.Connect(c.hold.get_output_port(), net.state_port)
    b.Connect(c.hold.get_output_port(), rmp.state_port)
    odometry, odo_port = None, c.hold.get_output_port()    # what the follower's side reads
    if drifts:
        odometry = b.AddNamedSystem("odometry", OdometrySensor(scenario.odometry, dt))
        b.Connect(c.hold.get_output_port(), odometry.state_port)
        odo_port = odometry.odometry_port
        b.Connect(odo_port, fsm.odometry_port)
        b.Connect(odo_port, net.odometry_port)
    obs = {"camera": c.camera.image_port if c.camera is not None else None,
           "lidar": c.lidar.ranges_port}.get(policy.observation)
    if obs is not None:
        b.Connect(obs, fsm.observation_port)
        b.Connect(obs, net.observation_port)
    if fsm.ranges_port is not None:
        b.Connect(c.lidar.ranges_port, fsm.ranges_port)
    b.Connect(fsm.target_port, net.target_port)
    b.Connect(net.waypoint_port, select.net_port)
    b.Connect(fsm.held_waypoint_port, select.held_port)
    waypoint = select.waypoint_port
    if scenario.follower.manoeuvres:
        guard = b.AddNamedSystem("manoeuvres", ManoeuvreGuard(scenario.lidar, scenario.rmp,
                                                              scenario.vehicle, dt,
                                                              scenario.follower.manoeuvre))
        b.Connect(odo_port, guard.state_port)
        b.Connect(select.waypoint_port, guard.waypoint_in_port)
        b.Connect(c.lidar.ranges_port, guard.ranges_port)
        waypoint = guard.waypoint_port
    if drifts:          # the waypoint where it lies relative to the car, in the world
        frame = b.AddNamedSystem("odometry_frame", OdometryFrame())
        b.Connect(waypoint, frame.waypoint_in_port)
        b.Connect(odo_port, frame.odometry_port)
        b.Connect(c.hold.get_output_port(), frame.state_port)
        waypoint = frame.waypoint_port
    b.Connect(waypoint, rmp.waypoint_port)
    b.Connect(c.lidar.ranges_port, rmp.ranges_port)
    b.Connect(rmp.controls_port, c.noise.controls_port)
    b.ExportOutput(waypoint, "waypoint")
    b.ExportOutput(fsm.mode_port, "mode")
    mode_logger = LogVectorOutput(fsm.mode_port, b, dt)
    mode_logger.set_name("mode_log")
    recorder = None
    if record_sensors:
        from topodrake.systems.recorder import DriveRecorder

        recorder = b.AddNamedSystem("drive_recorder", DriveRecorder(c.lidar.lidar.config.beams,
                                                                    dt))
        b.Connect(c.hold.get_output_port(), recorder.state_port)
        b.Connect(odo_port, recorder.odometry_port)
        b.Connect(c.lidar.ranges_port, recorder.ranges_port)
        b.Connect(fsm.mode_port, recorder.mode_port)
        b.Connect(c.camera.image_port, recorder.image_port)
    diagram = b.Build()
    diagram.set_name("topodrake_navigation")
    return NavigationDiagram(diagram, c.car, fsm, net, c.pose_logger, c.noise_logger, mode_logger,
                             world, scenario, plan, odometry, recorder, c.changes)


@dataclass
class NavigationRunResult(RunResult):
    """A run along a route: ``outcome`` is "reached", "collision",
    "timeout", "search_failed" or "dead_reckoning_gave_up"; ``modes`` (K,)
    the follower's mode in each period."""
    modes: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64), repr=False)
    result: str = ""
    distance_m: float = 0.0
    probability: float = 1.0
    visited: int = -1          # the follower's last visited anchor at the end
    active: int = -1           # ... and its active anchor
    route: object = None       # the route driven at the end (a replanned one, or the plan)
    plans: int = 1             # routes driven (1 + accepted replans)
    changes: dict | None = None    # what was placed in the car's world (None: unchanged)

    @property
    def outcome(self) -> str:
        return self.result

    def summary(self) -> dict:
        out = super().summary()
        out.update({"distance_m": round(self.distance_m, 2),
                    "probability": round(self.probability, 4)})
        return out


class NavigationRunner(DiagramRunner):
    """Runs a navigation diagram (:func:`make_navigation_diagram`) from a start pose."""

    def run(self, start, seed: int = 0, t_max_s: float | None = None,
            goal_watch_m: float | None = None,
            odometry_seed: int | None = None) -> NavigationRunResult:
        """Drive from ``start``; with ``goal_watch_m`` the run also ends,
        reached, once the car is that close to the route's goal pose (the
        planning study's goal watch), whether or not the follower has
        declared arrival yet. Where the scenario's odometry drifts, its
        errors come from ``odometry_seed`` (default: ``seed``). The
        scenario's changes are placed on the route from ``seed``
        (:meth:`NavigationScenario.place_changes`); a route with no room
        for them raises."""
        b = self.built
        world = b.world
        start = world.check_pose(start, "start", free=False)
        if in_collision(np.array([[*start[:3], 0.0, 0.0]]), world.grid.clearance_at,
                        b.scenario.vehicle)[0]:
            raise TopodrakeError(f"start ({start[0]:.2f}, {start[1]:.2f}) puts the car's body "
                                 f"into a wall of {world.name!r}")
        context = self._reset(start, seed)
        if b.odometry is not None:
            b.odometry.set_start(b.odometry.GetMyMutableContextFromRoot(context), start,
                                 seed if odometry_seed is None else odometry_seed)
        placed = None
        if b.changes is not None:
            changes, placed = b.scenario.place_changes(world, b.route, start, seed)
            if placed is None:
                raise TopodrakeError(f"no room for {b.scenario.changes.label} on the route "
                                     f"from ({start[0]:.2f}, {start[1]:.2f})")
            b.changes.set_changes(b.changes.GetMyMutableContextFromRoot(context), changes)
        startup = 0.0 if self.warm else self._warm_up()
        replanner = b.follower.replanner
        if replanner is not None:
            replanner.reset()
        b.mode_logger.FindMutableLog(context).Clear()
        if b.recorder is not None:
            b.recorder.clear()
        goal_xy = np.asarray(b.route.goal_pose, np.float64)[:2]
        watch = (lambda x: False) if goal_watch_m is None else \
            (lambda x: math.hypot(x[0] - goal_xy[0], x[1] - goal_xy[1]) <= goal_watch_m)
        r = self._simulate(watch, b.scenario.t_max_s if t_max_s is None else t_max_s)
        r["startup"] = startup
        context = self.simulator.get_context()
        fsm_context = b.follower.GetMyContextFromRoot(context)
        fs = b.follower.follower_state(fsm_context)
        route = b.follower.current_route(fsm_context)
        mode = int(fs.mode[0])
        if r["collision"]:
            result = "collision"
        elif mode == Mode.REACHED or r["success"]:
            result = "reached"
        elif mode == Mode.FAILED:
            result = REASONS[int(fs.reason[0])]
        else:
            result = "timeout"
        x = r["state"]
        goal = route.goal_pose
        modes = b.mode_logger.FindLog(context).data()[0, 1:].round().astype(np.int64)
        poses = r["poses"]
        return NavigationRunResult(
            result == "reached", r["collision"], result == "timeout", r["time_s"],
            float(np.hypot(x[0] - goal[0], x[1] - goal[1])), poses, r["noise"], r["wall"],
            r["startup"], modes=modes, result=result,
            distance_m=path_length(poses[:, :2]),
            probability=float(b.route.probability), visited=int(fs.visited[0]),
            active=int(fs.active[0]), route=route,
            plans=1 if replanner is None else int(replanner.plans[0]), changes=placed)
