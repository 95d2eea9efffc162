"""Manoeuvres on the map the car has sensed: the expert's closed-loop check
and manoeuvre search (:mod:`topodrake.expert`), run toward the follower's
waypoint.

Each car keeps its recent lidar scans in its odometry frame, placed by the
odometry pose they were taken at; the expert's kernel runs on a clearance
grid built from them, with the "path" a ray from the car through the
follower's waypoint. Where the prediction passes, the waypoint goes to the
RMP unchanged; during a manoeuvre (a three-point turn) the leg's auxiliary
waypoint does. Neighbouring beams' hits that lie close are joined into wall
segments. Behind the start, where the car has seen nothing, the walls its
first scan sees beside it go on (``blind_extend_m``) and the blind cone
counts as walled (``blind_back_m``). A waypoint whose straight line from
the car crosses a seen wall is driven along A* on the sensed grid
(``detour``). Reasons and measured effects: docs/follower.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import distance_transform_edt

from topodrake.errors import TopodrakeError
from topodrake.expert import ExpertConfig, PackedPaths, expert_waypoints, initial_memory
from topodrake.expert.config import _M_LEFT, _M_MODE, _M_PT, _M_PX, _M_PY, _M_STEER, _M_TRUST
from topodrake.expert.kernel import lidar_world_points
from topodrake.rmp import RmpConfig
from topodrake.sensing.config import LidarConfig
from topodrake.vehicle import VehicleConfig
from topodrake.world.astar import astar
from topodrake.world.grid import CAR_RADIUS, OccupancyGrid


@dataclass
class ManoeuvreConfig:
    """The sensed map and the prediction (lengths in m)."""

    scans: int = 30               # scans kept per car ...
    every: int = 3                # ... one every this many periods
    half_m: float = 3.5           # the local grid reaches this far from the car each way
    resolution_m: float = 0.05
    join_m: float = 0.3           # neighbouring beams' hits closer than this are one wall
    ray_m: float = 3.0            # the predicted "path" runs this far through the waypoint
    blind_extend_m: float | None = 1.0  # the walls the first scan sees at the edges of its
                                  # view (within blind_near_m) go on this far into the blind
                                  # cone behind the start (None: off) ...
    blind_near_m: float = 1.0
    blind_until_m: float = 1.0    # ... until the car is this far from its start or has turned
                                  # past the lidar's blind half-angle
    blind_back_m: float | None = 0.6  # the blind cone counts as walled this far from the start
                                  # (dropped with the start walls; None: open)
    detour: bool = True           # a waypoint behind a seen wall is driven along A* on the grid
    detour_reach_m: float = 1.0   # ... toward its farthest point in sight within this (or the
                                  # waypoint's own distance, if farther)
    expert: ExpertConfig = field(default_factory=ExpertConfig)


@dataclass
class LocalGrid:
    """A clearance grid in the shape :func:`expert_waypoints` reads."""

    clearance: np.ndarray
    origin: tuple[float, float]
    resolution: float
    car_radius: float = CAR_RADIUS
    _cache: dict = field(default_factory=dict)


def scan_segments(points: np.ndarray, mask: np.ndarray, join_m: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pair of neighbouring beams of scans (..., B, 2) with ``mask``:
    the segment's ends (..., B-1, 2), (..., B-1, 2) and whether it is a
    wall (both beams hit, closer than ``join_m``)."""
    a, b = points[..., :-1, :], points[..., 1:, :]
    ok = mask[..., :-1] & mask[..., 1:] & (np.linalg.norm(b - a, axis=-1) < join_m)
    return a, b, ok


def wall_segments(points: np.ndarray, mask: np.ndarray, join_m: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The ends (P, 2), (P, 2) of the wall segments between neighbouring
    beams' hits of scans (S, B, 2) with ``mask`` that lie closer than ``join_m``."""
    a, b, ok = scan_segments(points, mask, join_m)
    return a[ok], b[ok]


def segments_crossed(a: np.ndarray, b: np.ndarray, ok: np.ndarray, start: np.ndarray,
                     end: np.ndarray) -> np.ndarray:
    """For M lines ``start`` -> ``end`` (M, 2), whether each crosses one of
    its own segments ``a`` -> ``b`` (M, K, 2) where ``ok`` (M, K)."""
    d = (end - start)[:, None, :]
    e = b - a
    den = d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0]
    w = a - start[:, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[..., 0] * e[..., 1] - w[..., 1] * e[..., 0]) / den
        u = (w[..., 0] * d[..., 1] - w[..., 1] * d[..., 0]) / den
    return np.any(ok & (np.abs(den) > 1e-12) & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1),
                  axis=1)


def wall_points(points: np.ndarray, mask: np.ndarray, join_m: float, step_m: float) -> np.ndarray:
    """Hit points (S, B, 2) of S scans with their mask, and points every
    ``step_m`` along the segment between neighbouring beams' hits that lie
    closer than ``join_m``: (P, 2)."""
    return _along_walls(points[mask], *wall_segments(points, mask, join_m), join_m, step_m)


def _along_walls(hits: np.ndarray, a: np.ndarray, b: np.ndarray, join_m: float, step_m: float
                 ) -> np.ndarray:
    m = max(2, int(np.ceil(join_m / step_m)) + 1)
    t = np.linspace(0.0, 1.0, m)[None, :, None]
    return np.concatenate([hits, (a[:, None] + t * (b - a)[:, None]).reshape(-1, 2)])


def local_grid(points: np.ndarray, centre: np.ndarray, half_m: float, resolution_m: float
               ) -> LocalGrid:
    """Clearance (m) to the nearest of ``points`` (P, 2) on a square grid
    around ``centre``; outside the grid counts as a wall (the kernel's rule)."""
    n = int(np.ceil(2 * half_m / resolution_m))
    ox, oy = float(centre[0] - half_m), float(centre[1] - half_m)
    occ = np.zeros((n, n), bool)
    c = np.floor((points[:, 0] - ox) / resolution_m).astype(np.int64)
    r = np.floor((points[:, 1] - oy) / resolution_m).astype(np.int64)
    inside = (c >= 0) & (c < n) & (r >= 0) & (r < n)
    occ[r[inside], c[inside]] = True
    clear = distance_transform_edt(~occ) * resolution_m if occ.any() else np.full((n, n), 1e3)
    return LocalGrid(np.ascontiguousarray(clear, np.float64), (ox, oy), resolution_m)


def edge_walls(poses: np.ndarray, ranges: np.ndarray, lidar: LidarConfig, extend_m: float,
               near_m: float, step_m: float, edge_beams: int = 4) -> list[np.ndarray]:
    """Per scan, points (P, 2) every ``step_m`` that continue the walls seen
    at the two edges of the lidar's field of view ``extend_m`` into the blind
    cone behind the car: where the ``edge_beams`` outermost beams of a side
    all hit within ``near_m``, the line through the outermost and the
    ``edge_beams``-th hit goes on past the outermost one."""
    pts, hit = lidar_world_points(poses, ranges, lidar)
    r = np.where(hit, np.asarray(ranges, np.float64).reshape(hit.shape), np.inf)
    t = np.arange(step_m, extend_m + 1e-9, step_m)
    out = []
    for i in range(len(pts)):
        walls = []
        for edge, inner in ((0, edge_beams - 1), (-1, -edge_beams)):
            side = slice(0, edge_beams) if edge == 0 else slice(-edge_beams, None)
            if not np.all(r[i, side] < near_m):
                continue
            d = pts[i, edge] - pts[i, inner]
            n = float(np.hypot(*d))
            if n > 1e-6:
                walls.append(pts[i, edge] + t[:, None] * (d / n))
        out.append(np.concatenate(walls) if walls else np.zeros((0, 2)))
    return out


def blind_arc(poses: np.ndarray, lidar: LidarConfig, radius_m: float, step_m: float
              ) -> np.ndarray:
    """Points (S, K, 2) every ``step_m`` on the arc ``radius_m`` round each
    pose's position (S, 3) across its lidar's blind cone behind it."""
    half = 0.5 * np.radians(lidar.fov_deg)
    span = 2.0 * np.pi - 2.0 * half
    k = max(2, int(np.ceil(span * radius_m / step_m)) + 1)
    a = poses[:, 2:3] + half + np.linspace(0.0, span, k)[None, :]
    return np.stack([poses[:, 0:1] + radius_m * np.cos(a),
                     poses[:, 1:2] + radius_m * np.sin(a)], axis=-1)


def crosses_walls(points: np.ndarray, mask: np.ndarray, start: np.ndarray, end: np.ndarray,
                  join_m: float) -> bool:
    """Whether the segment ``start`` -> ``end`` crosses a wall segment of
    the scans' hits (S, B, 2) with ``mask`` (:func:`wall_segments`)."""
    a, b, ok = scan_segments(points, mask, join_m)
    return bool(segments_crossed(a.reshape(1, -1, 2), b.reshape(1, -1, 2), ok.reshape(1, -1),
                                 np.asarray(start, np.float64)[None],
                                 np.asarray(end, np.float64)[None])[0])


def detour_path(grid: LocalGrid, start: np.ndarray, goal: np.ndarray, snap_m: float = 0.3
                ) -> np.ndarray | None:
    """A* (K, 2) on the sensed grid from ``start`` to ``goal``, either end
    moved to the nearest free cell within ``snap_m`` where it lies in a
    wall's margin (the path keeps the exact ends); None where none joins them."""
    occ = grid.clearance < 0.5 * grid.resolution
    occ_grid = OccupancyGrid(occ, np.array(grid.origin), grid.resolution, grid.car_radius)
    free = occ_grid.free_space
    ends = []
    for xy in (start, goal):
        rc = occ_grid.to_cell(xy)
        if not occ_grid.in_bounds(rc):
            return None
        if not free[rc[0], rc[1]]:
            r = int(np.ceil(snap_m / grid.resolution))
            lo = np.maximum(rc - r, 0)
            cells = np.argwhere(free[lo[0]:rc[0] + r + 1, lo[1]:rc[1] + r + 1]) + lo
            if not len(cells):
                return None
            centres = occ_grid.to_world(cells)
            dist = np.hypot(*(centres - xy).T)
            if dist.min() > snap_m:
                return None
            ends.append(centres[int(np.argmin(dist))])
        else:
            ends.append(np.asarray(xy, np.float64))
    try:
        path = astar(occ_grid, ends[0], ends[1])
    except TopodrakeError:
        return None
    return np.concatenate([np.asarray(start, np.float64)[None], path,
                           np.asarray(goal, np.float64)[None]])


def detour_waypoint(path: np.ndarray, points: np.ndarray, mask: np.ndarray, join_m: float,
                    reach_m: float) -> np.ndarray:
    """The farthest point of ``path`` (K, 2; from the car) within
    ``reach_m`` of its start whose straight line from the start crosses no
    wall of the scans (:func:`crosses_walls`); the path's first point past
    the start where none does."""
    d = np.hypot(*(path - path[0]).T)
    for k in np.flatnonzero((d <= reach_m) & (d > 1e-6))[::-1]:
        if not crosses_walls(points, mask, path[0], path[k], join_m):
            return path[k]
    return path[min(1, len(path) - 1)]


def ray_path(pose: np.ndarray, waypoint: np.ndarray, ray_m: float, step_m: float = 0.1
             ) -> np.ndarray:
    """Points (K, 2) from the car's position through ``waypoint`` to at least ``ray_m``."""
    d = waypoint - pose[:2]
    length = float(np.hypot(*d))
    if length < 1e-6:
        d, length = np.array([np.cos(pose[2]), np.sin(pose[2])]), 1.0
    total = max(length, ray_m)
    s = np.linspace(0.0, total, max(2, int(np.ceil(total / step_m)) + 1))
    return pose[:2] + s[:, None] * (d / length)


class Manoeuvres:
    """Per-car sensed scans and expert memory for N cars; :meth:`step`
    turns the follower's waypoints into the ones the RMP drives toward."""
    def __init__(self, n: int, starts_odo: np.ndarray, lidar: LidarConfig,
                 config: ManoeuvreConfig | None = None, rmp: RmpConfig | None = None,
                 vehicle: VehicleConfig | None = None):
        self.config = config or ManoeuvreConfig()
        self.lidar, self.rmp, self.vehicle = lidar, rmp or RmpConfig(), vehicle or VehicleConfig()
        s, b = self.config.scans, lidar.beams
        self.points = np.zeros((n, s, b, 2))
        self.mask = np.zeros((n, s, b), bool)
        # each kept scan's wall segments (scan_segments), made once when it is kept
        self.seg_a = np.zeros((n, s, b - 1, 2))
        self.seg_b = np.zeros((n, s, b - 1, 2))
        self.seg_ok = np.zeros((n, s, b - 1), bool)
        self.periods = np.zeros(n, np.int64)
        self.memory = initial_memory(starts_odo)
        self.started = np.zeros(n, np.int64)   # manoeuvres started, per car
        self.starts = np.asarray(starts_odo, np.float64).reshape(-1, 3).copy()
        self.blind: list[np.ndarray] = [np.zeros((0, 2))] * n   # from each car's first scan
        self.blind_on = np.full(n, self.config.blind_extend_m is not None)

    def remember(self, cars: np.ndarray, poses_odo: np.ndarray, ranges: np.ndarray) -> None:
        """Keep every ``every``-th scan of ``cars``, placed at their odometry poses."""
        keep = self.periods[cars] % self.config.every == 0
        if keep.any():
            c = cars[keep]
            pts, hit = lidar_world_points(poses_odo[keep], ranges[keep], self.lidar)
            slot = (self.periods[c] // self.config.every) % self.config.scans
            self.points[c, slot] = pts
            self.mask[c, slot] = hit
            a, b, ok = scan_segments(pts, hit, self.config.join_m)
            self.seg_a[c, slot], self.seg_b[c, slot], self.seg_ok[c, slot] = a, b, ok
        self.periods[cars] += 1

    def step(self, cars: np.ndarray, poses_odo: np.ndarray, waypoints: np.ndarray,
             ranges: np.ndarray) -> np.ndarray:
        """Waypoints (M, 2) for ``cars`` (M,) at odometry poses (M, 3) with
        the follower's waypoints (M, 2; NaN rows pass through) and current
        scans (M, B), all in the odometry frame."""
        cars = np.asarray(cars, np.int64)
        poses_odo = np.asarray(poses_odo, np.float64).reshape(-1, 3)
        cfg = self.config
        first = self.periods[cars] == 0
        self.remember(cars, poses_odo, ranges)
        out = np.array(waypoints, np.float64).reshape(-1, 2)
        if cfg.blind_extend_m is not None and first.any():
            made = edge_walls(poses_odo[first], ranges[first], self.lidar, cfg.blind_extend_m,
                              cfg.blind_near_m, 0.5 * cfg.resolution_m)
            if cfg.blind_back_m is not None:
                arcs = blind_arc(poses_odo[first], self.lidar, cfg.blind_back_m,
                                 0.5 * cfg.resolution_m)
                made = [np.concatenate([w, arc]) for w, arc in zip(made, arcs)]
            for car, walls in zip(cars[first], made):
                self.blind[car] = walls
        blocked = self._blocked(cars, poses_odo, out) if cfg.detour else np.zeros(len(cars), bool)
        skip = self._unchecked(cars, poses_odo, out) & ~blocked
        self._leave_start(cars, poses_odo)
        for i, car in enumerate(cars):
            row = self.memory[car:car + 1]          # a view: the kernel updates it in place
            if skip[i] or not np.isfinite(out[i]).all():
                _note_pose(row[0], poses_odo[i], self.vehicle)
                row[0, _M_TRUST] = max(row[0, _M_TRUST] - 1, 0)
                continue
            ok = self.seg_ok[car]
            walls = _along_walls(self.points[car][self.mask[car]], self.seg_a[car][ok],
                                 self.seg_b[car][ok], cfg.join_m, 0.5 * cfg.resolution_m)
            if self.blind_on[car]:
                walls = np.concatenate([walls, self.blind[car]])
            grid = local_grid(walls, poses_odo[i], cfg.half_m, cfg.resolution_m)
            path = detour_path(grid, poses_odo[i, :2], out[i]) if blocked[i] else None
            paths = PackedPaths.pack([ray_path(poses_odo[i], out[i], cfg.ray_m) if path is None
                                      else path])
            was = row[0, _M_MODE] == 1.0 and row[0, _M_LEFT] > 0
            wp, _ = expert_waypoints(grid, paths, np.zeros(1, np.int64), poses_odo[i:i + 1],
                                     cfg.expert, memory=row, ranges=ranges[i:i + 1],
                                     lidar=self.lidar, rmp=self.rmp, vehicle=self.vehicle)
            if row[0, _M_MODE] == 1.0:
                out[i] = wp[0]
                self.started[car] += int(not was)
            elif path is not None:
                reach = max(float(np.hypot(*(out[i] - poses_odo[i, :2]))), cfg.detour_reach_m)
                out[i] = detour_waypoint(path, self.points[car], self.mask[car], cfg.join_m, reach)
        return out

    def _blocked(self, cars: np.ndarray, poses: np.ndarray, waypoints: np.ndarray) -> np.ndarray:
        """Whether each car's straight line to its waypoint crosses a wall it has seen."""
        out = np.zeros(len(cars), bool)
        live = np.flatnonzero(np.isfinite(waypoints).all(axis=1))
        if len(live):
            c = cars[live]
            k = self.seg_ok.shape[1] * self.seg_ok.shape[2]
            out[live] = segments_crossed(self.seg_a[c].reshape(len(c), k, 2),
                                         self.seg_b[c].reshape(len(c), k, 2),
                                         self.seg_ok[c].reshape(len(c), k),
                                         poses[live, :2], waypoints[live])
        return out

    def _leave_start(self, cars: np.ndarray, poses: np.ndarray) -> None:
        """Drop the start walls of cars that drove ``blind_until_m`` from their
        start or turned past the lidar's blind half-angle: they have seen
        behind the start, or left it."""
        on = self.blind_on[cars]
        if not on.any():
            return
        d = poses - self.starts[cars]
        turned = np.abs(np.angle(np.exp(1j * d[:, 2])))
        half_blind = np.pi - 0.5 * np.radians(self.lidar.fov_deg)
        left = (np.hypot(d[:, 0], d[:, 1]) > self.config.blind_until_m) | (turned > half_blind)
        self.blind_on[cars[on & left]] = False

    def _unchecked(self, cars, poses, waypoints) -> np.ndarray:
        """Cars the kernel would not check this period (M,): no manoeuvre
        under way and a passed check still trusted, or the car in the open
        (clear of what it has seen, moving, its waypoint ahead), as the
        kernel's own test; the grid is built only for the others."""
        e = self.config.expert
        mem = self.memory[cars]
        idle = mem[:, _M_MODE] != 1.0
        trusted = mem[:, _M_TRUST] > 0
        d = self.points[cars] - poses[:, None, None, :2]
        dist = np.where(self.mask[cars], np.hypot(d[..., 0], d[..., 1]), np.inf)
        clear = dist.reshape(len(cars), -1).min(axis=1) - self.config.join_m / 2
        v = _driven(mem, poses) / self.vehicle.dt
        w = waypoints - poses[:, :2]
        ahead = (w[:, 0] * np.cos(poses[:, 2]) + w[:, 1] * np.sin(poses[:, 2])
                 > np.cos(np.radians(e.open_bearing_deg)) * np.hypot(w[:, 0], w[:, 1]))
        opened = (clear > e.open_clearance_m) & (v > e.open_speed) & ahead
        return idle & (trusted | opened)


def _driven(mem: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Distance driven since the expert memory's previous pose, along the
    mean heading, as the kernel estimates it (rows of ``mem`` and ``pose``)."""
    th = 0.5 * (pose[..., 2] + mem[..., _M_PT])
    return (pose[..., 0] - mem[..., _M_PX]) * np.cos(th) + \
        (pose[..., 1] - mem[..., _M_PY]) * np.sin(th)


def _note_pose(mem: np.ndarray, pose: np.ndarray, vehicle: VehicleConfig) -> None:
    """The expert memory's previous pose and steering estimate, updated as
    the kernel does on each call (its speed estimate reads them)."""
    ds = float(_driven(mem, pose))
    if abs(ds) > 0.005:
        mem[_M_STEER] = np.clip(np.arctan(vehicle.wheelbase * (pose[2] - mem[_M_PT]) / ds),
                                -vehicle.steer_limit, vehicle.steer_limit)
    mem[_M_PX], mem[_M_PY], mem[_M_PT] = pose


__all__ = ["Manoeuvres", "ManoeuvreConfig", "LocalGrid", "blind_arc", "crosses_walls",
           "detour_path", "detour_waypoint", "edge_walls", "local_grid", "ray_path",
           "scan_segments", "segments_crossed", "wall_points", "wall_segments"]
