"""Batched 2-D point-to-line ICP between lidar scans (numba).

A scan (ranges of the planar lidar, :class:`topodrake.sensing.config.LidarConfig`)
becomes points in the car frame (the lidar sits ``forward_m`` ahead of the
car's reference point); beams that hit nothing in range are dropped.
:func:`register` aligns B (source scan, target scan, initial guess)
problems at once and returns the pose of the source car in the target
car's frame, ``(dx, dy, dtheta)``: a source point ``p`` lies at
``R(dtheta) p + (dx, dy)`` in the target frame.

Each iteration pairs every source point with its nearest target point
within a correspondence gate that starts short (``gate_m``, 0.75 m: a
longer first gate matches the wrong walls of small rooms) and shrinks by
``shrink`` per iteration down to ``gate_min_m``; it then minimises the
point-to-line distances to the target's local wall lines (normals from each
target point's beam neighbours) with a damped Gauss-Newton step. A fit has
converged when its step is below ``tol`` once the gate is at its minimum
(or below ``50 tol`` when the iterations run out there: correspondences
that flip between near neighbours keep the step from vanishing).

The result check: ``inlier`` (the share of source points within the final
gate of a target point), ``inlier_back`` (the share of target points within
it of a source point), ``rms`` (the inliers' point-to-line residual), the
iterations spent and ``constraint``, how well the matched wall lines pin the
translation (near 0 in a corridor, whose walls leave the fit free to slide
along it: the damping then keeps the guess in that direction, so a tracker's
odometry carries it). ``accepted`` asks for convergence, ``inlier >=
min_inlier``, ``rms <= max_rms_m`` and a correction from the initial guess of
at most ``max_shift_m`` / ``max_turn_rad`` (agreement with odometry, which
gave the guess). A converged fit rarely signals its own failure, so these
limits are the caller's to tighten.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.sensing.config import LidarConfig
from topodrake.se2 import wrap as _wrap

__all__ = ["IcpConfig", "Registration", "register", "scan_points"]


@dataclass(frozen=True)
class IcpConfig:
    """ICP settings and the result check."""

    gate_m: float = 0.75          # first correspondence gate
    shrink: float = 0.8           # gate factor per iteration
    gate_min_m: float = 0.15      # final gate (and the inlier distance)
    max_iterations: int = 30
    tol: float = 1e-4             # step (m and rad) that counts as converged
    damping: float = 1e-3         # Gauss-Newton damping (keeps corridors solvable)
    neighbour_m: float = 0.4      # target beam neighbours farther apart give no wall line
    min_points: int = 8           # fewer valid points in either scan: no fit
    min_inlier: float = 0.6       # result check
    max_rms_m: float = 0.05
    max_shift_m: float = 0.5
    max_turn_rad: float = 0.35

    def check(self) -> "IcpConfig":
        if not 0 < self.gate_min_m <= self.gate_m:
            raise TopodrakeError(f"ICP gates must satisfy 0 < gate_min_m <= gate_m, got "
                                 f"{self.gate_min_m} and {self.gate_m}")
        if not 0 < self.shrink <= 1:
            raise TopodrakeError(f"ICP shrink must be in (0, 1], got {self.shrink}")
        if self.max_iterations < 1 or self.min_points < 3:
            raise TopodrakeError("ICP max_iterations must be >= 1 and min_points >= 3")
        for name in ("tol", "damping", "neighbour_m", "max_rms_m", "max_shift_m", "max_turn_rad"):
            if not getattr(self, name) > 0:
                raise TopodrakeError(f"ICP {name} must be > 0, got {getattr(self, name)}")
        if not 0 <= self.min_inlier <= 1:
            raise TopodrakeError(f"ICP min_inlier must be in [0, 1], got {self.min_inlier}")
        return self


@dataclass
class Registration:
    """Results of B registrations."""

    pose: np.ndarray          # (B, 3) source pose in the target frame (dx, dy, dtheta)
    inlier: np.ndarray        # (B,) share of source points matched within the final gate
    inlier_back: np.ndarray   # (B,) share of target points matched within the final gate
    rms: np.ndarray           # (B,) inliers' point-to-line residual (m); inf without a fit
    constraint: np.ndarray    # (B,) weakest translation constraint of the wall lines (the
                              # smaller eigenvalue of the mean n n^T, 0..0.5; ~0 in a corridor)
    iterations: np.ndarray    # (B,) int
    converged: np.ndarray     # (B,) bool
    accepted: np.ndarray      # (B,) bool: converged and passed the result check


def scan_points(ranges, lidar: LidarConfig | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Car-frame points (B, beams, 2) of scans ``ranges`` (B, beams) and their
    validity (B, beams): finite ranges short of the lidar's range."""
    lidar = lidar or LidarConfig()
    r = np.asarray(ranges, np.float64)
    if r.ndim == 1:
        r = r[None]
    if r.ndim != 2 or r.shape[1] != lidar.beams:
        raise TopodrakeError(f"scans must be (B, {lidar.beams}) ranges, got {np.shape(ranges)}")
    valid = np.isfinite(r) & (r > 0) & (r < lidar.range_m)
    ang = lidar.beam_angles()[None]
    rr = np.where(valid, r, 0.0)
    pts = np.stack([lidar.forward_m + rr * np.cos(ang), rr * np.sin(ang)], axis=-1)
    return pts, valid


def register(source, target, initial=None, config: IcpConfig | None = None,
             lidar: LidarConfig | None = None) -> Registration:
    """Register scans ``source`` (B, beams) onto ``target`` (B, beams) (either
    may be one scan, shared by all B) from ``initial`` (B, 3) or (3,) guesses
    of the source pose in the target frame (default: identity)."""
    cfg = (config or IcpConfig()).check()
    sp, sv = scan_points(source, lidar)
    tp, tv = scan_points(target, lidar)
    b = max(len(sp), len(tp))
    if initial is None:
        initial = np.zeros(3)
    init = np.asarray(initial, np.float64).reshape(-1, 3)
    b = max(b, len(init))
    for name, n in (("source scans", len(sp)), ("target scans", len(tp)), ("initial guesses", len(init))):
        if n not in (1, b):
            raise TopodrakeError(f"{n} {name} for a batch of {b} registrations")
    if not np.all(np.isfinite(init)):
        raise TopodrakeError("initial guesses must be finite")
    out = register_points(sp, sv, tp, tv, init, b, cfg)
    return out


def register_points(sp, sv, tp, tv, init, b: int, cfg: IcpConfig) -> Registration:
    """:func:`register` on scans already turned into points (leading
    dimension 1 or ``b``: broadcast)."""
    pose = np.zeros((b, 3))
    stats = np.zeros((b, 4))
    its = np.zeros(b, np.int64)
    conv = np.zeros(b, np.bool_)
    _register_batch(np.ascontiguousarray(sp, np.float64), np.ascontiguousarray(sv),
                    np.ascontiguousarray(tp, np.float64), np.ascontiguousarray(tv),
                    np.ascontiguousarray(init, np.float64), cfg.gate_m, cfg.shrink, cfg.gate_min_m,
                    cfg.max_iterations, cfg.tol, cfg.damping, cfg.neighbour_m, cfg.min_points,
                    pose, stats, its, conv)
    shift = np.hypot(*(pose[:, :2] - np.broadcast_to(init, (b, 3))[:, :2]).T)
    turn = np.abs(_wrap(pose[:, 2] - np.broadcast_to(init, (b, 3))[:, 2]))
    ok = (conv & (stats[:, 0] >= cfg.min_inlier) & (stats[:, 2] <= cfg.max_rms_m)
          & (shift <= cfg.max_shift_m) & (turn <= cfg.max_turn_rad))
    return Registration(pose, stats[:, 0].copy(), stats[:, 1].copy(), stats[:, 2].copy(),
                        stats[:, 3].copy(), its, conv, ok)


# ---------------------------------------------------------------- kernels

@nb.njit(cache=True, fastmath=True)
def _normals(tp, tv, neighbour_m, nrm, nok):
    """Unit normals of each valid target point's wall line, from its beam
    neighbours (the nearer side when only one side is close)."""
    n = tp.shape[0]
    for i in range(n):
        nok[i] = False
        if not tv[i]:
            continue
        lo = i
        hi = i
        if i > 0 and tv[i - 1] and math.hypot(tp[i, 0] - tp[i - 1, 0],
                                              tp[i, 1] - tp[i - 1, 1]) < neighbour_m:
            lo = i - 1
        if i < n - 1 and tv[i + 1] and math.hypot(tp[i, 0] - tp[i + 1, 0],
                                                  tp[i, 1] - tp[i + 1, 1]) < neighbour_m:
            hi = i + 1
        if lo == hi:
            continue
        dx = tp[hi, 0] - tp[lo, 0]
        dy = tp[hi, 1] - tp[lo, 1]
        d = math.hypot(dx, dy)
        if d < 1e-9:
            continue
        nrm[i, 0] = -dy / d
        nrm[i, 1] = dx / d
        nok[i] = True


@nb.njit(cache=True, fastmath=True)
def _nearest(qx, qy, xs, ys, m, gate2):
    """Index of the nearest of the first ``m`` points (xs, ys) to (qx, qy)
    within squared distance ``gate2`` (-1: none) and that squared distance."""
    best = gate2
    arg = -1
    for j in range(m):
        dx = xs[j] - qx
        dy = ys[j] - qy
        d = dx * dx + dy * dy
        if d < best:
            best = d
            arg = j
    return arg, best


@nb.njit(cache=True, fastmath=True)
def _register_one(sp, sv, tp, tv, x0, y0, t0, gate0, shrink, gate_min, max_it, tol, damping,
                  neighbour_m, min_points, out, stats):
    nb_t = tp.shape[0]
    nrm = np.zeros((nb_t, 2))
    nok = np.zeros(nb_t, np.bool_)
    _normals(tp, tv, neighbour_m, nrm, nok)
    # compact target points with a wall line, and all valid ones (for the reverse share)
    txs = np.empty(nb_t)
    tys = np.empty(nb_t)
    axs = np.empty(nb_t)
    ays = np.empty(nb_t)
    tnx = np.empty(nb_t)
    tny = np.empty(nb_t)
    m = 0
    n_tv = 0
    for j in range(nb_t):
        if tv[j]:
            axs[n_tv] = tp[j, 0]
            ays[n_tv] = tp[j, 1]
            n_tv += 1
        if nok[j]:
            txs[m] = tp[j, 0]
            tys[m] = tp[j, 1]
            tnx[m] = nrm[j, 0]
            tny[m] = nrm[j, 1]
            m += 1
    ns = 0
    sxs = np.empty(sp.shape[0])
    sys_ = np.empty(sp.shape[0])
    for i in range(sp.shape[0]):
        if sv[i]:
            sxs[ns] = sp[i, 0]
            sys_[ns] = sp[i, 1]
            ns += 1
    x, y, t = x0, y0, t0
    out[0], out[1], out[2] = x, y, t
    stats[0], stats[1], stats[2], stats[3] = 0.0, 0.0, math.inf, 0.0
    if ns < min_points or m < min_points:
        return 0, False
    gate = gate0
    converged = False
    it = 0
    last_step = math.inf
    while it < max_it:
        it += 1
        c = math.cos(t)
        s = math.sin(t)
        a00 = a01 = a02 = a11 = a12 = a22 = 0.0
        b0 = b1 = b2 = 0.0
        used = 0
        g2 = gate * gate
        for i in range(ns):
            px = c * sxs[i] - s * sys_[i] + x
            py = s * sxs[i] + c * sys_[i] + y
            j, d2 = _nearest(px, py, txs, tys, m, g2)
            if j < 0:
                continue
            nx = tnx[j]
            ny = tny[j]
            r = nx * (px - txs[j]) + ny * (py - tys[j])
            jt = nx * (-(py - y)) + ny * (px - x)     # d r / d theta (rotation about the origin
            #                                            of the source, then the translation)
            # the step is applied as: t += dt; (x, y) += (dx, dy) with points rotated about (x, y)
            a00 += nx * nx
            a01 += nx * ny
            a02 += nx * jt
            a11 += ny * ny
            a12 += ny * jt
            a22 += jt * jt
            b0 -= nx * r
            b1 -= ny * r
            b2 -= jt * r
            used += 1
        if used < min_points:
            break
        lam = damping * used
        a00 += lam
        a11 += lam
        a22 += lam
        # solve the symmetric 3x3 system by Cramer's rule
        c00 = a11 * a22 - a12 * a12
        c01 = a02 * a12 - a01 * a22
        c02 = a01 * a12 - a02 * a11
        det = a00 * c00 + a01 * c01 + a02 * c02
        if abs(det) < 1e-18:
            break
        c11 = a00 * a22 - a02 * a02
        c12 = a01 * a02 - a00 * a12
        c22 = a00 * a11 - a01 * a01
        dx = (c00 * b0 + c01 * b1 + c02 * b2) / det
        dy = (c01 * b0 + c11 * b1 + c12 * b2) / det
        dt = (c02 * b0 + c12 * b1 + c22 * b2) / det
        x += dx
        y += dy
        t += dt
        last_step = max(abs(dx), abs(dy), abs(dt))
        if last_step < tol and gate <= gate_min * 1.0000001:
            converged = True
            break
        gate = max(gate * shrink, gate_min)
    # out of iterations at the final gate, flipping between nearly equal
    # correspondences: the step is still tiny
    if not converged and it == max_it and last_step < 50.0 * tol:
        converged = True
    t = (t + math.pi) % (2 * math.pi) - math.pi
    out[0], out[1], out[2] = x, y, t
    # the result check at the final gate
    c = math.cos(t)
    s = math.sin(t)
    g2 = gate_min * gate_min
    hits = 0
    lined = 0
    ss = 0.0
    sxx = sxy = syy = 0.0
    qx = np.empty(ns)
    qy = np.empty(ns)
    for i in range(ns):
        px = c * sxs[i] - s * sys_[i] + x
        py = s * sxs[i] + c * sys_[i] + y
        qx[i] = px
        qy[i] = py
        j, d2 = _nearest(px, py, axs, ays, n_tv, g2)
        if j >= 0:
            hits += 1
        j, d2 = _nearest(px, py, txs, tys, m, g2)
        if j >= 0:
            r = tnx[j] * (px - txs[j]) + tny[j] * (py - tys[j])
            ss += r * r
            lined += 1
            sxx += tnx[j] * tnx[j]
            sxy += tnx[j] * tny[j]
            syy += tny[j] * tny[j]
    back = 0
    for j in range(nb_t):
        if tv[j]:
            k, d2 = _nearest(tp[j, 0], tp[j, 1], qx, qy, ns, g2)
            if k >= 0:
                back += 1
    stats[0] = hits / ns
    stats[1] = back / max(n_tv, 1)
    stats[2] = math.sqrt(ss / lined) if lined > 0 else math.inf
    if lined > 0:
        tr = (sxx + syy) / lined
        dt = (sxx * syy - sxy * sxy) / (lined * lined)
        stats[3] = 0.5 * tr - math.sqrt(max(0.25 * tr * tr - dt, 0.0))
    return it, converged


@nb.njit(cache=True)
def _register_batch(sp, sv, tp, tv, init, gate0, shrink, gate_min, max_it, tol, damping,
                    neighbour_m, min_points, pose, stats, its, conv):
    b = pose.shape[0]
    for k in range(b):
        ks = k if sp.shape[0] > 1 else 0
        kt = k if tp.shape[0] > 1 else 0
        ki = k if init.shape[0] > 1 else 0
        it, ok = _register_one(sp[ks], sv[ks], tp[kt], tv[kt], init[ki, 0], init[ki, 1],
                               init[ki, 2], gate0, shrink, gate_min, max_it, tol, damping,
                               neighbour_m, min_points, pose[k], stats[k])
        its[k] = it
        conv[k] = ok
