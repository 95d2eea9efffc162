"""Unmapped obstacles: boxes added to a world after its map was built."""

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.world.textures import FURNITURE_TEXTURES
from topodrake.world.obstacles import boxes_on_path, with_boxes


def test_with_boxes_occupies_and_renders_without_touching_the_original(box_world):
    box = np.array([[2.0, 2.0, 2.5, 2.5]])
    world = with_boxes(box_world, box)
    assert len(world.walls) == len(box_world.walls) + 1
    assert len(world.faces) == len(box_world.faces) + 4
    assert world.walls.texture[-1] in FURNITURE_TEXTURES
    assert not world.grid.is_free(np.array([2.25, 2.25]))
    assert box_world.grid.is_free(np.array([2.25, 2.25]))     # the original is unchanged
    assert world.grid.is_free(np.array([3.0, 3.0]))           # 0.5 m from the box: free


def test_bad_boxes_are_refused(box_world):
    with pytest.raises(TopodrakeError, match="xmin < xmax"):
        with_boxes(box_world, np.array([[2.0, 2.0, 1.0, 2.5]]))
    with pytest.raises(TopodrakeError, match="path for obstacles"):
        boxes_on_path(box_world, np.zeros((1, 2)), 1, np.random.default_rng(0))


def test_boxes_on_path_sit_on_the_route_away_from_its_ends_and_leave_it_open(box_world):
    path = box_world.astar((2.0, 2.0, 0.0), (8.0, 2.0, 0.0))
    boxes = boxes_on_path(box_world, path, 3, np.random.default_rng(4))
    assert boxes.shape == (3, 4)
    side = boxes[:, 2] - boxes[:, 0]
    assert np.all((side >= 0.3) & (side <= 0.6)) and np.allclose(side, boxes[:, 3] - boxes[:, 1])
    centres = 0.5 * (boxes[:, :2] + boxes[:, 2:])
    to_path = np.min(np.hypot(*(centres[:, None] - path[None, :, :2]).transpose(2, 0, 1)), axis=1)
    assert np.all(to_path < 0.2)
    for end in (path[0], path[-1]):
        assert np.all(np.hypot(*(centres - end[:2]).T) > 1.0)
    blocked = with_boxes(box_world, boxes)
    detour = blocked.astar((2.0, 2.0, 0.0), (8.0, 2.0, 0.0))      # still a way around
    assert len(detour) > 2
    again = boxes_on_path(box_world, path, 3, np.random.default_rng(4))
    assert np.array_equal(boxes, again)                           # seeded


def test_boxes_that_would_close_the_way_are_not_placed(box_world):
    # a corridor 0.8 m wide: any 0.3-0.6 m box in it leaves less than the car's 0.4 m
    narrow = with_boxes(box_world, np.array([[0.2, 4.0, 4.5, 9.8], [0.2, 0.2, 4.5, 3.2]]))
    path = np.column_stack([np.linspace(0.6, 4.0, 40), np.full(40, 3.6)])
    with pytest.raises(TopodrakeError, match="without closing it"):
        boxes_on_path(narrow, path, 1, np.random.default_rng(0), attempts=30)
