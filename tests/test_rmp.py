"""RMP algebra, the control-point Jacobians and the laser navigation policy."""

import numpy as np
import pytest

from topodrake.rmp import (Rmp, RmpConfig, control_point_kinematics, obstacle_metric_weight,
                           pullback, pushforward, resolve, rmp_controls, solve_metric,
                           stretch_waypoints, sum_rmps)
from topodrake.vehicle import VehicleConfig, vehicle_derivatives

VEH = VehicleConfig()
CFG = RmpConfig()


def car(v=0.0, steer=0.0, n=1):
    return np.tile([0.0, 0.0, 0.0, v, steer], (n, 1))


def controls(state, wp, obs=None, mask=None, cfg=CFG, backend="numba"):
    return rmp_controls(state, np.atleast_2d(wp), obs, mask, cfg, VEH, backend=backend)


# ------------------------------------------------------------------ algebra

def random_spd(rng, shape, n):
    A = rng.normal(size=shape + (n, n))
    return A @ np.swapaxes(A, -1, -2) + 0.1 * np.eye(n)


def test_single_rmp_resolves_to_itself():
    rng = np.random.default_rng(0)
    for n in (2, 3):
        M = random_spd(rng, (5,), n)
        a = rng.normal(size=(5, n))
        rmp = Rmp.from_canonical(a, M)
        np.testing.assert_allclose(resolve([rmp]), a, rtol=1e-6, atol=1e-8)
        np.testing.assert_allclose(rmp.canonical()[0], a, rtol=1e-6, atol=1e-8)


def test_resolve_is_the_metric_weighted_average():
    a1, a2 = np.array([[1.0, 0.0]]), np.array([[0.0, 2.0]])
    M1, M2 = np.diag([3.0, 1.0])[None], np.diag([1.0, 1.0])[None]
    a = resolve([Rmp.from_canonical(a1, M1), Rmp.from_canonical(a2, M2)])
    np.testing.assert_allclose(a, [[3.0 / 4.0, 1.0]], atol=1e-8)
    # a rank-one metric only constrains its own direction (min-norm elsewhere)
    h = np.array([1.0, 1.0]) / np.sqrt(2)
    a = resolve([Rmp.from_canonical(np.array([[2.0, 0.0]]), np.outer(h, h)[None])])
    np.testing.assert_allclose(a, [[1.0, 1.0]], atol=1e-7)
    assert np.all(solve_metric(np.zeros((1, 2, 2)), np.zeros((1, 2))) == 0.0)
    f, M = sum_rmps([Rmp.from_canonical(a1, M1), Rmp.from_canonical(a2, M2)])
    np.testing.assert_allclose(M, M1 + M2)


def test_pullback_and_pushforward_are_consistent():
    rng = np.random.default_rng(1)
    M = random_spd(rng, (4,), 2)
    a = rng.normal(size=(4, 2))
    f_q, M_q = pullback(a, M, np.broadcast_to(np.eye(2), (4, 2, 2)))
    np.testing.assert_allclose(M_q, M)
    np.testing.assert_allclose(f_q, np.einsum("nij,nj->ni", M, a))
    # with an invertible J and bias, pushing the resolved q-acceleration
    # forward recovers the task acceleration
    J = rng.normal(size=(4, 2, 2)) + 2 * np.eye(2)
    b = rng.normal(size=(4, 2))
    qdd = resolve([pullback(a, M, J, b)])
    np.testing.assert_allclose(pushforward(qdd, J, b), a, atol=1e-6)  # ridge 1e-9
    # an over-determined stack of tasks: resolve = weighted least squares
    J2 = rng.normal(size=(4, 3, 2))
    M2 = random_spd(rng, (4,), 3)
    a2 = rng.normal(size=(4, 3))
    qdd = resolve([pullback(a2, M2, J2)])
    grad = np.einsum("nji,njk,nk->ni", J2, M2, np.einsum("nij,nj->ni", J2, qdd) - a2)
    np.testing.assert_allclose(grad, 0.0, atol=1e-7)


def test_control_point_jacobian_matches_the_vehicle_model():
    """xddot = J u + b against finite differences of the bicycle model."""
    rng = np.random.default_rng(2)
    cp = VEH.control_points_array()
    for _ in range(5):
        s = np.array([[0.3, -0.1, rng.uniform(-3, 3), rng.uniform(0.05, 0.45),
                       rng.uniform(-0.3, 0.3)]])
        u = rng.uniform(-0.5, 0.5, size=(1, 2))

        def world_vel(state):
            # world velocity of every control point
            d = vehicle_derivatives(state, u, VEH)[0]
            th, w = state[0, 2], d[2]
            R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
            return d[:2][None] + w * (R @ np.stack([-cp[:, 1], cp[:, 0]])).T

        h = 1e-6
        s_plus = s + h * vehicle_derivatives(s, u, VEH)
        s_minus = s - h * vehicle_derivatives(s, u, VEH)
        acc_world = (world_vel(s_plus) - world_vel(s_minus)) / (2 * h)
        th = s[0, 2]
        acc_car = acc_world @ np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
        _, xdot, J, b = control_point_kinematics(s, VEH)
        pred = np.einsum("pij,j->pi", J[0], u[0]) + b[0]
        np.testing.assert_allclose(pred, acc_car, atol=1e-6)
        R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
        np.testing.assert_allclose(xdot[0] @ R.T, world_vel(s), atol=1e-12)


# ------------------------------------------------------------------ policy pieces

def test_obstacle_metric_weight_decreases_with_distance():
    d = np.linspace(0.05, 3.0, 50)
    w = obstacle_metric_weight(d, CFG)
    assert np.all(np.diff(w) < 0)
    assert obstacle_metric_weight(0.49, CFG) == pytest.approx(1.0 / 16.0)


def test_waypoints_are_stretched_to_two_metres():
    w = stretch_waypoints(np.array([[0.5, 0.5], [3.0, 0.0], [0.0, 0.0], [np.nan, 1.0]]), 2.0)
    np.testing.assert_allclose(w[0], [np.sqrt(2), np.sqrt(2)])
    np.testing.assert_allclose(w[1:3], [[3.0, 0.0], [0.0, 0.0]])
    assert np.isnan(w[3, 0])
    # the policy applies it: a 0.5 m waypoint acts like the same one at 2 m
    s = car(0.3, 0.05)
    np.testing.assert_allclose(controls(s, [0.3, 0.4]), controls(s, [1.2, 1.6]), atol=1e-12)


# ------------------------------------------------------------------ policy behaviour

def test_waypoint_ahead_accelerates_forward_without_steering():
    for v in (0.0, 0.3):
        u = controls(car(v), [3.0, 0.0])
        assert u[0, 0] > 0.05
        assert abs(u[0, 1]) < 1e-9


def test_waypoint_to_the_left_steers_left():
    for v in (0.0, 0.1, 0.4):
        u = controls(car(v), [2.0, 1.0])
        assert u[0, 1] > 0.1
        u_right = controls(car(v), [2.0, -1.0])
        assert u_right[0, 1] == pytest.approx(-u[0, 1], abs=1e-9)


def test_mirror_symmetric_obstacles_cancel_laterally():
    obs = np.array([[[0.5, 0.3], [0.5, -0.3], [0.2, 0.25], [0.2, -0.25]]])
    u_free = controls(car(0.4), [3.0, 0.0])
    u = controls(car(0.4), [3.0, 0.0], obs)
    assert abs(u[0, 1]) < 1e-9
    assert u[0, 0] != pytest.approx(u_free[0, 0])      # the obstacles did act


def test_closer_obstacle_dominates():
    obs = np.array([[[0.4, 0.3], [0.4, -0.6]]])        # left one is closer
    u = controls(car(0.4), [3.0, 0.0], obs)
    assert u[0, 1] < -0.05                              # steer right, away from it
    obs = np.array([[[0.4, 0.6], [0.4, -0.3]]])
    assert controls(car(0.4), [3.0, 0.0], obs)[0, 1] > 0.05


def test_obstacle_ahead_slows_or_turns():
    wall = np.column_stack([np.full(9, 0.58), np.linspace(-0.2, 0.2, 9)])  # 0.4 m ahead of nose
    u_free = controls(car(0.4), [3.0, 0.0])
    u = controls(car(0.4), [3.0, 0.0], wall[None])
    assert u[0, 0] < 0.0 < u_free[0, 0]
    # slightly off-centre, it also turns away
    u = controls(car(0.4), [3.0, 0.0], (wall + [0.0, 0.1])[None])
    assert u[0, 0] < 0.0 and u[0, 1] < -0.05


def test_masked_and_nan_obstacles_are_ignored():
    obs = np.array([[[0.5, 0.1], [0.4, -0.2], [np.nan, np.nan]]])
    u_one = controls(car(0.3), [2.0, 0.5], obs[:, :1])
    u_masked = controls(car(0.3), [2.0, 0.5], obs, np.array([[True, False, True]]))
    np.testing.assert_allclose(u_masked, u_one, atol=1e-12)


def test_rear_points_ignore_obstacles_and_no_waypoint_brakes():
    u_free = controls(car(0.3), [2.0, 0.0])
    behind = np.array([[[-0.3, 0.0], [-0.25, 0.1]]])
    # a point behind affects the side points only through distance; right
    # behind the tail the weights are small and the forward demand stays
    assert controls(car(0.3), [2.0, 0.0], behind)[0, 0] > 0.0
    u_stop = controls(car(0.3), [np.nan, np.nan])
    assert u_stop[0, 0] < 0.0 and abs(u_stop[0, 1]) < 1e-9
    assert u_free[0, 0] > 0.0


def test_controls_are_clipped_to_vehicle_limits():
    obs = np.array([[[0.2, 0.02]]])                     # almost touching the nose
    u = controls(car(0.5, 0.1), [2.0, 0.0], obs)
    assert abs(u[0, 1]) <= VEH.steer_rate_limit
    assert abs(u[0, 0]) <= VEH.accel_limit


def test_numba_kernel_matches_numpy_reference():
    rng = np.random.default_rng(3)
    n, b = 40, 32
    s = np.column_stack([rng.uniform(-1, 1, (n, 2)), rng.uniform(-3, 3, n),
                         rng.uniform(-0.5, 0.5, n), rng.uniform(-0.36, 0.36, n)])
    wp = rng.uniform(-3, 3, (n, 2))
    wp[0] = np.nan
    obs = rng.uniform(-1.5, 1.5, (n, b, 2))
    mask = rng.random((n, b)) < 0.7
    for cfg in (CFG, RmpConfig(include_bias=False, steer_servo_metric=0.0, min_waypoint_m=0.0)):
        u_nb = controls(s, wp, obs, mask, cfg)
        u_np = controls(s, wp, obs, mask, cfg, backend="numpy")
        np.testing.assert_allclose(u_nb, u_np, rtol=1e-9, atol=1e-10)
    # a batch of one is the same computation as a row of a batch
    np.testing.assert_array_equal(controls(s[5:6], wp[5], obs[5:6], mask[5:6]),
                                  controls(s, wp, obs, mask)[5:6])


def test_config_change_is_picked_up():
    cfg = RmpConfig()
    u1 = controls(car(0.3), [2.0, 1.0], cfg=cfg)
    cfg.heading_gain = 0.0
    u2 = controls(car(0.3), [2.0, 1.0], cfg=cfg)
    assert u1[0, 1] != pytest.approx(u2[0, 1])


def test_bad_config_names_the_problem():
    from topodrake.errors import TopodrakeError
    with pytest.raises(TopodrakeError, match="combined_accel_gain"):
        controls(car(0.3), [2.0, 0.0], cfg=RmpConfig(combined_accel_gain=[1.0] * 5))
    with pytest.raises(TopodrakeError, match="goal_points"):
        controls(car(0.3), [2.0, 0.0], cfg=RmpConfig(goal_points=[0, 12]), backend="numpy")
