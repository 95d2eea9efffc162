"""Odometry that drifts, and the relative poses of a route's legs."""

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.contract.route import teach_legs
from topodrake.odometry import Odometry, OdometryConfig, odometry_along, odometry_errors
from topodrake.se2 import compose, invert, relative


def straight(n=101, length=10.0):
    x = np.linspace(0.0, length, n)
    return np.column_stack([x, np.zeros(n), np.zeros(n)])


def arc(n=200, radius=2.0, turn=np.pi):
    a = np.linspace(0.0, turn, n)
    return np.column_stack([radius * np.sin(a), radius * (1 - np.cos(a)), a])


def test_se2_compose_invert_relative_agree():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    np.testing.assert_allclose(compose(a, invert(a))[:, :2], 0.0, atol=1e-12)
    np.testing.assert_allclose(compose(a, relative(a, b)), compose(b, np.zeros((5, 3))), atol=1e-12)


def test_perfect_odometry_reads_the_true_pose():
    poses = arc()
    np.testing.assert_allclose(odometry_along(poses, OdometryConfig.perfect(), 3), poses)


def test_wheel_odometry_scales_distance_by_the_cars_own_error():
    cfg = OdometryConfig(scale_std=0.05)
    err = odometry_errors(cfg, [7])[0]
    odo = odometry_along(straight(), cfg, 7)
    assert err[0] != 0.0
    assert odo[-1, 0] == pytest.approx(10.0 * (1 + err[0]))
    assert np.allclose(odo[:, 1:], 0.0)            # a straight drive: no heading error to grow


def test_heading_bias_grows_with_distance_and_errors_are_seeded():
    cfg = OdometryConfig.wheel()
    a, b, c = (odometry_along(arc(), cfg, s) for s in (1, 1, 2))
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)
    true = arc()
    gap = np.hypot(*(a[:, :2] - true[:, :2]).T)
    assert gap[0] == 0.0 and gap[-1] > gap[len(gap) // 4] > 0.0


def test_batched_odometry_matches_one_car_at_a_time():
    cfg = OdometryConfig.wheel()
    paths = [arc(), arc(radius=3.0, turn=-1.0)]
    odo = Odometry(cfg, [4, 5], np.array([p[0] for p in paths]))
    for t in range(1, 200):
        odo.update(np.arange(2), np.array([p[t] for p in paths]))
    for i, (p, s) in enumerate(zip(paths, [4, 5])):
        np.testing.assert_allclose(odo.poses[i], odometry_along(p, cfg, s)[-1], atol=1e-12)


def test_odometry_config_refuses_a_negative_error():
    with pytest.raises(TopodrakeError, match="scale_std"):
        OdometryConfig(scale_std=-0.1).check()


def test_teach_legs_are_relative_poses_of_consecutive_anchors():
    poses = arc()
    legs, paths = teach_legs(poses, [0, 50, 120, 199], points=4)
    np.testing.assert_allclose(paths[:, -1], legs, atol=1e-12)       # each path ends at the anchor
    np.testing.assert_allclose(compose(poses[50:51], paths[1, 1]), poses[85:86], atol=1e-9)
    np.testing.assert_allclose(compose(compose(compose(poses[:1], legs[0]), legs[1]), legs[2]),
                               poses[199:200], atol=1e-9)
    drifted, _ = teach_legs(poses, [0, 50, 120, 199], OdometryConfig.wheel(), seed=3)
    assert not np.allclose(drifted, legs)
    assert np.abs(drifted - legs).max() < 0.2      # a few per cent over a 2 m leg
