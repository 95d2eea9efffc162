"""Our 2.5-D depth against Drake's RenderEngineVtk in a test house."""

import numpy as np

from topodrake.experiments.vtk_parity import depth_errors, parity_summary
from topodrake.world import load_world


def test_depth_matches_vtk_in_a_test_house():
    world = load_world("test-2")
    poses = world.sample_free_pose(np.random.default_rng(5), 60)
    errors = depth_errors(world, poses)
    s = parity_summary(errors)
    assert s["pixels"] > 0.8 * 60 * 64 * 64     # nearly every pixel sees a surface in both
    assert s["depth_parity_median_m"] < 0.02
    assert s["depth_parity_p99_m"] < 0.10
