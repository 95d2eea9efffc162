"""The expert's final approach: Reeds-Shepp paths to a goal pose, on the grid."""

import math

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.expert.approach import ApproachConfig, plan_pose_path, pose_reached, wrap
from topodrake.rollout import SUCCESS, ExpertRollout, RolloutConfig
from topodrake.world.walls import WallSet
from topodrake.world.world import world_from_walls


def _box_world(width=6.0, height=3.0, inner=None):
    """A rectangular room, optionally with an inner wall segment."""
    segs = [[0, 0, width, 0], [width, 0, width, height], [width, height, 0, height],
            [0, height, 0, 0]]
    if inner is not None:
        segs.append(inner)
    n = len(segs)
    return world_from_walls("box", WallSet(np.array(segs, np.float64), np.full(n, 0.1),
                                           np.zeros(n, np.int32)))


def _valid(world, path, margin=0.0):
    return np.all(world.grid.clearance_at(path[:, :2]) > world.grid.car_radius - margin)


def test_u_turn_path_reverses_and_ends_at_the_pose():
    world = _box_world()
    start, goal = np.array([2.0, 1.5, 0.0]), np.array([2.2, 1.5, math.pi])
    path = plan_pose_path(world.grid, start, goal)
    assert path is not None
    assert np.allclose(path[0, :3], start, atol=1e-6)
    assert np.hypot(*(path[-1, :2] - goal[:2])) < 1e-3 and abs(wrap(path[-1, 2] - goal[2])) < 1e-3
    assert (path[:, 3] < 0).any() or np.ptp(path[:, 1]) > 0.8   # a reversal, or a loop
    assert _valid(world, path)


def test_planner_goes_around_a_wall_the_direct_curve_crosses():
    world = _box_world(inner=[3.0, 0.0, 3.0, 2.0])
    start, goal = np.array([1.5, 1.0, 0.0]), np.array([4.5, 1.0, 0.0])
    path = plan_pose_path(world.grid, start, goal, seed=3)
    assert path is not None and _valid(world, path, margin=0.01)
    assert path[:, 1].max() > 2.1            # it passes above the wall's end
    again = plan_pose_path(world.grid, start, goal, seed=3)
    assert np.array_equal(path, again)       # seeded


def test_expert_reaches_goal_poses_behind_it():
    world = _box_world()
    starts = np.array([[1.5, 1.5, 0.0], [4.0, 1.0, math.pi / 2]])
    goals = np.array([[2.0, 1.5, math.pi], [3.0, 2.0, -math.pi / 2]])
    res = ExpertRollout(world, RolloutConfig(t_max_s=60.0)).run(starts, goals)
    assert (res.outcome == SUCCESS).all()
    final = res.poses[np.arange(2), res.steps]
    assert pose_reached(final, goals, 0.27, 15.0).all()


def test_position_goals_keep_the_plain_expert():
    world = _box_world()
    res = ExpertRollout(world, RolloutConfig(t_max_s=60.0)).run(
        np.array([[1.0, 1.5, 0.0]]), np.array([[5.0, 1.5]]))
    assert res.outcome[0] == SUCCESS
    assert abs(res.poses[0, res.steps[0], 2]) < 0.5      # arrived head-on, no turn


def test_bad_approach_config_is_refused():
    with pytest.raises(TopodrakeError, match="heading_tol_deg"):
        ApproachConfig(heading_tol_deg=0).check()
