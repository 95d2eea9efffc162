"""Drive a route in the Drake navigation diagram, and draw the drive.

:func:`chain_route` makes a route of one demonstration (RE sparsification,
the hops' probabilities); :func:`drive_route` follows a route in the Drake
diagram (``topodrake.systems.navigation``), optionally recording Meshcat;
:func:`plot_drive` draws the floor plan, the map, the plan and the driven
path coloured by the follower's mode. ``topodrake navigate`` and
``topodrake demo`` are built from these.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from topodrake.contract.route import Route, route_from_observations
from topodrake.navigation.follower import MODES
from topodrake.world.plot import legend_below, plot_world, save_figure

#: the driven path by follower mode, in colours the map (blues) and the plan (purple) do not use
MODE_COLORS = {"search": "tab:olive", "follow": "tab:green", "dead_reckoning": "tab:orange",
               "reached": "tab:cyan", "failed": "tab:brown"}


def chain_route(world, poses: np.ndarray, policy, reach, p: float = 0.99) -> Route:
    """One trajectory's route: anchors kept while RE > ``p``, each anchor's
    context for both networks, each hop's RE (anchor calibration) and
    their product as the route's probability."""
    obs = reach.observe(world, poses)
    feats = reach.frame_features(obs)
    anchors = reach.sparsify(obs, p=p, feats=feats)
    wide = policy if policy.k >= reach.k else reach
    route = route_from_observations(obs, poses, anchors, wide.k, wide.frame_step, reach.observation)
    if len(anchors) > 1:
        hops = reach.pairwise(feats, anchors[:-1], reach.context_rows(len(poses), anchors[1:]))
        route.edge_probability = hops
        route.probability = float(np.prod(hops))
    return route


def make_recorder():
    """A headless Meshcat that records. Its server's "listening" line is not
    logged: nobody connects, the recording is saved as an HTML file."""
    import logging

    from pydrake.geometry import Meshcat

    log = logging.getLogger("drake")
    level = log.level
    log.setLevel(logging.WARNING)
    try:
        viewer = Meshcat()
    finally:
        log.setLevel(level)
    viewer.StartRecording(frames_per_second=10.0, set_visualizations_while_recording=False)
    return viewer


def drive_route(scenario, route: Route, start, *, world=None, policy=None, reach=None,
                record: bool = False, seed: int = 0, replanner=None,
                goal_watch_m: float | None = None, record_sensors: bool = False):
    """Follow ``route`` from ``start`` in the Drake navigation diagram
    (replanning while dead reckoning with ``replanner``, a
    :class:`~topodrake.navigation.replan.Replanner` over ``[route]``; ending
    within ``goal_watch_m`` of the goal as the planning study's trials do);
    returns the :class:`~topodrake.systems.navigation.NavigationRunResult`
    with ``build_s`` (diagram construction, including the route's features)
    and ``recording`` (with ``record``, the drive as Meshcat HTML; else None)
    and ``frames`` (with ``record_sensors``, each period's sensor readings,
    :meth:`~topodrake.systems.recorder.DriveRecorder.frames`; else None)."""
    from topodrake.systems.navigation import NavigationRunner, make_navigation_diagram

    viewer = make_recorder() if record else None
    t0 = time.perf_counter()
    built = make_navigation_diagram(scenario, route, viewer, world=world, policy=policy,
                                    reach=reach, replanner=replanner,
                                    record_sensors=record_sensors)
    runner = NavigationRunner(built)
    build_s = time.perf_counter() - t0
    result = runner.run(start, seed=seed, goal_watch_m=goal_watch_m)
    result.build_s = build_s
    result.recording = None
    result.frames = built.recorder.frames() if built.recorder is not None else None
    if viewer is not None:
        viewer.StopRecording()
        viewer.PublishRecording()
        result.recording = viewer.StaticHtml()
    return result


def plot_drive(world, route: Route, result, out, *, start=None, goal=None, map_layers=None,
               title: str = "") -> Path:
    """The floor plan, the map (``map_layers``: vertex poses, edges, edge
    probabilities), the route's anchors and the driven path coloured by mode."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D


    fig, ax = plt.subplots(figsize=(10, 9))
    if map_layers is not None:
        from topodrake.topomap.plot import draw_map

        draw_map(ax, world, *map_layers)
    else:
        plot_world(world, ax)
    a = np.asarray(route.poses)
    if start is not None:          # the start's link to the first anchor
        a = np.vstack([np.asarray(start)[None, :3], a])
    ax.plot(a[:, 0], a[:, 1], "-o", color="tab:purple", lw=1.2, ms=4, zorder=5, alpha=0.8)
    poses = np.asarray(result.poses)
    modes = np.asarray(result.modes)
    for k in range(min(len(modes), len(poses) - 1)):
        name = MODES[int(modes[k])] if 0 <= modes[k] < len(MODES) else "failed"
        ax.plot(poses[k:k + 2, 0], poses[k:k + 2, 1], color=MODE_COLORS[name], lw=2.2, zorder=6)
    if start is not None:
        ax.plot(*np.asarray(start)[:2], "s", color="white", mec="k", ms=9, zorder=7)
    goal = route.goal_pose if goal is None else np.asarray(goal)
    ax.plot(*goal[:2], "*", color="tab:red", mec="k", ms=15, zorder=7)
    handles = [Line2D([], [], color="tab:purple", marker="o", lw=1.2,
                      label="plan: start, anchors, goal")]
    handles += [Line2D([], [], color=MODE_COLORS[m], lw=2.2, label=f"driven: {m.replace('_', ' ')}")
                for m in ("search", "follow", "dead_reckoning")]
    handles += [Line2D([], [], color="white", mec="k", marker="s", lw=0, label="start"),
                Line2D([], [], color="tab:red", mec="k", marker="*", ms=12, lw=0, label="goal")]
    if map_layers is not None:
        handles.append(Line2D([], [], color="navy", marker="o", ms=3.5, lw=0, label="map vertex"))
    legend_below(ax, handles)
    ax.set_title(title or f"{result.outcome} in {result.time_s:.1f} s")
    save_figure(fig, out)
    return Path(out)
