"""Closed-loop prediction of the expert + RMP + car (compiled): the
path-following check and the manoeuvre search (see :mod:`topodrake.expert`)."""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from topodrake.expert.config import (_E_BODY, _E_DT, _E_FINAL, _E_H, _E_IMM, _E_LCOS, _E_LFWD,
                                     _E_LOOK, _E_MDIRS, _E_MRAD, _E_MSTEPS, _E_OBSR, _E_PROG,
                                     _E_REACH, _E_RESCAN, _E_SEARCH, _E_TURN, _RESELECT)
from topodrake.expert.sight import _advance, _body_clear, _progress, _waypoint
from topodrake.rmp import _P_DLIM, _P_L, _P_VMAX, _P_VMIN, rmp_car_controls
from topodrake.sensing.raycast import cast


# ---------------------------------------------------------------- prediction

@nb.njit(cache=True, inline="always")
def _deriv(th, v, d, a, s, prm):
    L = prm[_P_L]
    vmin = prm[_P_VMIN]
    vmax = prm[_P_VMAX]
    dlim = prm[_P_DLIM]
    ve = min(max(v, vmin), vmax)
    de = min(max(d, -dlim), dlim)
    if (v >= vmax and a > 0.0) or (v <= vmin and a < 0.0):
        a = 0.0
    if (d >= dlim and s > 0.0) or (d <= -dlim and s < 0.0):
        s = 0.0
    return ve * math.cos(th), ve * math.sin(th), ve * math.tan(de) / L, a, s


@nb.njit(cache=True, inline="always")
def _local_obstacles(obs, omask, eprm, x, y, c, s, buf, bmask):
    """Lidar hits (world) within ``obstacle_range_m`` of the car at (x, y)
    with heading (c, s) and inside the lidar's field of view, written to
    ``buf`` in the car frame; returns their number."""
    r2 = eprm[_E_OBSR] ** 2
    fwd = eprm[_E_LFWD]
    cmin = eprm[_E_LCOS]
    k = 0
    for j in range(obs.shape[0]):
        if not omask[j]:
            continue
        dx = obs[j, 0] - x
        dy = obs[j, 1] - y
        if dx * dx + dy * dy > r2:
            continue
        lx = c * dx + s * dy
        ly = -s * dx + c * dy
        ex = lx - fwd
        if ex < cmin * math.sqrt(ex * ex + ly * ly):
            continue
        buf[k, 0] = lx
        buf[k, 1] = ly
        bmask[k] = True
        k += 1
    return k


@nb.njit(cache=True)
def _rollout(clear, ox, oy, res, eprm, prm, pts, obs, omask, buf, bmask, sc, points, arclen, hi,
             p, x, y, th, v, d, wx, wy, steps, follow):
    """Roll the noise-free RMP and bicycle model forward for ``steps``
    periods (Heun steps, as the vehicle). With ``follow`` the waypoint is
    the expert's A* waypoint, re-selected every ``_RESELECT`` periods from
    the predicted pose (as the expert will); otherwise the fixed world
    point (wx, wy). Returns (periods driven before a predicted collision,
    or ``steps``; period at which the goal came within ``reach_m``, or -1;
    progress index; final x, y, theta, v, steer)."""
    dlim = prm[_P_DLIM]
    vmin = prm[_P_VMIN]
    vmax = prm[_P_VMAX]
    dt = eprm[_E_DT]
    body = eprm[_E_BODY]
    reach2 = eprm[_E_REACH] ** 2
    imminent = int(eprm[_E_IMM])
    rescan = int(eprm[_E_RESCAN]) if sc[4].shape[0] == obs.shape[0] else 0
    tmax = eprm[_E_OBSR] + eprm[_E_LFWD]
    gx = points[hi - 1, 0]
    gy = points[hi - 1, 1]
    for k in range(steps):
        if follow and k % _RESELECT == 0:
            p = _advance(points, arclen, p, hi, x, y, eprm[_E_SEARCH])
            j = _waypoint(clear, ox, oy, res, eprm, points, arclen, p, hi, x, y)
            wx = points[j, 0]
            wy = points[j, 1]
        c = math.cos(th)
        s = math.sin(th)
        lx = c * (wx - x) + s * (wy - y)
        ly = -s * (wx - x) + c * (wy - y)
        if rescan > 0 and k > 0 and k % rescan == 0:
            # Re-render the lidar at the predicted pose (hits within the
            # obstacle range only), as the car will see it there.
            faces, cstart, cfaces, sgrid, beams, wobs, wmask = sc
            lo_x = x + eprm[_E_LFWD] * c
            lo_y = y + eprm[_E_LFWD] * s
            for j in range(beams.shape[0]):
                a = th + beams[j]
                ca = math.cos(a)
                sa = math.sin(a)
                t, _, _ = cast(faces, cstart, cfaces, sgrid, lo_x, lo_y, ca, sa, tmax)
                wmask[j] = t <= tmax
                wobs[j, 0] = lo_x + t * ca if wmask[j] else 0.0
                wobs[j, 1] = lo_y + t * sa if wmask[j] else 0.0
            obs = wobs
            omask = wmask
        n_obs = _local_obstacles(obs, omask, eprm, x, y, c, s, buf, bmask)
        a, sg = rmp_car_controls(v, d, lx, ly, buf[:n_obs], bmask[:n_obs], prm, pts)
        k0 = _deriv(th, v, d, a, sg, prm)
        ta = th + dt * k0[2]
        va = v + dt * k0[3]
        da = d + dt * k0[4]
        ka = _deriv(ta, va, da, a, sg, prm)
        x = x + 0.5 * dt * (k0[0] + ka[0])
        y = y + 0.5 * dt * (k0[1] + ka[1])
        th = th + 0.5 * dt * (k0[2] + ka[2])
        v = min(max(v + 0.5 * dt * (k0[3] + ka[3]), vmin), vmax)
        d = min(max(d + 0.5 * dt * (k0[4] + ka[4]), -dlim), dlim)
        if not _body_clear(clear, ox, oy, res, body, pts, x, y, math.cos(th), math.sin(th)):
            if v < 0.0 or k < imminent:
                return k, -1, p, x, y, th, v, d
            # A wall met driving forward later on: the lidar will see it by
            # then (the prediction only knows the current scan) and the
            # RMP avoids it; the prediction ends here.
            return steps, -1, p, x, y, th, v, d
        if (x - gx) ** 2 + (y - gy) ** 2 < reach2:
            return k + 1, k + 1, p, x, y, th, v, d
    return steps, -1, p, x, y, th, v, d


#: Outcome classes of a predicted drive, best last.
_COLLIDES, _STALLS, _PASSES = 0, 1, 2


@nb.njit(cache=True, inline="always")
def _rank(cls, value):
    """Scalar order of predicted outcomes: class first, then the value."""
    return 1000.0 * cls + value


@nb.njit(cache=True)
def _follow(clear, ox, oy, res, eprm, prm, pts, obs, omask, buf, bmask, sc, points, arclen, lo,
            hi, p, x, y, th, v, d, steps, s_ref, t0):
    """Predicted path following for ``steps`` periods from state (x, y, th,
    v, d) with progress index p, starting ``t0`` periods from now. Returns
    the rank (:func:`_rank`) of the outcome: _PASSES when the goal is
    reached (value 200 minus the arrival time in s) or the drive is
    collision-free with at least ``min_progress_m`` of path progress, except
    within ``final_m`` of the goal where only reaching it passes (value: the
    progress from ``s_ref``); _STALLS when collision-free otherwise;
    _COLLIDES (value: the time to the collision)."""
    n, reached, p1, xe, ye, te, _, _ = _rollout(
        clear, ox, oy, res, eprm, prm, pts, obs, omask, buf, bmask, sc, points, arclen, hi, p,
        x, y, th, v, d, 0.0, 0.0, steps, True)
    dt = eprm[_E_DT]
    if reached >= 0:
        return _rank(_PASSES, 200.0 - (t0 + reached) * dt)
    if n < steps:
        return _rank(_COLLIDES, (t0 + n) * dt)
    s0 = _progress(points, arclen, lo, hi, p, x, y, th, 1.0, eprm[_E_LOOK], eprm[_E_TURN])
    s1 = _progress(points, arclen, lo, hi, p1, xe, ye, te, 1.0, eprm[_E_LOOK], eprm[_E_TURN])
    far = arclen[hi - 1] - arclen[p] > eprm[_E_FINAL]
    if far and s1 - s0 >= eprm[_E_PROG]:
        return _rank(_PASSES, s1 - s_ref)
    return _rank(_STALLS, s1 - s_ref)


@nb.njit(cache=True)
def _leg(clear, ox, oy, res, eprm, prm, pts, obs, omask, buf, bmask, sc, points, arclen, hi, p,
         x, y, th, v, d, angle):
    """A manoeuvre leg: ``manoeuvre_s`` toward the auxiliary waypoint at
    ``manoeuvre_radius_m`` and ``angle`` from the heading th."""
    rad = eprm[_E_MRAD]
    return _rollout(clear, ox, oy, res, eprm, prm, pts, obs, omask, buf, bmask, sc, points, arclen,
                    hi, p, x, y, th, v, d, x + rad * math.cos(th + angle),
                    y + rad * math.sin(th + angle), int(eprm[_E_MSTEPS]), False)


@nb.njit(cache=True)
def _search(clear, ox, oy, res, eprm, prm, pts, obs, omask, buf, bmask, sc, points, arclen, lo, hi,
            p, x, y, th, v, d, s_ref):
    """Best manoeuvre of one or two legs, each toward an auxiliary waypoint
    at an angle ``k 2 pi / manoeuvre_directions`` from the leg's initial
    heading, then predicted path following; all sequences end at the same
    time. Two-leg sequences are tried only when no one-leg sequence passes.
    Returns (rank, first angle, second angle or NaN)."""
    nd = int(eprm[_E_MDIRS])
    m = int(eprm[_E_MSTEPS])
    h = int(eprm[_E_H])
    dt = eprm[_E_DT]
    best = -math.inf
    b1 = 0.0
    b2 = math.nan
    ends = np.zeros((nd, 6))
    for k1 in range(nd):
        a1 = 2.0 * math.pi * k1 / nd
        n1, r1, p1, x1, y1, t1, v1, d1 = _leg(clear, ox, oy, res, eprm, prm, pts, obs, omask,
                                              buf, bmask, sc, points, arclen, hi, p, x, y, th, v, d,
                                              a1)
        ends[k1, 0] = -1.0
        if r1 >= 0:
            val = _rank(_PASSES, 200.0 - r1 * dt)
        elif n1 < m:
            val = _rank(_COLLIDES, n1 * dt)
        else:
            ends[k1, 0] = p1
            ends[k1, 1] = x1
            ends[k1, 2] = y1
            ends[k1, 3] = t1
            ends[k1, 4] = v1
            ends[k1, 5] = d1
            val = _follow(clear, ox, oy, res, eprm, prm, pts, obs, omask, buf, bmask, sc, points,
                         arclen, lo, hi, p1, x1, y1, t1, v1, d1, h + m, s_ref, m)
        if val > best:
            best, b1, b2 = val, a1, math.nan
    if best >= _rank(_PASSES, -100.0):
        return best, b1, b2
    for k1 in range(nd):
        if ends[k1, 0] < 0.0:
            continue
        p1 = int(ends[k1, 0])
        x1, y1, t1, v1, d1 = ends[k1, 1], ends[k1, 2], ends[k1, 3], ends[k1, 4], ends[k1, 5]
        for k2 in range(nd):
            a2 = 2.0 * math.pi * k2 / nd
            n2, r2, p2, x2, y2, t2, v2, d2 = _leg(clear, ox, oy, res, eprm, prm, pts, obs, omask,
                                                  buf, bmask, sc, points, arclen, hi, p1, x1, y1,
                                                  t1, v1, d1, a2)
            if r2 >= 0:
                val = _rank(_PASSES, 200.0 - (m + r2) * dt)
            elif n2 < m:
                val = _rank(_COLLIDES, (m + n2) * dt)
            else:
                val = _follow(clear, ox, oy, res, eprm, prm, pts, obs, omask, buf, bmask, sc, points,
                             arclen, lo, hi, p2, x2, y2, t2, v2, d2, h, s_ref, 2 * m)
            if val > best:
                best, b1, b2 = val, 2.0 * math.pi * k1 / nd, a2
    return best, b1, b2
