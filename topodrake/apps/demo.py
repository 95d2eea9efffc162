"""``topodrake demo``: the learned system end to end, or (``--expert``) the expert.

The learned demo (:func:`run_learned_demo`) plans on a map file, by default
the shipped map of ``test-0`` (``checkpoints/demo_map``, 90 drives, built
for the registration C_WP and its learned RE), from the start place's
observation to the goal place's, and the car drives the plan in the Drake
navigation diagram with the controller the map was built for. With
``--controller`` (or ``--reach``, or another world) the route is instead one
expert drive between the places, sparsified by the controller's RE into a
chain of anchors. With ``--boxes`` and ``--people`` the car meets a
changed house (unmapped boxes on its route, people walking along and across
it; :mod:`topodrake.world.changes`). It writes the drive over the
floor plan (the anchors, the map, and the path coloured by the follower's
mode) and a Meshcat HTML recording whose camera frames the whole house
(and shows the boxes and the people walking).

The expert demo (:func:`run_demo`) drives the expert between the places and
writes a top-down plan (walls, places, the A* path, the driven path, lidar
hits along the way), a strip of camera frames re-rendered from the logged
poses (the same renderer the CameraSensor runs), and with Meshcat a static
HTML recording of the run.

The demo keeps a record of the files it wrote in its folder, with their
SHA-256 (:data:`OWN_OUTPUTS`): a later demo replaces those of them that
are unchanged, and any other file there only with ``--force``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from topodrake.apps import argtypes as at
from topodrake.apps.drive import drive_route, plot_drive
from topodrake.apps.endpoints import source_world
from topodrake.apps.navigate_cli import EXIT_HELP, chain_from_expert, plan_on_map, success_chance
from topodrake.apps.outputs import (
    add_force_option,
    check_output,
    check_output_folder,
    lock_output,
    write_kept,
)
from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_bytes, atomic_write_json, file_sha256
from topodrake.navigation.outcomes import SUCCESS_M, drive_outcome, exit_status, goal_distance
from topodrake.odometry import ODOMETRY_MODELS, odometry_model
from topodrake.sensing.camera import Camera
from topodrake.sensing.lidar import Lidar
from topodrake.systems.scenario import Scenario
from topodrake.topomap.mapfile import read_map_meta
from topodrake.topomap.sources import check_controller, resolve_checkpoint
from topodrake.world import load_world
from topodrake.world.changes import WorldChanges
from topodrake.world.plot import legend_below, plot_world, save_figure


def run_demo(world_name: str = "test-0", start_place: int = 0, goal_place: int = 5,
             out_dir: str = "out/demo", seed: int = 0, noise_std: float = 0.33,
             meshcat: bool = False, n_frames: int = 8) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from topodrake.systems.diagram import build_expert_diagram
    from topodrake.systems.run import ExpertRunner

    wall = time.perf_counter()
    world = load_world(world_name)
    scenario = Scenario(world=world_name, start_place=start_place, goal_place=goal_place,
                        noise_std=noise_std, seed=seed, t_max_s=150.0)
    viewer = None
    if meshcat:
        from topodrake.apps.drive import make_recorder

        viewer = make_recorder()
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
    summary = result.summary()
    summary["outcome"] = drive_outcome(summary["outcome"], summary["distance_to_goal_m"])
    ax.set_title(f"{world.name}: place {start_place} -> {goal_place}, {summary['outcome']} "
                 f"in {result.time_s:.1f} s (noise {noise_std})")
    legend_below(ax)
    files["plan"] = write_kept(out / "plan.png", lambda p: save_figure(fig, p), "the plot")

    images = Camera(world, scenario.camera).render(result.poses[frames_at])
    fig, axes = plt.subplots(1, n_frames, figsize=(2 * n_frames, 2.4))
    for n, (axi, k) in enumerate(zip(np.atleast_1d(axes), frames_at)):
        axi.imshow(images[n])
        axi.set_title(f"{chr(ord('a') + n)}: t={k * scenario.vehicle.dt:.1f} s", fontsize=8)
        axi.axis("off")
    files["camera"] = write_kept(out / "camera.png", lambda p: save_figure(fig, p), "the frames")

    if viewer is not None:
        viewer.StopRecording()
        viewer.PublishRecording()
        html = viewer.StaticHtml().encode()
        files["meshcat"] = write_kept(out / "meshcat.html", lambda p: atomic_write_bytes(p, html),
                                      "the recording")
    summary.update({"world": world.name, "start_place": start_place, "goal_place": goal_place,
                    "seed": seed, "realtime_factor": round(result.time_s / max(result.wall_time_s, 1e-9), 1),
                    "demo_wall_s": round(time.perf_counter() - wall, 2)})
    return {"files": files, "summary": summary}


#: the demo's drive ends this near the goal place (m), inside the success radius SUCCESS_M
DEMO_STOP_M = 0.3

#: the demo's C_WP without a map: of the shipped controllers with their own RE, the one that
#: holds routes best
DEMO_CONTROLLER = "checkpoints/lidar_k5/checkpoint.pt"
#: the shipped map the demo plans on by default (card beside it), and its world
DEMO_MAP = "checkpoints/demo_map/map.tdmap"
DEMO_WORLD = "test-0"


def run_learned_demo(world_name: str = "test-0", start_place: int = 3, goal_place: int = 6,
                     out_dir: str = "out/demo", seed: int = 0, noise_std: float = 0.0,
                     p: float = 0.99, controller: str = DEMO_CONTROLLER,
                     reach: str | None = None, meshcat: bool = True, map_path=None,
                     odometry: str = "wheel", changes: WorldChanges | None = None) -> dict:
    """The learned follower between two places: a plan on ``map_path``
    (followed by the controller it was built for), or without a map a chain
    of anchors from one expert drive, followed by ``controller`` (a C_WP
    checkpoint or ``"registration"``) and ``reach`` (default: the RE
    shipped for it), on ``odometry`` (a model of
    :data:`topodrake.odometry.ODOMETRY_MODELS`, its errors drawn from ``seed``),
    in a house changed by ``changes`` (placed on the plan from ``seed``);
    returns the written files and a summary (outcome, times, real-time
    factor warm and cold, the changes and where they were put)."""
    from topodrake.systems.navigation import NavigationScenario, load_networks

    wall = time.perf_counter()
    odometry_cfg = odometry_model(odometry)
    changes = (changes or WorldChanges()).check("demo")
    import torch

    if reach is None and map_path is None:
        from topodrake.topomap.sources import default_reach

        reach = str(default_reach(controller))

    # one car: batch-1 inference runs faster on one thread than on two here
    # (and far faster when other processes share the cores)
    torch.set_num_threads(1)
    map_path = Path(map_path) if map_path else None
    if map_path is not None:
        if not map_path.is_file():
            raise TopodrakeError(f"map file {map_path} does not exist")
        world_name = read_map_meta(map_path)["world"]
    world = load_world(world_name)
    start = world.place_pose(start_place, "--start-place")
    goal = world.place_pose(goal_place, "--goal-place")
    if start_place == goal_place:
        raise TopodrakeError("--start-place and --goal-place must differ")
    t0 = time.perf_counter()
    layers = planner = None
    if map_path is not None:
        planner, route = plan_on_map(map_path, start, goal,
                                     time_limit_s=NavigationScenario().t_max_s)
        world, policy, reach_net, layers = (planner.world, planner.policy, planner.reach,
                                            planner.layers)
    else:
        scenario = NavigationScenario(world=world_name, controller=controller, reach=reach)
        policy, reach_net = load_networks(scenario)
        _, route = chain_from_expert(world_name, start, goal, policy, reach_net, p)
    map_s = time.perf_counter() - t0
    scenario = NavigationScenario(world=world_name, noise_std=noise_std, seed=seed,
                                  controller=controller, reach=reach, odometry=odometry_cfg,
                                  camera_enabled=policy.observation == "camera", changes=changes)
    out = Path(out_dir)
    files: dict[str, Path] = {}
    # the drive ends near the goal place, as the planning study's trials end within its
    # success radius (the follower's own arrival test often misses the goal view); the
    # demo drives on to DEMO_STOP_M so that it arrives with a margin
    result = drive_route(scenario, route, start, world=world, policy=policy, reach=reach_net,
                         record=meshcat, seed=seed, goal_watch_m=DEMO_STOP_M)
    goal_m = goal_distance(result.poses, goal)
    outcome = drive_outcome(result.outcome, goal_m)
    if meshcat:
        html = result.recording.encode()
        files["meshcat"] = write_kept(out / "meshcat.html", lambda p: atomic_write_bytes(p, html),
                                      "the recording")
    title = (f"{world.name}: place {start_place} -> {goal_place}, {outcome} in "
             f"{result.time_s:.1f} s ({len(route)} anchors, plan probability "
             f"{route.probability:.3f}, noise {noise_std})")
    files["plan"] = write_kept(out / "plan.png", lambda p: plot_drive(
        world, route, result, p, start=start, goal=goal, map_layers=layers, title=title),
        "the plot")
    summary = {"outcome": outcome, "time_s": round(result.time_s, 2),
               "probability": round(float(route.probability), 4),
               "distance_m": round(result.distance_m, 2), "distance_to_goal_m": round(goal_m, 3),
               "anchors": len(route), "map": str(map_path) if map_path else "one expert drive",
               "controller": getattr(policy, "name", None)
               or ("the map's" if map_path else str(controller)),
               "world": world.name, "start_place": start_place,
               "goal_place": goal_place, "seed": seed, "noise": noise_std, "odometry": odometry,
               "changes": changes.label, **({"placed": result.changes} if changes.any else {}),
               "map_s": round(map_s, 2), "startup_s": round(result.startup_s, 2),
               "realtime_factor": round(result.time_s / max(result.wall_time_s, 1e-9), 1),
               "realtime_factor_cold": round(result.time_s / max(result.wall_time_s
                                                                 + result.startup_s, 1e-9), 1),
               "demo_wall_s": round(time.perf_counter() - wall, 2)}
    chance = success_chance(planner, route)
    if chance is not None:
        summary["success_probability"] = chance
    return {"files": files, "summary": summary}


#: the demo's record of the files it wrote in its folder (name -> SHA-256)
OWN_OUTPUTS = ".topodrake-demo.json"
_OWN_FORMAT = "topodrake-demo-outputs"


def own_outputs(folder) -> dict:
    """The files an earlier demo wrote in ``folder``, by name, with their
    SHA-256 then (empty without a readable record)."""
    try:
        record = json.loads((Path(folder) / OWN_OUTPUTS).read_text())
    except (OSError, ValueError):
        return {}
    files = record.get("files") if isinstance(record, dict) \
        and record.get("format") == _OWN_FORMAT else None
    return {k: v for k, v in files.items() if isinstance(v, str)} if isinstance(files, dict) \
        else {}


def is_own_output(path) -> bool:
    """``path`` is a file an earlier demo wrote, unchanged since."""
    path = Path(path)
    want = own_outputs(path.parent).get(path.name)
    return want is not None and path.is_file() and file_sha256(path) == want


def record_outputs(folder, files) -> None:
    """Add the files the demo wrote in ``folder`` to its record."""
    folder = Path(folder)
    own = own_outputs(folder)
    for path in map(Path, files):
        if path.is_file() and path.parent.resolve() == folder.resolve():
            own[path.name] = file_sha256(path)
    atomic_write_json(folder / OWN_OUTPUTS, {"format": _OWN_FORMAT, "version": 1,
                                             "files": own})


def check_outputs(args) -> None:
    """The demo's folder and the files it writes there, checked (and the
    folder locked) before the drive: a file there that an earlier demo did
    not write, or that changed since, is replaced only with --force."""
    out = check_output_folder(args.out)
    lock_output(out)
    files = ["plan.png"] + (["camera.png"] if args.expert else []) \
        + (["meshcat.html"] if args.meshcat or not args.expert else [])
    for name in files:
        check_output(out / name, "image" if name.endswith(".png") else "html", force=args.force,
                     replace=is_own_output(out / name))


def cmd_demo(args) -> int:
    import math

    if args.noise is not None and not (math.isfinite(args.noise) and args.noise >= 0):
        raise TopodrakeError(f"--noise must be finite and >= 0, got {args.noise}")
    if args.seed < 0:
        raise TopodrakeError(f"--seed must be >= 0, got {args.seed}")
    if args.expert and (args.boxes or args.people):
        raise TopodrakeError("--boxes and --people change the house of the learned demo, "
                             "not --expert's")
    check_outputs(args)
    if not args.expert and args.map and (args.controller or args.reach):
        raise TopodrakeError("--controller and --reach go without --map (a map is followed "
                             "by the controller it was built for)")
    map_path = None if args.expert else demo_map(args)
    world = source_world(map_path or args.world)       # its places, checked before the drive
    world.place_pose(args.start_place, "--start-place")
    world.place_pose(args.goal_place, "--goal-place")
    if not args.json:
        where = f" on {map_path}" if map_path else ""
        print(f"topodrake demo: {'the A* expert' if args.expert else 'the learned follower'} "
              f"drives {args.world} from place {args.start_place} to place {args.goal_place}"
              f"{where}", flush=True)
    if args.expert:
        noise = 0.33 if args.noise is None else args.noise
        result = run_demo(args.world, args.start_place, args.goal_place, args.out, args.seed,
                          noise, args.meshcat)
    else:
        check_controller(args.controller, args.reach)       # present, and not damaged
        extra = {"controller": args.controller} if args.controller else {}
        result = run_learned_demo(args.world, args.start_place, args.goal_place, args.out,
                                  args.seed, args.noise or 0.0, map_path=map_path,
                                  reach=args.reach, odometry=args.odometry,
                                  changes=WorldChanges(boxes=args.boxes, people=args.people),
                                  **extra)
    record_outputs(args.out, result["files"].values())
    if args.json:
        print(json.dumps(result["summary"]))
        return exit_status(result["summary"]["outcome"])
    for what, path in result["files"].items():
        print(f"wrote {what}: {path}")
    print(json.dumps(result["summary"]))
    s = result["summary"]
    if not args.expert:
        print(f"outcome {s['outcome']} in {s['time_s']} s over {s['distance_m']} m, "
              f"{s['distance_to_goal_m']} m from the goal (plan of {s['anchors']} anchors, "
              f"probability {s['probability']}"
              + (f", calibrated chance of success {s['success_probability']}"
                 if "success_probability" in s else "")
              + ")" + (f" with {s['changes']}" if s.get("changes", "none") != "none" else "")
              + f"; real-time factor {s['realtime_factor']} "
              f"after start-up, {s['realtime_factor_cold']} with it; demo took {s['demo_wall_s']} s")
    return exit_status(s["outcome"])


def demo_map(args):
    """The map the learned demo plans on: ``--map``; none with ``--controller``
    or ``--reach`` or ``--world`` (one expert drive's anchors); else the
    shipped demo map."""
    if args.map:
        return args.map
    if args.controller or args.reach or args.world != DEMO_WORLD:
        return None
    return str(resolve_checkpoint(DEMO_MAP))


def add_demo_parser(sub) -> None:
    demo = sub.add_parser("demo", help="the learned follower drives a plan between two "
                                       "places in the Drake diagram (--expert: the expert drives)",
                          epilog=EXIT_HELP)
    demo.add_argument("--world", default=DEMO_WORLD,
                      help="catalogue name or map YAML/JSON; another world than test-0 follows "
                           "one expert drive (default: test-0)")
    demo.add_argument("--map", help="plan on this map file (.tdmap; its world replaces --world) "
                                    f"(default: the shipped {DEMO_MAP} of test-0, followed by the "
                                    "controller it was built for; with --controller or --reach: "
                                    "none, the anchors of one expert drive)")
    demo.add_argument("--start-place", type=at.count0, default=3, metavar="N",
                      help="index of the start place ('topodrake world info WORLD' lists them) "
                           "(default: 3)")
    demo.add_argument("--goal-place", type=at.count0, default=6, metavar="N",
                      help="index of the goal place (default: 6)")
    demo.add_argument("--seed", type=int, default=0, help="seed of the actuation noise (default: 0)")
    demo.add_argument("--noise", type=float, default=None,
                      help="actuation noise std, 0 = off (default: 0; with --expert 0.33)")
    demo.add_argument("--odometry", choices=ODOMETRY_MODELS, default="wheel",
                      help="what the learned follower's odometry reads: wheel odometry that "
                           "drifts (errors drawn from --seed) or the true pose (default: wheel)")
    demo.add_argument("--boxes", type=at.count0, default=0, metavar="N",
                      help="unmapped boxes (0.3-0.6 m) on the learned follower's route, placed "
                           "from --seed (default: 0)")
    demo.add_argument("--people", type=at.count0, default=0, metavar="N",
                      help="people walking along and across the learned follower's route, "
                           "placed from --seed; the recording shows them (default: 0)")
    demo.add_argument("--expert", action="store_true",
                      help="drive the A* expert instead of the learned follower (default: off)")
    demo.add_argument("--meshcat", action="store_true",
                      help="with --expert, also save a Meshcat HTML recording; the learned demo "
                           "always saves one (default: off)")
    demo.add_argument("--controller", help="C_WP checkpoint, or 'registration' for the lidar "
                                           "teach-and-repeat C_WP, following one expert drive "
                                           f"without a map (default there: {DEMO_CONTROLLER}, "
                                           "the best shipped one with its own RE)")
    demo.add_argument("--reach", help="RE checkpoint trained for --controller (default: the "
                                      "controller's shipped RE)")
    demo.add_argument("--out", default="out/demo",
                      help=f"output folder (default: out/demo); the demo's own earlier outputs "
                           f"there (the files listed in its {OWN_OUTPUTS}, unchanged since) are "
                           f"replaced, any other file only with --force")
    demo.add_argument("--json", action="store_true",
                      help="print only the summary as one JSON object (default: off)")

    add_force_option(demo)
    demo.set_defaults(func=cmd_demo)
