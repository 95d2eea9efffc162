"""Plan on the shipped map and drive the plan in the Drake navigation diagram.

    python docs/tutorials/diagram.py            # about 20 s on 2 CPU cores

Prints one JSON object: the plan (anchors, probability) and the first
seconds of the drive (outcome so far, distance driven, periods in each
follower mode).
"""

import json
import time

import numpy as np

from topodrake.learning.reachability.controllers import controller_policy
from topodrake.odometry import odometry_model
from topodrake.systems.navigation import (NavigationRunner, NavigationScenario,
                                          make_navigation_diagram)
from topodrake.topomap.plan import plan_path
from topodrake.topomap.sources import drive_observations, open_map, view_scans

SECONDS = 8.0      # simulated time; the whole drive takes about 90 s

# 1. The map file, with the RE and C_WP it was built for (refused with any other).
loaded = open_map("checkpoints/demo_map/map.tdmap")
world, topomap = loaded.world, loaded.topomap
policy, reach = controller_policy(loaded.controller), loaded.scorer.reach

# 2. Plan from place 3 to place 6: both ends are views, rendered at the places' poses.
start, goal = world.places[3], world.places[6]
poses = np.stack([start, goal])
views = drive_observations(world, loaded.scorer, poses)
plan = plan_path(topomap, views[0], views[1], start_pose=start, goal_pose=goal,
                 view_scans=view_scans(world, topomap, poses))
assert plan.reachable, plan.reason

# 3. The diagram: CarPlant, sensors, FollowerFsm, WaypointNet, RMP, actuation noise and
#    wheel odometry that drifts; a Drake Simulator runs it from the start pose.
scenario = NavigationScenario(world=world.name, controller=str(loaded.controller),
                              reach=str(loaded.reach), noise_std=0.33,
                              odometry=odometry_model("wheel"))
built = make_navigation_diagram(scenario, plan.route, world=world, policy=policy, reach=reach)
wall = time.perf_counter()
result = NavigationRunner(built).run(start, seed=0, t_max_s=SECONDS)
wall = time.perf_counter() - wall

print(json.dumps({
    "diagram": built.diagram.get_name(),
    "systems": sorted(s.get_name() for s in built.diagram.GetSystems()),
    "anchors": len(plan.route),
    "plan_probability": round(plan.probability, 4),
    "simulated_s": round(result.time_s, 2),
    "outcome": result.outcome,           # "timeout": it drove for SECONDS and was stopped
    "distance_m": round(result.distance_m, 2),
    # periods in each follower mode (0 Search, 1 Follow, 2 Dead reckoning)
    "mode_periods": {str(m): int(n) for m, n in zip(*np.unique(result.modes, return_counts=True))},
    "wall_s": round(wall, 2),
}))
