"""The expert's control step for a batch of cars: the per-car kernel, its
serial and parallel loops, and the public :func:`expert_waypoints`."""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from topodrake.expert.config import (ExpertConfig, MEMORY_SIZE, PackedPaths, _E_COSOPEN, _E_DT,
                                     _E_FINAL, _E_H, _E_LOOK, _E_MGAIN, _E_MRAD, _E_MSTEPS,
                                     _E_OPEN, _E_OPENFIN, _E_PREDICT, _E_SEARCH, _E_TRUST,
                                     _E_TURN, _E_VOPEN, _M_AX, _M_AY, _M_LEFT, _M_MODE, _M_NEXT,
                                     _M_PT, _M_PX, _M_PY, _M_STEER, _M_TRUST, _expert_params)
from topodrake.expert.predict import _PASSES, _follow, _rank, _rollout, _search
from topodrake.expert.sight import _advance, _clear_at, _progress, _waypoint
from topodrake.rmp import _P_DLIM, _P_L, SERIAL_BELOW, RmpConfig, packed_params
from topodrake.sensing.config import LidarConfig
from topodrake.vehicle import VehicleConfig


@nb.njit(cache=True)
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


@nb.njit(cache=True)
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


@nb.njit(cache=True, parallel=True)
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
