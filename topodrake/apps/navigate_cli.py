"""``topodrake navigate``: plan, then follow the plan in the Drake diagram.

    topodrake navigate t0.tdmap --start 1.0,2.0,0 --goal 8.5,3.0,1.57 --json
    topodrake navigate t0.tdmap --start-place 1 --goal-place 4
    topodrake navigate test-0 --start 1.0,2.0,0 --goal 8.5,3.0,1.57
    topodrake navigate data/demos/pairs-s0/test-0 --drive 3 --plot nav.png

MAP is a map file (``topodrake map build``; the plan runs from the start's
observation to the goal's on it, with the RE and C_WP the map was built
for), a demonstration folder (``topodrake collect``; the drive nearest to
the start and goal, or ``--drive``, becomes a chain of anchors under RE),
or a world (catalogue name or map YAML/JSON; the expert drives once from
the start to the goal and that drive becomes the chain). Prints the outcome
(:mod:`topodrake.navigation.outcomes`), the time, the plan's probability and
anchors, the distance driven and the distance left to the goal; ``--json``
prints them as one object. Exit status: 0 reached, 3 any other outcome, 1
no plan, 2 bad input or an output that cannot be written.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from topodrake.apps.drive import chain_route, drive_route, plot_drive
from topodrake.apps.endpoints import add_endpoint_options, resolve_endpoints
from topodrake.apps.map_cli import Unreachable
from topodrake.apps.outputs import (
    add_force_option,
    check_folder,
    check_output,
    lock_output,
    write_kept,
)
from topodrake.bag import write_drive_mcap
from topodrake.demonstrations import load_demos
from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_bytes
from topodrake.learning.reachability.controllers import controller_policy
from topodrake.navigation.follower import MODES
from topodrake.navigation.outcomes import SUCCESS_M, drive_outcome, exit_status, goal_distance
from topodrake.navigation.replan import route_traversals
from topodrake.odometry import ODOMETRY_MODELS, odometry_model
from topodrake.rollout import ExpertRollout, RolloutConfig
from topodrake.topomap.mapfile import save_map
from topodrake.topomap.plan import plan_from_vertex, plan_path
from topodrake.topomap.plot import _map_layers
from topodrake.topomap.recalibrate import record_traversals
from topodrake.topomap.sources import (
    check_controller,
    drive_observations,
    load_networks,
    open_map,
    view_scans,
)
from topodrake.world import load_world

DEFAULT_CONTROLLER = "checkpoints/camera_k5/checkpoint.pt"
EXIT_HELP = (f"Exit status: 0 when the car reached the goal (within {SUCCESS_M} m), 3 for any "
             "other outcome (false_reached, collision, timeout, search_failed, "
             "dead_reckoning_gave_up), 1 when there is no plan, 2 for bad input or an output "
             "that cannot be written.")


def check_args(args) -> None:
    """Numbers checked where they enter."""
    if not (math.isfinite(args.noise) and args.noise >= 0):
        raise TopodrakeError(f"--noise must be finite and >= 0, got {args.noise}")
    if args.seed < 0:
        raise TopodrakeError(f"--seed must be >= 0, got {args.seed}")
    if not (math.isfinite(args.t_max) and args.t_max > 0):
        raise TopodrakeError(f"--t-max must be finite and > 0, got {args.t_max}")
    if not 0.0 < args.p < 1.0:
        raise TopodrakeError(f"--p must be in (0, 1), got {args.p}")
    if args.update_map and Path(args.map).suffix != ".tdmap":
        raise TopodrakeError("--update-map needs a map file (.tdmap) as MAP")
    if args.replan < 0:
        raise TopodrakeError(f"--replan must be >= 0, got {args.replan}")
    if args.drive is not None and args.drive < 0:
        raise TopodrakeError(f"--drive must be >= 0, got {args.drive}")


def _networks(controller: str, reach: str | None):
    """(C_WP, RE): ``controller`` a C_WP checkpoint or ``"registration"``
    (whose RE defaults to its shipped one)."""
    return load_networks(controller, reach)


class MapPlanner:
    """A map file loaded once, with the RE and C_WP it was built for, that
    plans from poses (their observations rendered) and replans without
    given edges."""
    def __init__(self, path: Path, reach_path=None, controller_path=None):
        self.path = Path(path)
        loaded = open_map(path, reach_path, controller_path)
        if not hasattr(loaded.scorer, "reach"):
            raise TopodrakeError(f"{path} is an oracle map; navigate follows learned maps")
        self.world, self.scorer, self.topomap = loaded.world, loaded.scorer, loaded.topomap
        self.calibration = loaded.calibration        # the plan calibration of its RE, or None
        self.policy = controller_policy(loaded.controller)
        self.reach = self.scorer.reach
        self.layers = _map_layers(self.topomap)

    def plan(self, start, goal, excluded_edges=(), time_limit_s: float | None = None,
             vertex: int | None = None):
        """The PlanResult from pose ``start`` (or from the map vertex
        ``vertex``: a replanning car returning to an anchor) to pose
        ``goal``, made for ``time_limit_s`` seconds of driving where given."""
        poses = np.stack([start, goal])
        obs = drive_observations(self.world, self.scorer, poses)
        scans = view_scans(self.world, self.topomap, poses)
        if vertex is not None:
            return plan_from_vertex(self.topomap, vertex, obs[1], goal_pose=goal,
                                    goal_scan=None if scans is None else scans[1],
                                    excluded_edges=excluded_edges, time_limit_s=time_limit_s)
        return plan_path(self.topomap, obs[0], obs[1], start_pose=start, goal_pose=goal,
                         excluded_edges=excluded_edges, time_limit_s=time_limit_s,
                         view_scans=scans)


def success_chance(planner: MapPlanner | None, route) -> float | None:
    """A route's calibrated chance of success on a map (None where no plan
    calibration ships for the map's RE, or without a map)."""
    if planner is None or planner.calibration is None:
        return None
    return round(float(planner.calibration.predict(route.probability, len(route))[0]), 4)


def plan_on_map(path: Path, start, goal, reach_path=None, controller_path=None,
                time_limit_s: float | None = None):
    """(the map's MapPlanner, route) of a plan on a map file, made for
    ``time_limit_s`` seconds of driving where given."""
    planner = MapPlanner(path, reach_path, controller_path)
    planner.world.check_pose(start, "start")
    planner.world.check_pose(goal, "goal")
    route = _plan_or_refuse(planner.plan(start, goal, time_limit_s=time_limit_s), path)
    return planner, route


def chain_from_demos(folder: Path, start, goal, drive, policy, reach, p):
    """(world, route, drive index) of a demonstration folder's drive."""
    manifest, demos = load_demos(folder, successful_only=True)
    if not demos:
        raise TopodrakeError(f"{folder} holds no successful drives")
    world = load_world(manifest["world"])
    if drive is None:
        cost = [np.hypot(*(d.poses[0, :2] - start[:2])) + np.hypot(*(d.poses[-1, :2] - goal[:2]))
                for d in demos]
        drive = int(np.argmin(cost))
    elif drive >= len(demos):
        raise TopodrakeError(f"--drive must be in 0..{len(demos) - 1} ({folder} has {len(demos)} "
                             f"successful drives)")
    return world, chain_route(world, demos[drive].poses, policy, reach, p), drive


TEACH_GOAL_M = 0.1     # a teach drive drives on toward its goal until this close ...
TEACH_STOP_M = 0.27    # ... and ends at its closest pass once within the expert's own stop


def teach_end(poses: np.ndarray, goal) -> int:
    """The frame a teach drive ends at: its first closest pass of ``goal``
    within ``TEACH_STOP_M`` (a car-like expert told to come closer circles
    the goal; the circle would put a cluster of anchors on it)."""
    d = np.hypot(*(np.asarray(poses)[:, :2] - np.asarray(goal)[:2]).T)
    inside = np.flatnonzero(d <= TEACH_STOP_M)
    if inside.size == 0:
        return len(d) - 1
    k = int(inside[0])
    while k + 1 < len(d) and d[k + 1] < d[k]:
        k += 1
    return k


def chain_from_expert(world_spec: str, start, goal, policy, reach, p):
    """(world, route) of one noise-free expert drive from ``start`` to
    ``goal``, ended at its closest pass of the goal (:func:`teach_end`: the
    route's last anchor is the goal's view)."""
    world = load_world(world_spec)
    world.check_pose(start, "start")
    world.check_pose(goal, "goal")
    res = ExpertRollout(world, RolloutConfig(t_max_s=150.0, goal_tolerance_m=TEACH_GOAL_M)).run(
        start[None], goal[None, :2])
    poses = res.trajectory(0)["poses"]
    end = teach_end(poses, goal)
    if not res.success[0] and np.hypot(*(poses[end, :2] - goal[:2])) > TEACH_STOP_M:
        raise TopodrakeError(f"the expert could not drive from the start to the goal in "
                             f"{world.name!r} ({res.trajectory(0)['outcome']}): no demonstration")
    return world, chain_route(world, poses[:end + 1], policy, reach, p)


def check_outputs(args) -> None:
    """Every file navigate writes, checked before the drive."""
    check_output(args.plot, "image", force=args.force, option="--plot")
    check_output(args.meshcat, "html", force=args.force, option="--meshcat")
    check_output(args.record_mcap, "mcap", force=args.force, option="--record-mcap")
    if args.update_map:
        check_folder(Path(args.map).parent, "--update-map")
    lock_output(args.plot, "--plot")
    lock_output(args.meshcat, "--meshcat")
    lock_output(args.record_mcap, "--record-mcap")
    if args.update_map:
        lock_output(args.map, "--update-map")


def cmd_navigate(args) -> int:
    from topodrake.systems.navigation import NavigationScenario

    check_args(args)
    check_outputs(args)
    start, goal = resolve_endpoints(args, args.map)
    check_controller(args.controller, args.reach)
    import torch

    # one car: batch-1 inference runs faster on one thread than on two here
    # (and far faster when other processes share the cores)
    torch.set_num_threads(1)
    source = Path(args.map)
    layers = None
    planner = None
    extra = {}
    if source.suffix == ".tdmap":
        planner = MapPlanner(source, args.reach, args.controller)
        world, policy, reach, layers = planner.world, planner.policy, planner.reach, planner.layers
        world.check_pose(start, "start")
        world.check_pose(goal, "goal")
        route = _plan_or_refuse(planner.plan(start, goal, time_limit_s=args.t_max), source)
    else:
        if args.replan:
            raise TopodrakeError("--replan needs a map file (.tdmap) as MAP")
        controller = args.controller or DEFAULT_CONTROLLER
        reach = args.reach          # None: the RE that ships for the controller, as demo takes
        policy, reach = _networks(controller, reach)
        if source.is_dir():
            world, route, drive = chain_from_demos(source, start, goal, args.drive, policy, reach,
                                                   args.p)
            extra["drive"] = drive
        else:
            if args.drive is not None:
                raise TopodrakeError("--drive needs a demonstration folder as MAP")
            world, route = chain_from_expert(args.map, start, goal, policy, reach, args.p)
    world.check_pose(start, "start", free=False)
    scenario = NavigationScenario(world=args.map, noise_std=args.noise, seed=args.seed,
                                  t_max_s=args.t_max, odometry=odometry_model(args.odometry),
                                  camera_enabled=policy.observation == "camera")
    replanner = None
    if planner is not None and args.replan:
        from topodrake.navigation.replan import Replanner, ReplanSchedule

        replanner = Replanner(lambda _, pose, excluded, vertex=None: _route_or_none(planner.plan(
            pose, goal, excluded, time_limit_s=args.t_max, vertex=vertex)), [route],
            ReplanSchedule(max_replans=args.replan))
    result = drive_route(scenario, route, start, world=world, policy=policy, reach=reach,
                         record=bool(args.meshcat), seed=args.seed, replanner=replanner,
                         record_sensors=bool(args.record_mcap))
    first_p, anchors = float(route.probability), len(route)
    chance = success_chance(planner, route)
    if chance is not None:
        extra["success_probability"] = chance
    if replanner is not None:
        extra["replans"] = int(replanner.plans[0]) - 1
        route = result.route
    goal_m = goal_distance(result.poses, goal)
    outcome = drive_outcome(result.outcome, goal_m)
    if planner is not None and args.update_map:
        failed = [] if replanner is None else replanner.excluded[0]
        extra["updated_edges"] = _update_map(planner, route, result, failed, outcome)
    out = {"outcome": outcome, "time_s": round(result.time_s, 2),
           "probability": round(first_p, 4), "anchors": anchors,
           "distance_m": round(result.distance_m, 2), "distance_to_goal_m": round(goal_m, 3),
           "odometry": args.odometry, **extra}
    if args.json:
        print(json.dumps(out), flush=True)
    else:
        rtf = result.time_s / max(result.wall_time_s, 1e-9)
        print(f"{outcome} in {result.time_s:.1f} s over {result.distance_m:.1f} m, {goal_m:.2f} m "
              f"from the goal; plan of {anchors} anchors, probability {first_p:.3f}"
              + (f", {extra['replans']} replans" if "replans" in extra else "")
              + f"; real-time factor {rtf:.1f} (start-up {result.startup_s:.1f} s)"
              + (f"; updated {len(extra['updated_edges'])} driven edges in {source}"
                 if "updated_edges" in extra else ""), flush=True)
    _write_drive_files(args, world, route, result, start, goal, layers, outcome, extra)
    if args.record_mcap:
        write_kept(args.record_mcap, lambda p: write_drive_mcap(p, result.frames, scenario.lidar,
                                                                modes=MODES), "the recording")
        if not args.json:
            print(f"wrote {args.record_mcap}")
    return exit_status(outcome)


def _write_drive_files(args, world, route, result, start, goal, layers, outcome, extra) -> None:
    """The plot and the Meshcat recording of a drive (each kept elsewhere when
    its file cannot be written)."""
    if args.meshcat:
        write_kept(args.meshcat, lambda p: atomic_write_bytes(p, result.recording.encode()),
                   "the recording")
        if not args.json:
            print(f"wrote {args.meshcat}")
    if args.plot:
        title = (f"{world.name}: {outcome} in {result.time_s:.1f} s, "
                 + (f"last of {extra['replans'] + 1} plans: " if extra.get("replans")
                    else "plan of ")
                 + f"{len(route)} anchors (p = {route.probability:.3f})")
        write_kept(args.plot, lambda p: plot_drive(world, route, result, p, start=start,
                                                   goal=goal, map_layers=layers, title=title),
                   "the plot")
        if not args.json:
            print(f"wrote {args.plot}")


def _plan_or_refuse(plan, source):
    """The route of a plan; no plan ends the command with exit status 1."""
    if not plan.reachable:
        raise Unreachable(f"no plan from the start to the goal on {source}: {plan.reason}")
    return plan.route


def _update_map(planner, route, result, failed: list, outcome: str) -> list[dict]:
    """Fold the run into the map's edges (the hops it passed on its last
    route, the edge it failed on unless time ran out, and those replanning
    left) and save the map over its file."""
    passed, gave_up = route_traversals(route.vertices, result.visited, result.active,
                                       outcome == "reached", outcome == "timeout")
    changed = record_traversals(planner.topomap, passed, list(failed) + gave_up)
    if changed:
        save_map(planner.topomap, planner.path)
    return changed


def _route_or_none(plan):
    return plan.route if plan.reachable else None


def add_navigate_parser(sub) -> None:
    nv = sub.add_parser("navigate", help="plan on a map (or one demonstration) and follow the plan "
                                         "in the Drake diagram", epilog=EXIT_HELP)
    nv.add_argument("map", metavar="MAP", help="map file (.tdmap), demonstration folder, or world "
                                               "(one expert drive becomes the chain)")
    add_endpoint_options(nv)
    nv.add_argument("--noise", type=float, default=0.0,
                    help="actuation noise std, 0 = off (default: 0)")
    nv.add_argument("--seed", type=int, default=0, help="seed of the actuation noise (default: 0)")
    nv.add_argument("--odometry", choices=ODOMETRY_MODELS, default="wheel",
                    help="what the follower's odometry reads: wheel odometry that drifts "
                         "(errors drawn from --seed) or the true pose (default: wheel)")
    nv.add_argument("--t-max", type=float, default=150.0,
                    help="time limit of the drive in s; on a map the plan is the path most "
                         "likely to be driven within it (default: 150)")
    nv.add_argument("--controller", help=f"C_WP checkpoint, or 'registration' for the lidar "
                                         f"teach-and-repeat C_WP (default: the map's, else "
                                         f"{DEFAULT_CONTROLLER})")
    nv.add_argument("--reach", help="RE checkpoint (default: the map's, else the RE that ships "
                                    "for the controller)")
    nv.add_argument("--drive", type=int, help="index of the demonstration folder's drive to follow "
                                              "(default: the one nearest the start and goal)")
    nv.add_argument("--p", type=float, default=0.99,
                    help="p_sparsify of a chain (default: 0.99)")
    nv.add_argument("--replan", type=int, default=0,
                    help="on a map: a car about to give up in dead reckoning (its last 10 "
                         "periods, every 3) plans again from where it is without the edge it "
                         "fails on and takes the new plan if its follower can start it; at most "
                         "this many new plans (default: 0: no replanning)")
    nv.add_argument("--update-map", action="store_true",
                    help="on a map: fold the drive into the probability of each edge it passed "
                         "or gave up on and save the map over its file (edges from "
                         "experience; default: off)")
    nv.add_argument("--plot", metavar="PNG",
                    help="draw the map, the plan and the driven path (default: none)")
    nv.add_argument("--meshcat", metavar="HTML",
                    help="save a Meshcat recording of the drive (default: none)")
    nv.add_argument("--record-mcap", metavar="MCAP",
                    help="save the drive as a ROS 2 bag in MCAP for Foxglove: /scan "
                         "(LaserScan), /odom (Odometry), /camera/image (Image, rgb8), "
                         "/follower/mode (String) and /tf, one message per control period "
                         "in sim time (default: none)")
    nv.add_argument("--json", action="store_true",
                    help="print the outcome as one JSON object (default: off)")

    add_force_option(nv)
    nv.set_defaults(func=cmd_navigate)
