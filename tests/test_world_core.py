import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.world import OccupancyGrid, WallSet, astar, path_length


def test_wall_boxes_round_trip_to_corners():
    walls = WallSet.from_boxes(np.array([[1, 2, 4, 2.2], [0, 0, 0.1, 3]]), np.array([3, 4]))
    c = walls.corners()
    assert np.allclose(c[0].min(axis=0), [1, 2]) and np.allclose(c[0].max(axis=0), [4, 2.2])
    assert np.allclose(c[1].min(axis=0), [0, 0]) and np.allclose(c[1].max(axis=0), [0.1, 3])
    assert list(walls.texture) == [3, 4]


def test_bad_walls_are_refused():
    with pytest.raises(TopodrakeError, match="positive thickness"):
        WallSet(np.array([[0, 0, 1, 0]]), np.array([0.0]), np.array([0]))
    with pytest.raises(TopodrakeError, match="zero length"):
        WallSet(np.array([[1, 1, 1, 1]]), np.array([0.1]), np.array([0]))


def test_occupancy_and_free_space(box_world):
    g = box_world.grid
    assert g.resolution == 0.05
    # Partition cells are occupied, the room centre is free with > 1 m clearance.
    assert g.occupied[g.to_cell([5.0, 3.0])[0], g.to_cell([5.0, 3.0])[1]]
    assert box_world.grid.clearance_at(np.array([2.5, 5.0])) > 1.0
    assert not g.is_free(np.array([[5.0, 3.0], [0.3, 5.0]])).any()
    assert g.is_free(np.array([[2.5, 5.0]])).all()
    # Free area of the interior: 9.6 x 9.6 minus the partition (0.2 x 5.8) within a cell.
    assert abs(box_world.free_area_m2 - (9.6 * 9.6 - 0.2 * 5.8)) < 1.5


def test_astar_goes_around_the_partition(box_world):
    path = box_world.astar([2.5, 2.0], [7.5, 2.0])
    assert np.allclose(path[0], [2.5, 2.0]) and np.allclose(path[-1], [7.5, 2.0])
    assert path[:, 1].max() > 6.0               # it must go over the partition's end
    assert path_length(path) > 2 * (6.0 - 2.0)  # much longer than the 5 m straight line
    assert box_world.grid.is_free(path).all()
    # 8-connected steps between consecutive interior points.
    steps = np.linalg.norm(np.diff(path[1:-1], axis=0), axis=1)
    assert steps.max() <= 0.05 * np.sqrt(2) + 1e-9


def test_astar_keeps_away_from_walls_where_there_is_room(box_world):
    path = box_world.astar([1.0, 8.0], [4.0, 8.0])
    # Straight corridor along y = 8 with walls far away: stays near the line.
    assert np.abs(path[:, 1] - 8.0).max() < 0.3
    hug = box_world.astar([2.5, 1.0], [2.5, 9.0])
    clear = box_world.grid.clearance_at(hug[1:-1])
    assert np.median(clear) > 1.0


def test_astar_errors_name_the_problem(box_world):
    with pytest.raises(TopodrakeError, match="outside the map"):
        box_world.astar([50.0, 2.0], [2.0, 2.0])
    with pytest.raises(TopodrakeError, match="collision"):
        box_world.astar([5.0, 3.0], [2.0, 2.0])


def test_unreachable_goal():
    occ = np.zeros((40, 80), bool)
    occ[:, 38:42] = True    # full-height wall: two separate halves
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
    g = OccupancyGrid(occ, [0.0, 0.0])
    with pytest.raises(TopodrakeError, match="unreachable"):
        astar(g, [0.8, 1.0], [3.2, 1.0])


def test_sample_free_pose_is_free_and_seeded(box_world):
    a = box_world.sample_free_pose(np.random.default_rng(3), 500)
    b = box_world.sample_free_pose(np.random.default_rng(3), 500)
    assert np.array_equal(a, b)
    assert box_world.grid.is_free(a[:, :2]).all()
    assert (np.abs(a[:, 2]) <= np.pi).all()
    # Both halves of the room are sampled.
    assert (a[:, 0] < 4.9).mean() > 0.3 and (a[:, 0] > 5.1).mean() > 0.3
    one = box_world.sample_free_pose(np.random.default_rng(0))
    assert one.shape == (3,)


def test_clearance_treats_beyond_the_grid_as_occupied():
    from topodrake.world.grid import OccupancyGrid

    occ = np.zeros((40, 60), bool)
    occ[20, 30] = True                       # one obstacle cell in the middle
    grid = OccupancyGrid(occ, origin=np.zeros(2), resolution=0.05)
    c = grid.clearance
    assert np.isfinite(c).all()
    assert c[0, 0] == pytest.approx(0.05)    # next to the edge: one cell from "outside"
    assert c[20, 31] == pytest.approx(0.05)  # next to the obstacle
    assert c[10, 10] == pytest.approx(0.55)  # 11 cells from the bottom/left edges
    # an empty grid has finite clearance too: the car stays off its edges
    empty = OccupancyGrid(np.zeros((10, 10), bool), origin=np.zeros(2))
    assert empty.clearance.max() == pytest.approx(0.25)
    assert not empty.is_free(np.array([0.02, 0.25]))
