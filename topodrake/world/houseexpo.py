"""HouseExpo floor plans: one JSON file per house.

A HouseExpo file holds ``verts``, the outer boundary polygon of the house's
free space as ``[x, y]`` pairs in metres, plus ``id``, ``bbox``
(``{"min": [x, y], "max": [x, y]}``), ``room_num`` and ``room_category``.
Only ``verts`` is required. The polygon interior is rasterised as free at
0.05 m (a cell is free when its centre is inside), everything outside is
wall, and :func:`world_from_occupancy` builds the world.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from matplotlib.path import Path as MplPath

from topodrake.errors import TopodrakeError
from topodrake.world.raster import world_from_occupancy
from topodrake.world.world import World

RESOLUTION = 0.05
MARGIN = 0.5


def load_houseexpo(json_path, resolution: float = RESOLUTION) -> World:
    """Load a HouseExpo JSON floor plan as a :class:`World`."""
    path = Path(json_path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise TopodrakeError(f"{path}: cannot read the HouseExpo file "
                             f"({getattr(exc, 'strerror', None) or exc})") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise TopodrakeError(f"{path}: malformed JSON at line {exc.lineno} "
                             f"column {exc.colno}: {exc.msg}") from None
    if not isinstance(data, dict):
        raise TopodrakeError(f"{path}: expected a JSON object with 'verts', "
                             f"got {type(data).__name__}")
    if "verts" not in data:
        raise TopodrakeError(f"{path}: missing key 'verts' (the boundary polygon)")
    verts = _verts(path, data["verts"])

    lo = np.floor((verts.min(axis=0) - MARGIN) / resolution) * resolution
    hi = verts.max(axis=0) + MARGIN
    w, h = np.ceil((hi - lo) / resolution).astype(int)
    xs = lo[0] + (np.arange(w) + 0.5) * resolution
    ys = lo[1] + (np.arange(h) + 0.5) * resolution
    px, py = np.meshgrid(xs, ys)
    inside = MplPath(verts, closed=False).contains_points(
        np.column_stack([px.ravel(), py.ravel()])).reshape(h, w)
    name = str(data.get("id") or path.stem)
    return world_from_occupancy(name, ~inside, lo, resolution, source=str(path))


def _verts(path: Path, raw) -> np.ndarray:
    ok = (isinstance(raw, list) and all(
        isinstance(v, (list, tuple)) and len(v) == 2
        and all(isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c)
                for c in v) for v in raw))
    if not ok:
        raise TopodrakeError(f"{path}: 'verts' must be a list of [x, y] number pairs")
    verts = np.array(raw, dtype=np.float64).reshape(-1, 2)
    if len(verts) and np.allclose(verts[0], verts[-1]):
        verts = verts[:-1]          # tolerate an explicitly closed ring
    if len(verts) < 3:
        raise TopodrakeError(f"{path}: 'verts' needs at least 3 vertices, got {len(verts)}")
    x, y = verts[:, 0], verts[:, 1]
    area = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
    if area < 1.0:
        raise TopodrakeError(f"{path}: degenerate boundary polygon (area {area:.3g} m^2)")
    extent = verts.max(axis=0) - verts.min(axis=0)
    if np.any(extent > 1000.0):
        raise TopodrakeError(f"{path}: boundary polygon spans {extent.max():.0f} m; "
                             "HouseExpo coordinates are metres")
    return verts
