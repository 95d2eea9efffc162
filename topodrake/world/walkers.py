"""People walking near a car's route: moving obstacles for batched simulations.

A planned route drives past people: some walk along it (towards the car or
away from it, a little to one side), some cross it (across the corridor and
back). :class:`Walkers` holds W walkers for each of N cars of a batched
simulation, as discs for collision checks (:meth:`Walkers.discs`) and as
polygons for the camera and the lidar (:meth:`Walkers.faces`). Nothing is
shared between cars: a car's walkers come from its own seed, and stepping
some cars leaves the others as they were.

Each walker walks back and forth on its own *track*, a polyline evenly
spaced in arc length: the car's route shifted sideways (less where the route
passes walls), or a straight line across the route from wall to wall. A step
moves it ``speed * dt`` along its track. It turns back at the track's ends
and where its next position would come closer to a wall than its radius plus
:func:`wall_margin`; it waits where its next position would come within its
radius + :data:`CAR_BODY_M` of the car's centre (people yield to the robot);
at random it stops for 1-3 s or turns back. The random draws are a hash of
the car's seed, its step count and the walker, so they need no shared state.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
from scipy import ndimage

from topodrake.errors import TopodrakeError
from topodrake.world.grid import OccupancyGrid
from topodrake.world.world import World

RADIUS_M = (0.2, 0.25)      # disc radius, uniform
SPEED_MPS = (0.5, 1.4)      # walking speed, uniform
CAR_BODY_M = 0.45           # the car's body around its centre, as walkers see it
STOP_S = (1.0, 3.0)         # length of a stop, uniform
STOP_PER_S = 0.1            # rate of stops while walking
GO_ON_S = 1.0               # walking time after a stop before the next can start
TURN_PER_S = 0.03           # rate of turning back at random while walking
START_CLEAR_M = 2.0         # from the car's start, at creation
KEEP_CLEAR_M = 1.0          # from the route's ends, at creation
OFFSET_M = 0.4              # largest sideways offset of a walker along the route
CROSS_HALF_M = 2.0          # farthest a crossing walker goes to either side
MIN_CROSS_M = 1.0           # shortest crossing track
STEP_M = 0.05               # spacing of track points
_SMOOTH_M = 0.3             # half window smoothing the route's grid steps
_NORMAL_M = 0.5             # half window smoothing the route's direction
_SLACK_M = 0.03             # extra clearance a track keeps where it can
_EPS = 1e-9


def wall_margin(grid: OccupancyGrid) -> float:
    """Clearance (m) a walker keeps beyond its radius: grid clearance is
    measured between cell centres, up to about 1.4 cells more than the true
    distance to a wall, and never less than 0.05 m."""
    return max(0.05, 1.5 * grid.resolution)


@dataclass
class Walkers:
    """W walkers for each of N cars; arrays are (N, W, ...) unless noted.

    Walker ``w`` of car ``i`` walks on ``track[i, w, :track_n[i, w]]``
    (points ``spacing[i, w]`` m apart in arc length, padded with the last
    point) at arc length ``s`` in ``direction`` +1 / -1. ``stop_s`` is what
    is left of a stop (0: walking), ``go_s`` how long it walks on before it
    may stop again; ``waiting`` marks walkers that yielded to their car in
    the last step. ``key`` and ``tick`` (N,) are each car's random stream:
    drawn from its seed, and the steps it took.
    """

    xy: np.ndarray          # (N, W, 2) positions
    heading: np.ndarray     # (N, W) radians of walking direction
    speed: np.ndarray       # (N, W) m/s when walking
    radius: np.ndarray      # (N, W) m
    crossing: np.ndarray    # (N, W) bool: crosses the route, else walks along it
    track: np.ndarray       # (N, W, T, 2)
    track_n: np.ndarray     # (N, W) int
    spacing: np.ndarray     # (N, W) m
    s: np.ndarray           # (N, W) m
    direction: np.ndarray   # (N, W) +1.0 / -1.0
    stop_s: np.ndarray      # (N, W) s
    go_s: np.ndarray        # (N, W) s
    waiting: np.ndarray     # (N, W) bool
    key: np.ndarray         # (N,) uint64
    tick: np.ndarray        # (N,) uint64
    grid: OccupancyGrid     # the world's, shared and read-only
    margin: float           # see wall_margin

    @property
    def stopped(self) -> np.ndarray:
        """(N, W) bool: standing still in the next step (a stop not over yet)."""
        return self.stop_s > _EPS

    @classmethod
    def on_paths(cls, world: World, paths: list[np.ndarray], n: int, seeds: list,
                 car_starts: np.ndarray | None = None) -> Walkers:
        """``n`` walkers near each car's route ``paths[i]`` (K, 2+), drawn
        from ``np.random.default_rng(seeds[i])``: ``n // 2`` cross the route,
        the others walk along it (in random order and direction). Each
        starts with clearance >= radius + :func:`wall_margin`, off the other
        walkers, more than 1 m from the route's ends and more than 2 m from
        ``car_starts[i]`` (N, 2+) where given."""
        paths, seeds = list(paths), list(seeds)
        if len(paths) != len(seeds):
            raise TopodrakeError(f"walkers need one seed per route: {len(paths)} routes, "
                                 f"{len(seeds)} seeds")
        if int(n) != n or n < 0:
            raise TopodrakeError(f"the number of walkers per car must be >= 0, got {n}")
        starts = None
        if car_starts is not None:
            starts = np.asarray(car_starts, np.float64)
            if starts.ndim != 2 or starts.shape[0] != len(paths) or starts.shape[1] < 2 \
                    or not np.all(np.isfinite(starts[:, :2])):
                raise TopodrakeError(f"car_starts must be finite ({len(paths)}, 2+), "
                                     f"got shape {starts.shape}")
        margin = wall_margin(world.grid)
        cars = [_place(world.grid, _route(p, i), int(n), np.random.default_rng(seed),
                       None if starts is None else starts[i, :2], margin, i)
                for i, (p, seed) in enumerate(zip(paths, seeds))]
        return _stack(cars, int(n), world.grid, margin)

    def step(self, dt: float, cars, car_xy: np.ndarray) -> None:
        """Advance the walkers of ``cars`` (indices into N) by ``dt`` s;
        ``car_xy`` (len(cars), 2+) are those cars' centres. A walker that
        would step within its radius + :data:`CAR_BODY_M` of its car, and
        nearer to it than it is, waits (it may still walk away from the car);
        one that would step within its radius + :attr:`margin` of a wall
        turns back instead."""
        dt = float(dt)
        if not (np.isfinite(dt) and dt > 0):
            raise TopodrakeError(f"a walkers' step needs dt > 0, got {dt}")
        cars = np.asarray(cars, np.intp).reshape(-1)
        car_xy = np.asarray(car_xy, np.float64)
        if car_xy.ndim != 2 or car_xy.shape[0] != len(cars) or car_xy.shape[1] < 2:
            raise TopodrakeError(f"car_xy must be ({len(cars)}, 2), got {car_xy.shape}")
        w = self.radius.shape[1]
        if w == 0 or len(cars) == 0:
            self.tick[cars] += np.uint64(1)
            return
        u = _uniform(self.key[cars], self.tick[cars], w, 3)
        self.tick[cars] += np.uint64(1)
        stop, go_on = self.stop_s[cars], self.go_s[cars]
        d, s, radius, xy = self.direction[cars], self.s[cars], self.radius[cars], self.xy[cars]
        walking = stop <= _EPS
        pause = walking & (go_on <= _EPS) & (u[..., 0] < -np.expm1(-STOP_PER_S * dt))
        d = np.where(walking & ~pause & (u[..., 1] < -np.expm1(-TURN_PER_S * dt)), -d, d)
        move = walking & ~pause
        length = self.spacing[cars] * (self.track_n[cars] - 1)
        ahead = s + d * self.speed[cars] * dt
        end = (ahead <= 0.0) | (ahead >= length)
        ahead = np.clip(ahead, 0.0, length)
        nxt, seg = self._at(cars, ahead)
        clear = self.grid.clearance_at(nxt) >= radius + self.margin
        car = car_xy[:, None, :2]
        gap = np.linalg.norm(nxt - car, axis=-1)
        near = (gap < radius + CAR_BODY_M) & (gap < np.linalg.norm(xy - car, axis=-1))
        go = move & clear & ~near
        d = np.where((go & end) | (move & ~clear), -d, d)
        self.s[cars] = np.where(go, ahead, s)
        self.xy[cars] = np.where(go[..., None], nxt, xy)
        self.direction[cars] = d
        self.waiting[cars] = move & clear & near
        pause_s = STOP_S[0] + (STOP_S[1] - STOP_S[0]) * u[..., 2] - dt    # this step's too
        left = np.where(pause, pause_s, np.maximum(stop - dt, 0.0))
        left[left <= _EPS] = 0.0
        self.stop_s[cars] = left
        self.go_s[cars] = np.where((stop > _EPS) & (left == 0.0), GO_ON_S,
                                   np.maximum(go_on - dt * walking, 0.0))
        heading = np.arctan2(d * seg[..., 1], d * seg[..., 0])
        self.heading[cars] = np.where(walking, heading, self.heading[cars])

    def discs(self, cars) -> tuple[np.ndarray, np.ndarray]:
        """Centres (len(cars), W, 2) and radii (len(cars), W) of ``cars``' walkers."""
        cars = np.asarray(cars, np.intp).reshape(-1)
        return self.xy[cars], self.radius[cars]

    def faces(self, cars, sides: int = 8) -> np.ndarray:
        """(len(cars), W * sides, 4) segments ``ax, ay, bx, by``: each walker
        a regular polygon of ``sides`` sides circumscribing its disc (a vertex
        at angle 0), its faces counter-clockwise like
        :meth:`~topodrake.world.walls.Faces.from_walls` (outside to the right
        of a -> b); walker w's faces are rows ``w * sides ..``."""
        if int(sides) != sides or sides < 3:
            raise TopodrakeError(f"a walker's polygon needs >= 3 sides, got {sides}")
        xy, r = self.discs(cars)
        angle = 2.0 * np.pi * np.arange(sides) / sides
        unit = np.stack([np.cos(angle), np.sin(angle)], axis=-1)
        a = xy[:, :, None] + (r / np.cos(np.pi / sides))[..., None, None] * unit
        b = np.roll(a, -1, axis=2)
        return np.concatenate([a, b], axis=-1).reshape(len(xy), -1, 4)

    def take(self, cars) -> Walkers:
        """A copy of the walkers of ``cars`` (indices into N)."""
        cars = np.asarray(cars, np.intp).reshape(-1)
        kept = {f.name: getattr(self, f.name)[cars].copy() for f in fields(self)
                if f.name not in ("grid", "margin")}
        return Walkers(**kept, grid=self.grid, margin=self.margin)

    def _at(self, cars: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points (C, W, 2) at arc lengths ``s`` on ``cars``' tracks, and the
        track's segment (C, W, 2) there."""
        q = s / self.spacing[cars]
        i = np.clip(np.floor(q).astype(np.intp), 0, self.track_n[cars] - 2)
        c, w = cars[:, None], np.arange(s.shape[1])[None, :]
        p0, p1 = self.track[c, w, i], self.track[c, w, i + 1]
        return p0 + (q - i)[..., None] * (p1 - p0), p1 - p0


def _route(path, i: int) -> np.ndarray:
    """Route ``i`` as a finite (K >= 2, 2) polyline of positive length."""
    path = np.asarray(path, np.float64)
    if path.ndim != 2 or path.shape[1] < 2 or len(path) < 2:
        raise TopodrakeError(f"route {i} for walkers must be (K >= 2, 2) points, "
                             f"got shape {path.shape}")
    if not np.all(np.isfinite(path[:, :2])):
        raise TopodrakeError(f"route {i} for walkers has non-finite points (NaN or inf)")
    if not np.any(np.diff(path[:, :2], axis=0)):
        raise TopodrakeError(f"route {i} for walkers has zero length")
    return path[:, :2]


def _place(grid: OccupancyGrid, route: np.ndarray, n: int, rng: np.random.Generator,
           start: np.ndarray | None, margin: float, i: int, attempts: int = 200) -> dict:
    """One car's ``n`` walkers as arrays, tracks as a list."""
    key = rng.integers(0, 2**64, dtype=np.uint64)
    base = _resample(_smooth(_resample(route, STEP_M), _SMOOTH_M), STEP_M)
    normals = _normals(base)
    ends = route[[0, -1]]
    inner = np.min(np.linalg.norm(base[:, None] - ends[None], axis=-1), axis=1) > KEEP_CLEAR_M
    if n > 0 and not inner.any():
        raise TopodrakeError(f"route {i} has no point {KEEP_CLEAR_M} m away from both its "
                             f"ends to put walkers near")
    crossing = rng.permutation(np.arange(n) < n // 2)
    xy, radius, speed, tracks, s = [], [], [], [], []
    for w in range(n):
        r, v = rng.uniform(*RADIUS_M), rng.uniform(*SPEED_MPS)
        for _ in range(attempts):
            if crossing[w]:
                track = _across(grid, base[inner], normals[inner], rng, r + margin)
            else:
                track = _beside(grid, base, normals, rng.uniform(-OFFSET_M, OFFSET_M),
                                r + margin)
            if track is None:
                continue
            s0 = rng.uniform(0.0, _length(track))
            p = _point(track, s0)
            if (grid.clearance_at(p) >= r + margin
                    and np.min(np.linalg.norm(ends - p, axis=1)) > KEEP_CLEAR_M
                    and (start is None or np.linalg.norm(p - start) > START_CLEAR_M)
                    and all(np.linalg.norm(p - q) > r + rq for q, rq in zip(xy, radius))):
                break
        else:
            raise TopodrakeError(f"could place only {w} of {n} walkers near route {i} "
                                 f"(free space, {START_CLEAR_M} m from the car's start, "
                                 f"{KEEP_CLEAR_M} m from the route's ends)")
        xy.append(p)
        radius.append(r)
        speed.append(v)
        tracks.append(track)
        s.append(s0)
    direction = rng.choice([-1.0, 1.0], size=n)
    return {"xy": xy, "radius": radius, "speed": speed, "tracks": tracks, "s": s,
            "direction": direction, "crossing": crossing, "key": key}


def _stack(cars: list[dict], n: int, grid: OccupancyGrid, margin: float) -> Walkers:
    """The cars' walkers as (N, W, ...) arrays, tracks padded to one length."""
    big = max([len(t) for c in cars for t in c["tracks"]], default=2)
    track = np.zeros((len(cars), n, big, 2))
    track_n = np.full((len(cars), n), 2, np.intp)
    spacing = np.ones((len(cars), n))
    for i, c in enumerate(cars):
        for w, t in enumerate(c["tracks"]):
            track[i, w, :len(t)], track[i, w, len(t):] = t, t[-1]
            track_n[i, w] = len(t)
            spacing[i, w] = _length(t) / (len(t) - 1)

    def arr(name, dtype=np.float64, shape=()):
        return np.array([c[name] for c in cars], dtype).reshape(len(cars), n, *shape)

    walkers = Walkers(
        xy=arr("xy", shape=(2,)), heading=np.zeros((len(cars), n)), speed=arr("speed"),
        radius=arr("radius"), crossing=arr("crossing", bool), track=track, track_n=track_n,
        spacing=spacing, s=arr("s"), direction=arr("direction"),
        stop_s=np.zeros((len(cars), n)), go_s=np.zeros((len(cars), n)),
        waiting=np.zeros((len(cars), n), bool),
        key=np.array([c["key"] for c in cars], np.uint64).reshape(len(cars)),
        tick=np.zeros(len(cars), np.uint64), grid=grid, margin=margin)
    if n > 0:
        _, seg = walkers._at(np.arange(len(cars)), walkers.s)
        d = walkers.direction
        walkers.heading = np.arctan2(d * seg[..., 1], d * seg[..., 0])
    return walkers


def _beside(grid: OccupancyGrid, base: np.ndarray, normals: np.ndarray, offset: float,
            need: float) -> np.ndarray:
    """The route ``base`` shifted ``offset`` m to its left, less where that
    comes within ``need`` m of a wall (as far as the route itself allows)."""
    frac = np.array([1.0, 0.75, 0.5, 0.25, 0.0])
    points = base[None] + (frac[:, None, None] * offset) * normals[None]
    ok = grid.clearance_at(points) >= need + _SLACK_M
    best = np.where(ok.any(axis=0), frac[np.argmax(ok, axis=0)], 0.0)
    # narrow ahead of a pinch, then smooth: the mean of the window minima stays
    # <= each point's own largest free fraction
    size = 2 * round(_NORMAL_M / STEP_M) + 1
    best = ndimage.uniform_filter1d(ndimage.minimum_filter1d(best, size, mode="nearest"),
                                    size, mode="nearest")
    return _resample(base + (best * offset)[:, None] * normals, STEP_M, passes=3)


def _across(grid: OccupancyGrid, base: np.ndarray, normals: np.ndarray,
            rng: np.random.Generator, need: float) -> np.ndarray | None:
    """A line across the route at a random point of ``base``, as far to
    either side (up to :data:`CROSS_HALF_M`) as it keeps ``need`` m off
    walls; None where that is shorter than :data:`MIN_CROSS_M`."""
    k = rng.integers(len(base))
    t = np.arange(0.0, CROSS_HALF_M + 1e-9, STEP_M)
    reach = []
    for sign in (-1.0, 1.0):
        ok = grid.clearance_at(base[k] + sign * t[:, None] * normals[k]) >= need + _SLACK_M
        if not ok[0]:
            return None
        reach.append(t[len(ok) - 1 if ok.all() else np.argmin(ok) - 1])
    if sum(reach) < MIN_CROSS_M:
        return None
    return _resample(np.stack([base[k] - reach[0] * normals[k],
                               base[k] + reach[1] * normals[k]]), STEP_M)


def _resample(xy: np.ndarray, step: float, passes: int = 1) -> np.ndarray:
    """The polyline ``xy`` as points evenly spaced in arc length, at most
    ``step`` apart; each further pass evens out the chords (which a corner
    shortens) on the polyline of the last."""
    for _ in range(passes):
        seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
        xy = xy[np.concatenate([[True], seg > 0])]
        s = np.concatenate([[0.0], np.cumsum(seg[seg > 0])])
        t = np.linspace(0.0, s[-1], max(1, int(np.ceil(s[-1] / step))) + 1)
        xy = np.column_stack([np.interp(t, s, xy[:, 0]), np.interp(t, s, xy[:, 1])])
    return xy


def _smooth(xy: np.ndarray, half_m: float) -> np.ndarray:
    """Moving mean over ``half_m`` m either side (evenly spaced points at
    :data:`STEP_M`), the window shrinking at the ends so they stay put."""
    k = np.arange(len(xy))
    h = np.minimum(round(half_m / STEP_M), np.minimum(k, len(xy) - 1 - k))
    c = np.concatenate([np.zeros((1, 2)), np.cumsum(xy, axis=0)])
    return (c[k + h + 1] - c[k - h]) / (2 * h + 1)[:, None]


def _normals(xy: np.ndarray) -> np.ndarray:
    """Unit left normals of the smoothed direction of the polyline ``xy``."""
    tangent = np.gradient(_smooth(xy, _NORMAL_M), axis=0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
    return np.column_stack([-tangent[:, 1], tangent[:, 0]])


def _length(track: np.ndarray) -> float:
    return float(np.sum(np.linalg.norm(np.diff(track, axis=0), axis=1)))


def _point(track: np.ndarray, s: float) -> np.ndarray:
    """The point at arc length ``s`` on an evenly spaced ``track``."""
    q = s / (_length(track) / (len(track) - 1))
    i = min(int(q), len(track) - 2)
    return track[i] + (q - i) * (track[i + 1] - track[i])


_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_ODD = np.uint64(0xD1B54A32D192ED03)


def _uniform(key: np.ndarray, tick: np.ndarray, w: int, k: int) -> np.ndarray:
    """(C, w, k) uniforms in [0, 1) from each car's ``key`` and ``tick``:
    splitmix64 of a counter, so a car's draws depend on nothing else."""
    j = np.arange(1, w * k + 1, dtype=np.uint64).reshape(1, w, k)
    z = key[:, None, None] + tick[:, None, None] * _GOLDEN + j * _ODD
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z = z ^ (z >> np.uint64(31))
    return (z >> np.uint64(11)).astype(np.float64) * 2.0**-53
