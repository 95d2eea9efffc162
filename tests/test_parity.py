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
