"""People walking near a car's route, batched over cars."""

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.world import load_world
from topodrake.world.walkers import (
    CAR_BODY_M,
    OFFSET_M,
    RADIUS_M,
    SPEED_MPS,
    Walkers,
    wall_margin,
)

DT = 0.1
FAR = np.array([-100.0, -100.0])       # a car nowhere near its walkers


@pytest.fixture(scope="module")
def house():
    """test-0, three routes between its places, and the cars' starts."""
    world = load_world("test-0")
    paths = [world.astar(world.places[a], world.places[b]) for a, b in ((0, 1), (2, 3), (4, 5))]
    return world, paths, np.array([p[0] for p in paths])


@pytest.fixture(scope="module")
def box_route(box_world):
    """A route around the partition of the box world (about 17 m)."""
    return box_world.astar((1.0, 1.0, 0.0), (9.0, 1.0, 0.0))


def wall_distance(walls, p):
    """(M,) exact distance from points (M, 2) to the nearest wall box (0 inside)."""
    a = walls.segments[:, :2]
    d = walls.segments[:, 2:] - a
    length = np.linalg.norm(d, axis=1)
    u = d / length[:, None]
    rel = p[:, None] - a[None]
    along = rel[..., 0] * u[:, 0] + rel[..., 1] * u[:, 1]
    across = -rel[..., 0] * u[:, 1] + rel[..., 1] * u[:, 0]
    dx = np.maximum(np.abs(along - 0.5 * length) - 0.5 * length, 0.0)
    dy = np.maximum(np.abs(across) - 0.5 * walls.thickness, 0.0)
    return np.hypot(dx, dy).min(axis=1)


def cross(a, b):
    """z of the 2-D cross product, over the last axis."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def run(walkers, steps, car_xy=None):
    """Step every car ``steps`` times; positions (steps + 1, N, W, 2), s, direction."""
    n = len(walkers.xy)
    car_xy = np.tile(FAR, (n, 1)) if car_xy is None else car_xy
    xy, s, d = [walkers.xy.copy()], [walkers.s.copy()], [walkers.direction.copy()]
    for _ in range(steps):
        walkers.step(DT, np.arange(n), car_xy)
        xy.append(walkers.xy.copy())
        s.append(walkers.s.copy())
        d.append(walkers.direction.copy())
    return np.array(xy), np.array(s), np.array(d)


def test_walkers_start_in_free_space_near_the_route_away_from_the_car(house):
    world, paths, starts = house
    wk = Walkers.on_paths(world, paths, 4, [0, 1, 2], starts)
    assert wk.xy.shape == (3, 4, 2) and wk.heading.shape == wk.speed.shape == (3, 4)
    assert np.all(world.grid.clearance_at(wk.xy) >= wk.radius + 0.05)
    assert np.all(wall_distance(world.walls, wk.xy.reshape(-1, 2)) > wk.radius.ravel())
    assert np.all((wk.radius >= RADIUS_M[0]) & (wk.radius <= RADIUS_M[1]))
    assert np.all((wk.speed >= SPEED_MPS[0]) & (wk.speed <= SPEED_MPS[1]))
    assert np.array_equal(wk.crossing.sum(axis=1), [2, 2, 2])      # n // 2 cross
    for i, path in enumerate(paths):
        p = wk.xy[i]
        assert np.all(np.linalg.norm(p - starts[i], axis=1) > 2.0)
        for end in (path[0], path[-1]):
            assert np.all(np.linalg.norm(p - end, axis=1) > 1.0)
        to_route = np.linalg.norm(p[:, None] - path[None], axis=-1).min(axis=1)
        assert np.all(to_route[~wk.crossing[i]] < OFFSET_M + 0.05)     # beside the route
        for w in np.flatnonzero(~wk.crossing[i]):    # beside the route, through its doors
            track = wk.track[i, w, :wk.track_n[i, w]]
            assert np.linalg.norm(track[[0, -1]] - path[[0, -1]], axis=1).max() < OFFSET_M
            assert world.grid.clearance_at(track).min() >= wk.radius[i, w] + wk.margin
        gaps = np.linalg.norm(p[:, None] - p[None], axis=-1) + 9 * np.eye(4)
        assert np.all(gaps > wk.radius[i][:, None] + wk.radius[i][None])
        for w in np.flatnonzero(wk.crossing[i]):    # a straight line through the route
            track = wk.track[i, w, :wk.track_n[i, w]]
            assert np.linalg.norm(track[:, None] - path[None], axis=-1).min() < 0.1
            d = track[-1] - track[0]
            off = np.abs(cross(track - track[0], d / np.linalg.norm(d)))
            assert off.max() < 1e-9
    assert not np.array_equal(wk.xy[0], Walkers.on_paths(world, paths[:1], 4, [1]).xy[0])


def test_walkers_never_overlap_walls_and_go_back_and_forth(house):
    world, paths, starts = house
    wk = Walkers.on_paths(world, paths, 3, [3, 4, 5], starts)
    xy, s, d = run(wk, 600)
    flat = xy.reshape(-1, 2)
    radius = np.broadcast_to(wk.radius, xy.shape[:-1]).ravel()
    assert np.all(wall_distance(world.walls, flat) >= radius)         # the true walls
    assert np.all(world.grid.clearance_at(flat) >= radius + wall_margin(world.grid))
    walked = np.linalg.norm(np.diff(xy, axis=0), axis=-1).sum(axis=0)
    assert np.all(walked > 15.0)                                      # over 60 s
    assert np.all((np.diff(d, axis=0) != 0).sum(axis=0) >= 2)         # turned back
    length = wk.spacing * (wk.track_n - 1)
    across = wk.crossing                                              # from side to side
    assert across.any() and np.all(s.min(axis=0)[across] == 0.0)
    assert np.all(s.max(axis=0)[across] == length[across])


def test_a_walker_turns_back_at_a_wall_in_its_way(box_world, box_route):
    wk = Walkers.on_paths(box_world, [box_route], 1, [0])
    line = np.column_stack([np.linspace(3.0, 6.0, 61), np.full(61, 3.0)])    # through x=4.9..5.1
    wk.track, wk.track_n[:], wk.spacing[:] = line[None, None], 61, 0.05
    wk.xy[:], wk.s[:], wk.direction[:], wk.speed[:] = line[0], 0.0, 1.0, 1.4
    xy, _, _ = run(wk, 100)
    x, r = xy[:, 0, 0, 0], wk.radius[0, 0]
    assert x.max() + r <= 4.9                                 # never into the partition
    assert np.all(box_world.grid.clearance_at(xy[:, 0, 0]) >= r + wall_margin(box_world.grid))
    assert x.max() > 4.9 - r - 0.2                           # but up to it
    assert x[np.argmax(x):].min() < x.max() - 1.0             # and back


def test_walkers_walk_at_their_speed_and_stand_still_when_stopped(box_world, box_route):
    wk = Walkers.on_paths(box_world, [box_route] * 2, 4, [10, 11])
    stopped, step = [], []
    for _ in range(300):
        stopped.append(wk.stopped.copy())
        before = wk.xy.copy()
        wk.step(DT, [0, 1], np.tile(FAR, (2, 1)))
        step.append(np.linalg.norm(wk.xy - before, axis=-1))
    step, stopped = np.array(step), np.array(stopped)
    expected = np.broadcast_to(wk.speed * DT, step.shape)
    assert np.all(step <= expected * (1 + 1e-5))
    assert np.all(step[stopped] == 0.0)
    moved = step > 0
    assert moved.mean() > 0.7
    assert np.median(step[moved] / expected[moved]) > 0.999


def test_walkers_stop_for_one_to_three_seconds_turn_back_and_go_on(box_world, box_route):
    wk = Walkers.on_paths(box_world, [box_route] * 2, 4, [20, 21])
    xy, s, d = run(wk, 600)
    still = np.linalg.norm(np.diff(xy, axis=0), axis=-1) == 0        # (600, N, W)
    stops = []
    for i, w in np.ndindex(still.shape[1:]):
        edges = np.flatnonzero(np.diff(np.concatenate([[0], still[:, i, w], [0]])))
        for a, b in zip(edges[::2], edges[1::2]):
            if b - a >= 2 and b < len(still):        # a stop, not a turn at a wall; it ended
                stops.append(b - a)
    assert len(stops) >= 5
    assert min(stops) >= 1.0 / DT and max(stops) <= 3.0 / DT + 1
    length = wk.spacing * (wk.track_n - 1)
    ds = np.diff(s, axis=0)
    back = (ds * d[:-1] < 0) & (s[1:] > 0) & (s[1:] < length)        # turned mid-track
    assert back.sum() >= 3


def test_walkers_are_seeded_per_car_and_independent_of_the_batch(house):
    world, paths, starts = house
    batch = Walkers.on_paths(world, paths, 3, [7, 8, 9], starts)
    alone = Walkers.on_paths(world, paths[1:], 3, [8, 9], starts[1:])
    for name in ("xy", "heading", "speed", "radius", "crossing", "s", "direction", "key"):
        assert np.array_equal(getattr(batch, name)[1:], getattr(alone, name)), name
    run(batch, 100, starts)
    run(alone, 100, starts[1:])
    assert np.array_equal(batch.xy[1:], alone.xy) and np.array_equal(batch.stop_s[1:],
                                                                        alone.stop_s)
    held = batch.take([1])
    for _ in range(20):
        batch.step(DT, [0, 2], starts[[0, 2]])                       # car 1 is left alone
    assert np.array_equal(batch.xy[1], held.xy[0]) and batch.tick[1] == held.tick[0]
    again = Walkers.on_paths(world, paths, 3, [7, 8, 9], starts)
    run(again, 100, starts)
    for _ in range(20):
        again.step(DT, [0, 2], starts[[0, 2]])
    assert np.array_equal(again.xy, batch.xy)                        # deterministic
    other = Walkers.on_paths(world, paths, 3, [7, 8, 10], starts)
    assert not np.array_equal(other.xy[2], batch.take([2]).xy[0])


def test_walkers_yield_to_a_car_in_their_way(box_world, box_route):
    wk = Walkers.on_paths(box_world, [box_route], 2, [5])
    w = int(np.flatnonzero(~wk.crossing[0])[0])
    ahead = wk.s[0, w] + wk.direction[0, w] * 1.2
    assert 0 < ahead < wk.spacing[0, w] * (wk.track_n[0, w] - 1)
    car = wk._at(np.array([0]), np.full((1, 2), ahead))[0][0, w][None]      # on its track
    free = wk.take([0])
    xy, _, _ = run(free, 60)                                          # no car: it walks there
    reach = wk.radius[0, w] + CAR_BODY_M
    assert np.linalg.norm(xy[:, 0, w] - car, axis=-1).min() < reach
    waited = 0
    for _ in range(60):
        before = wk.xy[0, w].copy()
        wk.step(DT, [0], car)
        assert np.linalg.norm(wk.xy[0, w] - car[0]) >= reach         # never walks into it
        assert np.linalg.norm(wk.xy[0, w] - before) <= wk.speed[0, w] * DT * (1 + 1e-5)
        waited += wk.waiting[0, w]
    assert waited > 10
    assert np.allclose(wk._at(np.array([0]), wk.s)[0], wk.xy)         # still on its track


def test_faces_are_closed_counter_clockwise_polygons_around_each_disc(box_world, box_route):
    wk = Walkers.on_paths(box_world, [box_route] * 2, 3, [0, 1])
    assert wk.faces([0, 1]).shape == (2, 3 * 8, 4)
    faces = wk.faces([1, 0], sides=6)
    assert faces.shape == (2, 18, 4)
    a, b = faces[..., :2].reshape(2, 3, 6, 2), faces[..., 2:].reshape(2, 3, 6, 2)
    assert np.array_equal(b, np.roll(a, -1, axis=2))                   # closed
    centre, radius = wk.discs([1, 0])
    assert np.array_equal(centre, wk.xy[[1, 0]]) and np.array_equal(radius, wk.radius[[1, 0]])
    ra, edge = a - centre[:, :, None], b - a
    assert np.all(cross(ra, edge) > 0)                               # counter-clockwise
    tangent = cross(ra, edge) / np.linalg.norm(edge, axis=-1)       # centre to each face
    assert np.allclose(tangent, radius[..., None])                     # around the disc
    right = np.stack([edge[..., 1], -edge[..., 0]], axis=-1)
    assert np.all(np.sum((a + 0.5 * edge - centre[:, :, None]) * right, axis=-1) > 0)


def test_take_copies_a_sub_batch(box_world, box_route):
    wk = Walkers.on_paths(box_world, [box_route] * 3, 2, [0, 1, 2])
    sub = wk.take([2, 0])
    assert np.array_equal(sub.xy, wk.xy[[2, 0]]) and np.array_equal(sub.key, wk.key[[2, 0]])
    assert np.array_equal(sub.track, wk.track[[2, 0]])
    sub.step(DT, [0, 1], np.tile(FAR, (2, 1)))
    wk.step(DT, [2, 0], np.tile(FAR, (2, 1)))
    assert np.array_equal(sub.xy, wk.xy[[2, 0]])                      # steps alike
    sub.xy[:] = 0.0
    assert not np.any(wk.xy == 0.0)                                  # a copy


def test_no_walkers(box_world, box_route):
    wk = Walkers.on_paths(box_world, [box_route] * 2, 0, [0, 1])
    assert wk.xy.shape == (2, 0, 2) and wk.radius.shape == (2, 0)
    wk.step(DT, [0, 1], np.zeros((2, 2)))
    centre, radius = wk.discs([1])
    assert centre.shape == (1, 0, 2) and radius.shape == (1, 0)
    assert wk.faces([0, 1]).shape == (2, 0, 4) and wk.take([1]).xy.shape == (1, 0, 2)


def test_bad_input_is_refused(box_world, box_route):
    with pytest.raises(TopodrakeError, match=r"route 0 for walkers must be \(K >= 2, 2\)"):
        Walkers.on_paths(box_world, [np.zeros((1, 2))], 1, [0])
    with pytest.raises(TopodrakeError, match="route 1 for walkers has non-finite"):
        Walkers.on_paths(box_world, [box_route, np.array([[1.0, 1.0], [np.nan, 2.0]])], 1,
                         [0, 1])
    with pytest.raises(TopodrakeError, match="zero length"):
        Walkers.on_paths(box_world, [np.ones((3, 2))], 1, [0])
    with pytest.raises(TopodrakeError, match="one seed per route"):
        Walkers.on_paths(box_world, [box_route], 1, [0, 1])
    with pytest.raises(TopodrakeError, match=">= 0"):
        Walkers.on_paths(box_world, [box_route], -1, [0])
    with pytest.raises(TopodrakeError, match="car_starts"):
        Walkers.on_paths(box_world, [box_route], 1, [0], np.zeros((2, 2)))
    short = np.array([[2.0, 5.0], [3.5, 5.0]])
    with pytest.raises(TopodrakeError, match="no point 1.0 m away from both its ends"):
        Walkers.on_paths(box_world, [short], 1, [0])
    middle = np.array([[2.0, 5.0], [5.0, 5.0]])                        # car start in its middle
    with pytest.raises(TopodrakeError, match="could place only 0 of 1 walkers near route 1"):
        Walkers.on_paths(box_world, [box_route, middle], 1, [0, 1],
                         np.array([box_route[0], [3.5, 5.0]]))
    wk = Walkers.on_paths(box_world, [box_route], 1, [0])
    with pytest.raises(TopodrakeError, match="dt > 0"):
        wk.step(0.0, [0], np.zeros((1, 2)))
    with pytest.raises(TopodrakeError, match=r"car_xy must be \(1, 2\)"):
        wk.step(DT, [0], np.zeros(2))
    with pytest.raises(TopodrakeError, match=">= 3 sides"):
        wk.faces([0], sides=2)
