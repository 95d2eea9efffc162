"""A world in Drake: SceneGraph registration, VTK rendering, Meshcat drawing.

Three entry points, all importing pydrake lazily so ``import topodrake.world``
stays light:

* :func:`register_world` puts a :class:`~topodrake.world.World` into a
  SceneGraph as anchored geometry (walls, a floor slab, a ceiling slab) with
  illustration (Meshcat) and perception (cameras) properties.
* :class:`VtkDepthRenderer` (built by :func:`vtk_depth_renderer`) owns a
  standalone SceneGraph with Drake's ``RenderEngineVtk`` and renders depth and
  colour images for batches of car poses; it is the reference that tests hold
  the batched 2.5-D renderer against.
* :func:`add_meshcat_world` draws a world directly into a Meshcat instance;
  :func:`frame_whole_world` points its camera at the whole floor plan.

Geometry layout
---------------
Each wall is a ``Box(length, thickness, wall_height)`` centred on the midpoint
of its centre segment, yawed along it, bottom face at z = 0. The floor is a
0.1 m slab whose top face is at z = 0, the ceiling a slab whose bottom face is
at z = wall_height; both cover the world's bounding box and use the first
room's texture (one slab each, whatever the number of rooms). The ceiling has
*perception* properties only, so Meshcat's top-down view is not blocked.

Textures
--------
Drake's box fits its diffuse map once over every face, and the uv-scale
property (``("phong", "diffuse_scale")``, an ``Eigen::Vector2d``) cannot be
created from Python (pydrake stores a numpy array as a Python object and VTK
then rejects it). So the texture PNG of each box is pre-tiled at the world's
1 texture tile per :data:`~topodrake.world.textures.TILE_M` metres for that
box's long faces: one PNG per (texture, face size), written once into a cache
directory (:func:`texture_cache_dir`) under a name hashed from its parameters
and the texture bank, with an atomic rename. Textures run from z = 0 upwards
like the batched renderer's.

``merge=True`` gives the render engines instead one in-memory OBJ mesh for all
walls (their vertical faces only) textured from an atlas with one pre-tiled
strip per texture id, with the batched renderer's texture coordinates; the
per-wall boxes stay, with illustration properties only, for Meshcat. This is
what keeps VTK fast on big houses: its cost is linear in the number of
perception geometries (64x64 images on llvmpipe, 2 shared cores: 150 wall
boxes ~4-7 ms depth / ~7-10 ms colour; merged ~1 / ~2.5-4.5 ms). The
:class:`VtkDepthRenderer` merges by default; :func:`register_world` does not.

``cull_hidden=True`` drops walls that cannot be seen from free space: a wall
is kept only if some free (unoccupied, in-bounds) cell of the world's
occupancy grid lies within two cells of its footprint.
"""

from __future__ import annotations

import hashlib
import io
import os
import tempfile
from functools import lru_cache
from pathlib import Path

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.sensing.config import CameraConfig
from topodrake.world.textures import TEXELS, TILE_M, texture_bank, texture_png_bytes
from topodrake.world.walls import Faces

#: Thickness (m) of the floor and ceiling slabs.
SLAB_M = 0.1
#: Pixels per metre (= per texture tile) of the pre-tiled wall PNGs: two per
#: texel, so VTK's bilinear filtering blurs only texel borders. (A texel is
#: about one pixel of a 64x64 120-degree image at 1 m.)
TILE_PX = 32
#: Pixels per metre of the floor and ceiling PNGs.
SLAB_PX = 32
#: Largest PNG side written; bigger faces get fewer pixels per tile.
MAX_PNG_PX = 4096
#: Padding rows around each band of a merged-wall texture atlas.
ATLAS_PAD = 2
#: Renderer name used by :class:`VtkDepthRenderer`.
RENDERER_NAME = "topodrake_vtk"


# ---------------------------------------------------------------------------
# texture files
# ---------------------------------------------------------------------------
def texture_cache_dir() -> Path:
    """Directory for texture PNGs: ``$TOPODRAKE_TEXTURE_DIR`` or
    ``<tempdir>/topodrake_textures``."""
    env = os.environ.get("TOPODRAKE_TEXTURE_DIR")
    path = Path(env) if env else Path(tempfile.gettempdir()) / "topodrake_textures"
    path.mkdir(parents=True, exist_ok=True)
    return path


@lru_cache(maxsize=1)
def _bank_digest() -> str:
    return hashlib.sha1(np.ascontiguousarray(texture_bank()).tobytes()).hexdigest()


def _write_once(prefix: str, key: tuple, make) -> str:
    """Path of ``cache/<prefix>_<hash of key and texture bank>.png``; if it is
    missing, write ``make()`` (PNG bytes) there with an atomic rename, so
    concurrent processes never see a partial file and nothing is re-encoded
    once cached."""
    digest = hashlib.sha1(repr((key, _bank_digest())).encode()).hexdigest()[:16]
    path = texture_cache_dir() / f"{prefix}_{digest}.png"
    if not path.exists():
        data = make()
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=".png")
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(data)
            os.replace(tmp, path)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise
    return str(path)


def _png_bytes(rgb: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb)).save(buf, format="PNG")
    return buf.getvalue()


def texture_png_path(tid: int) -> str:
    """Path of one texture tile's PNG (:func:`texture_png_bytes`), written once."""
    return _write_once(f"tex{int(tid):02d}", ("tile", int(tid)),
                       lambda: texture_png_bytes(int(tid)))


def tiled_png_path(tid: int, width_m: float, height_m: float,
                   u_start: float = 0.0, v_start: float = 0.0,
                   px_per_m: float = TILE_PX) -> str:
    """PNG of texture ``tid`` repeated over a ``width_m x height_m`` face at one
    tile per ``TILE_M`` (nearest-neighbour texels), written once.

    The face's texture coordinate (0, 0) (OpenGL: bottom-left of the image)
    sits at world texture position ``(u_start, v_start)`` metres, and texel
    ``(floor(v * TEXELS / TILE_M), floor(u * TEXELS / TILE_M))`` (mod TEXELS)
    of the tile is shown at ``(u, v)``, as in the batched renderer (u along a
    wall or world x, v = height z or world y). ``px_per_m`` is lowered so that
    no side exceeds :data:`MAX_PNG_PX`.
    """
    px_per_m = min(px_per_m, MAX_PNG_PX / max(width_m, height_m, 1e-9))
    w = max(1, int(round(width_m * px_per_m)))
    h = max(1, int(round(height_m * px_per_m)))
    return _write_once(f"tiled{int(tid):02d}_{w}x{h}",
                       ("tiled", int(tid), width_m, height_m, u_start, v_start, w, h),
                       lambda: _tiled_png(tid, width_m, height_m, u_start, v_start, w, h))


def _tiled_png(tid, width_m, height_m, u_start, v_start, w, h) -> bytes:
    scale = TEXELS / TILE_M
    u = u_start + (np.arange(w) + 0.5) / w * width_m
    v = v_start + (np.arange(h) + 0.5) / h * height_m
    cols = np.floor(u * scale).astype(np.int64) % TEXELS
    rows = (np.floor(v * scale).astype(np.int64) % TEXELS)[::-1]  # PNG row 0 = top
    tile = (texture_bank()[int(tid)] * 255).astype(np.uint8)
    return _png_bytes(tile[rows[:, None], cols[None, :]])


def texture_rgba(tid: int) -> tuple[float, float, float]:
    """Mean colour of a texture tile (r, g, b) in [0, 1]."""
    return tuple(float(c) for c in texture_bank()[int(tid)].reshape(-1, 3).mean(axis=0))


# ---------------------------------------------------------------------------
# which walls to register
# ---------------------------------------------------------------------------
def visible_walls(world) -> np.ndarray:
    """(N,) bool: walls whose footprint (grown by two grid cells) touches a free
    cell of the occupancy grid. Walls buried in other walls, or lying entirely
    outside every room, are False."""
    walls = world.walls
    grid = world.grid
    res = grid.resolution
    free = ~grid.occupied
    margin = 2.0 * res
    keep = np.zeros(len(walls), bool)
    corners = walls.corners()
    for i in range(len(walls)):
        c = corners[i]
        lo = np.floor((c.min(axis=0) - margin - grid.origin) / res).astype(int)
        hi = np.ceil((c.max(axis=0) + margin - grid.origin) / res).astype(int)
        c0, r0 = np.maximum(lo, 0)
        c1, r1 = np.minimum(hi, [grid.shape[1], grid.shape[0]])
        if c0 >= c1 or r0 >= r1:
            continue
        sub = free[r0:r1, c0:c1]
        if not sub.any():
            continue
        xs = grid.origin[0] + (np.arange(c0, c1) + 0.5) * res
        ys = grid.origin[1] + (np.arange(r0, r1) + 0.5) * res
        px, py = np.meshgrid(xs, ys)
        p0 = walls.segments[i, :2]
        d = walls.segments[i, 2:] - p0
        length = float(np.hypot(*d))
        d = d / length
        rx, ry = px - p0[0], py - p0[1]
        along = rx * d[0] + ry * d[1]
        across = -rx * d[1] + ry * d[0]
        near = ((along >= -margin) & (along <= length + margin)
                & (np.abs(across) <= 0.5 * walls.thickness[i] + margin))
        keep[i] = bool((near & sub).any())
    return keep


# ---------------------------------------------------------------------------
# SceneGraph registration
# ---------------------------------------------------------------------------
def _properties(rgb, texture_path: str | None, *, illustration: bool = True):
    from pydrake.geometry import IllustrationProperties, PerceptionProperties, Rgba

    colour = Rgba(*rgb, 1.0)
    perception = PerceptionProperties()
    if texture_path is not None:
        # VTK multiplies the texture by the diffuse colour: keep it white.
        perception.AddProperty("phong", "diffuse", Rgba(1.0, 1.0, 1.0, 1.0))
        perception.AddProperty("phong", "diffuse_map", texture_path)
    else:
        perception.AddProperty("phong", "diffuse", colour)
    illus = None
    if illustration:
        illus = IllustrationProperties()
        illus.AddProperty("phong", "diffuse", colour)
    return illus, perception


def _register(scene_graph, source_id, name, shape, X_WG, illus, perception):
    from pydrake.geometry import GeometryInstance

    inst = GeometryInstance(X_WG, shape, name)
    if illus is not None:
        inst.set_illustration_properties(illus)
    if perception is not None:
        inst.set_perception_properties(perception)
    return scene_graph.RegisterAnchoredGeometry(source_id, inst)


def atlas_png_path(tids: tuple, width_m: float, height_m: float, u_start: float,
                   px_per_m: float) -> str:
    """Texture atlas for merged walls: one horizontal band per texture id in
    ``tids`` (top to bottom), each a strip as in :func:`tiled_png_path` of
    ``width_m x height_m`` starting at ``u_start``, with :data:`ATLAS_PAD`
    rows above and below that repeat the band's edge rows (so bilinear
    filtering never bleeds between bands). Written once."""
    w = max(1, int(round(width_m * px_per_m)))
    hb = max(1, int(round(height_m * px_per_m)))
    return _write_once(f"atlas{len(tids)}_{w}x{len(tids) * (hb + 2 * ATLAS_PAD)}",
                       ("atlas", tids, width_m, height_m, u_start, w, hb, ATLAS_PAD),
                       lambda: _atlas_png(tids, width_m, height_m, u_start, w, hb))


def _atlas_png(tids, width_m, height_m, u_start, w, hb) -> bytes:
    scale = TEXELS / TILE_M
    u = u_start + (np.arange(w) + 0.5) / w * width_m
    v = (np.arange(hb) + 0.5) / hb * height_m
    cols = np.floor(u * scale).astype(np.int64) % TEXELS
    rows = (np.floor(v * scale).astype(np.int64) % TEXELS)[::-1]
    rows = np.concatenate([np.full(ATLAS_PAD, rows[0]), rows, np.full(ATLAS_PAD, rows[-1])])
    bank = (texture_bank() * 255).astype(np.uint8)
    img = np.concatenate([bank[int(t)][rows[:, None], cols[None, :]] for t in tids], axis=0)
    return _png_bytes(img)


def _merged_walls(world, idx: np.ndarray) -> tuple[str, tuple]:
    """One OBJ (text) with the vertical faces of walls ``idx``, and the
    arguments of :func:`atlas_png_path` for its texture.

    Texture coordinates follow the batched renderer: u runs along each face
    from its :class:`~topodrake.world.walls.Faces` origin ``u0`` (metres),
    v = z. Drake's VTK engine clamps mesh textures instead of repeating them,
    so the coordinates point into an atlas with one pre-tiled strip per
    texture id covering ``[u_start, u_start + width_m] x [0, wall_height]``.
    Top and bottom faces are left out: the floor and ceiling slabs hide them.
    """
    walls = world.walls
    h = float(world.wall_height)
    c = walls.corners()[idx]                      # (K, 4, 2) counter-clockwise
    a = c.reshape(-1, 2)
    b = np.roll(c, -1, axis=1).reshape(-1, 2)
    tex = np.repeat(walls.texture[idx], 4)
    u0 = np.where(np.abs(b[:, 0] - a[:, 0]) >= np.abs(b[:, 1] - a[:, 1]), a[:, 0], a[:, 1])
    length = np.hypot(*(b - a).T)
    u_start = float(np.floor(u0.min()))
    width_m = float(np.ceil((u0 + length).max() - u_start + 1e-9))
    tids = tuple(int(t) for t in np.unique(tex))
    band = np.searchsorted(np.array(tids), tex)
    px_per_m = min(TILE_PX / TILE_M, MAX_PNG_PX / width_m,
                   (MAX_PNG_PX / len(tids) - 2 * ATLAS_PAD) / h)
    hb = max(1, int(round(h * px_per_m)))
    total = len(tids) * (hb + 2 * ATLAS_PAD)
    # Image rows from the top: band k spans [k (hb + 2 pad) + pad, ... + hb).
    top = band * (hb + 2 * ATLAS_PAD) + ATLAS_PAD
    t_lo = 1.0 - (top + hb) / total           # z = 0
    t_hi = 1.0 - top / total                  # z = h
    m = len(a)
    v = np.empty((m, 4, 3))
    v[:, 0, :2], v[:, 0, 2] = a, 0.0
    v[:, 1, :2], v[:, 1, 2] = b, 0.0
    v[:, 2, :2], v[:, 2, 2] = b, h
    v[:, 3, :2], v[:, 3, 2] = a, h
    s0 = (u0 - u_start) / width_m
    s1 = (u0 + length - u_start) / width_m
    uv = np.empty((m, 4, 2))
    uv[:, 0] = np.column_stack([s0, t_lo])
    uv[:, 1] = np.column_stack([s1, t_lo])
    uv[:, 2] = np.column_stack([s1, t_hi])
    uv[:, 3] = np.column_stack([s0, t_hi])
    # Corners run counter-clockwise, so the outward normal of a -> b is on its
    # right; the quads (a0, b0, bh, ah) are counter-clockwise seen from outside.
    d = (b - a) / length[:, None]
    normals = np.column_stack([d[:, 1], -d[:, 0], np.zeros(m)])
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in v.reshape(-1, 3)]
    lines += [f"vt {p:.8f} {q:.8f}" for p, q in uv.reshape(-1, 2)]
    lines += [f"vn {x:.6f} {y:.6f} {z:.6f}" for x, y, z in normals]
    for f in range(m):
        k = 4 * f + 1
        n = f + 1
        lines.append(f"f {k}/{k}/{n} {k + 1}/{k + 1}/{n} {k + 2}/{k + 2}/{n}")
        lines.append(f"f {k}/{k}/{n} {k + 2}/{k + 2}/{n} {k + 3}/{k + 3}/{n}")
    return "\n".join(lines) + "\n", (tids, width_m, h, u_start, hb / h)


def register_world(scene_graph, world, *, textures: bool = True,
                   source_name: str = "topodrake_world", merge: bool = False,
                   cull_hidden: bool = False):
    """Register ``world`` into ``scene_graph`` as anchored geometry; return the SourceId.

    One Box per wall (``length x thickness x wall_height``; named
    ``wall_<i>``), plus ``floor`` (top face at z = 0) and ``ceiling`` (bottom
    face at z = wall_height, perception only) slabs over the world bbox. Every
    geometry has perception properties (phong diffuse colour, or a pre-tiled
    ``diffuse_map`` PNG when ``textures``); walls and floor also have
    illustration properties (mean texture colour) for Meshcat.

    ``merge`` gives cameras one OBJ mesh for all walls (named ``walls``,
    perception only, texture atlas) and keeps the boxes for illustration
    only; ``cull_hidden`` skips walls that cannot be seen from free space
    (:func:`visible_walls`). ``source_name`` must not be registered in
    ``scene_graph`` already.
    """
    from pydrake.common import MemoryFile
    from pydrake.geometry import Box, InMemoryMesh, Mesh
    from pydrake.math import RigidTransform, RotationMatrix

    try:
        source_id = scene_graph.RegisterSource(source_name)
    except RuntimeError as e:
        raise TopodrakeError(
            f"cannot register world {world.name!r} as source {source_name!r}: {e}") from None

    walls = world.walls
    h = float(world.wall_height)
    if h <= 0:
        raise TopodrakeError(f"world {world.name!r}: wall height must be positive, got {h}")
    keep = visible_walls(world) if cull_hidden else np.ones(len(walls), bool)
    lengths = walls.lengths()
    yaws = walls.yaws()
    mids = 0.5 * (walls.segments[:, :2] + walls.segments[:, 2:])

    # The box's -y face runs p0 -> p1 like face 0 of Faces.from_walls; start
    # its texture where the batched renderer does. (The +y face, mapped from
    # p1 backwards, is then off by the wall length mod 1 m.)
    first = Faces.from_walls(walls).u0[0::4]
    for i in np.flatnonzero(keep):
        tid = int(walls.texture[i])
        L = float(lengths[i])
        X = RigidTransform(RotationMatrix.MakeZRotation(float(yaws[i])),
                           [float(mids[i, 0]), float(mids[i, 1]), 0.5 * h])
        shape = Box(L, float(walls.thickness[i]), h)
        if merge:   # illustration only; cameras see the merged mesh
            illus, _ = _properties(texture_rgba(tid), None)
            perc = None
        else:
            path = (tiled_png_path(tid, round(L, 4), h, round(float(first[i]), 4))
                    if textures else None)
            illus, perc = _properties(texture_rgba(tid), path)
        _register(scene_graph, source_id, f"wall_{int(i)}", shape, X, illus, perc)
    if merge and keep.any():
        idx = np.flatnonzero(keep)
        obj, atlas = _merged_walls(world, idx)
        mesh = Mesh(InMemoryMesh(mesh_file=MemoryFile(obj, ".obj", "walls")))
        rgb = np.mean([texture_rgba(t) for t in walls.texture[idx]], axis=0)
        _, perc = _properties(tuple(rgb), atlas_png_path(*atlas) if textures else None,
                              illustration=False)
        _register(scene_graph, source_id, "walls", mesh, RigidTransform(), None, perc)

    (x0, y0), (x1, y1) = np.asarray(world.bbox, dtype=np.float64)
    w, d = float(x1 - x0), float(y1 - y0)
    cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    for name, tex_arr, z, illustrate in (
            ("floor", world.floor_texture, -0.5 * SLAB_M, True),
            ("ceiling", world.ceiling_texture, h + 0.5 * SLAB_M, False)):
        tid = int(tex_arr[0]) if len(tex_arr) else 0
        path = (tiled_png_path(tid, round(w, 4), round(d, 4), float(x0), float(y0),
                               SLAB_PX) if textures else None)
        illus, perc = _properties(texture_rgba(tid), path, illustration=illustrate)
        _register(scene_graph, source_id, name, Box(w, d, SLAB_M),
                  RigidTransform([cx, cy, z]), illus, perc)
    return source_id


# ---------------------------------------------------------------------------
# VTK rendering
# ---------------------------------------------------------------------------
def camera_pose(pose, camera):
    """``RigidTransform`` X_WC of the camera for one car pose ``(x, y, theta)``.

    Drake's camera frame: +X right, +Y down, +Z forward along the optical axis.
    """
    from pydrake.math import RigidTransform, RotationMatrix

    x, y, th = (float(v) for v in pose)
    c, s = np.cos(th), np.sin(th)
    R = np.array([[s, 0.0, c],
                  [-c, 0.0, s],
                  [0.0, -1.0, 0.0]])
    return RigidTransform(RotationMatrix(R),
                          [x + camera.forward_m * c, y + camera.forward_m * s, camera.height_m])


def default_lights() -> list:
    """Four world-frame directional lights for the colour camera.

    Drake's default single light is a directional *camera* light along the
    optical axis; with a horizontal optical axis it leaves the floor and the
    ceiling black. Here one light points straight up (ceiling fully lit) and
    three point down at 20 deg below the horizon from azimuths 120 deg apart:
    the floor gets 3 * 0.9 * sin 20deg = 0.92 and any wall, whatever its
    yaw, 0.85 to 0.98 (the batched renderer: 1 and 0.7 to 1). Each light costs
    about 0.35 ms per 64x64 colour image on llvmpipe, hence only four.
    """
    from pydrake.geometry import LightParameter

    def light(direction, intensity):
        return LightParameter(type="directional", frame="world",
                              direction=np.asarray(direction, float), intensity=intensity)

    tilt = np.radians(20.0)
    lights = [light([0.0, 0.0, 1.0], 1.0)]
    for az in np.radians([90.0, 210.0, 330.0]):
        lights.append(light([np.cos(tilt) * np.cos(az), np.cos(tilt) * np.sin(az),
                             -np.sin(tilt)], 0.9))
    return lights


def _check_poses(poses) -> np.ndarray:
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim == 1:
        p = p[None]
    if p.ndim != 2 or p.shape[1] != 3 or not np.all(np.isfinite(p)):
        raise TopodrakeError(
            f"poses must be finite (N, 3) rows of x, y, heading; got shape {p.shape}")
    return p


class VtkDepthRenderer:
    """Drake ``RenderEngineVtk`` over one world, posed per image.

    Built once: a standalone SceneGraph with the world registered
    (:func:`register_world`) and a VTK render engine. Each image renders
    through ``QueryObject.RenderDepthImage`` / ``RenderColorImage`` with the
    camera posed relative to the world frame (``X_PC`` = X_WC), so moving the
    camera costs nothing beyond the render. Not thread-safe.

    Depth is z-depth in metres (distance along the optical axis), float32;
    ``inf`` where nothing lies within ``camera.max_depth_m`` and 0 closer than
    ``min_depth_m`` (Drake's conventions).

    ``textures``, ``merge`` (default True here: one wall mesh, much faster on
    big worlds, same depth) and ``cull_hidden`` go to :func:`register_world`;
    ``backend`` to ``RenderEngineVtkParams`` ("" = Drake's default, EGL on
    Linux). Colour images use :func:`default_lights`. Build one renderer per
    process (do not carry one across ``fork``).
    """
    def __init__(self, world, camera=None, *, textures: bool = True, merge: bool = True,
                 cull_hidden: bool = False, min_depth_m: float = 0.01, backend: str = ""):
        from pydrake.geometry import (
            ClippingRange,
            ColorRenderCamera,
            DepthRange,
            DepthRenderCamera,
            MakeRenderEngineVtk,
            RenderCameraCore,
            RenderEngineVtkParams,
            SceneGraph,
        )
        from pydrake.math import RigidTransform
        from pydrake.systems.sensors import CameraInfo


        self.world = world
        self.camera = camera if camera is not None else CameraConfig()
        cam = self.camera
        W, H = int(cam.width), int(cam.height)
        # Drake/VTK put the centre of pixel (u, v) at continuous image
        # coordinates (u + 0.5, v + 0.5); CameraConfig's cx, cy index pixel
        # centres from 0 (ray of column j: (j - cx) / fx). Shift by half a
        # pixel. (This also makes a 1-row camera legal: Drake wants
        # 0 < center_y < height.)
        cx, cy = float(cam.cx) + 0.5, float(cam.cy) + 0.5
        info = CameraInfo(W, H, float(cam.fx), float(cam.fx), cx, cy)
        far = float(cam.max_depth_m)
        core = RenderCameraCore(RENDERER_NAME, info, ClippingRange(min_depth_m, far * 1.01),
                                RigidTransform())
        self._depth_camera = DepthRenderCamera(core, DepthRange(min_depth_m, far))
        self._color_camera = ColorRenderCamera(core, False)

        params = RenderEngineVtkParams()
        params.lights = default_lights()
        params.default_clear_color = np.array([0.5, 0.5, 0.55])
        if backend:
            params.backend = backend
        self._scene_graph = SceneGraph()
        self._scene_graph.AddRenderer(RENDERER_NAME, MakeRenderEngineVtk(params))
        register_world(self._scene_graph, world, textures=textures, merge=merge,
                       cull_hidden=cull_hidden)
        self._context = self._scene_graph.CreateDefaultContext()
        self._world_frame = self._scene_graph.world_frame_id()
        self.shape = (H, W)

    @property
    def scene_graph(self):
        return self._scene_graph

    @property
    def num_render_geometries(self) -> int:
        """Geometries the render engine draws (those with perception properties)."""
        from pydrake.geometry import Role

        return self._scene_graph.model_inspector().NumGeometriesWithRole(Role.kPerception)

    def _query(self):
        return self._scene_graph.get_query_output_port().Eval(self._context)

    def render_depth(self, poses) -> np.ndarray:
        """(N, H, W) float32 z-depth (m) for car poses (N, 3) or one (3,)."""
        poses = _check_poses(poses)
        out = np.empty((len(poses), *self.shape), np.float32)
        query = self._query()
        for k, pose in enumerate(poses):
            img = query.RenderDepthImage(self._depth_camera, self._world_frame,
                                         camera_pose(pose, self.camera))
            out[k] = img.data[:, :, 0]
        return out

    def render_rgb(self, poses) -> np.ndarray:
        """(N, H, W, 3) uint8 colour images for car poses (N, 3) or one (3,)."""
        poses = _check_poses(poses)
        out = np.empty((len(poses), *self.shape, 3), np.uint8)
        query = self._query()
        for k, pose in enumerate(poses):
            img = query.RenderColorImage(self._color_camera, self._world_frame,
                                         camera_pose(pose, self.camera))
            out[k] = img.data[:, :, :3]
        return out


def vtk_depth_renderer(world, camera=None, **kwargs) -> VtkDepthRenderer:
    """A :class:`VtkDepthRenderer` for ``world`` seen by ``camera`` (a
    :class:`~topodrake.sensing.config.CameraConfig`; default one if None)."""
    return VtkDepthRenderer(world, camera, **kwargs)


# ---------------------------------------------------------------------------
# Meshcat
# ---------------------------------------------------------------------------
def add_meshcat_world(meshcat, world, *, path: str = "/topodrake/world",
                      cull_hidden: bool = False) -> str:
    """Draw ``world`` into ``meshcat`` with direct ``SetObject`` calls.

    Each wall is a box at ``<path>/walls/<i>`` coloured with its texture's mean
    colour, the floor a slab at ``<path>/floor`` (top face at z = 0); no
    ceiling, so the view from above is open. No diagram is needed; to see a
    world inside a simulation instead, :func:`register_world` it into the
    diagram's SceneGraph and let a ``MeshcatVisualizer`` draw it. Returns
    ``path`` (``meshcat.Delete(path)`` removes the world).
    """
    from pydrake.geometry import Box, Rgba
    from pydrake.math import RigidTransform, RotationMatrix

    walls = world.walls
    h = float(world.wall_height)
    keep = visible_walls(world) if cull_hidden else np.ones(len(walls), bool)
    lengths = walls.lengths()
    yaws = walls.yaws()
    mids = 0.5 * (walls.segments[:, :2] + walls.segments[:, 2:])
    meshcat.Delete(path)
    for i in np.flatnonzero(keep):
        p = f"{path}/walls/{int(i)}"
        meshcat.SetObject(p, Box(float(lengths[i]), float(walls.thickness[i]), h),
                          Rgba(*texture_rgba(int(walls.texture[i])), 1.0))
        meshcat.SetTransform(p, RigidTransform(
            RotationMatrix.MakeZRotation(float(yaws[i])),
            [float(mids[i, 0]), float(mids[i, 1]), 0.5 * h]))
    (x0, y0), (x1, y1) = np.asarray(world.bbox, dtype=np.float64)
    tid = int(world.floor_texture[0]) if len(world.floor_texture) else 0
    meshcat.SetObject(f"{path}/floor", Box(float(x1 - x0), float(y1 - y0), SLAB_M),
                      Rgba(*texture_rgba(tid), 1.0))
    meshcat.SetTransform(f"{path}/floor", RigidTransform(
        [0.5 * (x0 + x1), 0.5 * (y0 + y1), -0.5 * SLAB_M]))
    return path


#: Vertical field of view (deg) of Meshcat's default perspective camera.
MESHCAT_FOV_DEG = 75.0


def view_angles(camera: np.ndarray, target: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 2) horizontal and vertical angles (deg) of ``points`` (N, 3) off
    the axis of a camera at ``camera`` looking at ``target`` with z up;
    NaN for points behind it."""
    forward = (target - camera) / np.linalg.norm(target - camera)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    d = np.asarray(points, np.float64) - camera
    depth = d @ forward
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.degrees(np.arctan2(np.abs(np.stack([d @ right, d @ up], -1)), depth[:, None]))
    out[depth <= 0] = np.nan
    return out


def framing_camera_pose(world, *, tilt_deg: float = 20.0,
                        fill: float = 0.9) -> tuple[np.ndarray, np.ndarray]:
    """Camera position and target (Drake world frame, z up) that show the
    whole floor plan, walls included: above the centre of its bounding box,
    tilted ``tilt_deg`` from vertical toward -y, at the nearest distance
    where every corner lies within ``fill`` of Meshcat's vertical field of
    view in both directions (so any window at least as wide as tall shows
    it all)."""
    (x0, y0), (x1, y1) = np.asarray(world.bbox, dtype=np.float64)
    h = float(world.wall_height)
    target = np.array([0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.0])
    corners = np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (0.0, h)])
    tilt = np.radians(tilt_deg)
    direction = np.array([0.0, -np.sin(tilt), np.cos(tilt)])
    limit = fill * 0.5 * MESHCAT_FOV_DEG
    distance = 0.5 * max(x1 - x0, y1 - y0, 1.0) / np.tan(np.radians(limit)) + h
    for _ in range(200):
        camera = target + distance * direction
        angles = view_angles(camera, target, corners)
        if np.all(angles < limit):
            break
        distance *= 1.05
    return camera, target


def frame_whole_world(meshcat, world, **kwargs) -> None:
    """Point ``meshcat``'s camera at the whole floor plan
    (:func:`framing_camera_pose`). A recording's static HTML
    (``meshcat.StaticHtml()``) opens with this view."""
    camera, target = framing_camera_pose(world, **kwargs)
    meshcat.SetCameraPose(camera, target)
