"""Planar poses (x, y, theta) as (N, 3) arrays: composition, inverse, relative pose."""

from __future__ import annotations

import numpy as np


def wrap(a):
    """Angles wrapped to [-pi, pi)."""
    return (np.asarray(a, np.float64) + np.pi) % (2 * np.pi) - np.pi


def compose(a, b) -> np.ndarray:
    """Poses ``a ∘ b`` (N, 3): ``b`` given in the frame of ``a``."""
    a = np.asarray(a, np.float64).reshape(-1, 3)
    b = np.asarray(b, np.float64).reshape(-1, 3)
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    return np.column_stack([a[:, 0] + c * b[:, 0] - s * b[:, 1], a[:, 1] + s * b[:, 0] + c * b[:, 1],
                            wrap(a[:, 2] + b[:, 2])])


def invert(a) -> np.ndarray:
    """Inverse poses (N, 3)."""
    a = np.asarray(a, np.float64).reshape(-1, 3)
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    return np.column_stack([-c * a[:, 0] - s * a[:, 1], s * a[:, 0] - c * a[:, 1], -a[:, 2]])


def relative(a, b) -> np.ndarray:
    """Poses ``b`` in the frames of ``a``: ``a^-1 ∘ b`` (N, 3)."""
    return compose(invert(a), b)


def rotate(v, theta) -> np.ndarray:
    """Vectors ``v`` (N, 2) turned by ``theta`` (N,)."""
    v = np.asarray(v, np.float64).reshape(-1, 2)
    c, s = np.cos(theta), np.sin(theta)
    return np.column_stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]])
