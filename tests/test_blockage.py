"""A passage closed on a route (a door shut): placed across it, wall to wall,
only where another way remains."""

from dataclasses import replace

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.world import Faces, WallSet, path_length, world_from_walls
from topodrake.world.blockage import (
    THICKNESS_M,
    block_faces,
    block_on_path,
    blocked_world,
)

START, GOAL = (1.0, 1.0, 0.0), (9.0, 1.0, 0.0)


def _ring(angle_deg: float = 0.0):
    """A 10 x 6 m room (inner faces 0.2 .. 9.8, 0.2 .. 5.8) around an island
    x in [2, 8], y in [2, 4]: corridors 1.8 m wide all round, so the bottom
    one has the top one as another way; turned by ``angle_deg`` about (5, 3)."""
    boxes = np.array([[0, 0, 10, 0.2], [0, 5.8, 10, 6], [0, 0, 0.2, 6], [9.8, 0, 10, 6],
                      [2, 2, 8, 4]], float)
    walls = WallSet.from_boxes(boxes, np.arange(5))
    return world_from_walls("ring", _turned(walls, angle_deg))


def _turned(walls: WallSet, angle_deg: float) -> WallSet:
    a = np.deg2rad(angle_deg)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    seg = walls.segments.reshape(-1, 2, 2)
    seg = (seg - (5.0, 3.0)) @ rot.T + (5.0, 3.0)
    return WallSet(seg.reshape(-1, 4), walls.thickness, walls.texture)


def _turn_pose(pose, angle_deg: float):
    a = np.deg2rad(angle_deg)
    x, y = pose[0] - 5.0, pose[1] - 3.0
    return (5.0 + np.cos(a) * x - np.sin(a) * y, 3.0 + np.sin(a) * x + np.cos(a) * y, 0.0)


@pytest.fixture(scope="module")
def ring():
    return _ring()


@pytest.fixture(scope="module")
def two_rooms():
    """Two 4.8 x 4.6 m rooms joined by one 0.9 m door in the partition at x = 5."""
    boxes = np.array([[0, 0, 10, 0.2], [0, 4.8, 10, 5], [0, 0, 0.2, 5], [9.8, 0, 10, 5],
                      [4.9, 0, 5.1, 2.0], [4.9, 2.9, 5.1, 5]], float)
    return world_from_walls("two-rooms", WallSet.from_boxes(boxes, np.arange(6)))


def _crosses(path: np.ndarray, a: np.ndarray, b: np.ndarray) -> bool:
    """Whether the polyline ``path`` crosses the segment ``a -> b``."""
    p, q = path[:-1, :2], path[1:, :2]

    def side(o, u, v):
        return np.sign((u[..., 0] - o[..., 0]) * (v[..., 1] - o[..., 1])
                       - (u[..., 1] - o[..., 1]) * (v[..., 0] - o[..., 0]))

    return bool(np.any((side(p, q, a) != side(p, q, b)) & (side(a, b, p) != side(a, b, q))))


def _long_axis(corners: np.ndarray):
    """The block's centre segment (the ends of its long axis) and its sides."""
    long_side, short_side = corners[1] - corners[0], corners[3] - corners[0]
    if np.hypot(*long_side) < np.hypot(*short_side):
        corners = np.roll(corners, -1, axis=0)
        long_side, short_side = short_side, -long_side
    a, b = 0.5 * (corners[0] + corners[3]), 0.5 * (corners[1] + corners[2])
    return a, b, np.hypot(*long_side), np.hypot(*short_side)


def _check_block(world, start, goal, corners, keep_clear_m=1.5, min_width=0.0):
    """Everything block_on_path promises, checked from the outside."""
    path = world.astar(start, goal)
    assert corners.shape == (4, 2)
    a, b, length, thickness = _long_axis(corners)
    assert thickness == pytest.approx(THICKNESS_M)
    assert min_width < length <= 2.0 + 0.1
    assert _crosses(path, a, b)                                 # A* goes through it
    for end in (start, goal):
        assert np.min(np.hypot(*(corners - end[:2]).T)) > keep_clear_m
        assert np.hypot(*(0.5 * (a + b) - end[:2])) > keep_clear_m
    # wall to wall: both ends of the block lie in walls of the world as it was
    assert world.grid.occupied[tuple(world.grid.to_cell(a))]
    assert world.grid.occupied[tuple(world.grid.to_cell(b))]
    blocked = blocked_world(world, corners)
    detour = blocked.astar(start, goal)                         # another way remains
    assert not _crosses(detour, a, b)
    assert path_length(detour) >= path_length(path) + 1.0
    assert not np.all(blocked.grid.is_free(path))               # the old route is shut
    assert np.all(world.grid.is_free(path))


def test_block_shuts_the_bottom_corridor_and_leaves_the_top_one(ring):
    path = ring.astar(START, GOAL)
    corners = block_on_path(ring, path, np.random.default_rng(0))
    _check_block(ring, START, GOAL, corners, min_width=1.8)
    a, b, _, _ = _long_axis(corners)
    assert abs(a[0] - b[0]) < 1e-6                              # across the corridor
    assert sorted([a[1], b[1]]) == pytest.approx([0.15, 2.05], abs=0.06)   # into the walls


def test_block_on_a_turned_passage_is_turned_with_it():
    world = _ring(30.0)
    start, goal = _turn_pose(START, 30.0), _turn_pose(GOAL, 30.0)
    corners = block_on_path(world, world.astar(start, goal), np.random.default_rng(1))
    _check_block(world, start, goal, corners, min_width=1.8)
    a, b, _, _ = _long_axis(corners)
    along = np.array([np.cos(np.deg2rad(30.0)), np.sin(np.deg2rad(30.0))])
    assert abs((b - a) @ along) < 0.15                          # across the corridor (a few degrees)


def test_block_is_seeded_and_drawn_among_places(ring):
    path = ring.astar(START, GOAL)
    first = block_on_path(ring, path, np.random.default_rng(7))
    assert np.array_equal(first, block_on_path(ring, path, np.random.default_rng(7)))
    centres = {tuple(np.round(block_on_path(ring, path, np.random.default_rng(s)).mean(axis=0), 2))
               for s in range(8)}
    assert len(centres) > 1


def test_a_door_with_no_other_way_is_not_shut(two_rooms):
    start, goal = (2.5, 2.5, 0.0), (7.5, 2.5, 0.0)
    path = two_rooms.astar(start, goal)
    with pytest.raises(TopodrakeError, match="no passage on the route can be closed with "
                                             "another way left.*cuts the start off the goal"):
        block_on_path(two_rooms, path, np.random.default_rng(0))


def test_no_narrow_place_far_enough_from_the_ends(ring):
    path = ring.astar(START, GOAL)
    with pytest.raises(TopodrakeError, match="another way left.*no place at most 1.0 m wide"):
        block_on_path(ring, path, np.random.default_rng(0), max_width_m=1.0)
    with pytest.raises(TopodrakeError, match="another way left.*farther than 5.0 m"):
        block_on_path(ring, path, np.random.default_rng(0), keep_clear_m=5.0)


@pytest.mark.parametrize("path", [np.zeros((1, 2)), np.zeros(4), np.zeros((3, 1)),
                                  np.array([[1.0, 1.0], [np.nan, 1.0], [9.0, 1.0]])])
def test_bad_paths_are_refused(ring, path):
    with pytest.raises(TopodrakeError, match="a path to block"):
        block_on_path(ring, path, np.random.default_rng(0))


def test_a_path_starting_in_a_wall_is_refused(ring):
    with pytest.raises(TopodrakeError, match="the path's start .* in collision"):
        block_on_path(ring, np.array([[0.1, 1.0], [9.0, 1.0]]), np.random.default_rng(0))


def test_block_faces_and_blocked_world(ring):
    corners = np.array([[4.5, 2.05], [4.5, 0.15], [4.6, 0.15], [4.6, 2.05]])   # counter-clockwise
    faces = block_faces(corners)
    assert faces.shape == (4, 4)
    assert np.allclose(faces[:, 2:], np.roll(faces[:, :2], -1, axis=0))         # a closed loop
    area = 0.5 * np.sum(faces[:, 0] * faces[:, 3] - faces[:, 2] * faces[:, 1])
    assert area == pytest.approx(0.1 * 1.9)                                     # ccw, positive
    assert {tuple(f) for f in np.round(block_faces(corners[::-1]), 9)} == \
        {tuple(f) for f in np.round(faces, 9)}                                  # cw input too
    world = blocked_world(ring, corners)
    assert len(world.walls) == len(ring.walls) + 1 and len(world.faces) == len(ring.faces) + 4
    assert not world.grid.is_free(np.array([4.55, 1.0])) and ring.grid.is_free(np.array([4.55, 1.0]))
    over = replace(ring, faces_override=Faces.from_walls(ring.walls))
    assert len(blocked_world(over, corners).faces) == len(ring.faces) + 4
    with pytest.raises(TopodrakeError, match="rectangle"):
        blocked_world(ring, np.array([[0, 0], [1, 0], [1.2, 1], [0, 1]], float))
    with pytest.raises(TopodrakeError, match=r"\(4, 2\) finite corners"):
        block_faces(np.zeros((3, 2)))


def test_block_on_a_house_route():
    from topodrake.world import load_world

    world = load_world("test-0")
    start, goal = world.places[0], world.places[1]
    corners = block_on_path(world, world.astar(start, goal), np.random.default_rng(0))
    _check_block(world, start[:2], goal[:2], corners)


def test_a_gap_with_an_equally_short_way_round_is_not_worth_shutting():
    """A 0.2 m pillar in the middle of a 2.6 m wide hall: shutting the gap on
    one side of it leaves the other, no longer, so nothing is shut."""
    boxes = np.array([[0, 0, 10, 0.2], [0, 2.8, 10, 3], [0, 0, 0.2, 3], [9.8, 0, 10, 3],
                      [4.9, 1.4, 5.1, 1.6]], float)
    hall = world_from_walls("hall", WallSet.from_boxes(boxes, np.arange(5)))
    path = hall.astar((1.0, 1.5, 0.0), (9.0, 1.5, 0.0))
    with pytest.raises(TopodrakeError, match="another way left.*lengthens the way by less than"):
        block_on_path(hall, path, np.random.default_rng(0))


def test_a_trial_with_a_closed_passage_gets_the_time_of_the_way_left_open(ring):
    """The planning study times a blocked trial by the way round (A* at the
    labels' least speed), never less than its own limit; trials without a
    block keep theirs."""
    from topodrake.experiments.plan_scenario import PlanningScenario
    from topodrake.experiments.plan_study import detour_time_limits
    from topodrake.world.astar import path_length

    path = ring.astar(START, GOAL)
    corners = block_on_path(ring, path, np.random.default_rng(0))
    sc = PlanningScenario(houses=["box"])
    starts, goals = np.array([START, START]), np.array([GOAL, GOAL])
    placed = [{"boxes": None, "block": np.round(corners, 3).tolist()}, None]
    out = detour_time_limits(sc, ring, starts, goals, np.array([10.0, 10.0]), placed)
    around = path_length(blocked_world(ring, corners).astar(START, GOAL))
    assert out[1] == 10.0
    assert out[0] >= around / 0.25 - 0.2
    assert out[0] < (around + 2.0) / 0.25
