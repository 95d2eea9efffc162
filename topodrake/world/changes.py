"""What differs, for each car of a batch, from the world its map was made in.

A building changes after its drives were taught: a box left in a corridor,
people walking, a door shut. :class:`CarChanges` holds such changes per car
of a batched simulation (each car meets its own), as faces the sensors see
on top of the world's (:meth:`CarChanges.faces`, the extra faces of
:meth:`topodrake.sensing.lidar.Lidar.scan` and
:meth:`topodrake.sensing.camera.Camera.render`), a collision check
(:meth:`CarChanges.touching`) and a clock that moves the walkers
(:meth:`CarChanges.step`). The world itself, its map and the oracles stay
as mapped: the changes are what the car meets, not what it knows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.vehicle import VehicleConfig, car_to_world
from topodrake.world.blockage import block_on_path
from topodrake.world.obstacles import boxes_on_path
from topodrake.world.textures import FURNITURE_TEXTURES
from topodrake.world.walkers import Walkers

BOX_TEXTURE = FURNITURE_TEXTURES[0]
BLOCK_TEXTURE = FURNITURE_TEXTURES[5]
WALKER_TEXTURE = FURNITURE_TEXTURES[3]


@dataclass
class WorldChanges:
    """How a world differs from the one its map was made in, per trial:
    ``boxes`` unmapped boxes (0.3-0.6 m) on the planned route, ``people``
    walkers along and across it, ``blocked`` (0 or 1) a passage on the route
    closed wall to wall where another way exists."""

    boxes: int = 0
    people: int = 0
    blocked: int = 0

    def check(self, where: str = "changes") -> "WorldChanges":
        for name in ("boxes", "people", "blocked"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise TopodrakeError(f"{where}: {name} must be a whole number >= 0, got {v!r}")
        if self.blocked > 1:
            raise TopodrakeError(f"{where}: blocked closes at most 1 passage, got {self.blocked}")
        return self

    @property
    def any(self) -> bool:
        return bool(self.boxes or self.people or self.blocked)

    @property
    def label(self) -> str:
        """``boxes=3,people=2`` (the non-zero ones), or ``none``."""
        parts = [f"{k}={v}" for k, v in vars(self).items() if v]
        return ",".join(parts) or "none"

    @classmethod
    def parse(cls, text: str) -> "WorldChanges":
        """From ``boxes=3,people=2,blocked=1`` (``none``: nothing changed)."""
        text = text.strip()
        if text in ("", "none"):
            return cls()
        values: dict = {}
        for part in text.split(","):
            key, eq, value = part.partition("=")
            key = key.strip()
            if not eq or key not in ("boxes", "people", "blocked"):
                raise TopodrakeError(f"changes: expected boxes=N, people=N or blocked=1, got "
                                     f"{part.strip()!r}")
            try:
                values[key] = int(value)
            except ValueError:
                raise TopodrakeError(f"changes: {key} must be a whole number, got "
                                     f"{value.strip()!r}") from None
        return cls(**values).check()


def place_changes(world, paths: list, spec: WorldChanges, seeds: list,
                  starts: np.ndarray | None = None) -> tuple["CarChanges", list]:
    """Each trial's changes on its planned path ``paths[i]`` (K, 2+) (None:
    a trial not driven), drawn from ``seeds[i]``: ``spec.boxes`` boxes
    (:func:`~topodrake.world.obstacles.boxes_on_path`), ``spec.people``
    walkers (:meth:`~topodrake.world.walkers.Walkers.on_paths`) and
    ``spec.blocked`` closed passages
    (:func:`~topodrake.world.blockage.block_on_path`). Returns the
    changes of all trials and per trial what was placed (a dict with
    ``boxes``, ``block``) or None where the path has no room for them
    (a trial left out of the rates: ``no_room``)."""
    n = len(paths)
    seeds = [s if isinstance(s, np.random.SeedSequence) else np.random.SeedSequence(s)
             for s in seeds]
    boxes, blocks, placed = [None] * n, [None] * n, [None] * n
    for i, path in enumerate(paths):
        if path is None:
            continue
        try:
            if spec.boxes:
                boxes[i] = boxes_on_path(world, path, spec.boxes, np.random.default_rng(seeds[i]))
            if spec.blocked:
                blocks[i] = block_on_path(world, path,
                                          np.random.default_rng(_child(seeds[i], 1)))
        except TopodrakeError:
            boxes[i] = blocks[i] = None
            continue
        placed[i] = {"boxes": None if boxes[i] is None else np.round(boxes[i], 3).tolist(),
                     "block": None if blocks[i] is None else np.round(blocks[i], 3).tolist()}
    walkers = None
    if spec.people and any(p is not None for p in paths):
        live = [None if p is None else np.asarray(p, np.float64)[:, :2] for p in paths]
        stand_in = next(p for p in live if p is not None)     # undriven trials' walkers idle
        walkers = Walkers.on_paths(world, [stand_in if p is None else p for p in live],
                                   spec.people, [_child(s, 2) for s in seeds], starts)
    return CarChanges.of(boxes, blocks, walkers, n=n), placed


def _child(seed: np.random.SeedSequence, k: int) -> np.random.SeedSequence:
    """Child ``k`` of ``seed``, the same however often it is asked for."""
    return np.random.SeedSequence(seed.entropy, spawn_key=(*seed.spawn_key, k))


def box_segments(boxes: np.ndarray) -> np.ndarray:
    """(B * 4, 4) faces ``ax, ay, bx, by`` of axis-aligned boxes (B, 4)
    ``xmin, ymin, xmax, ymax``, counter-clockwise."""
    b = np.asarray(boxes, np.float64).reshape(-1, 4)
    x0, y0, x1, y1 = b.T
    corners = np.stack([np.stack([x0, y0], 1), np.stack([x1, y0], 1),
                        np.stack([x1, y1], 1), np.stack([x0, y1], 1)], axis=1)   # (B, 4, 2)
    return polygon_segments(corners)


def polygon_segments(corners: np.ndarray) -> np.ndarray:
    """(B * K, 4) faces of closed polygons (B, K, 2), corner k to corner k+1."""
    c = np.asarray(corners, np.float64)
    nxt = np.roll(c, -1, axis=1)
    return np.concatenate([c, nxt], axis=2).reshape(-1, 4)


def face_table(segments: np.ndarray, texture: np.ndarray) -> np.ndarray:
    """(..., 8) render rows ``ax, ay, bx, by, u0, length, shade, texture`` of
    faces (..., 4), as the ray scene stores the world's (NaN rows stay NaN)."""
    seg = np.asarray(segments, np.float64)
    e = seg[..., 2:4] - seg[..., 0:2]
    length = np.hypot(e[..., 0], e[..., 1])
    normal = np.stack([e[..., 1], -e[..., 0]], -1) / np.maximum(length, 1e-12)[..., None]
    shade = 0.7 + 0.3 * np.abs(normal @ np.array([0.6, 0.8]))
    u0 = np.where(np.abs(e[..., 0]) >= np.abs(e[..., 1]), seg[..., 0], seg[..., 1])
    tex = np.broadcast_to(np.asarray(texture, np.float64), length.shape)
    return np.concatenate([seg, u0[..., None], length[..., None], shade[..., None],
                           tex[..., None]], axis=-1)


def padded(per_car: list, width: int = 4) -> np.ndarray:
    """(N, max F, width) of per-car arrays (F_i, width) (None: none), padded with NaN."""
    rows = [np.zeros((0, width)) if a is None else np.asarray(a, np.float64).reshape(-1, width)
            for a in per_car]
    f = max((len(r) for r in rows), default=0)
    out = np.full((len(rows), f, width), np.nan)
    for i, r in enumerate(rows):
        out[i, :len(r)] = r
    return out


@dataclass
class CarChanges:
    """Per car of a batch: ``fixed`` (N, S, 8) render rows of still faces
    (boxes, closed doors; NaN rows are padding) and ``walkers`` (a
    :class:`~topodrake.world.walkers.Walkers` of N cars, or None)."""

    fixed: np.ndarray
    walkers: object | None = None

    def __post_init__(self) -> None:
        self.fixed = np.asarray(self.fixed, np.float64)
        if self.fixed.ndim != 3 or self.fixed.shape[2] != 8:
            raise TopodrakeError(f"changed faces must be (N, S, 8), got {self.fixed.shape}")
        if self.walkers is not None and len(self.walkers.xy) != len(self.fixed):
            raise TopodrakeError(f"walkers of {len(self.walkers.xy)} cars for "
                                 f"{len(self.fixed)} cars")

    @classmethod
    def of(cls, boxes: list | None = None, blocks: list | None = None, walkers=None,
           n: int | None = None) -> "CarChanges":
        """From per-car boxes (B_i, 4) and blocks (closed passages as (4, 2)
        corners; None: none) and walkers of the same cars."""
        n = n if n is not None else len(boxes if boxes is not None else blocks or [])
        if walkers is not None:
            n = len(walkers.xy)
        boxes = boxes if boxes is not None else [None] * n
        blocks = blocks if blocks is not None else [None] * n
        if len(boxes) != n or len(blocks) != n:
            raise TopodrakeError(f"changes for {n} cars got {len(boxes)} box lists and "
                                 f"{len(blocks)} blocks")
        rows = []
        for b, k in zip(boxes, blocks):
            parts = []
            if b is not None and len(b):
                parts.append(face_table(box_segments(b), BOX_TEXTURE))
            if k is not None:
                parts.append(face_table(polygon_segments(np.asarray(k)[None]), BLOCK_TEXTURE))
            rows.append(np.concatenate(parts) if parts else None)
        return cls(padded(rows, 8), walkers)

    def __len__(self) -> int:
        return len(self.fixed)

    @property
    def moving(self) -> bool:
        return self.walkers is not None and self.walkers.xy.shape[1] > 0

    def take(self, cars) -> "CarChanges":
        """The changes of the cars ``cars`` (indices), a copy."""
        cars = np.asarray(cars, np.int64)
        return CarChanges(self.fixed[cars].copy(),
                          None if self.walkers is None else self.walkers.take(cars))

    def faces(self, cars) -> np.ndarray:
        """(len(cars), F, 8) render rows of what the cars ``cars`` meet now."""
        cars = np.asarray(cars, np.int64)
        rows = self.fixed[cars]
        if self.moving:
            seg = self.walkers.faces(cars)
            rows = np.concatenate([rows, face_table(seg, WALKER_TEXTURE)], axis=1)
        return rows

    def solids(self, car: int) -> tuple[np.ndarray, np.ndarray]:
        """Car ``car``'s still changes as quadrilaterals, for drawing: corners
        (Q, 4, 2) counter-clockwise and textures (Q,) (:data:`BOX_TEXTURE`
        for a box, :data:`BLOCK_TEXTURE` for a closed passage)."""
        rows = self.fixed[int(car)]
        rows = rows[np.isfinite(rows[:, 0])]
        return rows[:, :2].reshape(-1, 4, 2).copy(), rows[::4, 7].astype(np.int64)

    def step(self, dt: float, cars, car_xy: np.ndarray) -> None:
        """Move the walkers of cars ``cars`` by ``dt`` s (cars at ``car_xy``)."""
        if self.moving:
            self.walkers.step(dt, np.asarray(cars, np.int64), np.asarray(car_xy, np.float64))

    def touching(self, cars, states: np.ndarray, vehicle: VehicleConfig) -> np.ndarray:
        """(len(cars),) bool: does car ``cars[j]`` at ``states[j]`` touch what
        changed? As the world's check (rays from the car's reference point to
        its control points): a ray crosses a changed face, or a control point
        lies within ``collision_clearance`` of one."""
        seg = self.faces(cars)[..., :4]
        n = len(seg)
        if seg.shape[1] == 0 or n == 0:
            return np.zeros(n, bool)
        pts = car_to_world(vehicle.control_points_array(), states)          # (n, P, 2)
        o = np.asarray(states, np.float64)[:, None, :2]                      # (n, 1, 2)
        a, b = seg[:, None, :, :2], seg[:, None, :, 2:]                      # (n, 1, F, 2)
        p, q = o[:, :, None], pts[:, :, None]                                # (n, P, 1, 2)
        crosses = _segments_cross(p, q, a, b)
        near = _point_segment_distance(q, a, b) < vehicle.collision_clearance
        valid = np.isfinite(seg[:, None, :, 0])
        return ((crosses | near) & valid).any(axis=(1, 2))


def _cross(u, v):
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def _segments_cross(p, q, a, b) -> np.ndarray:
    """Whether segments p-q and a-b intersect (broadcast)."""
    with np.errstate(invalid="ignore"):
        d1, d2 = _cross(q - p, a - p), _cross(q - p, b - p)
        d3, d4 = _cross(b - a, p - a), _cross(b - a, q - a)
        return (d1 * d2 <= 0) & (d3 * d4 <= 0)


def _point_segment_distance(q, a, b) -> np.ndarray:
    """Distance from points q to segments a-b (broadcast)."""
    e = b - a
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.clip(np.sum((q - a) * e, -1) / np.maximum(np.sum(e * e, -1), 1e-12), 0.0, 1.0)
        return np.hypot(*np.moveaxis(q - (a + t[..., None] * e), -1, 0))
