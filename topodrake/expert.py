"""The A* expert: waypoints along a planned path, for many cars at once.

Each car has an A* path to its goal (2-D, on the configuration-space grid;
paths of different lengths are packed into one array with offsets). Every
control step the expert

1. advances the car's progress index to the nearest path point a little
   ahead of it;
2. takes the *A* waypoint*: the farthest path point within ``lookahead_m``
   of path length that the car sees along a straight line keeping
   ``sight_margin_m`` more than the car's radius from walls (when the car
   itself stands closer than that to a wall, the bare c-space is used);
3. *predicts* the closed loop of this expert and the car's controller for
   ``horizon_s``: the same RMP (:func:`topodrake.rmp.rmp_car_controls`,
   noise-free), fed with the current lidar hits that lie within
   ``obstacle_range_m`` of the predicted car and inside the lidar's field of
   view, and the bicycle model; the waypoint is re-selected along the way
   as in step 2. The predicted body is checked on the clearance map. The A*
   waypoint is emitted when the prediction is collision-free and makes
   ``min_progress_m`` of progress along the path, or reaches the goal
   (which it must when the goal is closer than ``final_m``);
4. otherwise plans a *manoeuvre*: a leg of ``manoeuvre_s`` toward one of a
   ring of auxiliary waypoints around the car (ahead, to the sides, behind;
   the RMP reverses toward a waypoint behind, swinging its nose toward it),
   followed in the prediction by step 3 from the leg's end. It commits to
   the leg with the most predicted progress (or the earliest arrival at
   the goal), re-checking it against walls every step.

Why predict instead of geometry: the car turns with radius >= 0.425 m, but
the RMP does not drive circles of that radius. It stretches short waypoints
to 2 m, which under-steers near the goal (a goal inside the turning circle
is orbited for ever); it reverses whenever the waypoint is behind, with its
rear control points blind and the lidar covering only 240 deg forward; and
near a wall its nose repulsion can dominate the waypoint (a car parked
facing a wall backs up, whatever the waypoint says). Rolling out the
controller itself on the map -- the expert is an oracle: it has the grid,
its clearance map, the car's pose and the lidar -- catches exactly these
cases (a goal orbited instead of reached, a start facing a wall or with a
wall behind, a doorway entered too fast from a corridor, a furniture corner
cut by a straight sight line, a blind reversal into a wall), and the
manoeuvre search turns them into three-point turns checked against walls
the lidar cannot see. Where the prediction passes, which is nearly
everywhere, the expert is the plain farthest-visible-waypoint expert.

The expert sees the pose and the lidar (as in the Drake diagram), not the
speed and steering: those are estimated for the prediction from the
previous pose held in the car's ``memory`` (columns
:data:`MEMORY_COLUMNS`), which also holds the manoeuvre in progress. Both
executors (the batched engine and the Drake ``ExpertWaypoints``) carry
``progress`` and ``memory`` per car.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from topodrake.rmp import (_P_DLIM, _P_L, _P_VMAX, _P_VMIN, SERIAL_BELOW, RmpConfig, packed_params,
                           rmp_car_controls)
from topodrake.sensing.config import LidarConfig
from topodrake.sensing.raycast import cast
from topodrake.vehicle import VehicleConfig


@dataclass(frozen=True)
class ExpertConfig:
    lookahead_m: float = 5.0
    search_ahead_m: float = 2.0   # how far ahead the progress index may jump per step
    # The line of sight to a waypoint must keep this much more than the car's
    # radius from walls, so the car does not cut door jambs and corners it
    # cannot turn around (its turning radius is 0.43 m).
    sight_margin_m: float = 0.1
    # Closed-loop prediction and manoeuvres (module docstring). predict=False
    # gives the plain farthest-visible-waypoint expert.
    predict: bool = True
    horizon_s: float = 3.0          # prediction horizon of the path-following check
    recheck_s: float = 0.3          # a passed check is trusted this long
    body_margin_m: float = 0.0      # predicted body keeps this beyond the collision clearance
    imminent_s: float = 1.0         # forward collisions predicted later than this are ignored
    rescan_s: float = 0.5           # the prediction re-renders the lidar this often (0: never)
    obstacle_range_m: float = 1.0   # lidar hits farther from the car are left out of the prediction
    turn_cost_m: float = 0.5        # progress lost per radian of heading away from the path
    min_progress_m: float = 0.25    # path progress the prediction must show over the horizon
    final_m: float = 1.0            # closer than this (path length) the goal must be reached
    reach_m: float = 0.2            # predicted "reached" (the success tolerance is 0.27 m)
    manoeuvre_s: float = 1.0        # length of a committed manoeuvre leg
    manoeuvre_radius_m: float = 2.0  # distance of the auxiliary waypoints
    manoeuvre_directions: int = 6   # auxiliary waypoints on a ring around the car
    manoeuvre_gain_m: float = 0.3   # a manoeuvre must beat following by this much progress
    # No check (the plain expert is safe) when the car has this clearance,
    # this speed, its waypoint within this bearing and this much path
    # beyond final_m left.
    open_clearance_m: float = 0.5
    open_speed: float = 0.2
    open_bearing_deg: float = 45.0
    open_goal_m: float = 1.0


#: Per-car memory of the expert (float64 columns).
MEMORY_COLUMNS = ("mode", "steps_left", "aux_x", "aux_y", "next_angle", "prev_x", "prev_y",
                  "prev_theta", "steer_estimate", "trusted_steps")
MEMORY_SIZE = len(MEMORY_COLUMNS)
_M_MODE, _M_LEFT, _M_AX, _M_AY, _M_NEXT, _M_PX, _M_PY, _M_PT, _M_STEER, _M_TRUST = \
    range(MEMORY_SIZE)


def initial_memory(poses: np.ndarray) -> np.ndarray:
    """(N, MEMORY_SIZE) expert memory of cars at rest at ``poses`` (N, 3)."""
    poses = np.asarray(poses, np.float64).reshape(-1, 3)
    mem = np.zeros((len(poses), MEMORY_SIZE))
    mem[:, _M_PX:_M_PT + 1] = poses
    mem[:, _M_NEXT] = np.nan
    return mem


@dataclass
class PackedPaths:
    """Paths (K_i, 2) packed as ``points`` with ``offsets`` (N + 1,) and arc length."""

    points: np.ndarray
    offsets: np.ndarray
    arclen: np.ndarray

    @classmethod
    def pack(cls, paths: list[np.ndarray]) -> "PackedPaths":
        offsets = np.zeros(len(paths) + 1, np.int64)
        offsets[1:] = np.cumsum([len(p) for p in paths])
        points = np.ascontiguousarray(np.concatenate(paths), np.float64)
        arclen = np.concatenate([np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
                                 for p in paths])
        return cls(points, offsets, arclen)

    def goals(self) -> np.ndarray:
        return self.points[self.offsets[1:] - 1]


# Layout of the expert parameter vector.
_E_LOOK, _E_SEARCH, _E_SIGHT, _E_CSPACE, _E_H, _E_TRUST, _E_BODY, _E_OBSR, _E_PROG, \
    _E_FINAL, _E_REACH, _E_MSTEPS, _E_MRAD, _E_MDIRS, _E_DT, _E_PREDICT, _E_LFWD, \
    _E_LCOS, _E_OPEN, _E_VOPEN, _E_COSOPEN, _E_OPENFIN, _E_MGAIN, _E_IMM, _E_TURN, _E_RESCAN, _E_COUNT = range(27)
#: The predicted expert re-selects its waypoint every this many periods.
_RESELECT = 10


# ---------------------------------------------------------------- grid queries

@nb.njit(cache=True, inline="always")
def _clear_at(clear, ox, oy, res, x, y):
    c = int(math.floor((x - ox) / res))
    r = int(math.floor((y - oy) / res))
    h, w = clear.shape
    if r < 0 or c < 0 or r >= h or c >= w:
        return 0.0
    return clear[r, c]


@nb.njit(cache=True)
def segment_clear(clear, ox, oy, res, thr, x0, y0, x1, y1):
    """True when every point of the segment has grid clearance > ``thr``.

    Sphere tracing on the clearance map: from a sample with clearance ``c``
    the next ``c - thr - sqrt(2) res`` metres cannot drop below ``thr`` (the
    map is 1-Lipschitz between cell centres), so open space is crossed in a
    few lookups; the step never falls below half a cell."""
    dx = x1 - x0
    dy = y1 - y0
    length = math.sqrt(dx * dx + dy * dy)
    slack = 1.4143 * res
    s = 0.0
    while True:
        f = s / length if length > 0.0 else 0.0
        c = _clear_at(clear, ox, oy, res, x0 + f * dx, y0 + f * dy)
        if c <= thr:
            return False
        if s >= length:
            return True
        s = min(s + max(c - thr - slack, 0.5 * res), length)


@nb.njit(cache=True, inline="always")
def _body_clear(clear, ox, oy, res, thr, pts, x, y, c, s):
    for i in range(pts.shape[0]):
        bx = x + c * pts[i, 0] - s * pts[i, 1]
        by = y + s * pts[i, 0] + c * pts[i, 1]
        if _clear_at(clear, ox, oy, res, bx, by) <= thr:
            return False
    return True


# ---------------------------------------------------------------- path queries

@nb.njit(cache=True)
def _advance(points, arclen, p, hi, px, py, search_ahead):
    """Index of the nearest path point within ``search_ahead`` ahead of ``p``."""
    best = p
    best_d = math.inf
    j = p
    while j < hi and arclen[j] - arclen[p] <= search_ahead:
        d = (points[j, 0] - px) ** 2 + (points[j, 1] - py) ** 2
        if d < best_d:
            best_d = d
            best = j
        j += 1
    return best


@nb.njit(cache=True)
def _farthest_visible(clear, ox, oy, res, thr, points, arclen, best, hi, px, py, lookahead):
    """Farthest path point after ``best`` within ``lookahead`` of path length
    with a clear line of sight; points are tried ~0.2 m apart, then one by
    one back from the first blocked one. The point at the lookahead limit
    is tried first: in open space and corridors it is the answer."""
    jmax = best
    while jmax + 1 < hi and arclen[jmax + 1] - arclen[best] <= lookahead:
        jmax += 1
    if jmax > best and segment_clear(clear, ox, oy, res, thr, px, py,
                                     points[jmax, 0], points[jmax, 1]):
        return jmax
    wp = best
    stride = 4
    j = best + stride
    while True:
        if j >= hi:
            j = hi - 1
        if j <= wp or arclen[j] - arclen[best] > lookahead:
            break
        if segment_clear(clear, ox, oy, res, thr, px, py, points[j, 0], points[j, 1]):
            wp = j
            if j == hi - 1:
                break
            j += stride
            continue
        for jj in range(wp + 1, j):
            if not segment_clear(clear, ox, oy, res, thr, px, py, points[jj, 0], points[jj, 1]):
                break
            wp = jj
        break
    # Close the gap to the lookahead limit one point at a time.
    j = wp + 1
    while j < hi and arclen[j] - arclen[best] <= lookahead and j - wp <= stride:
        if not segment_clear(clear, ox, oy, res, thr, px, py, points[j, 0], points[j, 1]):
            break
        wp = j
        j += 1
    return wp


@nb.njit(cache=True)
def _waypoint(clear, ox, oy, res, eprm, points, arclen, best, hi, x, y):
    """The A* waypoint: the farthest visible path point with the sight
    margin; when none is visible with it (the car stands closer than the
    margin to a wall), the farthest visible in the bare configuration space."""
    wp = _farthest_visible(clear, ox, oy, res, eprm[_E_SIGHT], points, arclen, best, hi, x, y,
                           eprm[_E_LOOK])
    if wp == best and best < hi - 1:
        wp = _farthest_visible(clear, ox, oy, res, eprm[_E_CSPACE], points, arclen, best, hi,
                               x, y, eprm[_E_LOOK])
    return wp


@nb.njit(cache=True)
def _progress(points, arclen, lo, hi, p, x, y, th, back, ahead, turn):
    """Path progress of the pose (x, y, th): the arc length of the nearest
    path point within [s_p - back, s_p + ahead], minus the distance to it
    (leaving the path costs as much as going back along it), minus
    ``turn`` times the angle between the heading and the bearing of the
    path point 1 m further on (a car turns with a radius: facing away from
    the path costs about a U-turn's length)."""
    sp = arclen[p]
    j = p
    while j > lo and arclen[j - 1] >= sp - back:
        j -= 1
    best_d = math.inf
    best = p
    while j < hi and arclen[j] <= sp + ahead:
        d = (points[j, 0] - x) ** 2 + (points[j, 1] - y) ** 2
        if d < best_d:
            best_d = d
            best = j
        j += 1
    value = arclen[best] - math.sqrt(best_d)
    j = best
    while j < hi - 1 and arclen[j] < arclen[best] + 1.0:
        j += 1
    bx = points[j, 0] - x
    by = points[j, 1] - y
    if turn > 0.0 and bx * bx + by * by > 0.09:
        err = th - math.atan2(by, bx)
        err = abs((err + math.pi) % (2.0 * math.pi) - math.pi)
        value -= turn * err
    return value


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


@nb.njit(cache=False)
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


@nb.njit(cache=False)
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


@nb.njit(cache=False)
def _leg(clear, ox, oy, res, eprm, prm, pts, obs, omask, buf, bmask, sc, points, arclen, hi, p,
         x, y, th, v, d, angle):
    """A manoeuvre leg: ``manoeuvre_s`` toward the auxiliary waypoint at
    ``manoeuvre_radius_m`` and ``angle`` from the heading th."""
    rad = eprm[_E_MRAD]
    return _rollout(clear, ox, oy, res, eprm, prm, pts, obs, omask, buf, bmask, sc, points, arclen,
                    hi, p, x, y, th, v, d, x + rad * math.cos(th + angle),
                    y + rad * math.sin(th + angle), int(eprm[_E_MSTEPS]), False)


@nb.njit(cache=False)
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


@nb.njit(cache=False)
def _expert_car(i, clear, ox, oy, res, points, offsets, arclen, cars, progress, memory,
                poses, has_heading, obs_all, omask_all, eprm, prm, pts, buf, bmask, sc,
                out_wp, out_progress, stats):
    """The expert's waypoint for row ``i`` (car ``cars[i]``); ``buf``,
    ``bmask`` and ``sc`` are the row's scratch space, ``stats`` its counters."""
    L = prm[_P_L]
    dlim = prm[_P_DLIM]
    dt = eprm[_E_DT]
    horizon = int(eprm[_E_H])
    msteps = int(eprm[_E_MSTEPS])
    rad = eprm[_E_MRAD]
    car = cars[i]
    lo = offsets[car]
    hi = offsets[car + 1]
    x = poses[i, 0]
    y = poses[i, 1]
    p = max(lo, min(progress[car], hi - 1))
    best = _advance(points, arclen, p, hi, x, y, eprm[_E_SEARCH])
    out_progress[i] = best
    wp = _waypoint(clear, ox, oy, res, eprm, points, arclen, best, hi, x, y)
    wx = points[wp, 0]
    wy = points[wp, 1]
    out_wp[i, 0] = wx
    out_wp[i, 1] = wy
    if not has_heading or eprm[_E_PREDICT] == 0.0:
        return
    obs = obs_all[i]
    omask = omask_all[i]
    th = poses[i, 2]
    mem = memory[car]
    # Speed and steering estimated from the previous pose.
    dx = x - mem[_M_PX]
    dy = y - mem[_M_PY]
    c = math.cos(th)
    sn = math.sin(th)
    tm = 0.5 * (th + mem[_M_PT])
    ds = dx * math.cos(tm) + dy * math.sin(tm)
    v = ds / dt
    d = mem[_M_STEER]
    if abs(ds) > 0.005:
        d = min(max(math.atan(L * (th - mem[_M_PT]) / ds), -dlim), dlim)
    mem[_M_PX] = x
    mem[_M_PY] = y
    mem[_M_PT] = th
    mem[_M_STEER] = d
    # A committed manoeuvre returns while its legs stay collision-free.
    if mem[_M_MODE] == 1.0:
        if mem[_M_LEFT] <= 0 and not math.isnan(mem[_M_NEXT]):
            mem[_M_AX] = x + rad * math.cos(th + mem[_M_NEXT])
            mem[_M_AY] = y + rad * math.sin(th + mem[_M_NEXT])
            mem[_M_NEXT] = math.nan
            mem[_M_LEFT] = msteps
        left = int(mem[_M_LEFT])
        if left > 0:
            n, _, _, _, _, _, _, _ = _rollout(clear, ox, oy, res, eprm, prm, pts, obs, omask,
                                              buf, bmask, sc, points, arclen, hi, best, x, y, th,
                                              v, d, mem[_M_AX], mem[_M_AY], left, False)
            if n == left:
                mem[_M_LEFT] = left - 1
                out_wp[i, 0] = mem[_M_AX]
                out_wp[i, 1] = mem[_M_AY]
                return
    mem[_M_MODE] = 0.0
    mem[_M_LEFT] = 0.0
    mem[_M_NEXT] = math.nan
    if mem[_M_TRUST] > 0:
        mem[_M_TRUST] -= 1
        return
    # The check is needed only where the plain expert can fail: near
    # walls, when slow, when the waypoint is not ahead, near the goal.
    lx = c * (wx - x) + sn * (wy - y)
    ly = -sn * (wx - x) + c * (wy - y)
    if (_clear_at(clear, ox, oy, res, x, y) > eprm[_E_OPEN]
            and v > eprm[_E_VOPEN]
            and lx > eprm[_E_COSOPEN] * math.sqrt(lx * lx + ly * ly)
            and arclen[hi - 1] - arclen[best] > eprm[_E_FINAL] + eprm[_E_OPENFIN]):
        return
    stats[0] += 1
    s_ref = _progress(points, arclen, lo, hi, best, x, y, th, 1.0, eprm[_E_LOOK],
                      eprm[_E_TURN])
    follow = _follow(clear, ox, oy, res, eprm, prm, pts, obs, omask, buf, bmask, sc,
                     points, arclen, lo, hi, best, x, y, th, v, d, horizon, s_ref, 0)
    if follow >= _rank(_PASSES, -100.0):
        mem[_M_TRUST] = eprm[_E_TRUST]
        return
    # Compare with the manoeuvres over their full length.
    follow = _follow(clear, ox, oy, res, eprm, prm, pts, obs, omask, buf, bmask, sc,
                     points, arclen, lo, hi, best, x, y, th, v, d,
                     horizon + 2 * msteps, s_ref, 0)
    stats[1] += 1
    rank, a1, a2 = _search(clear, ox, oy, res, eprm, prm, pts, obs, omask, buf, bmask, sc,
                           points, arclen, lo, hi, best, x, y, th, v, d, s_ref)
    if rank > follow + eprm[_E_MGAIN]:
        stats[2] += 1
        mem[_M_MODE] = 1.0
        mem[_M_LEFT] = msteps - 1
        mem[_M_AX] = x + rad * math.cos(th + a1)
        mem[_M_AY] = y + rad * math.sin(th + a1)
        mem[_M_NEXT] = a2
        out_wp[i, 0] = mem[_M_AX]
        out_wp[i, 1] = mem[_M_AY]
    else:
        # No manoeuvre beats following: follow a little before searching again.
        mem[_M_TRUST] = eprm[_E_TRUST]


@nb.njit(cache=False)
def _expert(clear, ox, oy, res, points, offsets, arclen, cars, progress, memory,
            poses, has_heading, obs_all, omask_all, faces, cstart, cfaces, sgrid, beams,
            eprm, prm, pts, out_wp, out_progress, stats):
    buf = np.zeros((obs_all.shape[1], 2))
    bmask = np.zeros(obs_all.shape[1], np.bool_)
    sc = (faces, cstart, cfaces, sgrid, beams, np.zeros((beams.shape[0], 2)),
          np.zeros(beams.shape[0], np.bool_))
    for i in range(poses.shape[0]):
        _expert_car(i, clear, ox, oy, res, points, offsets, arclen, cars, progress, memory,
                    poses, has_heading, obs_all, omask_all, eprm, prm, pts, buf, bmask, sc,
                    out_wp, out_progress, stats)


@nb.njit(cache=False, parallel=True)
def _expert_parallel(clear, ox, oy, res, points, offsets, arclen, cars, progress, memory,
                     poses, has_heading, obs_all, omask_all, faces, cstart, cfaces, sgrid, beams,
                     eprm, prm, pts, out_wp, out_progress, stats):
    # Rows are independent (each car owns its memory row), so a parallel
    # loop gives the serial loop's results; scratch space and counters are
    # per row.
    n = poses.shape[0]
    row_stats = np.zeros((n, stats.shape[0]), np.int64)
    for i in nb.prange(n):
        buf = np.zeros((obs_all.shape[1], 2))
        bmask = np.zeros(obs_all.shape[1], np.bool_)
        sc = (faces, cstart, cfaces, sgrid, beams, np.zeros((beams.shape[0], 2)),
              np.zeros(beams.shape[0], np.bool_))
        _expert_car(i, clear, ox, oy, res, points, offsets, arclen, cars, progress, memory,
                    poses, has_heading, obs_all, omask_all, eprm, prm, pts, buf, bmask, sc,
                    out_wp, out_progress, row_stats[i])
    for i in range(n):
        for j in range(stats.shape[0]):
            stats[j] += row_stats[i, j]


def _expert_params(config: ExpertConfig, vehicle: VehicleConfig, lidar: LidarConfig,
                   car_radius: float) -> np.ndarray:
    e = np.zeros(_E_COUNT)
    e[_E_LOOK] = config.lookahead_m
    e[_E_SEARCH] = config.search_ahead_m
    e[_E_SIGHT] = car_radius + config.sight_margin_m
    e[_E_CSPACE] = car_radius
    e[_E_H] = max(1, round(config.horizon_s / vehicle.dt))
    e[_E_TRUST] = max(0, round(config.recheck_s / vehicle.dt))
    e[_E_BODY] = vehicle.collision_clearance + config.body_margin_m
    e[_E_OBSR] = config.obstacle_range_m
    e[_E_PROG] = config.min_progress_m
    e[_E_FINAL] = config.final_m
    e[_E_REACH] = config.reach_m
    e[_E_MSTEPS] = max(1, round(config.manoeuvre_s / vehicle.dt))
    e[_E_MRAD] = config.manoeuvre_radius_m
    e[_E_MDIRS] = config.manoeuvre_directions
    e[_E_DT] = vehicle.dt
    e[_E_PREDICT] = float(config.predict)
    e[_E_LFWD] = lidar.forward_m
    e[_E_LCOS] = math.cos(0.5 * math.radians(min(lidar.fov_deg, 360.0)))
    e[_E_OPEN] = config.open_clearance_m
    e[_E_VOPEN] = config.open_speed
    e[_E_COSOPEN] = math.cos(math.radians(config.open_bearing_deg))
    e[_E_OPENFIN] = config.open_goal_m
    e[_E_MGAIN] = config.manoeuvre_gain_m
    e[_E_IMM] = round(config.imminent_s / vehicle.dt)
    e[_E_TURN] = config.turn_cost_m
    e[_E_RESCAN] = max(0, round(config.rescan_s / vehicle.dt))
    return e


def lidar_world_points(poses: np.ndarray, ranges: np.ndarray,
                       lidar: LidarConfig) -> tuple[np.ndarray, np.ndarray]:
    """World hit points (N, B, 2) and hit mask (N, B) of scans ``ranges``
    (N, B) taken at ``poses`` (N, 3)."""
    poses = np.asarray(poses, np.float64).reshape(-1, 3)
    ranges = np.asarray(ranges, np.float64).reshape(len(poses), -1)
    hit = np.isfinite(ranges)
    r = np.where(hit, ranges, 0.0)
    ang = poses[:, 2:3] + lidar.beam_angles()[None]
    ox = poses[:, 0:1] + lidar.forward_m * np.cos(poses[:, 2:3])
    oy = poses[:, 1:2] + lidar.forward_m * np.sin(poses[:, 2:3])
    pts = np.stack([ox + r * np.cos(ang), oy + r * np.sin(ang)], axis=-1)
    return np.ascontiguousarray(pts), np.ascontiguousarray(hit)


def expert_waypoints(grid, paths: PackedPaths, progress: np.ndarray, poses: np.ndarray,
                     config: ExpertConfig = ExpertConfig(),
                     cars: np.ndarray | None = None,
                     memory: np.ndarray | None = None,
                     ranges: np.ndarray | None = None,
                     lidar: LidarConfig | None = None,
                     scene=None,
                     rmp: RmpConfig | None = None,
                     vehicle: VehicleConfig | None = None) -> tuple[np.ndarray, np.ndarray]:
    """World-frame waypoints (M, 2) and updated progress (M,) for ``cars`` (M,)
    (default: all), whose poses (M, 3) are given. ``progress`` (N,) holds
    absolute indices into ``paths.points``; start each car at
    ``paths.offsets[:-1]``. ``memory`` (N, MEMORY_SIZE), from
    :func:`initial_memory` at the start poses, is updated in place for
    ``cars``. ``ranges`` (M, B) are the cars' current lidar scans (with
    ``lidar`` their config); ``rmp`` and ``vehicle`` are the controller
    and car the prediction models (defaults: the default configs).

    With poses (M, 2) (positions only) or without ``memory`` the expert
    cannot predict: it returns the plain A* waypoint (farthest visible path
    point), as used for labels."""
    poses = np.asarray(poses, np.float64)
    n = len(poses)
    cars = np.arange(n) if cars is None else np.asarray(cars, np.int64)
    has_heading = poses.ndim == 2 and poses.shape[1] >= 3 and memory is not None
    vehicle = vehicle or VehicleConfig()
    lidar = lidar or LidarConfig()
    key = ("clearance-f8",)
    clear = grid._cache.get(key)
    if clear is None:
        clear = grid._cache[key] = np.ascontiguousarray(np.minimum(grid.clearance, 1e3), np.float64)
    prm, pts = packed_params(rmp or _DEFAULT_RMP, vehicle)
    eprm = _expert_params(config, vehicle, lidar, grid.car_radius)
    if memory is None:
        memory = np.zeros((len(paths.offsets) - 1, MEMORY_SIZE))
    p3 = np.zeros((n, 3))
    p3[:, :min(3, poses.shape[1])] = poses[:, :3]
    if has_heading and ranges is not None:
        obs, omask = lidar_world_points(p3, ranges, lidar)
    else:
        obs, omask = np.zeros((n, 0, 2)), np.zeros((n, 0), np.bool_)
    if scene is not None and ranges is not None:
        faces, cstart, cfaces, sgrid = scene.faces, scene.cell_start, scene.cell_faces, scene.grid
        beams = np.ascontiguousarray(lidar.beam_angles(), np.float64)
    else:
        faces, cstart, cfaces, sgrid = _NO_SCENE
        beams = np.zeros(0)
    wp = np.empty((n, 2))
    prog = np.empty(n, np.int64)
    kernel = _expert if n < SERIAL_BELOW else _expert_parallel
    kernel(clear, grid.origin[0], grid.origin[1], grid.resolution,
            paths.points, paths.offsets, paths.arclen, cars, np.asarray(progress, np.int64),
            memory, p3, has_heading, obs, omask, faces, cstart, cfaces, sgrid, beams,
            eprm, prm, pts, wp, prog, STATS)
    return wp, prog


_DEFAULT_RMP = RmpConfig()
_NO_SCENE = (np.zeros((0, 8)), np.zeros(1, np.int32), np.zeros(0, np.int32), np.zeros(6))
#: Running counts of (closed-loop checks, manoeuvre searches, manoeuvres
#: started), for diagnostics; reset it with ``STATS[:] = 0``.
STATS = np.zeros(3, np.int64)
PSTATS = np.zeros(2, np.int64)
