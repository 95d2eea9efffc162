"""Real floor plans: ROS map_server maps, HouseExpo JSON, occupancy rasters."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from topodrake.errors import TopodrakeError
from topodrake.world.textures import WALL_TEXTURES
from topodrake.world.houseexpo import load_houseexpo
from topodrake.world.raster import occupied_boxes, world_from_occupancy
from topodrake.world.rosmap import classify, load_ros_map, read_gray

DATA = Path(__file__).parent / "data"
WILLOW = DATA / "maps" / "willow_full_0.05" / "map.yaml"
YUJIN = DATA / "maps" / "yujin_rnd_extended" / "map.yaml"
HOUSEEXPO = DATA / "houseexpo_sample.json"


@pytest.fixture(scope="module")
def willow():
    t = time.perf_counter()
    world = load_ros_map(WILLOW)
    world.load_seconds = time.perf_counter() - t
    return world


@pytest.fixture(scope="module")
def yujin():
    return load_ros_map(YUJIN)


@pytest.fixture(scope="module")
def apartment():
    return load_houseexpo(HOUSEEXPO)


# -- helpers -----------------------------------------------------------------------

def _boundary_edges(occ: np.ndarray) -> int:
    free = ~occ
    return int((free[1:] & occ[:-1]).sum() + (free[:-1] & occ[1:]).sum()
               + (free[:, 1:] & occ[:, :-1]).sum() + (free[:, :-1] & occ[:, 1:]).sum())


def _check_faces(world) -> None:
    """Faces are axis aligned, cover every free/occupied cell edge exactly
    once, and their normal (dy, -dx) points into free space."""
    f, g = world.faces, world.grid
    d = f.b - f.a
    length = np.linalg.norm(d, axis=1)
    assert np.all(length > 0)
    assert np.all((d[:, 0] == 0) | (d[:, 1] == 0)), "faces must be axis aligned"
    assert np.isclose(length.sum(), _boundary_edges(g.occupied) * g.resolution)
    n = np.stack([d[:, 1], -d[:, 0]], axis=1) / length[:, None]
    mid = 0.5 * (f.a + f.b)
    front = g.to_cell(mid + 0.02 * n)
    back = g.to_cell(mid - 0.02 * n)
    assert not g.occupied[front[:, 0], front[:, 1]].any(), "a face normal points into a wall"
    assert g.occupied[back[:, 0], back[:, 1]].all(), "a face has free space behind it"
    assert set(np.unique(f.texture)) <= set(WALL_TEXTURES)
    # u0 is the coordinate along the face direction (textures run on).
    s = np.sign(d)
    assert np.allclose(f.u0, f.a[:, 0] * s[:, 0] + f.a[:, 1] * s[:, 1])


def _check_world(world, shape, origin) -> None:
    g = world.grid
    assert g.shape == shape
    res = g.resolution
    expect = np.array([origin, np.asarray(origin) + res * np.array([shape[1], shape[0]])])
    assert np.allclose(world.bbox, expect)
    # One free region: every free cell is in the largest component.
    assert np.isclose(world.free_area_m2, (~g.occupied).sum() * res ** 2)
    assert np.all(g.occupied[[0, -1], :]) and np.all(g.occupied[:, [0, -1]])
    # Places: 10, in reachable space, spread out.
    assert world.places.shape == (10, 3)
    rc = g.to_cell(world.places[:, :2])
    assert g.reachable[rc[:, 0], rc[:, 1]].all()
    pair_d = np.linalg.norm(world.places[:, None, :2] - world.places[None, :, :2], axis=2)
    assert pair_d[np.triu_indices(10, 1)].min() > 1.0
    # Regions: free cells are room 0, floor and ceiling have one texture each.
    assert np.all(world.regions[~g.occupied] == 0)
    assert world.floor_texture.shape == (1,) and world.ceiling_texture.shape == (1,)
    # Walls cover exactly the occupied cells.
    assert len(world.walls) > 0
    _check_faces(world)


def _check_paths(world, pairs) -> None:
    for i, j in pairs:
        p, q = world.places[i, :2], world.places[j, :2]
        path = world.astar(p, q)
        assert np.allclose(path[0], p, atol=0.1) and np.allclose(path[-1], q, atol=0.1)
        assert world.grid.is_free(path).all()
        assert np.linalg.norm(np.diff(path, axis=0), axis=1).sum() >= np.linalg.norm(q - p) - 0.1


# -- real maps --------------------------------------------------------------------

def test_willow_garage(willow):
    # 1165 x 945 pixels at 0.05 m, origin (0, 0): ~58 x 47 m.
    _check_world(willow, (945, 1165), (0.0, 0.0))
    assert willow.name == "willow_full_0.05"
    assert 500.0 < willow.free_area_m2 < 2000.0
    assert willow.load_seconds < 10.0  # ~0.5 s on the dev machine
    assert len(np.unique(willow.faces.texture)) >= 16, "wall textures should vary"
    _check_paths(willow, [(0, 1), (2, 3)])


def test_yujin_office(yujin):
    _check_world(yujin, (413, 732), (-3.6, -3.2))
    assert 100.0 < yujin.free_area_m2 < 700.0
    _check_paths(yujin, [(0, 1), (2, 5)])


def test_image_is_flipped_so_row_zero_is_lowest_y(yujin):
    raw_free = classify(read_gray(YUJIN.parent / "yujin_rnd_extended.png")) == 0
    free = ~yujin.grid.occupied
    # Every kept free cell is free in the image read bottom-up (up to
    # removed one-cell specks), far from true for the image read top-down.
    assert (raw_free[::-1] & free).sum() > 0.999 * free.sum()
    assert (raw_free & free).sum() < 0.8 * free.sum()


def test_willow_walls_cover_occupied_cells(willow):
    g = willow.grid
    c = willow.walls.corners()
    lo = np.rint((c.min(axis=1) - g.origin) / g.resolution).astype(int)
    hi = np.rint((c.max(axis=1) - g.origin) / g.resolution).astype(int)
    painted = np.zeros(g.shape, np.int32)
    for (c0, r0), (c1, r1) in zip(lo, hi):
        painted[r0:r1, c0:c1] += 1
    assert np.array_equal(painted > 0, g.occupied)
    assert painted.max() == 1, "wall boxes overlap"


def test_houseexpo_apartment(apartment):
    g = apartment.grid
    assert apartment.name == "sample_l_apartment"
    # L-shape: 12 x 5 m + 6 x 5 m minus two thin wall stubs.
    assert 85.0 < apartment.free_area_m2 < 90.0
    (x0, y0), (x1, y1) = apartment.bbox
    assert x0 <= -0.45 and y0 <= -0.45 and x1 >= 12.45 and y1 >= 10.45
    # The missing quadrant of the L is wall; the rooms are free.
    assert not g.is_free(np.array([[9.0, 8.0]]))[0]
    assert g.is_free(np.array([[3.0, 8.0], [3.0, 2.0], [10.0, 2.5]])).all()
    # The wall stub at x = 8 (0.15 m thick) is solid.
    assert g.occupied[tuple(g.to_cell(np.array([8.01, 1.0])))]
    _check_world(apartment, g.shape, g.origin)
    _check_paths(apartment, [(0, 1), (2, 3)])


# -- occupancy raster processing --------------------------------------------------------

def test_occupancy_cleanup():
    occ = np.zeros((80, 100), bool)
    occ[:, :3] = occ[:, -3:] = occ[:3, :] = occ[-3:, :] = True
    occ[40, 50] = True                    # one-cell speck: noise, removed
    occ[20, 20:22] = True                 # two-cell obstacle: kept
    occ[60:66, 60:75] = True              # furniture with an enclosed free pocket
    occ[62, 65] = False                   # pocket: not reachable, becomes wall
    occ[30, 1:3] = False                  # a one-cell-wide dead-end crack into a wall
    occ[0:30, 50] = True                  # a one-cell-thin wall: kept
    world = world_from_occupancy("synthetic", occ, (1.0, 2.0), 0.1, source="synthetic.pgm")
    g = world.grid
    assert not g.occupied[40, 50]
    assert g.occupied[20, 20:22].all()
    assert g.occupied[62, 65]
    assert g.occupied[30, 1:3].all()
    assert np.array_equal(g.occupied[0:30, 50], np.ones(30, bool))
    assert np.allclose(world.bbox, [[1.0, 2.0], [11.0, 10.0]])
    _check_faces(world)


def test_occupied_boxes_cover_mask_exactly():
    rng = np.random.default_rng(3)
    mask = rng.random((40, 50)) < 0.4
    mask[10:30, 5:25] = True
    boxes = occupied_boxes(mask)
    painted = np.zeros(mask.shape, np.int32)
    for r0, c0, r1, c1 in boxes:
        painted[r0:r1, c0:c1] += 1
    assert np.array_equal(painted > 0, mask) and painted.max() == 1
    runs = int((np.diff(np.pad(mask, ((0, 0), (1, 0))).astype(np.int8), axis=1) == 1).sum())
    assert len(boxes) < runs       # identical runs of the block merged


# -- ROS map files ------------------------------------------------------------------------

def _write_map(tmp_path: Path, pixels: np.ndarray, yaml_text: str | None = None,
               name: str = "m.png", **keys) -> Path:
    Image.fromarray(pixels.astype(np.uint8)).save(tmp_path / name)
    meta = {"image": name, "resolution": 0.05, "origin": "[0.0, 0.0, 0.0]", "negate": 0,
            "occupied_thresh": 0.65, "free_thresh": 0.196}
    meta.update(keys)
    path = tmp_path / "map.yaml"
    path.write_text(yaml_text if yaml_text is not None else
                    "".join(f"{k}: {v}\n" for k, v in meta.items()))
    return path


def _halves() -> np.ndarray:
    """A 60 x 100 image: white (free) left of column 60, black right of it."""
    img = np.zeros((60, 100), np.uint8)
    img[:, :60] = 254
    return img


def test_negate_flips_semantics(tmp_path):
    plain = load_ros_map(_write_map(tmp_path, _halves()))
    x = plain.grid.to_world(np.argwhere(~plain.grid.occupied))[:, 0]
    assert x.max() < 3.0                  # free on the left (white)
    flipped = load_ros_map(_write_map(tmp_path, _halves(), negate=1))
    x = flipped.grid.to_world(np.argwhere(~flipped.grid.occupied))[:, 0]
    assert x.min() > 3.0                  # free on the right (black)


def test_classify_trinary_and_raw():
    v = np.array([0, 100, 150, 204, 206, 254, 255])
    assert classify(v).tolist() == [1, -1, -1, -1, 0, 0, 0]
    assert classify(v, negate=True).tolist() == [0, -1, -1, 1, 1, 1, 1]
    assert classify(np.array([0, 10, 50, 100, 255]), mode="raw").tolist() == [0, 0, -1, 1, -1]


def test_rgba_png_channels_averaged_alpha_ignored(tmp_path):
    img = np.zeros((60, 100, 4), np.uint8)
    img[:, :60, :3] = 254
    img[..., 3] = 0                       # fully transparent: alpha is ignored
    Image.fromarray(img, "RGBA").save(tmp_path / "rgba.png")
    path = tmp_path / "map.yaml"
    path.write_text("image: rgba.png\nresolution: 0.05\norigin: [0, 0, 0]\n")
    world = load_ros_map(path)
    assert world.grid.to_world(np.argwhere(~world.grid.occupied))[:, 0].max() < 3.0


def _error(call, path) -> str:
    with pytest.raises(TopodrakeError) as info:
        call(path)
    msg = str(info.value)
    assert str(path) in msg, msg
    assert "\n" not in msg
    return msg


@pytest.mark.parametrize("text, expect", [
    ("image: m.png\nresolution: [0.05\norigin: [0, 0, 0]\n", "malformed YAML"),
    ("- just\n- a list\n", "mapping"),
    ("image: m.png\norigin: [0, 0, 0]\n", "resolution"),
    ("resolution: 0.05\norigin: [0, 0, 0]\n", "image"),
    ("image: m.png\nresolution: 0\norigin: [0, 0, 0]\n", "resolution"),
    ("image: m.png\nresolution: -0.05\norigin: [0, 0, 0]\n", "resolution"),
    ("image: m.png\nresolution: abc\norigin: [0, 0, 0]\n", "resolution"),
    ("image: m.png\nresolution: 0.05\norigin: [0, 0]\nfree_thresh: 0.7\n", "thresh"),
    ("image: m.png\nresolution: 0.05\norigin: [0, 0]\noccupied_thresh: 1.5\n", "thresh"),
    ("image: m.png\nresolution: 0.05\norigin: zero\n", "origin"),
    ("image: m.png\nresolution: 0.05\norigin: [0, 0]\nmode: fancy\n", "mode"),
    ("image: m.png\nresolution: 0.05\norigin: [0, 0]\nnegate: 2\n", "negate"),
    ("image: nowhere.png\nresolution: 0.05\norigin: [0, 0, 0]\n", "does not exist"),
])
def test_bad_yaml_is_one_line_error_naming_file(tmp_path, text, expect):
    path = _write_map(tmp_path, _halves(), yaml_text=text)
    assert expect in _error(load_ros_map, path)


def test_missing_yaml_file(tmp_path):
    _error(load_ros_map, tmp_path / "absent.yaml")


def test_truncated_png(tmp_path):
    data = (YUJIN.parent / "yujin_rnd_extended.png").read_bytes()
    (tmp_path / "cut.png").write_bytes(data[: len(data) // 2])
    path = _write_map(tmp_path, _halves(), yaml_text="image: cut.png\nresolution: 0.05\n"
                      "origin: [0, 0, 0]\n")
    assert "cut.png" in _error(load_ros_map, path)


def test_not_an_image(tmp_path):
    (tmp_path / "junk.pgm").write_bytes(b"P5\n12 x\n")
    path = _write_map(tmp_path, _halves(), yaml_text="image: junk.pgm\nresolution: 0.05\n"
                      "origin: [0, 0, 0]\n")
    _error(load_ros_map, path)


def test_map_with_no_free_space(tmp_path):
    path = _write_map(tmp_path, np.full((40, 40), 205, np.uint8))   # all unknown
    assert "no free space" in _error(load_ros_map, path)
    path = _write_map(tmp_path, np.zeros((40, 40), np.uint8))       # all occupied
    assert "no free space" in _error(load_ros_map, path)


def test_map_too_narrow_for_the_car(tmp_path):
    img = np.zeros((40, 40), np.uint8)
    img[10:30, 18:21] = 254                                        # 15 cm wide strip
    assert "car" in _error(load_ros_map, _write_map(tmp_path, img))


# -- HouseExpo files ------------------------------------------------------------------------

@pytest.mark.parametrize("text, expect", [
    ('{"verts": [[0, 0], [5, 0], [5, 5]', "malformed JSON"),
    ('[1, 2, 3]', "object"),
    ('{"id": "x", "bbox": {"min": [0, 0], "max": [1, 1]}}', "verts"),
    ('{"verts": [[0, 0], [5, 0]]}', "at least 3"),
    ('{"verts": [[0, 0], [5, 0], [10, 0]]}', "degenerate"),
    ('{"verts": [[0, 0], [5, "a"], [5, 5]]}', "pairs"),
    ('{"verts": "square"}', "pairs"),
])
def test_bad_houseexpo_is_one_line_error_naming_file(tmp_path, text, expect):
    path = tmp_path / "house.json"
    path.write_text(text)
    assert expect in _error(load_houseexpo, path)


def test_missing_houseexpo_file(tmp_path):
    _error(load_houseexpo, tmp_path / "absent.json")
