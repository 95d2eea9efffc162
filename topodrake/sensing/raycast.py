"""Compiled 2-D ray casting against wall faces (numba).

``cast`` returns the ray parameter ``t`` of the first face hit along
``o + t d`` (``d`` need not be unit length: with ``d = forward + x_n right``
``t`` is the camera's z-depth), the face index and the hit position along the
face (0..1). Misses return ``t = inf`` and face -1.

``cast_extra`` goes on with a short list of faces of one ray's own (what
changed in one car's world since it was mapped: boxes, people, a closed
door): a closer hit there returns face ``-2 - j`` for row ``j`` of the list.
Rows whose first coordinate is NaN are padding.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

EPS = 1e-9


@nb.njit(cache=True, fastmath=True, inline="always")
def cast(faces, cell_start, cell_faces, grid, ox, oy, dx, dy, tmax):
    gx0 = grid[0]
    gy0 = grid[1]
    cs = grid[2]
    nx = int(grid[3])
    ny = int(grid[4])
    best_t = math.inf
    best_f = -1
    best_s = 0.0
    fx = (ox - gx0) / cs
    fy = (oy - gy0) / cs
    cx = int(math.floor(fx))
    cy = int(math.floor(fy))
    if dx > 0:
        step_x = 1
        t_dx = cs / dx
        t_x = (cx + 1 - fx) * cs / dx
    elif dx < 0:
        step_x = -1
        t_dx = -cs / dx
        t_x = (fx - cx) * cs / -dx
    else:
        step_x = 0
        t_dx = math.inf
        t_x = math.inf
    if dy > 0:
        step_y = 1
        t_dy = cs / dy
        t_y = (cy + 1 - fy) * cs / dy
    elif dy < 0:
        step_y = -1
        t_dy = -cs / dy
        t_y = (fy - cy) * cs / -dy
    else:
        step_y = 0
        t_dy = math.inf
        t_y = math.inf
    while True:
        t_exit = min(t_x, t_y)
        if 0 <= cx < nx and 0 <= cy < ny:
            c = cy * nx + cx
            for k in range(cell_start[c], cell_start[c + 1]):
                f = cell_faces[k]
                ax = faces[f, 0]
                ay = faces[f, 1]
                ex = faces[f, 2] - ax
                ey = faces[f, 3] - ay
                den = dx * ey - dy * ex
                if abs(den) < EPS:
                    continue
                wx = ax - ox
                wy = ay - oy
                t = (wx * ey - wy * ex) / den
                if t <= 1e-7 or t >= best_t:
                    continue
                s = (wx * dy - wy * dx) / den
                if s < 0.0 or s > 1.0:
                    continue
                best_t = t
                best_f = f
                best_s = s
        elif (cx < 0 and step_x <= 0) or (cx >= nx and step_x >= 0) or \
                (cy < 0 and step_y <= 0) or (cy >= ny and step_y >= 0):
            break
        if best_t <= t_exit or t_exit > tmax:
            break
        if t_x < t_y:
            cx += step_x
            t_x += t_dx
        else:
            cy += step_y
            t_y += t_dy
    if best_t > tmax:
        return math.inf, -1, 0.0
    return best_t, best_f, best_s


@nb.njit(cache=True, fastmath=True, inline="always")
def cast_extra(extra, ox, oy, dx, dy, tmax, best_t, best_f, best_s):
    """``cast``'s hit ``(best_t, best_f, best_s)`` or a closer one among the
    faces ``extra`` (F, 8+) (face ``-2 - j`` for row ``j``), within ``tmax``."""
    for j in range(extra.shape[0]):
        ax = extra[j, 0]
        if ax != ax:
            continue
        ay = extra[j, 1]
        ex = extra[j, 2] - ax
        ey = extra[j, 3] - ay
        den = dx * ey - dy * ex
        if abs(den) < EPS:
            continue
        wx = ax - ox
        wy = ay - oy
        t = (wx * ey - wy * ex) / den
        if t <= 1e-7 or t >= best_t or t > tmax:
            continue
        s = (wx * dy - wy * dx) / den
        if s < 0.0 or s > 1.0:
            continue
        best_t = t
        best_f = -2 - j
        best_s = s
    return best_t, best_f, best_s


@nb.njit(cache=True, fastmath=True)
def _fan_row(faces, cell_start, cell_faces, grid, origins, headings, offsets, tmax, extra, i,
             out):
    for j in range(offsets.shape[0]):
        a = headings[i] + offsets[j]
        dx = math.cos(a)
        dy = math.sin(a)
        t, f, s = cast(faces, cell_start, cell_faces, grid, origins[i, 0], origins[i, 1],
                       dx, dy, tmax)
        if extra.shape[1] > 0:
            t, f, s = cast_extra(extra[i], origins[i, 0], origins[i, 1], dx, dy, tmax, t, f, s)
        out[i, j] = t


@nb.njit(cache=True)
def _fan_serial(faces, cell_start, cell_faces, grid, origins, headings, offsets, tmax, extra,
                out):
    for i in range(origins.shape[0]):
        _fan_row(faces, cell_start, cell_faces, grid, origins, headings, offsets, tmax, extra, i,
                 out)


@nb.njit(cache=True, parallel=True)
def _fan_parallel(faces, cell_start, cell_faces, grid, origins, headings, offsets, tmax, extra,
                  out):
    for i in nb.prange(origins.shape[0]):
        _fan_row(faces, cell_start, cell_faces, grid, origins, headings, offsets, tmax, extra, i,
                 out)


#: Batches smaller than this run on one thread (thread start-up costs more).
SERIAL_BELOW = 8


def extra_faces(extra, n: int) -> np.ndarray:
    """(n, F, 8) float64 per-ray-origin extra faces (``None``: none, F = 0)."""
    if extra is None:
        return np.zeros((n, 0, 8))
    extra = np.ascontiguousarray(extra, np.float64)
    if extra.ndim != 3 or extra.shape[0] != n or extra.shape[2] < 4:
        raise ValueError(f"extra faces must be ({n}, F, 8), got {extra.shape}")
    return extra


def cast_fan(faces, cell_start, cell_faces, grid, origins, headings, offsets, tmax, extra=None):
    """Unit-direction rays: origins (N, 2), headings (N,), offsets (B,) -> (N, B) float32
    distances (``inf`` for no hit within ``tmax``); ``extra`` (N, F, 8): each
    origin's own faces besides the scene's (:func:`cast_extra`)."""
    out = np.empty((origins.shape[0], offsets.shape[0]), np.float32)
    kernel = _fan_serial if origins.shape[0] < SERIAL_BELOW else _fan_parallel
    kernel(faces, cell_start, cell_faces, grid, origins, headings, offsets, tmax,
           extra_faces(extra, origins.shape[0]), out)
    return out


def cast_rays(scene, origins: np.ndarray, directions: np.ndarray, tmax: float = 1e3):
    """Plain batch interface: origins (N, 2), directions (N, 2) -> (t, face, s) arrays."""
    origins = np.ascontiguousarray(origins, np.float64).reshape(-1, 2)
    directions = np.ascontiguousarray(directions, np.float64).reshape(-1, 2)
    return _cast_rays(scene.faces, scene.cell_start, scene.cell_faces, scene.grid,
                      origins, directions, float(tmax))


@nb.njit(cache=True, parallel=True)
def _cast_rays(faces, cell_start, cell_faces, grid, origins, directions, tmax):
    n = origins.shape[0]
    ts = np.empty(n)
    fs = np.empty(n, np.int32)
    ss = np.empty(n)
    for i in nb.prange(n):
        t, f, s = cast(faces, cell_start, cell_faces, grid, origins[i, 0], origins[i, 1],
                       directions[i, 0], directions[i, 1], tmax)
        ts[i] = t
        fs[i] = f
        ss[i] = s
    return ts, fs, ss
