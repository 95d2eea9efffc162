"""ROS map_server maps: a YAML file next to a PGM or PNG image.

The YAML keys are map_server's: ``image`` (relative to the YAML file, or
absolute), ``resolution`` (m per pixel), ``origin`` ``[x, y, yaw]`` (the world
pose of the lower-left pixel), ``negate``, ``occupied_thresh``, ``free_thresh``
and the optional ``mode``. ``image``, ``resolution`` and ``origin`` are
required; the others default to map_server's usual values (``negate: 0``,
``occupied_thresh: 0.65``, ``free_thresh: 0.196``, ``mode: trinary``).

Pixels are classified as map_server does: the colour channels are averaged
(alpha ignored) to a value ``v`` in 0..255 and ``p = (255 - v) / 255``
(``v / 255`` with ``negate``); ``p > occupied_thresh`` is occupied,
``p < free_thresh`` is free, anything in between is unknown. ``scale`` mode
classifies the same way (it only changes the values map_server publishes for
unknown cells). ``raw`` mode reads ``v`` as the occupancy percentage itself:
``p = v / 100`` for ``v <= 100`` and unknown above. Unknown cells are treated
as walls.

A nonzero origin yaw (a rotated map, as some SLAM exports write) is applied:
the image is rotated by the yaw about the origin into the world frame (the
ROS map frame, where rviz draws it), resampled at the same resolution to
the nearest pixel (lossless for multiples of 90 degrees); cells outside the
rotated image are walls. Coordinates given to topodrake (starts, goals)
are therefore in the ROS map frame, whatever the yaw.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import yaml
from PIL import Image

from topodrake.errors import TopodrakeError
from topodrake.world.raster import world_from_occupancy
from topodrake.world.world import World

MODES = ("trinary", "scale", "raw")


def load_ros_map(yaml_path) -> World:
    """Load a ROS map_server map (YAML + image) as a :class:`World`."""
    path = Path(yaml_path)
    meta = _read_yaml(path)
    image_path, resolution, origin, negate, occ_t, free_t, mode = _parse(path, meta)
    value = read_gray(image_path, path)
    occupied = classify(value, negate=negate, occupied_thresh=occ_t,
                        free_thresh=free_t, mode=mode) != 0
    name = path.parent.name if path.stem == "map" and path.parent.name else path.stem
    # Image row 0 is the top of the map (highest y); the grid's row 0 is the bottom.
    occupied, corner = rotate_raster(occupied[::-1], resolution, origin)
    return world_from_occupancy(name, occupied, corner, resolution, source=str(path))


def rotate_raster(occupied: np.ndarray, resolution: float, origin) -> tuple[np.ndarray, np.ndarray]:
    """An (H, W) raster (row 0 = lowest y) whose lower-left corner is at
    ``origin[:2]`` and which is rotated by ``origin[2]`` (counter-clockwise)
    about that corner, resampled into an axis-aligned raster of the same
    resolution: returns the raster and the world xy of its lower-left
    corner. Each new cell takes the pixel under its centre; cells outside
    the image are occupied. Yaw 0 returns the input unchanged."""
    ox, oy, yaw = (float(v) for v in origin)
    occupied = np.asarray(occupied, dtype=bool)
    if yaw == 0.0:
        return occupied, np.array([ox, oy])
    h, w = occupied.shape
    c, s = math.cos(yaw), math.sin(yaw)
    corners = np.array([[0.0, 0.0], [w, 0.0], [0.0, h], [w, h]]) * resolution
    world = corners @ np.array([[c, s], [-s, c]]) + (ox, oy)
    lo, hi = world.min(axis=0), world.max(axis=0)
    nw, nh = (max(1, int(round(n))) for n in (hi - lo) / resolution)
    xs = lo[0] + (np.arange(nw) + 0.5) * resolution - ox
    ys = lo[1] + (np.arange(nh) + 0.5) * resolution - oy
    # Image coordinates of each new cell centre (rotate back by -yaw).
    col = np.floor((c * xs[None, :] + s * ys[:, None]) / resolution).astype(np.int64)
    row = np.floor((-s * xs[None, :] + c * ys[:, None]) / resolution).astype(np.int64)
    inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    out = np.ones((nh, nw), dtype=bool)
    out[inside] = occupied[row[inside], col[inside]]
    return out, lo


def classify(value: np.ndarray, *, negate: bool = False, occupied_thresh: float = 0.65,
             free_thresh: float = 0.196, mode: str = "trinary") -> np.ndarray:
    """map_server classification of 0..255 gray values: int8 raster with
    0 free, 1 occupied, -1 unknown."""
    v = np.asarray(value, dtype=np.float64)
    out = np.full(v.shape, -1, np.int8)
    if mode == "raw":
        known = v <= 100
        p = v / 100.0
    else:
        known = np.ones(v.shape, bool)
        p = v / 255.0 if negate else (255.0 - v) / 255.0
    out[known & (p > occupied_thresh)] = 1
    out[known & (p < free_thresh)] = 0
    return out


def read_gray(image_path: Path, yaml_path: Path | None = None) -> np.ndarray:
    """(H, W) float gray values 0..255 of a PGM/PNG image, channels averaged,
    alpha ignored. Errors name the image (and the YAML that refers to it)."""
    where = f"{image_path}" if yaml_path is None else f"{yaml_path}: image {image_path}"
    if not image_path.is_file():
        raise TopodrakeError(f"{where} does not exist")
    try:
        with Image.open(image_path) as im:
            im.load()
            if im.mode in ("I", "I;16", "I;16B", "I;16L", "F"):
                a = np.asarray(im, dtype=np.float64)
                top = 65535.0 if a.max(initial=0) > 255 else 255.0
                return a * (255.0 / top)
            if im.mode == "1" or im.mode == "L":
                return np.asarray(im.convert("L"), dtype=np.float64)
            rgb = np.asarray(im.convert("RGB"), dtype=np.float64)
            return rgb.mean(axis=2)
    except TopodrakeError:
        raise
    except Exception as exc:  # Pillow raises OSError, SyntaxError, ValueError, ...
        msg = " ".join(str(exc).split()) or type(exc).__name__
        raise TopodrakeError(f"{where} is not a readable image ({msg})") from None


def _read_yaml(path: Path) -> dict:
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise TopodrakeError(f"{path}: cannot read the map YAML "
                             f"({getattr(exc, 'strerror', None) or exc})") from None
    try:
        meta = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or "syntax error"
        raise TopodrakeError(f"{path}: malformed YAML{where}: {problem}") from None
    if not isinstance(meta, dict):
        raise TopodrakeError(f"{path}: expected a YAML mapping with image, resolution "
                             f"and origin, got {type(meta).__name__}")
    return meta


def _number(path: Path, meta: dict, key: str, default=None) -> float:
    if key not in meta:
        if default is None:
            raise TopodrakeError(f"{path}: missing key {key!r}")
        return float(default)
    v = meta[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise TopodrakeError(f"{path}: {key} must be a finite number, got {v!r}")
    return float(v)


def _parse(path: Path, meta: dict):
    missing = [k for k in ("image", "resolution", "origin") if k not in meta]
    if missing:
        raise TopodrakeError(f"{path}: missing key{'s' if len(missing) > 1 else ''} "
                             f"{', '.join(map(repr, missing))}")
    image = meta["image"]
    if not isinstance(image, str) or not image.strip():
        raise TopodrakeError(f"{path}: image must be a file name, got {image!r}")
    image_path = Path(image)
    if not image_path.is_absolute():
        image_path = path.parent / image_path

    resolution = _number(path, meta, "resolution")
    if resolution <= 0:
        raise TopodrakeError(f"{path}: resolution must be > 0, got {resolution:g}")

    origin = meta["origin"]
    if (not isinstance(origin, (list, tuple)) or len(origin) not in (2, 3)
            or not all(isinstance(o, (int, float)) and not isinstance(o, bool)
                       and math.isfinite(o) for o in origin)):
        raise TopodrakeError(f"{path}: origin must be [x, y, yaw] numbers, got {origin!r}")
    origin = np.array([*origin, 0.0][:3], dtype=np.float64)

    negate = meta.get("negate", 0)
    if negate not in (0, 1):
        raise TopodrakeError(f"{path}: negate must be 0 or 1, got {negate!r}")
    occ_t = _number(path, meta, "occupied_thresh", 0.65)
    free_t = _number(path, meta, "free_thresh", 0.196)
    if not (0.0 <= free_t < occ_t <= 1.0):
        raise TopodrakeError(f"{path}: thresholds must satisfy 0 <= free_thresh < "
                             f"occupied_thresh <= 1, got free_thresh {free_t:g}, "
                             f"occupied_thresh {occ_t:g}")
    mode = meta.get("mode", "trinary")
    if mode not in MODES:
        raise TopodrakeError(f"{path}: mode must be one of {', '.join(MODES)}, got {mode!r}")
    return image_path, resolution, origin, bool(negate), occ_t, free_t, mode
