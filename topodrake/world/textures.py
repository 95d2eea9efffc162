"""The texture bank: small procedural RGB tiles indexed by texture id.

Ids are grouped by use so worlds can draw from the right pool; some rooms of
a house share ids on purpose (perceptual aliasing). Each tile is
``TEXELS x TEXELS`` RGB and covers ``TILE_M`` metres of wall or floor.
The bank is deterministic (fixed seed) so rendered images never change
between runs or machines.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

TEXELS = 16
TILE_M = 1.0
WALL_TEXTURES = range(0, 32)
FLOOR_TEXTURES = range(32, 44)
CEILING_TEXTURES = range(44, 48)
FURNITURE_TEXTURES = range(48, 56)
N_TEXTURES = 56


def _tile(rng: np.random.Generator, kind: int) -> np.ndarray:
    base = rng.uniform(0.25, 0.95, size=3)
    accent = np.clip(base + rng.uniform(-0.45, 0.45, size=3), 0.05, 1.0)
    y, x = np.mgrid[0:TEXELS, 0:TEXELS]
    if kind == 0:      # plain with faint noise
        mask = np.zeros((TEXELS, TEXELS))
    elif kind == 1:    # vertical stripes
        period = int(rng.integers(2, 6))
        mask = ((x // period) % 2).astype(float)
    elif kind == 2:    # horizontal stripes
        period = int(rng.integers(2, 6))
        mask = ((y // period) % 2).astype(float)
    elif kind == 3:    # checker
        period = int(rng.choice([2, 4, 8]))
        mask = (((x // period) + (y // period)) % 2).astype(float)
    elif kind == 4:    # bricks
        row = y // 4
        mask = (((y % 4) == 0) | (((x + 4 * (row % 2)) % 8) == 0)).astype(float)
    else:              # diagonal
        period = int(rng.integers(3, 7))
        mask = (((x + y) // period) % 2).astype(float)
    tile = base[None, None, :] * (1 - mask[..., None]) + accent[None, None, :] * mask[..., None]
    tile *= 1.0 + rng.normal(0, 0.04, size=(TEXELS, TEXELS, 1))
    return np.clip(tile, 0.0, 1.0)


@lru_cache(maxsize=1)
def texture_bank() -> np.ndarray:
    """(N_TEXTURES, TEXELS, TEXELS, 3) float32 colours in [0, 1]."""
    rng = np.random.default_rng(20200531)
    tiles = []
    for tid in range(N_TEXTURES):
        if tid in CEILING_TEXTURES:
            kind = 0
        elif tid in FLOOR_TEXTURES:
            kind = int(rng.choice([0, 3, 1, 5]))
        else:
            kind = int(rng.integers(0, 6))
        tiles.append(_tile(rng, kind))
    bank = np.stack(tiles).astype(np.float32)
    bank[list(CEILING_TEXTURES)] = 0.55 + 0.4 * bank[list(CEILING_TEXTURES)]
    return np.ascontiguousarray(bank)


def texture_png_bytes(tid: int, scale: int = 8) -> bytes:
    """PNG of one tile (upscaled, nearest) for Drake/Meshcat materials."""
    import io

    from PIL import Image

    tile = (texture_bank()[tid] * 255).astype(np.uint8)
    img = Image.fromarray(tile).resize((TEXELS * scale, TEXELS * scale), Image.NEAREST)
    buf = io.BytesIO()
    img.save(buf, format="PNG")
    return buf.getvalue()
