r"""Riemannian Motion Policies: batched algebra and the car's navigation policy.

RMP algebra
-----------
An RMP on a task space x (dimension n) is a desired acceleration ``a`` with
a positive semi-definite metric ``M`` that says how much each direction of
``a`` matters. Its *canonical* form is ``(a, M)``; its *natural* form is
``(f, M)`` with ``f = M a``. Every array carries leading batch dimensions:
``a, f: (..., n)``, ``M: (..., n, n)``, ``J: (..., n, m)``.

* Sum (several RMPs on one task space): natural forms add,
  ``(f, M) = (sum_k f_k, sum_k M_k)``.
* Resolve: ``a = M^+ f``, the acceleration minimising
  ``sum_k ||a - a_k||^2_{M_k}``. We compute it with a Tikhonov-regularised
  solve ``a = (M + lambda I)^{-1} f``, ``lambda = ridge * tr(M)/n + 1e-12``;
  ``ridge`` defaults to 1e-9, so ``a`` equals ``pinv(M) f`` to ~1e-9
  relative for a well-conditioned ``M`` and tends to the minimum-norm
  solution (zero along the null space of ``M``) when ``M`` is singular.
* Pullback through a map x = phi(q) with Jacobian ``J`` and curvature term
  ``Jdot qdot`` (so that ``xddot = J qddot + Jdot qdot``):
  ``f_q = J^T M (a - Jdot qdot)``, ``M_q = J^T M J``. Resolving the sum of
  pulled-back RMPs gives the least-squares
  ``qddot = argmin sum_i ||J_i qddot + Jdot_i qdot - a_i||^2_{M_i}``.
* Pushforward: ``xddot = J qddot + Jdot qdot`` (and ``xdot = J qdot``).

The car's navigation policy
---------------------------
The configuration-space "acceleration" is the control ``u = (a, sigma)``
(forward acceleration, steering rate; see :mod:`topodrake.vehicle`). Every
body control point p = (p_x, p_y) (car frame, origin at the reference point)
has a velocity and acceleration in the car frame. With ``v`` the speed,
``delta`` the steering angle, ``t = tan(delta)``, ``omega = v t / L`` the yaw
rate and ``alpha = d omega/dt = a t / L + v (1 + t^2) sigma / L``::

    pdot  = (v - omega p_y,  omega p_x)
    pddot = (a - alpha p_y - omega^2 p_x,  v omega + alpha p_x - omega^2 p_y)

(rigid-body acceleration: the reference point accelerates by ``a`` along the
heading and ``v omega`` sideways; ``alpha x p`` and ``-omega^2 p`` are the
tangential and centripetal terms). ``pddot`` is affine in ``u``:
``pddot = J_p u + b_p`` with::

    J_p = [[1 - p_y t/L,   -p_y v (1+t^2)/L],
           [    p_x t/L,    p_x v (1+t^2)/L]]
    b_p = (-omega^2 p_x,  v omega - omega^2 p_y)      (the "Jdot qdot" term)

At ``v = 0`` the steering column vanishes: the steering rate moves no point
until the car rolls (the steering servo below decides the steering there).

Leaf RMPs, all in the car frame (the authors' laser RMP controller):

* goal attractor on the control points flagged ``goal_points`` (the nose and
  the two front corners): ``a = k_g (x_g - x)/(|x_g - x| + eps) - c_g xdot``,
  identity metric. ``x_g`` is the waypoint, stretched to
  ``min_waypoint_m`` when shorter. A NaN waypoint means "stop": the
  attraction and the heading target are dropped and only the damping acts.
* obstacle repulsion on the control points flagged ``obstacle_points``, one
  RMP per valid obstacle point o at distance ``d = |o - x|`` along the unit
  vector ``n = (o - x)/d``:
  ``a = -g_i (k_r + c_o n.xdot) n / (d/s_o + 0.001)`` and metric
  ``w(d) n n^T`` with ``w(d) = m_o exp(-k_w (d - d_0))``; ``g_i`` is the
  point's ``obstacle_accel_gain``. The damping term opposes motion along n
  in both directions, as in the authors' code.
* heading alignment on the nose (``heading_point``):
  ``a = k_h (w_y - c_h omega) R e_perp`` with ``w_y`` the waypoint's lateral
  offset (m), ``R`` the largest control-point radius and ``e_perp`` the unit
  vector perpendicular to the nose direction (car +y); metric
  ``m_h I``.
* steering servo (ours), an RMP directly on the steering rate (task map
  ``u -> sigma``, Jacobian ``[0, 1]``): ``sigma* = k_s (delta* - delta)``
  toward the pure-pursuit angle ``delta* = atan(2 L w_y / |w|^2)`` (clipped
  to the steering limit), metric ``m_s``. Because every point's steering
  column is proportional to ``v``, the point RMPs say nothing about the
  steering at standstill; without this term a car at rest with its waypoint
  to the side creeps backwards and flips its steering for seconds (the
  lateral demand is met neither by ``a`` at zero steering nor by ``sigma``
  at zero speed). With ``m_s = 0.01`` the servo decides the steering near
  ``v = 0`` and is negligible against the point RMPs (whose steering
  metric grows like ``v^2``, ~1 at cruise speed) once the car rolls.

Per control point the leaf RMPs are summed and resolved, and the resolved
acceleration is scaled by the point's ``combined_accel_gain`` (its metric is
not). The controls are the least-squares resolve of all points pulled back
through ``(J_p, b_p)``, clipped to the vehicle's limits.

Differences from the authors' implementation (the gains are theirs):

* the Jacobian is derived from our bicycle model as above. The authors' is
  "not rigorous" (their comment): it drops the ``omega^2`` and ``v omega``
  terms (no ``b_p``), has no ``-p_y`` coupling through ``a``, and its
  steering column lacks the ``1/L`` factor, which makes their steering rate
  6.25x larger for the same desired accelerations. We keep the rigorous
  form; ``steer_jacobian_scale`` (default 1) multiplies the steering column
  and ``include_bias`` (default True) switches ``b_p`` for experiments.
* the metric direction is the unit vector ``n`` (the authors normalise the
  acceleration by ``|a| + 0.001``, which shrinks it for tiny accelerations);
  distances are floored at 1e-6 m instead of adding 0.001 to ``d``.
* regularised solves instead of ``pinv`` (see above).
* the steering servo above is ours.

Two executors of the same math: ``backend="numba"`` (default; a compiled
loop over cars, control points and obstacle points) and ``backend="numpy"``
(written with the algebra functions of this module; the readable
reference the tests hold the kernel to).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import NamedTuple, Sequence

import numba
import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.vehicle import STATE_SIZE, STEER, V, VehicleConfig, clip_controls

_TINY = 1e-12


# ====================================================================== algebra

def _ridge_lambda(M: np.ndarray, ridge: float) -> np.ndarray:
    n = M.shape[-1]
    return ridge * np.trace(M, axis1=-2, axis2=-1) / n + _TINY


def solve_metric(M: np.ndarray, f: np.ndarray, ridge: float = 1e-9) -> np.ndarray:
    """``(M + lambda I)^{-1} f`` over a batch (the regularised ``pinv(M) f``)."""
    M = np.asarray(M, dtype=np.float64)
    f = np.asarray(f, dtype=np.float64)
    lam = _ridge_lambda(M, ridge)
    if M.shape[-1] == 2:
        m11, m12, m21, m22 = M[..., 0, 0] + lam, M[..., 0, 1], M[..., 1, 0], M[..., 1, 1] + lam
        det = m11 * m22 - m12 * m21
        return np.stack([(m22 * f[..., 0] - m12 * f[..., 1]) / det,
                         (m11 * f[..., 1] - m21 * f[..., 0]) / det], axis=-1)
    eye = np.eye(M.shape[-1])
    return np.linalg.solve(M + lam[..., None, None] * eye, f[..., None])[..., 0]


class Rmp(NamedTuple):
    """An RMP in natural form: ``f = M a`` (..., n) and metric ``M`` (..., n, n).

    ``Rmp.from_canonical(a, M)`` builds one from a desired acceleration;
    ``rmp.canonical()`` returns ``(a, M)``; ``rmp1 + rmp2`` is the sum on
    the same task space. It unpacks as ``f, M = rmp``.
    """

    f: np.ndarray
    M: np.ndarray

    @classmethod
    def from_canonical(cls, a: np.ndarray, M: np.ndarray) -> "Rmp":
        M = np.asarray(M, dtype=np.float64)
        return cls(np.einsum("...ij,...j->...i", M, np.asarray(a, dtype=np.float64)), M)

    def canonical(self, ridge: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
        return solve_metric(self.M, self.f, ridge), self.M

    def __add__(self, other: "Rmp") -> "Rmp":  # type: ignore[override]
        return Rmp(self.f + other.f, self.M + other.M)


def to_natural(a: np.ndarray, M: np.ndarray) -> Rmp:
    """Canonical ``(a, M)`` -> natural ``Rmp(M a, M)``."""
    return Rmp.from_canonical(a, M)


def to_canonical(f: np.ndarray, M: np.ndarray,
                 ridge: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """Natural ``(f, M)`` -> canonical ``(M^+ f, M)``."""
    return Rmp(np.asarray(f, dtype=np.float64), np.asarray(M, dtype=np.float64)).canonical(ridge)


def sum_rmps(rmps: Sequence[tuple[np.ndarray, np.ndarray]]) -> Rmp:
    """Sum of natural-form RMPs on one task space: ``Rmp(sum f, sum M)``."""
    if not rmps:
        raise ValueError("sum_rmps needs at least one RMP")
    f = sum(np.asarray(r[0], dtype=np.float64) for r in rmps)
    M = sum(np.asarray(r[1], dtype=np.float64) for r in rmps)
    return Rmp(f, M)


def resolve(rmps: Sequence[tuple[np.ndarray, np.ndarray]], ridge: float = 1e-9) -> np.ndarray:
    """``a = pinv(sum M) sum f`` for natural-form RMPs ``[(f, M), ...]``."""
    f, M = sum_rmps(rmps)
    return solve_metric(M, f, ridge)


def pullback(a: np.ndarray, M: np.ndarray, J: np.ndarray,
             Jdot_qdot: np.ndarray | None = None) -> Rmp:
    """Pull a canonical task-space RMP back to natural form in q.

    ``f_q = J^T M (a - Jdot_qdot)``, ``M_q = J^T M J``.
    """
    a = np.asarray(a, dtype=np.float64)
    if Jdot_qdot is not None:
        a = a - Jdot_qdot
    JtM = np.einsum("...ji,...jk->...ik", J, M)
    return Rmp(np.einsum("...ij,...j->...i", JtM, a), JtM @ J)


def pushforward(qddot: np.ndarray, J: np.ndarray,
                Jdot_qdot: np.ndarray | None = None) -> np.ndarray:
    """Task-space acceleration ``J qddot + Jdot_qdot`` (velocity: pass qdot, no bias)."""
    x = np.einsum("...ij,...j->...i", J, qddot)
    return x if Jdot_qdot is None else x + Jdot_qdot


# ====================================================================== config

def _default_goal_points() -> list[int]:
    return [0, 1, 11]


def _default_obstacle_points() -> list[int]:
    return [0, 1, 2, 3, 4, 8, 9, 10, 11]


def _default_obstacle_accel_gain() -> list[float]:
    return [25.0] + [1.0] * 11


def _default_combined_accel_gain() -> list[float]:
    return [0.5, 3.0] + [1.0] * 9 + [3.0]


@dataclass
class RmpConfig:
    """Gains of the laser RMP controller (defaults: the authors' minirccar).

    Per-control-point lists index :attr:`VehicleConfig.control_points`
    (default order: nose, left side front to back, tail, right side back to
    front). The rear three points (indices 5, 6, 7) ignore obstacles, as in
    the authors' configuration.

    Goal attractor: ``goal_gain`` k_g (m/s^2), ``goal_damping`` c_g (1/s),
    ``goal_softening`` eps (m), ``goal_metric`` (identity scale).
    Obstacles: ``obstacle_repel`` k_r, ``obstacle_damping`` c_o,
    ``obstacle_length`` s_o (m): acceleration magnitude
    ``(k_r + c_o n.xdot) / (d/s_o + 0.001)``; metric weight
    ``obstacle_metric_scale * exp(-obstacle_metric_decay * (d - obstacle_metric_offset))``
    (1/16, 9 /m, 0.49 m).
    Heading: ``heading_gain`` k_h (1/s^2), ``heading_damping`` c_h (m s),
    ``heading_metric`` m_h, applied at ``heading_point``.
    ``min_waypoint_m``: waypoints shorter than this are stretched to it
    (0 disables). Steering servo (ours): ``steer_servo_gain`` k_s (1/s),
    ``steer_servo_metric`` m_s (0 disables). ``steer_jacobian_scale``,
    ``include_bias`` and ``ridge``: see the module docstring.

    Every gain of the authors is kept. Added to them: the steering servo
    (without it a car at rest with a waypoint 5 m away at 90 deg needs 21 s
    to reach it, creeping backwards for the first 10 s; with it, 13.5 s and
    one smooth arc).
    """

    goal_gain: float = 0.18
    goal_damping: float = 0.2
    goal_softening: float = 0.01
    goal_metric: float = 1.0
    obstacle_repel: float = 0.1
    obstacle_damping: float = 0.2
    obstacle_length: float = 0.2
    obstacle_metric_scale: float = 1.0 / 16.0
    obstacle_metric_decay: float = 9.0
    obstacle_metric_offset: float = 0.49
    heading_gain: float = 1.5
    heading_damping: float = 5.0
    heading_metric: float = 1.0
    heading_point: int = 0
    goal_points: list[int] = field(default_factory=_default_goal_points)
    obstacle_points: list[int] = field(default_factory=_default_obstacle_points)
    obstacle_accel_gain: list[float] = field(default_factory=_default_obstacle_accel_gain)
    combined_accel_gain: list[float] = field(default_factory=_default_combined_accel_gain)
    min_waypoint_m: float = 2.0
    steer_jacobian_scale: float = 1.0
    steer_servo_gain: float = 5.0
    steer_servo_metric: float = 0.01
    obstacle_speed_ramp: float = 0.2
    obstacle_rest_weight: float = 0.1
    include_bias: bool = True
    ridge: float = 1e-9


# Layout of the packed parameter vector handed to the kernel.
_P_KG, _P_CG, _P_EPS, _P_GM, _P_KR, _P_CO, _P_SO, _P_MS, _P_MD, _P_MO, _P_KH, _P_CH, \
    _P_HM, _P_MINWP, _P_JS, _P_BIAS, _P_RIDGE, _P_L, _P_R, _P_VMIN, _P_VMAX, _P_DLIM, \
    _P_AMAX, _P_SMAX, _P_SSG, _P_SSM, _P_ORAMP, _P_OREST, _P_COUNT = range(29)
# Columns of the per-point table: x, y, goal flag, obstacle flag, obstacle
# gain, combined gain, heading flag, heading direction (x, y).
_PT_COLS = 9

_param_cache: dict = {}


def _pack(cfg: RmpConfig, veh: VehicleConfig) -> tuple[np.ndarray, np.ndarray]:
    # Cached per config object; a mutated config is detected by comparing
    # its fields with the snapshot taken when it was packed.
    key = (id(cfg), id(veh))
    hit = _param_cache.get(key)
    if hit is not None and hit[0] == cfg.__dict__ and hit[1] == veh.__dict__:
        return hit[2], hit[3]
    cp = veh.control_points_array()
    p = cp.shape[0]
    for name in ("obstacle_accel_gain", "combined_accel_gain"):
        if len(getattr(cfg, name)) != p:
            raise TopodrakeError(f"RmpConfig.{name} has {len(getattr(cfg, name))} entries, "
                                 f"the vehicle has {p} control points")
    for name in ("goal_points", "obstacle_points"):
        bad = [i for i in getattr(cfg, name) if not 0 <= i < p]
        if bad:
            raise TopodrakeError(f"RmpConfig.{name} indexes missing control points {bad}")
    if not 0 <= cfg.heading_point < p:
        raise TopodrakeError(f"RmpConfig.heading_point {cfg.heading_point} is not a control point")
    radius = float(np.max(np.linalg.norm(cp, axis=1)))
    pts = np.zeros((p, _PT_COLS))
    pts[:, 0:2] = cp
    pts[cfg.goal_points, 2] = 1.0
    pts[cfg.obstacle_points, 3] = 1.0
    pts[:, 4] = cfg.obstacle_accel_gain
    pts[:, 5] = cfg.combined_accel_gain
    hp = cfg.heading_point
    phi = np.arctan2(cp[hp, 1], cp[hp, 0])
    pts[hp, 6] = 1.0
    pts[hp, 7:9] = (-np.sin(phi), np.cos(phi))
    prm = np.zeros(_P_COUNT)
    prm[[_P_KG, _P_CG, _P_EPS, _P_GM, _P_KR, _P_CO, _P_SO, _P_MS, _P_MD, _P_MO, _P_KH, _P_CH,
         _P_HM, _P_MINWP, _P_JS, _P_BIAS, _P_RIDGE]] = [
        cfg.goal_gain, cfg.goal_damping, cfg.goal_softening, cfg.goal_metric,
        cfg.obstacle_repel, cfg.obstacle_damping, cfg.obstacle_length,
        cfg.obstacle_metric_scale, cfg.obstacle_metric_decay, cfg.obstacle_metric_offset,
        cfg.heading_gain, cfg.heading_damping, cfg.heading_metric, cfg.min_waypoint_m,
        cfg.steer_jacobian_scale, float(cfg.include_bias), cfg.ridge]
    prm[_P_SSG] = cfg.steer_servo_gain
    prm[_P_SSM] = cfg.steer_servo_metric
    prm[_P_ORAMP] = cfg.obstacle_speed_ramp
    prm[_P_OREST] = cfg.obstacle_rest_weight
    prm[[_P_L, _P_R, _P_VMIN, _P_VMAX, _P_DLIM, _P_AMAX, _P_SMAX]] = [
        veh.wheelbase, radius, veh.min_speed, veh.speed_cap, veh.steer_limit,
        veh.accel_limit, veh.steer_rate_limit]
    if len(_param_cache) > 64:
        _param_cache.clear()
    _param_cache[key] = (copy.deepcopy(cfg.__dict__), copy.deepcopy(veh.__dict__), prm, pts)
    return prm, pts


# ====================================================================== policy pieces

def obstacle_speed_gate(v: np.ndarray, cfg: RmpConfig) -> np.ndarray:
    """Factor on every obstacle metric at (saturated) speed ``v``."""
    v = np.abs(np.asarray(v, dtype=np.float64))
    if cfg.obstacle_speed_ramp <= 0.0:
        return np.ones_like(v)
    return np.minimum(1.0, cfg.obstacle_rest_weight
                      + (1.0 - cfg.obstacle_rest_weight) * v / cfg.obstacle_speed_ramp)


def obstacle_metric_weight(d: np.ndarray, cfg: RmpConfig) -> np.ndarray:
    """Obstacle metric weight ``w(d) = m_o exp(-k_w (d - d_0))``."""
    return cfg.obstacle_metric_scale * np.exp(
        -cfg.obstacle_metric_decay * (np.asarray(d, dtype=np.float64) - cfg.obstacle_metric_offset))


def stretch_waypoints(waypoint_local: np.ndarray, min_length: float) -> np.ndarray:
    """Waypoints (N, 2) shorter than ``min_length`` scaled up to it (NaN and zero kept)."""
    w = np.asarray(waypoint_local, dtype=np.float64)
    n = np.linalg.norm(w, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where((n < min_length) & (n > 1e-9), min_length / n, 1.0)
    return w * scale


def control_point_kinematics(state: np.ndarray, veh: VehicleConfig,
                             steer_jacobian_scale: float = 1.0
                             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Car-frame kinematics of the control points.

    Returns ``(x, xdot, J, b)`` with shapes (P, 2), (N, P, 2), (N, P, 2, 2),
    (N, P, 2): positions, velocities, and the affine map
    ``xddot = J u + b`` from controls ``u = (a, sigma)`` (module docstring).
    Speed and steering are saturated as in the vehicle model.
    """
    state = np.asarray(state, dtype=np.float64).reshape(-1, STATE_SIZE)
    cp = veh.control_points_array()
    px, py = cp[None, :, 0], cp[None, :, 1]
    v = np.clip(state[:, V], veh.min_speed, veh.speed_cap)[:, None]
    t = np.tan(np.clip(state[:, STEER], -veh.steer_limit, veh.steer_limit))[:, None]
    L = veh.wheelbase
    w = v * t / L
    xdot = np.stack([v - w * py, w * px], axis=-1)
    ds = steer_jacobian_scale * v * (1.0 + t * t) / L
    J = np.empty(xdot.shape[:2] + (2, 2))
    J[..., 0, 0] = 1.0 - py * t / L
    J[..., 0, 1] = -py * ds
    J[..., 1, 0] = px * t / L
    J[..., 1, 1] = px * ds
    b = np.stack([-w * w * px, v * w - w * w * py], axis=-1)
    return cp, xdot, J, b


def _rmp_controls_numpy(state, wp, obs, mask, cfg: RmpConfig, veh: VehicleConfig) -> np.ndarray:
    n = state.shape[0]
    cp, xdot, J, b = control_point_kinematics(state, veh, cfg.steer_jacobian_scale)
    p = cp.shape[0]
    eye = np.eye(2)
    wp = stretch_waypoints(wp, cfg.min_waypoint_m) if cfg.min_waypoint_m > 0 else wp
    has_wp = np.all(np.isfinite(wp), axis=-1)                         # (N,)
    wp0 = np.where(has_wp[:, None], wp, 0.0)

    # goal attractor (N, P, 2)
    r = wp0[:, None, :] - cp[None]
    attract = cfg.goal_gain * r / (np.linalg.norm(r, axis=-1, keepdims=True) + cfg.goal_softening)
    a_goal = np.where(has_wp[:, None, None], attract, 0.0) - cfg.goal_damping * xdot
    goal_on = np.zeros(p, bool)
    goal_on[cfg.goal_points] = True
    M_goal = (cfg.goal_metric * goal_on)[None, :, None, None] * eye
    rmps = [to_natural(a_goal, np.broadcast_to(M_goal, (n, p, 2, 2)))]

    # heading alignment at one point
    hp = cfg.heading_point
    phi = np.arctan2(cp[hp, 1], cp[hp, 0])
    e_perp = np.array([-np.sin(phi), np.cos(phi)])
    omega = (np.clip(state[:, V], veh.min_speed, veh.speed_cap)
             * np.tan(np.clip(state[:, STEER], -veh.steer_limit, veh.steer_limit))
             / veh.wheelbase)
    lat = np.where(has_wp, wp0[:, 1], 0.0) - cfg.heading_damping * omega
    a_head = np.zeros((n, p, 2))
    a_head[:, hp] = (cfg.heading_gain * lat * veh.approx_radius())[:, None] * e_perp
    M_head = np.zeros((p, 2, 2))
    M_head[hp] = cfg.heading_metric * eye
    rmps.append(to_natural(a_head, np.broadcast_to(M_head, (n, p, 2, 2))))

    # obstacles (N, P, B, 2)
    if obs.shape[1] > 0:
        rel = obs[:, None, :, :] - cp[None, :, None, :]
        d = np.maximum(np.linalg.norm(rel, axis=-1), 1e-6)
        u = rel / d[..., None]
        proj = np.einsum("npbi,npi->npb", u, xdot)
        gain = np.asarray(cfg.obstacle_accel_gain)[None, :, None]
        s = -gain * (cfg.obstacle_repel + cfg.obstacle_damping * proj) / (
            d / cfg.obstacle_length + 0.001)
        obs_on = np.zeros(p, bool)
        obs_on[cfg.obstacle_points] = True
        v_sat = np.clip(state[:, V], veh.min_speed, veh.speed_cap)
        gate = obstacle_speed_gate(v_sat, cfg)[:, None, None]
        wgt = gate * obstacle_metric_weight(d, cfg) * (mask[:, None, :] & obs_on[None, :, None])
        M_obs = wgt[..., None, None] * u[..., :, None] * u[..., None, :]
        a_obs = s[..., None] * u
        f_obs, M_obs = to_natural(a_obs, M_obs)
        rmps.append((f_obs.sum(axis=2), M_obs.sum(axis=2)))

    # per-point resolve, then the least-squares controls
    f_pt, M_pt = sum_rmps(rmps)
    a_pt = solve_metric(M_pt, f_pt, cfg.ridge) * np.asarray(cfg.combined_accel_gain)[None, :, None]
    f_u, M_u = pullback(a_pt, M_pt, J, b if cfg.include_bias else None)
    q_rmps = [(f_u.sum(axis=1), M_u.sum(axis=1))]

    # steering servo: a q-space RMP on sigma toward the pure-pursuit angle
    delta = np.clip(state[:, STEER], -veh.steer_limit, veh.steer_limit)
    n2 = np.sum(wp0 * wp0, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        dstar = np.clip(np.arctan(2.0 * veh.wheelbase * wp0[:, 1] / n2),
                        -veh.steer_limit, veh.steer_limit)
    on = has_wp & (n2 > 1e-12) & (cfg.steer_servo_metric > 0)
    sigma_star = np.where(on, cfg.steer_servo_gain * (np.where(on, dstar, 0.0) - delta), 0.0)
    M_servo = np.where(on, cfg.steer_servo_metric, 0.0)[:, None, None] * np.ones((n, 1, 1))
    J_servo = np.broadcast_to(np.array([[0.0, 1.0]]), (n, 1, 2))
    q_rmps.append(pullback(sigma_star[:, None], M_servo, J_servo))
    u = resolve(q_rmps, cfg.ridge)
    return clip_controls(u, veh)


# ====================================================================== kernel

@numba.njit(cache=True, fastmath=False, nogil=True)
def _solve2(m11, m12, m22, f1, f2, ridge):
    lam = ridge * 0.5 * (m11 + m22) + 1e-12
    a11 = m11 + lam
    a22 = m22 + lam
    det = a11 * a22 - m12 * m12
    return (a22 * f1 - m12 * f2) / det, (a11 * f2 - m12 * f1) / det


@numba.njit(cache=True, fastmath=False, nogil=True)
def _obstacle_gate(v, ramp, rest):
    if ramp <= 0.0:
        return 1.0
    return min(1.0, rest + (1.0 - rest) * abs(v) / ramp)


@numba.njit(cache=True, fastmath=False, nogil=True)
def rmp_car_controls(v_raw, steer_raw, wx, wy, obs, mask, prm, pts):
    """Controls ``(a, sigma)`` of one car: speed ``v_raw``, steering
    ``steer_raw``, car-frame waypoint ``(wx, wy)``, obstacle points ``obs``
    (B, 2) with ``mask`` (B,). ``prm, pts`` from :func:`packed_params`.

    The per-car body of the batched kernel; the A* expert also calls it
    (with no obstacles) to predict the closed loop."""
    n_pts = pts.shape[0]
    n_obs = obs.shape[0]
    L = prm[_P_L]
    ridge = prm[_P_RIDGE]
    minwp = prm[_P_MINWP]
    v = min(max(v_raw, prm[_P_VMIN]), prm[_P_VMAX])
    t = np.tan(min(max(steer_raw, -prm[_P_DLIM]), prm[_P_DLIM]))
    w = v * t / L
    ds = prm[_P_JS] * v * (1.0 + t * t) / L
    gate = _obstacle_gate(v, prm[_P_ORAMP], prm[_P_OREST])
    has_wp = np.isfinite(wx) and np.isfinite(wy)
    if not has_wp:
        wx = 0.0
        wy = 0.0
    elif minwp > 0.0:
        nw = np.sqrt(wx * wx + wy * wy)
        if nw < minwp and nw > 1e-9:
            wx *= minwp / nw
            wy *= minwp / nw
    A11 = 0.0
    A12 = 0.0
    A22 = 0.0
    B1 = 0.0
    B2 = 0.0
    for i in range(n_pts):
        px = pts[i, 0]
        py = pts[i, 1]
        xd = v - w * py
        yd = w * px
        m11 = 0.0
        m12 = 0.0
        m22 = 0.0
        f1 = 0.0
        f2 = 0.0
        if pts[i, 2] != 0.0:
            ax = -prm[_P_CG] * xd
            ay = -prm[_P_CG] * yd
            if has_wp:
                rx = wx - px
                ry = wy - py
                nr = np.sqrt(rx * rx + ry * ry) + prm[_P_EPS]
                ax += prm[_P_KG] * rx / nr
                ay += prm[_P_KG] * ry / nr
            gm = prm[_P_GM]
            m11 += gm
            m22 += gm
            f1 += gm * ax
            f2 += gm * ay
        if pts[i, 6] != 0.0:
            lat = (wy if has_wp else 0.0) - prm[_P_CH] * w
            hs = prm[_P_KH] * lat * prm[_P_R]
            hm = prm[_P_HM]
            m11 += hm
            m22 += hm
            f1 += hm * hs * pts[i, 7]
            f2 += hm * hs * pts[i, 8]
        if pts[i, 3] != 0.0:
            og = pts[i, 4]
            for j in range(n_obs):
                if not mask[j]:
                    continue
                rx = obs[j, 0] - px
                ry = obs[j, 1] - py
                d = max(np.sqrt(rx * rx + ry * ry), 1e-6)
                ux = rx / d
                uy = ry / d
                proj = ux * xd + uy * yd
                s = -og * (prm[_P_KR] + prm[_P_CO] * proj) / (d / prm[_P_SO] + 0.001)
                wgt = gate * prm[_P_MS] * np.exp(-prm[_P_MD] * (d - prm[_P_MO]))
                m11 += wgt * ux * ux
                m12 += wgt * ux * uy
                m22 += wgt * uy * uy
                # f = (w u u^T)(s u) = w s u
                f1 += wgt * s * ux
                f2 += wgt * s * uy
        if m11 == 0.0 and m22 == 0.0:
            continue
        a1, a2 = _solve2(m11, m12, m22, f1, f2, ridge)
        a1 *= pts[i, 5]
        a2 *= pts[i, 5]
        j11 = 1.0 - py * t / L
        j12 = -py * ds
        j21 = px * t / L
        j22 = px * ds
        if prm[_P_BIAS] != 0.0:
            a1 -= -w * w * px
            a2 -= v * w - w * w * py
        # rows of J^T M
        c11 = j11 * m11 + j21 * m12
        c12 = j11 * m12 + j21 * m22
        c21 = j12 * m11 + j22 * m12
        c22 = j12 * m12 + j22 * m22
        B1 += c11 * a1 + c12 * a2
        B2 += c21 * a1 + c22 * a2
        A11 += c11 * j11 + c12 * j21
        A12 += c11 * j12 + c12 * j22
        A22 += c21 * j12 + c22 * j22
    # steering servo toward the pure-pursuit steering angle (q-space RMP)
    if has_wp and prm[_P_SSM] > 0.0:
        n2 = wx * wx + wy * wy
        if n2 > 1e-12:
            dstar = np.arctan(2.0 * L * wy / n2)
            dstar = min(max(dstar, -prm[_P_DLIM]), prm[_P_DLIM])
            delta = min(max(steer_raw, -prm[_P_DLIM]), prm[_P_DLIM])
            A22 += prm[_P_SSM]
            B2 += prm[_P_SSM] * prm[_P_SSG] * (dstar - delta)
    u1, u2 = _solve2(A11, A12, A22, B1, B2, ridge)
    return (min(max(u1, -prm[_P_AMAX]), prm[_P_AMAX]),
            min(max(u2, -prm[_P_SMAX]), prm[_P_SMAX]))


@numba.njit(cache=True, fastmath=False, nogil=True)
def _rmp_kernel(state, wp, obs, mask, prm, pts, out):
    for k in range(state.shape[0]):
        out[k, 0], out[k, 1] = rmp_car_controls(state[k, 3], state[k, 4], wp[k, 0], wp[k, 1],
                                                obs[k], mask[k], prm, pts)


@numba.njit(cache=True, fastmath=False, nogil=True, parallel=True)
def _rmp_kernel_parallel(state, wp, obs, mask, prm, pts, out):
    for k in numba.prange(state.shape[0]):
        out[k, 0], out[k, 1] = rmp_car_controls(state[k, 3], state[k, 4], wp[k, 0], wp[k, 1],
                                                obs[k], mask[k], prm, pts)


#: Batches smaller than this run the serial kernel (thread start-up costs
#: more than it saves for the Drake systems' batch of one).
SERIAL_BELOW = 8


def packed_params(cfg: RmpConfig, vehicle: VehicleConfig) -> tuple[np.ndarray, np.ndarray]:
    """``(prm, pts)``: the RMP and vehicle parameters as the kernel's arrays
    (validated; cached per config object)."""
    return _pack(cfg, vehicle)


# ====================================================================== entry point

def rmp_controls(state: np.ndarray, waypoint_local: np.ndarray,
                 obstacle_points: np.ndarray | None = None,
                 obstacle_mask: np.ndarray | None = None,
                 cfg: RmpConfig | None = None, vehicle: VehicleConfig | None = None,
                 backend: str = "numba") -> np.ndarray:
    """Controls ``(N, 2) = (forward acceleration, steering rate)`` of the laser RMP.

    ``state`` (N, 5) as in :mod:`topodrake.vehicle`; ``waypoint_local`` (N, 2)
    in the car frame (origin at the reference point, x forward, y left; NaN
    = no waypoint: brake); ``obstacle_points`` (N, B, 2) in the *car frame*
    too (convert lidar hits with :func:`topodrake.vehicle.world_to_car`),
    with ``obstacle_mask`` (N, B) True where a point is a real hit (default:
    all finite points). Waypoints shorter than ``cfg.min_waypoint_m`` are
    stretched. The result is clipped to the vehicle's acceleration and
    steering-rate limits.
    """
    cfg = RmpConfig() if cfg is None else cfg
    veh = VehicleConfig() if vehicle is None else vehicle
    state = np.ascontiguousarray(state, dtype=np.float64).reshape(-1, STATE_SIZE)
    n = state.shape[0]
    wp = np.ascontiguousarray(waypoint_local, dtype=np.float64).reshape(n, 2)
    if obstacle_points is None:
        obs = np.zeros((n, 0, 2))
    else:
        obs = np.ascontiguousarray(obstacle_points, dtype=np.float64)
        if obs.ndim == 2:
            obs = obs[None]
        if obs.shape[0] != n or obs.shape[2] != 2:
            raise ValueError(f"obstacle_points must have shape ({n}, B, 2), got {obs.shape}")
    finite = np.isfinite(obs).all(axis=-1)
    if obstacle_mask is None:
        mask = finite
    else:
        mask = np.asarray(obstacle_mask, dtype=bool).reshape(obs.shape[:2]) & finite
    obs = np.where(mask[..., None], obs, 0.0) if not finite.all() else obs
    prm, pts = _pack(cfg, veh)          # also validates the configs
    if backend == "numpy":
        return _rmp_controls_numpy(state, wp, obs, mask, cfg, veh)
    if backend != "numba":
        raise ValueError(f"unknown backend {backend!r} (numba or numpy)")
    out = np.empty((n, 2))
    kernel = _rmp_kernel if n < SERIAL_BELOW else _rmp_kernel_parallel
    kernel(state, wp, obs, np.ascontiguousarray(mask), prm, pts, out)
    return out
