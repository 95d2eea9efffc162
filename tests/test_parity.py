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
    import topodrake.expert as expert
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
