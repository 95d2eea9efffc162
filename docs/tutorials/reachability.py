"""RE's probability against the controller's empirical success, pair by pair.

    python docs/tutorials/reachability.py       # about 30 s on 2 CPU cores

One expert drive from place 4 to place 9 of ``test-0``; sources and targets
are frames of it, from half a metre to several metres apart. For each pair
the learned RE (lidar, k = 5) says how likely its C_WP, driving the RMP
under actuation noise, gets from the source to the target; then that C_WP
drives each pair in the Drake diagram under 4 noise seeds, with the RE
labels' time limit and success rule. Prints one JSON object: per pair the
distance, RE's probability and the share of runs that arrived, and the
Brier score over all runs.
"""

import json

import numpy as np

from topodrake.learning.reachability.estimator import Reachability
from topodrake.learning.reachability.labels import ReachLabelConfig, time_limits
from topodrake.learning.waypoint.policy import LearnedWaypointPolicy, make_target_context
from topodrake.rollout import ExpertRollout
from topodrake.systems.run import TargetRunner
from topodrake.systems.scenario import Scenario
from topodrake.systems.waypoint_net import build_waypoint_diagram
from topodrake.world import load_world

CONTROLLER = "checkpoints/lidar_k5/checkpoint.pt"
REACH = "checkpoints/reach_lidar_k5/checkpoint.pt"
SEEDS = range(4)
GAPS = (10, 30, 60, 100, 160)       # frames from source to target (10 Hz, up to 0.5 m/s)

world = load_world("test-0")
poses = ExpertRollout(world).run(world.places[[4]], world.places[[9], :2]).trajectory(0)["poses"]
policy = LearnedWaypointPolicy.from_checkpoint(CONTROLLER)
reach = Reachability.from_checkpoint(REACH, CONTROLLER)    # refused for any other C_WP
labels = ReachLabelConfig()
runner = TargetRunner(build_waypoint_diagram(
    Scenario(world=world.name, noise_std=0.33, lidar=policy.sensor), policy, world=world),
    overlap_success=labels.overlap_success, overlap_lost=labels.overlap_lost)

pairs, outcomes, predicted = [], [], []
for n, gap in enumerate(GAPS):
    src, tgt = 20 * n, 20 * n + gap
    # RE: the target's context encoded once, then the source's view
    re_context = make_target_context(world, poses, tgt, reach.k, frame_step=reach.frame_step,
                                     modality=reach.observation, lidar=reach.sensor)
    view = make_target_context(world, poses, src, 0, modality=reach.observation,
                               lidar=reach.sensor).observations
    p = float(reach.probability(view, reach.encode_target(re_context.observations[None]))[0])
    # the C_WP drives it in the diagram, once per noise seed
    target = make_target_context(world, poses, tgt, policy.k, frame_step=policy.frame_step,
                                 modality=policy.observation, lidar=policy.sensor, key=n)
    t_max = float(time_limits(world, poses[[src]], poses[[tgt], :2], labels)[0])
    runs = [runner.run(poses[src], poses[tgt], target, seed=s, t_max_s=t_max).success
            for s in SEEDS]
    pairs.append({"source": src, "target": tgt,
                  "distance_m": round(float(np.hypot(*(poses[tgt, :2] - poses[src, :2]))), 2),
                  "re": round(p, 3), "success": float(np.mean(runs))})
    outcomes += runs
    predicted += [p] * len(runs)

brier = float(np.mean((np.array(predicted) - np.array(outcomes, float)) ** 2))
print(json.dumps({"world": world.name, "reach": REACH, "runs_per_pair": len(SEEDS),
                  "pairs": pairs, "brier": round(brier, 4)}))
