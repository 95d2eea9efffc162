"""Kinematic bicycle model of the RC car, actuation noise and collision checks.

All functions work on batches: a state array has shape ``(N, 5)`` and a
control array ``(N, 2)``; the Drake ``CarPlant`` calls them with ``N = 1`` and
the batched rollout engine with ``N`` cars at once (DESIGN.md, principle 1).
Nothing here imports Drake.

Conventions
-----------
State columns (see :data:`X`, :data:`Y`, :data:`THETA`, :data:`V`,
:data:`STEER`)::

    x, y    world position of the car's *reference point* (m)
    theta   heading (rad, counter-clockwise from world +x; never wrapped)
    v       signed speed along the heading (m/s; negative = reversing)
    steer   front steering angle delta (rad, positive = turn left)

Controls ``u = (a, sigma)``: forward acceleration ``a = dv/dt`` (m/s^2) and
steering rate ``sigma = d steer/dt`` (rad/s), held constant over a control
period (zero-order hold).

Reference point and body frame. The reference point is the centre of the
body: the origin of the 12 body control points (nose at +0.18 m, sides at
+-0.08 m, tail at -0.13 m), of the lidar (0.08 m ahead) and of the camera
(0.065 m ahead); the occupancy grid's ``car_radius`` is the circumscribed
radius about this point. The reference point moves along the heading
without side slip and the yaw rate is ``omega = v tan(steer) / L``: it is the
rear-axle point of a kinematic bicycle whose front axle is ``L`` ahead of it.
At constant steering the reference point therefore runs on a circle of
radius ``L / tan(steer)`` (0.425 m at the 0.36 rad limit). The authors' car
moves its centre the same way with ``omega = v sin(2 beta) / L``,
``tan beta = tan(steer) / 2``, which is within 3.5 % of ours over the
steering range. The car frame (used for waypoints and obstacle points) has
its origin at the reference point, x forward and y to the left.

Continuous dynamics::

    xdot = v_e cos(theta)      ydot = v_e sin(theta)
    thetadot = v_e tan(steer_e) / L
    vdot = a_e                 steerdot = sigma_e

with the saturations ``v_e = clip(v, min_speed, speed_cap)`` and
``steer_e = clip(steer, -steer_limit, steer_limit)``; ``a_e`` is ``a``
clipped to ``+-accel_limit`` and zeroed when it would push ``v`` further
past a speed bound; ``sigma_e`` is ``sigma`` clipped to
``+-steer_rate_limit`` and zeroed when it would push the steering further
past its limit. The saturations keep the derivative well defined at the
intermediate stage of an integration step, which can overshoot a bound;
:func:`vehicle_step` clamps ``v`` and ``steer`` after every step so that the
stored state always satisfies the bounds.

Integration. :func:`vehicle_step` is exactly Drake's
``RungeKutta2Integrator`` step (Heun's method: explicit Euler predictor,
trapezoidal corrector; Butcher tableau 0 | ; 1 | 1 ; 1/2 1/2) with the same
order of floating-point operations, followed by :func:`clamp_state`. A Drake
plant reproduces it with a fixed-step RK2 at h = dt, controls held over the
step, and a clamp of the continuous state at every period.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Callable

import numba
import numpy as np

#: Column indices of the state array.
X, Y, THETA, V, STEER = range(5)
STATE_SIZE = 5
#: Column indices of the control array.
ACCEL, STEER_RATE = range(2)
CONTROL_SIZE = 2


def default_control_points() -> list[list[float]]:
    """The 12 body control points of the authors' RC car, car frame (m).

    Counter-clockwise around the body outline starting at the nose: nose,
    five points down the left side (x = 0.13 ... -0.13, y = +0.08), the
    middle of the tail, five points up the right side (y = -0.08).
    """
    left = [[0.13, 0.08], [0.065, 0.08], [0.0, 0.08], [-0.065, 0.08], [-0.13, 0.08]]
    right = [[x, -y] for x, y in reversed(left)]
    return [[0.18, 0.0], *left, [-0.13, 0.0], *right]


@dataclass
class VehicleConfig:
    """Geometry, limits and noise of the RC car (authors' "minirccar").

    ``min_speed`` defaults to ``-speed_cap``: the authors cap the norm of the
    velocity, so the car may reverse, which the RMP uses for targets behind
    it. ``accel_limit`` has no counterpart in the authors' car (no
    acceleration limit); 10 m/s^2 crosses the whole speed range within one
    0.1 s period, so it only guards the integrator against absurd commands.
    """

    wheelbase: float = 0.16          # L (m)
    steer_limit: float = 0.36        # |steer| <= (rad)
    steer_rate_limit: float = 3.2    # |sigma| <= (rad/s)
    speed_cap: float = 0.5           # v <= (m/s)
    min_speed: float = -0.5          # v >= (m/s)
    accel_limit: float = 10.0        # |a| <= (m/s^2)
    dt: float = 0.1                  # control period and integration step (s)
    noise_std: float = 0.33          # actuation noise scale ~ N(1, noise_std)
    control_points: list[list[float]] = field(default_factory=default_control_points)
    collision_clearance: float = 0.05  # one grid cell (m)
    collision_ray_step: float = 0.025  # sample spacing along centre->point rays (m)

    def control_points_array(self) -> np.ndarray:
        """(P, 2) control points in the car frame."""
        return np.asarray(self.control_points, dtype=np.float64).reshape(-1, 2)

    def turn_radius(self) -> float:
        """The smallest turning radius of the reference point (m): wheelbase / tan(steer_limit)."""
        return float(self.wheelbase / np.tan(self.steer_limit))

    def approx_radius(self) -> float:
        """Largest distance of a control point from the reference point."""
        return float(np.max(np.linalg.norm(self.control_points_array(), axis=1)))


def _as_batch(a: np.ndarray, width: int, name: str) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 1:
        a = a[None]
    if a.ndim != 2 or a.shape[1] != width:
        raise ValueError(f"{name} must have shape (N, {width}), got {a.shape}")
    return a


def yaw_rate(state: np.ndarray, cfg: VehicleConfig) -> np.ndarray:
    """(N,) yaw rate ``v tan(steer) / L`` of the (saturated) state."""
    state = _as_batch(state, STATE_SIZE, "state")
    v = np.clip(state[:, V], cfg.min_speed, cfg.speed_cap)
    d = np.clip(state[:, STEER], -cfg.steer_limit, cfg.steer_limit)
    return v * np.tan(d) / cfg.wheelbase


def clip_controls(u: np.ndarray, cfg: VehicleConfig) -> np.ndarray:
    """Controls clipped to ``+-accel_limit`` and ``+-steer_rate_limit``."""
    u = _as_batch(u, CONTROL_SIZE, "u")
    out = np.empty_like(u)
    out[:, ACCEL] = np.clip(u[:, ACCEL], -cfg.accel_limit, cfg.accel_limit)
    out[:, STEER_RATE] = np.clip(u[:, STEER_RATE], -cfg.steer_rate_limit, cfg.steer_rate_limit)
    return out


@numba.njit(cache=True, nogil=True)
def _derivatives_kernel(state, u, prm, out):
    L, vmin, vmax, dlim, amax, smax = prm[0], prm[1], prm[2], prm[3], prm[4], prm[5]
    for k in range(state.shape[0]):
        theta = state[k, 2]
        v = state[k, 3]
        d = state[k, 4]
        v_e = min(max(v, vmin), vmax)
        d_e = min(max(d, -dlim), dlim)
        a = min(max(u[k, 0], -amax), amax)
        s = min(max(u[k, 1], -smax), smax)
        if (v >= vmax and a > 0.0) or (v <= vmin and a < 0.0):
            a = 0.0
        if (d >= dlim and s > 0.0) or (d <= -dlim and s < 0.0):
            s = 0.0
        out[k, 0] = v_e * np.cos(theta)
        out[k, 1] = v_e * np.sin(theta)
        out[k, 2] = v_e * np.tan(d_e) / L
        out[k, 3] = a
        out[k, 4] = s


def _vehicle_params(cfg: VehicleConfig) -> np.ndarray:
    return np.array([cfg.wheelbase, cfg.min_speed, cfg.speed_cap, cfg.steer_limit,
                     cfg.accel_limit, cfg.steer_rate_limit])


def vehicle_derivatives(state: np.ndarray, u: np.ndarray, cfg: VehicleConfig) -> np.ndarray:
    """(N, 5) continuous-time state derivative with the saturations applied.

    See the module docstring for the equations and saturation rules. A
    compiled loop (numba): the Drake plant and :func:`vehicle_step` both
    evaluate the dynamics through it, so they agree to the last bit.
    """
    state = np.ascontiguousarray(_as_batch(state, STATE_SIZE, "state"))
    u = np.ascontiguousarray(_as_batch(u, CONTROL_SIZE, "u"))
    if u.shape[0] != state.shape[0]:
        raise ValueError(f"u has {u.shape[0]} rows, state has {state.shape[0]}")
    out = np.empty_like(state)
    _derivatives_kernel(state, u, _vehicle_params(cfg), out)
    return out


def clamp_state(state: np.ndarray, cfg: VehicleConfig) -> np.ndarray:
    """A copy of ``state`` with speed and steering clamped to their bounds."""
    out = np.array(_as_batch(state, STATE_SIZE, "state"), copy=True)
    out[:, V] = np.minimum(np.maximum(out[:, V], cfg.min_speed), cfg.speed_cap)
    out[:, STEER] = np.minimum(np.maximum(out[:, STEER], -cfg.steer_limit), cfg.steer_limit)
    return out


def vehicle_step(state: np.ndarray, u: np.ndarray, cfg: VehicleConfig,
                 dt: float | None = None) -> np.ndarray:
    """One RK2 (Heun) step of length ``dt`` (default ``cfg.dt``), then clamp.

    Same operation order as Drake's ``RungeKutta2Integrator::DoStep``::

        k0 = f(x0);  xa = x0 + h*k0;  ka = f(xa)
        x1 = xa + (h/2)*ka;  x1 = x1 + (-h/2)*k0
    """
    h = cfg.dt if dt is None else float(dt)
    x0 = _as_batch(state, STATE_SIZE, "state")
    u = _as_batch(u, CONTROL_SIZE, "u")
    k0 = vehicle_derivatives(x0, u, cfg)
    xa = x0 + h * k0
    ka = vehicle_derivatives(xa, u, cfg)
    x1 = xa + (h / 2) * ka
    x1 = x1 + (-h / 2) * k0
    return clamp_state(x1, cfg)


# ----------------------------------------------------------------- noise

def sample_noise_scales(rng: np.random.Generator, n: int,
                        std: float = VehicleConfig.noise_std) -> np.ndarray:
    """(n, 2) independent multiplicative scales ``~ N(1, std)``, one per control.

    The authors multiply each control of each step by ``1 + N(0, 1)/3``.
    """
    return 1.0 + std * rng.standard_normal((int(n), CONTROL_SIZE))


def apply_actuation_noise(u: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Noisy controls ``u * scale`` (elementwise; scale from :func:`sample_noise_scales`)."""
    return _as_batch(u, CONTROL_SIZE, "u") * np.asarray(scale, dtype=np.float64)


# ----------------------------------------------------------------- frames

def car_to_world(points: np.ndarray, state: np.ndarray) -> np.ndarray:
    """Car-frame points (N, K, 2) (or (K, 2), shared) -> world (N, K, 2)."""
    state = _as_batch(state, STATE_SIZE, "state")
    p = np.asarray(points, dtype=np.float64)
    c, s = np.cos(state[:, THETA])[:, None], np.sin(state[:, THETA])[:, None]
    px, py = p[..., 0], p[..., 1]
    return np.stack([state[:, X, None] + c * px - s * py,
                     state[:, Y, None] + s * px + c * py], axis=-1)


def world_to_car(points: np.ndarray, state: np.ndarray) -> np.ndarray:
    """World points (N, K, 2) -> car frame (N, K, 2) of each car's pose."""
    state = _as_batch(state, STATE_SIZE, "state")
    p = np.asarray(points, dtype=np.float64)
    c, s = np.cos(state[:, THETA])[:, None], np.sin(state[:, THETA])[:, None]
    dx, dy = p[..., 0] - state[:, X, None], p[..., 1] - state[:, Y, None]
    return np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)


# ----------------------------------------------------------------- collision

def body_points(state: np.ndarray, cfg: VehicleConfig) -> np.ndarray:
    """(N, P, 2) world coordinates of the body control points (P = 12)."""
    return car_to_world(cfg.control_points_array(), state)


@functools.lru_cache(maxsize=16)
def _ray_samples(points: tuple, step: float) -> np.ndarray:
    """(P*K, 2) car-frame samples on the segments from the origin to each point."""
    cp = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    longest = float(np.max(np.linalg.norm(cp, axis=1)))
    k = max(int(np.ceil(longest / step)) + 1, 2)
    t = np.linspace(0.0, 1.0, k)
    out = (cp[:, None, :] * t[None, :, None]).reshape(-1, 2)
    out.setflags(write=False)
    return out


def in_collision(state: np.ndarray, clearance_fn: Callable[[np.ndarray], np.ndarray],
                 cfg: VehicleConfig) -> np.ndarray:
    """(N,) bool: does the car's body touch an obstacle?

    ``clearance_fn`` maps (M, 2) world points to clearance in metres (pass
    ``world.grid.clearance_at``). As in the authors' check (rays from the
    centre to the 12 control points), points are sampled along each segment
    from the reference point to a control point, at most
    ``collision_ray_step`` apart and including both ends; the car collides
    when any sample has clearance below ``collision_clearance`` (one grid
    cell). On a grid clearance map a clearance below one cell means the
    sample lies in an occupied cell, so this is "a control point is in an
    occupied cell or a ray crosses one".
    """
    state = _as_batch(state, STATE_SIZE, "state")
    n = state.shape[0]
    key = tuple(tuple(float(c) for c in p) for p in cfg.control_points)
    local = _ray_samples(key, float(cfg.collision_ray_step))
    world = car_to_world(local, state)                      # (N, P*K, 2)
    clear = np.asarray(clearance_fn(world.reshape(-1, 2)), dtype=np.float64)
    return (clear.reshape(n, -1) < cfg.collision_clearance).any(axis=1)
