"""Monte Carlo trial functions over Drake diagrams, for ``topodrake.montecarlo``.

A trial takes a seed and keyword settings and returns a small dict. Each
worker process builds its diagram once (cached per settings) and reuses it
across its trials, resetting only the context.
"""

from __future__ import annotations

from functools import lru_cache

from topodrake.systems.scenario import Scenario

from topodrake.learning.reachability.labels import ReachLabelConfig, draw_pairs, time_limits
from topodrake.learning.samples import collect_trajectories
from topodrake.learning.waypoint.evaluation import sample_controller_pair
from topodrake.navigation.outcomes import drive_outcome
from topodrake.sensing.overlap import mutual_overlap
from topodrake.world import load_world


@lru_cache(maxsize=8)
def _runner(world: str, noise_std: float, camera: bool):
    from topodrake.systems.diagram import build_expert_diagram
    from topodrake.systems.run import ExpertRunner

    return ExpertRunner(build_expert_diagram(
        Scenario(world=world, noise_std=noise_std, camera_enabled=camera)))


def expert_trial(seed: int, world: str = "test-0", start_place: int = 0, goal_place: int = 1,
                 noise_std: float = 0.33, camera: bool = False, t_max_s: float = 150.0) -> dict:
    """One expert drive between two places of ``world``; returns its summary
    (without the wall and start-up times, so results compare across machines)."""
    runner = _runner(world, float(noise_std), bool(camera))
    w = runner.built.world
    start = w.place_pose(start_place, "start_place")
    goal = w.place_pose(goal_place, "goal_place")
    result = runner.run(start=start, goal=goal[:2],
                        seed=seed, t_max_s=t_max_s)
    summary = result.summary()
    summary.pop("wall_time_s")
    summary.pop("startup_s")
    # the CLI's vocabulary: reached, false_reached, collision, timeout
    summary["outcome"] = drive_outcome(summary["outcome"], summary["distance_to_goal_m"])
    summary["seed"] = seed
    return summary


@lru_cache(maxsize=2)
def _evaluation_set(data_dir: str, worlds: tuple[str, ...]):
    """The test houses' expert trajectories (collected into ``data_dir`` once)
    and the loaded worlds."""
    from pathlib import Path


    trajs = collect_trajectories(list(worlds), Path(data_dir) / "demos" / "pairs-s0",
                                 progress=False)
    return trajs, {w: load_world(w) for w in worlds}


@lru_cache(maxsize=4)
def _policy(checkpoint: str):
    import torch

    from topodrake.learning.waypoint.policy import AStarOracle, LearnedWaypointPolicy

    torch.set_num_threads(1)        # one trial per core
    if checkpoint == "oracle":
        return AStarOracle
    if checkpoint == "registration":           # the registration C_WP: no checkpoint
        from topodrake.registration.policy import RegistrationPolicy

        return RegistrationPolicy()
    return LearnedWaypointPolicy.from_checkpoint(checkpoint)


@lru_cache(maxsize=8)
def _target_runner(checkpoint: str, data_dir: str, worlds: tuple[str, ...], world: str,
                   noise_std: float, overlap_lost: float | None = None):
    from topodrake.systems.run import TargetRunner
    from topodrake.systems.waypoint_net import build_waypoint_diagram

    from topodrake.learning.waypoint.policy import AStarOracle

    w = _evaluation_set(data_dir, worlds)[1][world]
    policy = _policy(checkpoint)
    if policy is AStarOracle:
        policy = AStarOracle(w)
    scenario = Scenario(world=w.name, noise_std=noise_std,
                        camera_enabled=policy.observation == "camera")
    if policy.observation == "camera":
        scenario.camera = policy.sensor
    elif policy.observation == "lidar":
        scenario.lidar = policy.sensor
    return TargetRunner(build_waypoint_diagram(scenario, policy, world=w),
                        overlap_lost=overlap_lost)


def controller_trial(seed: int, checkpoint: str = "oracle", noise_std: float = 0.0,
                     data_dir: str = "data",
                     worlds: tuple[str, ...] = ("test-0", "test-1", "test-2", "test-3", "test-4")
                     ) -> dict:
    """One run of the controller-success protocol
    (:mod:`topodrake.learning.waypoint.evaluation`): C_WP of ``checkpoint`` (or the A*
    ``"oracle"``) + RMP drives from the source of the seed's pair toward its
    target in the Drake diagram. The pair depends on the seed only."""
    from topodrake.learning.waypoint.policy import make_target_context

    trajs, loaded = _evaluation_set(str(data_dir), tuple(worlds))
    pair = sample_controller_pair(trajs, seed, loaded)
    runner = _target_runner(str(checkpoint), str(data_dir), tuple(worlds), pair.world,
                            float(noise_std))
    policy = runner.built.waypoint_net.policy
    poses = trajs.poses[trajs.rows(pair.trajectory)]
    target = make_target_context(loaded[pair.world], poses, pair.target, policy.k,
                                 frame_step=policy.frame_step, modality=policy.observation,
                                 camera=runner.built.scenario.camera,
                                 lidar=runner.built.scenario.lidar, key=seed % (2 ** 31))
    result = runner.run(poses[pair.source], poses[pair.target], target, seed=seed,
                        t_max_s=pair.t_max_s)
    out = result.summary()
    out.pop("wall_time_s")
    out.pop("startup_s")
    out.update(seed=seed, pair=pair.summary())
    return out


@lru_cache(maxsize=4)
def _reachability(reach: str, controller: str):
    from topodrake.learning.reachability.estimator import Reachability

    return Reachability.from_checkpoint(reach, controller)


def reach_trial(seed: int, reach: str = "", controller: str = "", noise_std: float = 0.33,
                data_dir: str = "data",
                worlds: tuple[str, ...] = ("test-0", "test-1", "test-2", "test-3", "test-4")) -> dict:
    """One calibration trial of an RE: a fresh (jittered source, target) pair
    drawn from the seed as for the RE labels, RE's predicted probability, and
    the outcome of the C_WP ``controller`` driving it in the Drake diagram."""
    import numpy as np

    from topodrake.learning.waypoint.policy import make_target_context

    cfg = ReachLabelConfig()
    trajs, loaded = _evaluation_set(str(data_dir), tuple(worlds))
    rng = np.random.default_rng(seed)
    w = int(rng.integers(len(trajs.worlds)))
    world = loaded[trajs.worlds[w]]
    pair = {k: v[0] for k, v in draw_pairs(world, trajs, np.flatnonzero(trajs.traj_world == w), 1,
                                          rng, cfg).items()}
    poses = trajs.poses[trajs.rows(int(pair["traj"]))]
    tgt_pose = poses[int(pair["tgt"])]
    t_max = float(time_limits(world, pair["src_pose"][None], tgt_pose[None, :2], cfg)[0])
    re = _reachability(str(reach), str(controller))
    sensor = {"camera" if re.observation == "camera" else "lidar": re.sensor}
    src_obs = make_target_context(world, pair["src_pose"][None], 0, 0, modality=re.observation,
                                  **sensor).observations
    ctx = make_target_context(world, poses, int(pair["tgt"]), re.k, frame_step=re.frame_step,
                              modality=re.observation, **sensor)
    p = float(re.probability(src_obs, re.encode_target(ctx.observations[None]))[0])
    runner = _target_runner(str(controller), str(data_dir), tuple(worlds), world.name,
                            float(noise_std), cfg.overlap_lost)
    policy = runner.built.waypoint_net.policy
    target = make_target_context(world, poses, int(pair["tgt"]), policy.k,
                                 frame_step=policy.frame_step, modality=policy.observation,
                                 camera=runner.built.scenario.camera,
                                 lidar=runner.built.scenario.lidar, key=seed % (2 ** 31))
    result = runner.run(pair["src_pose"], tgt_pose, target, seed=seed, t_max_s=t_max)
    start_overlap = mutual_overlap(world, pair["src_pose"][None], tgt_pose[None])[0]
    return {"seed": seed, "world": world.name, "p": p, "success": bool(result.success),
            "start_overlap": [round(float(v), 4) for v in start_overlap],
            "outcome": result.outcome, "same_trajectory": bool(pair["same"]), "t_max_s": t_max,
            "time_s": round(result.time_s, 2)}
