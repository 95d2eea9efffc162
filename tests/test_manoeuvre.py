"""Manoeuvres on the sensed map: the grid the car builds from its scans,
and the expert's manoeuvre search turning a waypoint the RMP circles into
one it reaches."""

import numpy as np
import pytest

from topodrake.control import controls_toward
from topodrake.navigation.manoeuvre import (ManoeuvreConfig, Manoeuvres, crosses_walls,
                                            detour_path, detour_waypoint, local_grid, ray_path,
                                            wall_points)
from topodrake.rmp import RmpConfig
from topodrake.sensing.config import LidarConfig
from topodrake.sensing.lidar import Lidar
from topodrake.vehicle import VehicleConfig, in_collision, vehicle_step


def test_wall_points_join_close_neighbours_only():
    pts = np.array([[[0.0, 0.0], [0.2, 0.0], [2.0, 0.0], [2.1, 0.0]]])
    mask = np.array([[True, True, True, False]])
    out = wall_points(pts, mask, join_m=0.3, step_m=0.05)
    assert len(out) > 3                                  # the 0.2 m gap is filled
    between = out[(out[:, 0] > 0.01) & (out[:, 0] < 0.19)]
    assert np.diff(np.sort(between[:, 0])).max() <= 0.05 + 1e-9
    assert not ((out[:, 0] > 0.25) & (out[:, 0] < 1.95)).any()   # 1.8 m apart: two walls
    assert not np.isclose(out[:, 0], 2.1).any()          # a miss adds nothing


def test_local_grid_measures_clearance_to_a_wall():
    wall = np.stack([np.full(200, 1.0), np.linspace(-2, 2, 200)], axis=1)
    g = local_grid(wall, np.array([0.0, 0.0]), half_m=3.0, resolution_m=0.05)
    col = int((0.0 - g.origin[0]) / g.resolution)
    row = int((0.0 - g.origin[1]) / g.resolution)
    assert g.clearance[row, col] == pytest.approx(1.0, abs=0.06)
    assert g.clearance.shape == (120, 120)
    empty = local_grid(np.zeros((0, 2)), np.zeros(2), 1.0, 0.1)
    assert empty.clearance.min() > 100                   # nothing seen: open


def test_ray_path_runs_through_the_waypoint_to_its_length():
    p = ray_path(np.array([1.0, 1.0, 0.0]), np.array([1.0, 2.0]), ray_m=3.0)
    assert p[0] == pytest.approx([1.0, 1.0])
    assert p[-1] == pytest.approx([1.0, 4.0])
    assert np.allclose(p[:, 0], 1.0)
    far = ray_path(np.array([0.0, 0.0, 0.0]), np.array([5.0, 0.0]), ray_m=3.0)
    assert far[-1] == pytest.approx([5.0, 0.0])


def _drive(world, start, waypoint, manoeuvres: bool, periods=150, config=None):
    lidar_cfg, veh, rmp = LidarConfig(), VehicleConfig(), RmpConfig()
    lidar = Lidar(world, lidar_cfg)
    st = np.zeros((1, 5))
    st[0, :3] = start
    man = Manoeuvres(1, st[:, :3], lidar_cfg, config) if manoeuvres else None
    for k in range(periods):
        ranges = lidar.scan(st[:, :3])
        wp = np.array([waypoint], float)
        if man is not None:
            wp = man.step(np.array([0]), st[:, :3], wp, ranges)
        st = vehicle_step(st, controls_toward(st, wp, ranges, lidar_cfg, rmp, veh), veh)
        if in_collision(st, world.grid.clearance_at, veh)[0]:
            return "collision", man
        if np.hypot(*(st[0, :2] - waypoint)) < 0.3:
            return "reached", man
    return "timeout", man


def _partition_scan(world, pose):
    from topodrake.expert.kernel import lidar_world_points

    cfg = LidarConfig()
    pts, hit = lidar_world_points(np.array([pose]), Lidar(world, cfg).scan(np.array([pose])), cfg)
    return pts, hit


def test_a_segment_through_a_seen_wall_crosses_it(box_world):
    pts, hit = _partition_scan(box_world, (4.5, 4.5, 0.0))
    assert crosses_walls(pts, hit, np.array([4.5, 4.5]), np.array([5.5, 4.5]), 0.3)
    assert not crosses_walls(pts, hit, np.array([4.5, 4.5]), np.array([4.5, 7.0]), 0.3)
    assert not crosses_walls(pts, np.zeros_like(hit), np.array([4.5, 4.5]),
                             np.array([5.5, 4.5]), 0.3)


def test_kept_scans_answer_the_crossing_test_as_their_points_do(box_world):
    """The segments each car keeps when it remembers a scan give every
    car's crossing answer in one pass, as :func:`crosses_walls` gives it
    from that car's own scans."""
    cfg = LidarConfig()
    poses = np.array([(4.5, 4.5, 0.0), (2.0, 2.0, 0.5), (6.5, 3.0, 3.0)])
    man = Manoeuvres(3, poses, cfg, ManoeuvreConfig(every=1, scans=2))
    man.remember(np.arange(3), poses, Lidar(box_world, cfg).scan(poses))
    ends = np.array([(5.5, 4.5), (2.0, 2.5), (2.0, 3.0)])
    got = man._blocked(np.array([0, 1, 2]), poses, ends)
    want = [crosses_walls(man.points[c], man.mask[c], poses[c, :2], ends[c], 0.3)
            for c in range(3)]
    assert got.tolist() == want and got[0] and not got[1]
    nan = man._blocked(np.array([0]), poses[:1], np.full((1, 2), np.nan))
    assert not nan[0]


def test_a_detour_goes_round_the_seen_wall_and_its_waypoint_is_in_sight(box_world):
    start, goal = np.array([4.5, 4.5]), np.array([5.5, 4.5])
    pts, hit = _partition_scan(box_world, (4.5, 4.5, 0.0))
    grid = local_grid(wall_points(pts, hit, 0.3, 0.025), start, 3.5, 0.05)
    path = detour_path(grid, start, goal)
    assert path is not None
    assert path[0] == pytest.approx(start) and path[-1] == pytest.approx(goal)
    assert path[:, 1].max() > 6.1                       # round the partition's end
    wp = detour_waypoint(path, pts, hit, 0.3, 1.0)
    assert np.hypot(*(wp - start)) <= 1.0 + 1e-9
    assert wp[1] > start[1] + 0.3                       # up along the partition, not through it
    assert not crosses_walls(pts, hit, start, wp, 0.3)
    assert detour_path(grid, start, np.array([20.0, 4.5])) is None     # off the grid


def test_a_waypoint_behind_a_seen_wall_is_reached_along_the_detour(box_world):
    start, goal = (4.5, 4.5, 0.0), (5.5, 4.5)
    straight, _ = _drive(box_world, start, goal, True, 250, ManoeuvreConfig(detour=False))
    detour, _ = _drive(box_world, start, goal, True, 250)
    assert straight != "reached"
    assert detour == "reached"


def test_a_waypoint_the_rmp_circles_is_reached_by_a_manoeuvre(box_world):
    # beside the partition's end, the waypoint behind it on the far side:
    # the RMP alone orbits it; the search backs up and turns in
    start, goal = (4.5, 7.0, 0.0), (5.5, 5.2)
    plain, _ = _drive(box_world, start, goal, manoeuvres=False)
    planned, man = _drive(box_world, start, goal, manoeuvres=True)
    assert plain == "timeout"
    assert planned == "reached"
    assert man.started[0] >= 1


def test_in_the_open_the_waypoint_passes_unchanged(box_world):
    lidar_cfg = LidarConfig()
    lidar = Lidar(box_world, lidar_cfg)
    pose = np.array([[2.5, 5.0, 0.0]])
    man = Manoeuvres(1, pose, lidar_cfg)
    wp = np.array([[4.0, 5.1]])
    for _ in range(5):
        pose = pose + [[0.05, 0.0, 0.0]]                 # moving ahead at 0.5 m/s
        out = man.step(np.array([0]), pose, wp, lidar.scan(pose))
        assert out == pytest.approx(wp)
    assert man.started[0] == 0
    nan = man.step(np.array([0]), pose, np.full((1, 2), np.nan), lidar.scan(pose))
    assert np.isnan(nan).all()


def test_manoeuvres_are_on_by_default_and_off_for_the_paper():
    from topodrake.navigation.follower import FollowerConfig

    assert FollowerConfig().manoeuvres
    assert not FollowerConfig.paper().manoeuvres


def test_cars_in_one_batch_keep_their_own_scans_and_memory(box_world):
    """Two cars stepped together (and one of them left out of some periods,
    as the engine does once a car stops) get the waypoints each gets alone."""
    lidar_cfg, veh, rmp = LidarConfig(), VehicleConfig(), RmpConfig()
    lidar = Lidar(box_world, lidar_cfg)
    starts = np.array([[4.5, 7.0, 0.0], [2.5, 5.0, 0.0]])
    goals = np.array([[5.5, 5.2], [4.0, 5.1]])

    def run(rows, periods=150):
        st = np.zeros((len(rows), 5))
        st[:, :3] = starts[rows]
        man = Manoeuvres(len(rows), st[:, :3], lidar_cfg)
        for k in range(periods):
            cars = np.arange(len(rows)) if k % 7 else np.arange(len(rows))[-1:]
            ranges = lidar.scan(st[cars, :3])
            wp = man.step(cars, st[cars, :3], goals[rows][cars], ranges)
            st[cars] = vehicle_step(st[cars], controls_toward(st[cars], wp, ranges, lidar_cfg,
                                                              rmp, veh), veh)
        return st, man

    both, man = run(np.array([0, 1]))
    alone1, man1 = run(np.array([1]))
    np.testing.assert_allclose(both[1], alone1[0])
    assert man.started[1] == man1.started[0]
    assert man.started[0] >= 1


def test_a_wall_beside_the_start_goes_on_into_the_blind_cone(box_world):
    from topodrake.navigation.manoeuvre import edge_walls

    lidar_cfg = LidarConfig()
    pose = np.array([[5.5, 3.0, np.pi / 2]])        # heading +y, the partition 0.4 m to its left
    ranges = Lidar(box_world, lidar_cfg).scan(pose)
    walls = edge_walls(pose, ranges, lidar_cfg, 1.0, 1.0, 0.025)[0]
    assert len(walls) > 30
    assert np.allclose(walls[:, 0], 5.1, atol=0.03)               # on the partition's face
    assert walls[:, 1].max() < pose[0, 1] and walls[:, 1].min() < pose[0, 1] - 0.9   # behind
    open_right = edge_walls(pose, ranges, lidar_cfg, 1.0, 0.3, 0.025)[0]
    assert len(open_right) == 0                      # nothing at the edges within 0.3 m


def test_the_kernel_sees_the_start_walls_until_the_car_leaves(box_world, monkeypatch):
    import topodrake.navigation.manoeuvre as manoeuvre

    seen = []
    real = manoeuvre.local_grid
    monkeypatch.setattr(manoeuvre, "local_grid",
                        lambda points, *a, **kw: seen.append(points) or real(points, *a, **kw))
    lidar_cfg = LidarConfig()
    lidar = Lidar(box_world, lidar_cfg)
    start = np.array([[5.5, 3.0, np.pi / 2]])
    man = Manoeuvres(1, start, lidar_cfg)
    behind = np.array([[5.1, 2.2]])                  # on the partition, in the blind cone

    def nearest(points):
        return float(np.min(np.hypot(*(points - behind).T)))

    man.step(np.array([0]), start, np.array([[5.5, 1.0]]), lidar.scan(start))
    assert nearest(seen[-1]) < 0.05 and man.blind_on[0]
    away = start + [[0.0, 1.5, 0.0]]
    man.memory[0, manoeuvre._M_TRUST] = 0            # make the kernel check again
    man.step(np.array([0]), away, np.array([[5.5, 1.0]]), lidar.scan(away))
    assert not man.blind_on[0] and nearest(seen[-1]) > 0.05
    off = Manoeuvres(1, start, lidar_cfg, manoeuvre.ManoeuvreConfig(blind_extend_m=None))
    assert not off.blind_on[0]


def test_the_blind_cone_behind_the_start_is_walled_at_blind_back_m(box_world, monkeypatch):
    import topodrake.navigation.manoeuvre as manoeuvre
    from topodrake.navigation.manoeuvre import blind_arc

    lidar_cfg = LidarConfig()
    pose = np.array([[2.5, 5.0, 0.0]])                  # heading +x, nothing near it
    arc = blind_arc(pose, lidar_cfg, 0.6, 0.025)[0]
    assert np.allclose(np.hypot(*(arc - pose[0, :2]).T), 0.6)
    bearing = np.degrees(np.abs(np.arctan2(arc[:, 1] - 5.0, arc[:, 0] - 2.5)))
    assert bearing.min() == pytest.approx(120.0) and bearing.max() == pytest.approx(180.0, abs=2)
    seen = []
    real = manoeuvre.local_grid
    monkeypatch.setattr(manoeuvre, "local_grid",
                        lambda points, *a, **kw: seen.append(points) or real(points, *a, **kw))
    man = Manoeuvres(1, pose, lidar_cfg)
    man.step(np.array([0]), pose, np.array([[1.5, 5.0]]), Lidar(box_world, lidar_cfg).scan(pose))
    assert np.min(np.hypot(*(seen[-1] - [1.9, 5.0]).T)) < 0.03      # straight behind, 0.6 m
    open_cfg = manoeuvre.ManoeuvreConfig(blind_back_m=None)
    man = Manoeuvres(1, pose, lidar_cfg, open_cfg)
    man.step(np.array([0]), pose, np.array([[1.5, 5.0]]), Lidar(box_world, lidar_cfg).scan(pose))
    assert np.min(np.hypot(*(seen[-1] - [1.9, 5.0]).T)) > 0.3


def test_the_blind_arc_goes_once_the_car_leaves_its_start_or_turns(box_world):
    lidar_cfg = LidarConfig()
    lidar = Lidar(box_world, lidar_cfg)
    starts = np.array([[2.5, 5.0, 0.0], [2.5, 5.0, 0.0], [2.5, 5.0, 0.0]])
    man = Manoeuvres(3, starts, lidar_cfg)
    moved = starts + [[0.3, 0.0, 0.0], [1.2, 0.0, 0.0], [0.0, 0.0, np.radians(70.0)]]
    man.step(np.arange(3), moved, moved[:, :2] + [[1.0, 0.0]], lidar.scan(moved))
    assert man.blind_on.tolist() == [True, False, False]
    back = starts.copy()                                    # coming back does not restore it
    man.step(np.arange(3), back, back[:, :2] + [[1.0, 0.0]], lidar.scan(back))
    assert man.blind_on.tolist() == [True, False, False]
