"""The world in Drake: SceneGraph registration and RenderEngineVtk images.

Depth images are checked against geometry worked out by hand for the
``box_world`` fixture (room walls' inner faces at 0.2 and 9.8, a partition
with its faces at x = 4.9 and 5.1 for y in [0, 6]).
"""

import numpy as np
import pytest

pytest.importorskip("pydrake")

from topodrake.sensing.config import CameraConfig  # noqa: E402
from topodrake.world import WallSet, world_from_walls  # noqa: E402
from topodrake.sensing.scenegraph import (  # noqa: E402
    add_meshcat_world, register_world, tiled_png_path, visible_walls, vtk_depth_renderer)

CAM = CameraConfig()


@pytest.fixture(scope="module")
def renderer(box_world):
    """One textured box per wall."""
    return vtk_depth_renderer(box_world, CAM, merge=False)


@pytest.fixture(scope="module")
def merged(box_world):
    """All walls as one mesh (the renderer's default)."""
    return vtk_depth_renderer(box_world, CAM)


def _roles(scene_graph):
    from pydrake.geometry import Role

    insp = scene_graph.model_inspector()
    return insp, {role: insp.NumGeometriesWithRole(role)
                  for role in (Role.kIllustration, Role.kPerception, Role.kProximity)}


def test_register_one_geometry_per_wall_plus_floor_and_ceiling(box_world):
    from pydrake.geometry import Role, SceneGraph

    sg = SceneGraph()
    source = register_world(sg, box_world)
    insp, counts = _roles(sg)
    n = len(box_world.walls)
    assert insp.num_geometries() == n + 2
    names = {insp.GetName(g) for g in insp.GetAllGeometryIds()}
    assert names == {f"wall_{i}" for i in range(n)} | {"floor", "ceiling"}
    assert counts[Role.kPerception] == n + 2
    assert counts[Role.kIllustration] == n + 1     # no ceiling in Meshcat
    assert counts[Role.kProximity] == 0
    assert all(insp.GetFrameId(g) == sg.world_frame_id() for g in insp.GetAllGeometryIds())
    assert insp.GetName(source) == "topodrake_world"


def test_register_merged_gives_cameras_one_wall_mesh(box_world):
    from pydrake.geometry import Role, SceneGraph

    sg = SceneGraph()
    register_world(sg, box_world, merge=True, source_name="merged")
    _, counts = _roles(sg)
    assert counts[Role.kPerception] == 3           # walls mesh, floor, ceiling
    assert counts[Role.kIllustration] == len(box_world.walls) + 1


def test_depth_facing_a_wall(renderer, merged):
    expected = 4.9 - 2.0 - CAM.forward_m
    for r in (renderer, merged):
        d = r.render_depth([2.0, 3.0, 0.0])
        assert d.shape == (1, CAM.height, CAM.width) and d.dtype == np.float32
        h, w = CAM.height // 2, CAM.width // 2
        np.testing.assert_allclose(d[0, h - 1:h + 1, w - 1:w + 1], expected, atol=0.01)


def test_depth_of_the_floor_per_row(renderer):
    # Facing -x from (2, 3): the wall at x = 0.2 is 1.7 m away; rows far
    # enough below the horizon see the floor first.
    d = renderer.render_depth([2.0, 3.0, np.pi])[0]
    rows = np.arange(40, CAM.height)
    y_n = (rows - CAM.cy) / CAM.fx
    expected = CAM.height_m / y_n
    assert np.all(expected < 1.7 - CAM.forward_m)
    np.testing.assert_allclose(d[rows, 5], expected, atol=0.01)
    np.testing.assert_allclose(d[rows, CAM.width - 6], expected, atol=0.01)


def test_depth_on_an_oblique_wall_per_column(renderer):
    # Heading 0.3 rad towards the partition's face x = 4.9: z-depth of column
    # j is (4.9 - ox) / (cos th + x_n sin th), x_n = (j - cx) / fx.
    th = 0.3
    d = renderer.render_depth([2.0, 3.0, th])[0]
    ox = 2.0 + CAM.forward_m * np.cos(th)
    cols = np.arange(24, CAM.width)
    x_n = (cols - CAM.cx) / CAM.fx
    expected = (4.9 - ox) / (np.cos(th) + x_n * np.sin(th))
    np.testing.assert_allclose(d[CAM.height // 2, cols], expected, atol=0.01)


def test_merged_walls_render_the_same_depth(renderer, merged, box_world):
    poses = box_world.sample_free_pose(np.random.default_rng(3), 8)
    a = renderer.render_depth(poses)
    b = merged.render_depth(poses)
    assert np.array_equal(np.isinf(a), np.isinf(b))
    fin = np.isfinite(a)
    assert np.mean(np.abs(a[fin] - b[fin]) > 0.01) < 0.002   # silhouette pixels only


def test_rgb_images(renderer, merged):
    poses = np.array([[2.0, 3.0, 0.0], [7.0, 8.0, -2.0]])
    for r in (renderer, merged):
        img = r.render_rgb(poses)
        assert img.shape == (2, CAM.height, CAM.width, 3) and img.dtype == np.uint8
        # The world lights make floor and ceiling visible (Drake's default
        # camera headlight along a horizontal axis leaves them black).
        assert img[:, -8:].mean() > 40 and img[:, :8].mean() > 40
    np.testing.assert_allclose(renderer.render_rgb(poses[:1]).astype(float).mean(),
                               merged.render_rgb(poses[:1]).astype(float).mean(), atol=6)


def test_one_row_camera(box_world):
    cam = CameraConfig(width=32, height=1)
    d = vtk_depth_renderer(box_world, cam, textures=False).render_depth([2.0, 3.0, 0.0])
    assert d.shape == (1, 1, 32)
    np.testing.assert_allclose(d[0, 0, 15:17], 4.9 - 2.0 - cam.forward_m, atol=0.01)


def test_bad_poses_raise(renderer):
    from topodrake.errors import TopodrakeError

    with pytest.raises(TopodrakeError, match="poses"):
        renderer.render_depth(np.zeros((2, 2)))


def test_cull_hidden_walls():
    # Four blocks fill the room's corner, a fifth is buried inside one of them.
    boxes = np.array([[0, 0, 10, 0.2], [0, 9.8, 10, 10], [0, 0, 0.2, 10], [9.8, 0, 10, 10],
                      [0.2, 0.2, 0.6, 0.6], [0.6, 0.2, 1.0, 0.6], [0.2, 0.6, 0.6, 1.0],
                      [0.6, 0.6, 1.0, 1.0], [0.3, 0.3, 0.5, 0.5]])
    world = world_from_walls("corner", WallSet.from_boxes(boxes, np.arange(len(boxes))))
    keep = visible_walls(world)
    assert keep.tolist() == [True] * 4 + [False, True, True, True, False]
    from pydrake.geometry import SceneGraph

    sg = SceneGraph()
    register_world(sg, world, cull_hidden=True, textures=False)
    assert sg.model_inspector().num_geometries() == 7 + 2


def test_texture_files_are_cached(tmp_path, monkeypatch):
    monkeypatch.setenv("TOPODRAKE_TEXTURE_DIR", str(tmp_path))
    p1 = tiled_png_path(3, 2.0, 2.5, 0.25)
    mtime = tmp_path.joinpath(p1.split("/")[-1]).stat().st_mtime_ns
    assert tiled_png_path(3, 2.0, 2.5, 0.25) == p1
    assert tmp_path.joinpath(p1.split("/")[-1]).stat().st_mtime_ns == mtime
    assert tiled_png_path(3, 2.0, 2.5, 0.5) != p1
    assert not list(tmp_path.glob(".tmp-*"))
    from PIL import Image

    assert Image.open(p1).size == (64, 80)   # TILE_PX per metre


def test_meshcat_world(box_world):
    from pydrake.geometry import Meshcat

    try:
        meshcat = Meshcat()
    except RuntimeError as e:  # no free port
        pytest.skip(f"Meshcat unavailable: {e}")
    path = add_meshcat_world(meshcat, box_world)
    assert meshcat.HasPath(f"{path}/floor")
    assert all(meshcat.HasPath(f"{path}/walls/{i}") for i in range(len(box_world.walls)))
