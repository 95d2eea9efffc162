"""Bicycle model, integration, clamps, actuation noise and collision checks."""

import numpy as np
import pytest

from topodrake.vehicle import (STEER, THETA, V, VehicleConfig, apply_actuation_noise,
                               body_points, car_to_world, clamp_state, in_collision,
                               sample_noise_scales, vehicle_derivatives, vehicle_step,
                               world_to_car, yaw_rate)

CFG = VehicleConfig()


def rollout(state, u, steps, cfg=CFG, dt=None):
    s = np.atleast_2d(np.asarray(state, float))
    for _ in range(steps):
        s = vehicle_step(s, u, cfg, dt)
    return s


def test_straight_driving_integrates_v_times_t():
    s0 = np.array([[1.0, 2.0, np.pi / 6, 0.4, 0.0]])
    s = rollout(s0, np.zeros((1, 2)), 50)           # 5 s
    expected = s0[0, :2] + 0.4 * 5.0 * np.array([np.cos(np.pi / 6), np.sin(np.pi / 6)])
    np.testing.assert_allclose(s[0, :2], expected, atol=1e-12)
    assert s[0, THETA] == pytest.approx(np.pi / 6)
    assert s[0, V] == pytest.approx(0.4)


def test_constant_steer_drives_a_circle_of_radius_L_over_tan():
    steer = 0.3
    radius = CFG.wheelbase / np.tan(steer)
    s0 = np.array([[0.0, 0.0, 0.0, 0.3, steer]])
    traj = [s0[0]]
    s = s0
    for _ in range(200):
        s = vehicle_step(s, np.zeros((1, 2)), CFG)
        traj.append(s[0])
    traj = np.array(traj)
    centre = np.array([0.0, radius])                 # turning left
    r = np.linalg.norm(traj[:, :2] - centre, axis=1)
    np.testing.assert_allclose(r, radius, rtol=2e-3)
    # heading advances at the yaw rate v tan(steer)/L
    assert traj[-1, THETA] == pytest.approx(0.3 * np.tan(steer) / CFG.wheelbase * 20.0, rel=1e-9)
    assert yaw_rate(s0, CFG)[0] == pytest.approx(0.3 * np.tan(steer) / CFG.wheelbase)


def test_speed_and_steering_clamps_hold():
    rng = np.random.default_rng(0)
    s = np.zeros((64, 5))
    for _ in range(100):
        u = rng.normal(0.0, 20.0, size=(64, 2))
        s = vehicle_step(s, u, CFG)
        assert np.all(s[:, V] <= CFG.speed_cap) and np.all(s[:, V] >= CFG.min_speed)
        assert np.all(np.abs(s[:, STEER]) <= CFG.steer_limit)
    # steering rate limit: one step changes the steering by at most rate * dt
    s0 = np.zeros((1, 5))
    s1 = vehicle_step(s0, np.array([[0.0, 100.0]]), CFG)
    assert s1[0, STEER] == pytest.approx(CFG.steer_rate_limit * CFG.dt)
    # speed cap is configurable and the derivative saturates at the bounds
    cfg = VehicleConfig(speed_cap=0.3, min_speed=0.0)
    s = rollout(np.zeros(5), np.array([[1.0, 0.0]]), 20, cfg)
    assert s[0, V] == pytest.approx(0.3)
    s = rollout(s, np.array([[-1.0, 0.0]]), 20, cfg)
    assert s[0, V] == pytest.approx(0.0)
    d = vehicle_derivatives(np.array([[0, 0, 0, 0.3, 0.36]]), np.array([[1.0, 1.0]]), cfg)
    assert d[0, V] == 0.0 and d[0, STEER] == 0.0
    np.testing.assert_array_equal(clamp_state(np.array([[0, 0, 0, 9, -9]]), CFG)[0, 3:],
                                  [CFG.speed_cap, -CFG.steer_limit])


def test_rk2_step_matches_fine_integration():
    rng = np.random.default_rng(1)
    s0 = np.column_stack([rng.uniform(-1, 1, (32, 2)), rng.uniform(-3, 3, 32),
                          rng.uniform(0.0, 0.45, 32), rng.uniform(-0.3, 0.3, 32)])
    u = np.column_stack([rng.uniform(-0.3, 0.3, 32), rng.uniform(-0.5, 0.5, 32)])
    coarse = vehicle_step(s0, u, CFG)                       # one step of 0.1 s
    fine = rollout(s0, u, 1000, CFG, dt=1e-4)
    # controls keep speed and steering strictly inside the bounds here
    assert np.all(np.abs(fine[:, STEER]) < CFG.steer_limit)
    err = np.abs(coarse - fine)
    assert err[:, :3].max() < 2e-4          # O(h^3) local error of Heun
    assert err[:, 3:].max() < 1e-12         # v and steer are linear in t


def test_rk2_operation_order_is_drakes():
    s0 = np.array([[0.1, -0.2, 0.3, 0.25, 0.1]])
    u = np.array([[0.2, -1.0]])
    h = CFG.dt
    k0 = vehicle_derivatives(s0, u, CFG)
    xa = s0 + h * k0
    ka = vehicle_derivatives(xa, u, CFG)
    x1 = xa + (h / 2) * ka
    x1 = x1 + (-h / 2) * k0
    np.testing.assert_array_equal(vehicle_step(s0, u, CFG), x1)


def test_noise_scales_have_mean_one_and_std_033():
    rng = np.random.default_rng(123)
    s = sample_noise_scales(rng, 200_000, CFG.noise_std)
    assert s.shape == (200_000, 2)
    assert s.mean(axis=0) == pytest.approx([1.0, 1.0], abs=0.005)
    assert s.std(axis=0) == pytest.approx([0.33, 0.33], abs=0.005)
    assert abs(np.corrcoef(s.T)[0, 1]) < 0.01            # independent per control
    u = np.array([[0.5, -2.0]])
    np.testing.assert_allclose(apply_actuation_noise(u, np.array([[1.2, 0.5]])), [[0.6, -1.0]])
    # seeded: the same seed gives the same draws
    np.testing.assert_array_equal(sample_noise_scales(np.random.default_rng(7), 5),
                                  sample_noise_scales(np.random.default_rng(7), 5))


def test_frames_round_trip_and_body_points():
    s = np.array([[1.0, 2.0, np.pi / 2, 0.0, 0.0]])
    pts = body_points(s, CFG)
    assert pts.shape == (1, 12, 2)
    np.testing.assert_allclose(pts[0, 0], [1.0, 2.18], atol=1e-12)      # nose points +y
    np.testing.assert_allclose(world_to_car(pts, s)[0], CFG.control_points_array(), atol=1e-12)
    np.testing.assert_allclose(car_to_world(np.array([[0.0, 1.0]]), s)[0, 0], [0.0, 2.0],
                               atol=1e-12)


def test_collision_against_a_wall():
    # wall: the half plane x >= 1 (clearance = distance to it)
    def clearance(p):
        return np.maximum(1.0 - p[:, 0], 0.0)

    heading_east = lambda x: np.array([x, 0.0, 0.0, 0.0, 0.0])
    s = np.stack([heading_east(0.5), heading_east(0.76), heading_east(0.78), heading_east(0.9)])
    # nose at x + 0.18: touches when x + 0.18 > 1 - 0.05
    np.testing.assert_array_equal(in_collision(s, clearance, CFG), [False, False, True, True])
    # facing away, the tail (0.13 behind) decides
    s_back = np.array([[0.80, 0.0, np.pi, 0.0, 0.0], [0.83, 0.0, np.pi, 0.0, 0.0]])
    np.testing.assert_array_equal(in_collision(s_back, clearance, CFG), [False, True])


def test_collision_ray_crosses_a_thin_obstacle():
    # a thin post at (0.12, 0.04) of radius 0.01: between control points, only
    # the ray from the centre to the front-left corner passes through it
    post = np.array([0.1, 0.06154])
    def clearance(p):
        return np.maximum(np.linalg.norm(p - post, axis=1) - 0.01, 0.0) + 0.05 * (
            np.linalg.norm(p - post, axis=1) > 0.011)
    s = np.zeros((1, 5))
    # the post lies on the segment (0,0)-(0.13,0.08) and is far from every control point
    assert np.min(np.linalg.norm(CFG.control_points_array() - post, axis=1)) > 0.03
    assert in_collision(s, clearance, CFG)[0]
    s_far = np.array([[0.0, -0.2, 0.0, 0.0, 0.0]])
    assert not in_collision(s_far, clearance, CFG)[0]
