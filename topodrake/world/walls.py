"""Walls: vertical boxes on the floor plan, stored as arrays.

A wall is a 2-D centre segment ``p0 -> p1`` with a thickness and a texture id;
extruded from the floor to the world's wall height it is a box. Everything
solid in a world (walls, furniture, the occupied cells of a scanned map) is a
wall. The renderer sees walls through their *faces*: the four sides of each
box as oriented segments, each with the texture of its wall.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from topodrake.errors import TopodrakeError


@dataclass(frozen=True)
class Wall:
    """One wall: centre segment, thickness (m) and texture id."""

    p0: tuple[float, float]
    p1: tuple[float, float]
    thickness: float
    texture: int


@dataclass(frozen=True)
class WallSet:
    """All walls of a world as arrays.

    ``segments`` is (N, 4) with rows ``x0, y0, x1, y1``; ``thickness`` (N,)
    and ``texture`` (N,) int32.
    """

    segments: np.ndarray
    thickness: np.ndarray
    texture: np.ndarray

    def __post_init__(self) -> None:
        seg = np.asarray(self.segments, dtype=np.float64).reshape(-1, 4)
        thick = np.asarray(self.thickness, dtype=np.float64).reshape(-1)
        tex = np.asarray(self.texture, dtype=np.int32).reshape(-1)
        if not (len(seg) == len(thick) == len(tex)):
            raise TopodrakeError(
                f"wall arrays disagree in length: {len(seg)} segments, "
                f"{len(thick)} thicknesses, {len(tex)} textures")
        if not np.all(np.isfinite(seg)) or not np.all(np.isfinite(thick)):
            raise TopodrakeError("wall coordinates must be finite numbers")
        if np.any(thick <= 0):
            raise TopodrakeError("every wall needs a positive thickness")
        if np.any(np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]) <= 0):
            raise TopodrakeError("a wall has zero length (p0 == p1)")
        object.__setattr__(self, "segments", seg)
        object.__setattr__(self, "thickness", thick)
        object.__setattr__(self, "texture", tex)

    @classmethod
    def from_walls(cls, walls: list[Wall]) -> "WallSet":
        if not walls:
            return cls(np.zeros((0, 4)), np.zeros(0), np.zeros(0, np.int32))
        seg = np.array([[*w.p0, *w.p1] for w in walls], dtype=np.float64)
        return cls(seg, np.array([w.thickness for w in walls]),
                   np.array([w.texture for w in walls], dtype=np.int32))

    @classmethod
    def from_boxes(cls, boxes: np.ndarray, texture: np.ndarray) -> "WallSet":
        """Axis-aligned boxes ``(xmin, ymin, xmax, ymax)`` as walls."""
        boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        w = boxes[:, 2] - boxes[:, 0]
        h = boxes[:, 3] - boxes[:, 1]
        horizontal = w >= h
        cx = 0.5 * (boxes[:, 0] + boxes[:, 2])
        cy = 0.5 * (boxes[:, 1] + boxes[:, 3])
        seg = np.where(
            horizontal[:, None],
            np.stack([boxes[:, 0], cy, boxes[:, 2], cy], axis=1),
            np.stack([cx, boxes[:, 1], cx, boxes[:, 3]], axis=1))
        return cls(seg, np.where(horizontal, h, w), texture)

    def __len__(self) -> int:
        return len(self.segments)

    def concat(self, other: "WallSet") -> "WallSet":
        return WallSet(np.concatenate([self.segments, other.segments]),
                       np.concatenate([self.thickness, other.thickness]),
                       np.concatenate([self.texture, other.texture]))

    def corners(self) -> np.ndarray:
        """(N, 4, 2) box corners, counter-clockwise."""
        p0 = self.segments[:, :2]
        p1 = self.segments[:, 2:]
        d = p1 - p0
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        n = np.stack([-d[:, 1], d[:, 0]], axis=1) * (0.5 * self.thickness)[:, None]
        return np.stack([p0 - n, p1 - n, p1 + n, p0 + n], axis=1)

    def lengths(self) -> np.ndarray:
        d = self.segments[:, 2:] - self.segments[:, :2]
        return np.hypot(d[:, 0], d[:, 1])

    def yaws(self) -> np.ndarray:
        d = self.segments[:, 2:] - self.segments[:, :2]
        return np.arctan2(d[:, 1], d[:, 0])

    def bbox(self) -> np.ndarray:
        """[[xmin, ymin], [xmax, ymax]] over all box corners."""
        c = self.corners().reshape(-1, 2)
        return np.array([c.min(axis=0), c.max(axis=0)])


@dataclass(frozen=True)
class Faces:
    """Oriented wall faces for rendering: segment ``a -> b``, texture id.

    ``u0`` is the texture coordinate (m) at ``a`` so that textures run on
    continuously along a wall.
    """

    a: np.ndarray        # (M, 2)
    b: np.ndarray        # (M, 2)
    texture: np.ndarray  # (M,) int32
    u0: np.ndarray       # (M,)

    def __len__(self) -> int:
        return len(self.a)

    @classmethod
    def from_walls(cls, walls: WallSet) -> "Faces":
        c = walls.corners()
        a = c.reshape(-1, 2)
        b = np.roll(c, -1, axis=1).reshape(-1, 2)
        tex = np.repeat(walls.texture, 4)
        # Sides 0 and 2 are the long faces; give them a texture origin that
        # follows the world x/y so neighbouring walls line up.
        u0 = np.where(np.abs(b[:, 0] - a[:, 0]) >= np.abs(b[:, 1] - a[:, 1]),
                      a[:, 0], a[:, 1])
        return cls(a, b, tex.astype(np.int32), u0)
