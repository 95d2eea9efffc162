"""The Drake diagram and the batched engine drive the same path."""

import numpy as np
import pytest

from topodrake.rollout import ExpertRollout, RolloutConfig
from topodrake.systems.diagram import build_expert_diagram
from topodrake.systems.run import ExpertRunner
from topodrake.systems.scenario import Scenario


@pytest.mark.parametrize("noise_std", [0.0, 0.33])
def test_drake_and_batched_paths_agree(box_world, noise_std):
    start, goal = [1.0, 1.5, 0.3], [8.0, 2.0]
    sc = Scenario(world="box", start=start, goal=goal, noise_std=noise_std, seed=11,
                  t_max_s=20.0, camera_enabled=False)
    drake = ExpertRunner(build_expert_diagram(sc, world=box_world)).run()
    batched = ExpertRollout(box_world, RolloutConfig(noise_std=noise_std, t_max_s=20.0)).run(
        np.array([start]), np.array([goal]), noise=drake.noise[None])
    k = min(len(drake.poses), int(batched.steps[0]) + 1)
    assert k > 150        # the comparison covers most of the 20 s
    dev = np.linalg.norm(drake.poses[:k, :2] - batched.poses[0, :k, :2], axis=1)
    assert dev.max() <= 0.01
    # The car really drove: it went around the partition toward the goal.
    assert np.linalg.norm(drake.poses[-1, :2] - drake.poses[0, :2]) > 2.0


def test_parallel_batch_matches_serial_batch(box_world, monkeypatch):
    """Batches of >= 8 cars take the parallel expert and RMP kernels; they
    must drive exactly the paths the serial kernels drive."""
    import topodrake.expert.kernel as expert
    import topodrake.rmp as rmp

    rng = np.random.default_rng(3)
    starts = np.array([box_world.sample_free_pose(rng) for _ in range(12)])
    goals = np.array([box_world.sample_free_pose(rng)[:2] for _ in range(12)])
    cfg = RolloutConfig(noise_std=0.33, t_max_s=8.0)
    parallel = ExpertRollout(box_world, cfg).run(starts, goals, seeds=range(12))
    monkeypatch.setattr(expert, "SERIAL_BELOW", 10 ** 9)
    monkeypatch.setattr(rmp, "SERIAL_BELOW", 10 ** 9)
    serial = ExpertRollout(box_world, cfg).run(starts, goals, seeds=range(12))
    assert parallel.steps.sum() > 12 * 40          # the cars really drove
    np.testing.assert_array_equal(parallel.poses, serial.poses)
    np.testing.assert_array_equal(parallel.outcome, serial.outcome)


def _policy_parity(box_world, policy, target_poses, noise_std, t_max):
    from topodrake.learning.waypoint.policy import make_target_context
    from topodrake.rollout import PolicyRollout
    from topodrake.systems.run import TargetRunner
    from topodrake.systems.waypoint_net import build_waypoint_diagram

    start = np.array([1.0, 1.5, 0.3])
    sc = Scenario(world="box", noise_std=noise_std, camera_enabled=policy.observation == "camera")
    target = make_target_context(box_world, target_poses, len(target_poses) // 2, policy.k,
                                 frame_step=1, modality=policy.observation, key=1)
    goal = target_poses[len(target_poses) // 2]
    drake = TargetRunner(build_waypoint_diagram(sc, policy, world=box_world)).run(
        start, goal, target, seed=4, t_max_s=t_max)
    from topodrake.contract.waypoint import target_input
    feats = policy.encode_target(target_input(policy, target))
    noise = np.zeros((1, int(round(t_max / 0.1)), 2))
    noise[0, :len(drake.noise)] = drake.noise
    batched = PolicyRollout(box_world, policy, RolloutConfig(noise_std=noise_std)).run(
        start[None], goal[None], feats, t_max_s=t_max, noise=noise)
    k = int(batched.steps[0])
    assert k == round(drake.time_s / 0.1)         # same number of control periods
    # (the Drake log may repeat its final pose: it logs at the stop and the run appends it)
    dev = np.linalg.norm(drake.poses[:k + 1, :2] - batched.poses[0, :k + 1, :2], axis=1)
    assert dev.max() <= 0.01
    assert batched.outcome[0] == {"success": 0, "collision": 1, "timeout": 2}[drake.outcome]
    return drake, batched


def test_oracle_policy_drake_and_batched_agree(box_world, noise_std=0.33):
    from topodrake.learning.waypoint.policy import AStarOracle

    # target around the partition: the oracle must drive there
    tposes = np.array([[7.6, 7.5, -1.2], [7.7, 7.3, -1.3], [7.8, 7.1, -1.4]])
    drake, batched = _policy_parity(box_world, AStarOracle(box_world, k=1, frame_step=1),
                                    tposes, noise_std, 30.0)
    assert drake.success and batched.success[0]
    assert len(drake.poses) > 60                  # a real drive, not an immediate success


def test_learned_camera_policy_drake_and_batched_agree(box_world):
    """An untrained camera network drives somewhere; both executors drive it
    the same way (images, cached features, waypoint, RMP, noise)."""
    import torch

    from topodrake.learning.networks import NetworkConfig, WaypointNetwork
    from topodrake.learning.waypoint.policy import LearnedWaypointPolicy
    from topodrake.sensing.config import CameraConfig

    torch.manual_seed(0)
    net = WaypointNetwork(NetworkConfig(k=1, channels=[8, 8, 16], feature_dim=16,
                                        combine_channels=16, hidden=16), 64)
    policy = LearnedWaypointPolicy(net, CameraConfig())
    tposes = np.array([[3.0, 2.0, 0.0], [3.2, 2.0, 0.0], [3.4, 2.0, 0.0]])
    drake, batched = _policy_parity(box_world, policy, tposes, 0.33, 6.0)
    assert np.linalg.norm(drake.poses[-1, :2] - drake.poses[0, :2]) > 0.05   # it moved
