"""Grid and path queries of the expert (compiled): clearance look-ups, line
of sight, progress along the path and the farthest visible waypoint."""

from __future__ import annotations

import math

import numba as nb

from topodrake.expert.config import _E_CSPACE, _E_LOOK, _E_SIGHT


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
