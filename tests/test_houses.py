"""Procedural houses and the world catalogue."""

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.world.textures import FLOOR_TEXTURES, FURNITURE_TEXTURES, WALL_TEXTURES
from topodrake.world import load_world as load_world_pkg
from topodrake.world.catalogue import CATALOGUE, catalogue_names, load_world
from topodrake.world.houses import HouseConfig, generate_house, generate_house_with_layout

NAMES = catalogue_names()

#: Free areas (m^2) of the catalogue houses: the catalogue must not drift,
#: shipped checkpoints and study results refer to these floor plans.
PINNED_AREA_M2 = {
    "train-00": 332.8, "train-01": 343.9, "train-02": 303.3, "train-03": 259.6,
    "train-04": 214.2, "train-05": 238.9, "train-06": 289.0, "train-07": 225.8,
    "train-08": 245.5, "train-09": 274.1, "train-10": 233.6, "train-11": 270.4,
    "train-12": 280.8, "train-13": 383.3, "train-14": 313.6, "train-15": 294.7,
    "train-16": 264.7, "train-17": 421.7, "train-18": 342.8, "train-19": 266.2,
    "train-20": 342.7, "train-21": 298.8, "train-22": 213.4, "train-23": 294.7,
    "train-24": 281.6, "train-25": 394.1, "train-26": 251.7, "train-27": 217.7,
    "train-28": 387.6, "train-29": 399.2, "train-30": 268.9, "train-31": 367.8,
    "train-32": 402.5, "train-33": 398.1, "train-34": 254.1, "train-35": 288.8,
    "train-36": 277.4, "train-37": 287.4, "train-38": 279.8, "train-39": 408.9,
    "train-40": 394.9, "train-41": 402.1, "train-42": 295.0, "train-43": 245.6,
    "train-44": 219.7, "train-45": 396.3, "train-46": 233.1, "train-47": 336.1,
    "train-48": 369.1, "train-49": 275.2, "train-50": 323.7, "train-51": 379.6,
    "train-52": 273.2, "train-53": 394.6, "train-54": 220.9, "train-55": 379.2,
    "train-56": 418.9, "train-57": 305.3, "train-58": 219.3, "train-59": 312.7,
    "train-60": 426.7, "train-61": 347.3, "train-62": 352.1, "train-63": 423.8,
    "train-64": 268.1, "train-65": 428.8, "train-66": 309.1, "train-67": 418.9,
    "train-68": 394.5, "train-69": 432.9, "train-70": 259.6, "train-71": 268.7,
    "train-72": 325.3, "train-73": 290.6, "train-74": 436.7, "train-75": 390.2,
    "train-76": 295.2, "train-77": 324.4, "train-78": 408.9, "train-79": 422.7,
    "train-80": 402.4, "train-81": 316.1, "train-82": 388.4, "train-83": 300.1,
    "train-84": 405.9, "train-85": 395.1, "train-86": 390.2, "train-87": 324.5,
    "train-88": 339.4, "train-89": 244.3, "train-90": 366.3, "train-91": 228.6,
    "train-92": 214.7, "train-93": 378.3, "train-94": 373.4, "train-95": 315.1,
    "test-0": 337.1, "test-1": 304.7, "test-2": 400.7, "test-3": 279.8, "test-4": 358.9,
    "calib-0": 312.3, "calib-1": 410.7, "calib-2": 245.7, "calib-3": 228.1, "calib-4": 397.3,
}


@pytest.fixture(scope="module")
def houses():
    """name -> (world from load_world, layout)."""
    out = {}
    for name in NAMES:
        _, layout = generate_house_with_layout(CATALOGUE[name], name)
        out[name] = (load_world(name), layout)
    return out


def test_catalogue_names_and_seeds():
    assert NAMES == ([f"train-{i:02d}" for i in range(96)] + [f"test-{i}" for i in range(5)]
                     + [f"calib-{i}" for i in range(5)])
    assert len(set(CATALOGUE.values())) == 106
    assert set(PINNED_AREA_M2) == set(NAMES)


def test_same_seed_same_house_and_different_seeds_differ():
    a = generate_house(77, "a")
    b = generate_house(77, "b")
    c = generate_house(78, "c")
    assert np.array_equal(a.walls.segments, b.walls.segments)
    assert np.array_equal(a.walls.thickness, b.walls.thickness)
    assert np.array_equal(a.walls.texture, b.walls.texture)
    assert np.array_equal(a.places, b.places)
    assert np.array_equal(a.grid.occupied, b.grid.occupied)
    assert (a.walls.segments.shape != c.walls.segments.shape
            or not np.allclose(a.walls.segments, c.walls.segments))
    assert not np.allclose(a.places, c.places)


def test_load_world_caches_and_matches_the_generator(houses):
    world, layout = houses["train-03"]
    assert load_world("train-03") is world
    assert load_world_pkg("train-03") is world
    fresh = generate_house(CATALOGUE["train-03"], "train-03")
    assert np.array_equal(fresh.walls.segments, world.walls.segments)
    assert world.name == "train-03"


@pytest.mark.parametrize("name", NAMES)
def test_catalogue_house(houses, name):
    world, layout = houses[name]
    g = world.grid
    # Area in the paper's range, and pinned.
    assert 200.0 <= world.free_area_m2 <= 460.0
    assert world.free_area_m2 == pytest.approx(PINNED_AREA_M2[name], abs=0.1)
    # Ten places, reachable, spread out.
    assert world.places.shape == (10, 3)
    rc = g.to_cell(world.places[:, :2])
    assert g.in_bounds(rc).all() and g.reachable[rc[:, 0], rc[:, 1]].all()
    d = np.linalg.norm(world.places[:, None, :2] - world.places[None, :, :2], axis=-1)
    assert d[np.triu_indices(10, 1)].min() >= 2.0
    # Every doorway is passable: both sides of it are in the reachable region.
    probes = layout.door_probes().reshape(-1, 2)
    prc = g.to_cell(probes)
    assert g.reachable[prc[:, 0], prc[:, 1]].all()
    # Furniture never cuts off free space.
    free = g.free_space
    assert (free & g.reachable).sum() / free.sum() > 0.97
    # Rooms (not corridors) are 3-7 m on a side.
    rooms = np.array([k == "room" for k in layout.room_kind])[layout.tile_room]
    sides = layout.tiles[rooms, 2:] - layout.tiles[rooms, :2]
    assert sides.min() >= 3.0 - 1e-9 and sides.max() <= 7.0 + 1e-9
    assert layout.room_kind.count("corridor") == 1


@pytest.mark.parametrize("name", NAMES)
def test_places_are_joined_by_astar(houses, name):
    world, _ = houses[name]
    p = world.places
    for i, j in ((0, 9), (3, 6), (8, 1)):
        path = world.astar(p[i], p[j])
        assert np.allclose(path[0], p[i, :2]) and np.allclose(path[-1], p[j, :2])
        assert world.grid.is_free(path[1:-1]).all()
        assert np.linalg.norm(np.diff(path, axis=0), axis=1).max() < 0.1


def test_walls_textures_and_aliasing(houses):
    for name, (world, layout) in houses.items():
        n_furn = len(layout.furniture)
        walls = world.walls
        building = slice(0, len(walls) - n_furn)
        # Interior walls are two 0.05 m halves, exterior walls 0.2 m.
        assert set(np.round(walls.thickness[building], 6)) == {0.05, 0.2}
        assert np.isin(walls.texture[building], list(WALL_TEXTURES)).all()
        # Every half wall shows the wall texture of the room it lies in (faces).
        half = np.flatnonzero(np.isclose(walls.thickness[building], 0.05))
        mid = 0.5 * (walls.segments[half, :2] + walls.segments[half, 2:])
        t = layout.tiles
        inside = ((t[None, :, 0] < mid[:, None, 0]) & (mid[:, None, 0] < t[None, :, 2])
                  & (t[None, :, 1] < mid[:, None, 1]) & (mid[:, None, 1] < t[None, :, 3]))
        assert (inside.sum(axis=1) == 1).all()
        room = layout.tile_room[inside.argmax(axis=1)]
        assert np.array_equal(walls.texture[half], layout.wall_texture[room])
        # Floors per region follow the rooms.
        assert np.isin(layout.floor_texture, list(FLOOR_TEXTURES)).all()
        assert np.array_equal(world.floor_texture, layout.floor_texture[layout.tile_room])
        # Perceptual aliasing: some rooms look alike, but only a minority.
        pairs = layout.alike_pairs()
        assert pairs, name
        looks = {(int(w), int(f)) for w, f in zip(layout.wall_texture, layout.floor_texture)}
        assert len(looks) >= 0.6 * layout.n_rooms, name
        alike_rooms = {i for p in pairs for i in p}
        assert len(alike_rooms) <= 0.65 * layout.n_rooms, name


def test_furniture_exists_and_is_furniture(houses):
    total = 0
    for name, (world, layout) in houses.items():
        f = layout.furniture
        assert len(f) >= 1, name
        total += len(f)
        size = f[:, 2:] - f[:, :2]
        assert size.min() >= 0.4 - 1e-9 and size.max() <= 1.5 + 1e-9
        assert np.isin(layout.furniture_texture, list(FURNITURE_TEXTURES)).all()
        assert np.array_equal(world.walls.texture[-len(f):], layout.furniture_texture)
        # Furniture stands inside the room it belongs to, on occupied cells.
        kinds = np.array(layout.room_kind)[layout.furniture_room]
        assert (kinds == "room").all()
        centre = 0.5 * (f[:, :2] + f[:, 2:])
        rc = world.grid.to_cell(centre)
        assert world.grid.occupied[rc[:, 0], rc[:, 1]].all()
    assert total >= 17 * 5


def test_furniture_that_blocks_a_door_is_dropped(monkeypatch):
    import topodrake.world.houses as H

    placed = {}
    real = H._place_furniture

    def sabotage(rng, tiles_m, tile_room, room_kind, doors_m, door_tiles, cfg):
        boxes, tex, rooms = real(rng, tiles_m, tile_room, room_kind, doors_m, door_tiles, cfg)
        i = next(t for pair in door_tiles for t in pair if room_kind[tile_room[t]] == "room")
        d, n = H._room_doors(tiles_m[i], doors_m, door_tiles, i)[0]
        c = 0.5 * (d[:2] + d[2:]) + 0.05 * n
        lo, hi = c - 0.75 * np.abs(n[::-1]), c + 0.75 * np.abs(n[::-1]) + 1.0 * n
        bad = np.concatenate([np.minimum(lo, hi), np.maximum(lo, hi)])
        placed["bad"], placed["count"] = bad, len(boxes) + 1
        return (np.vstack([boxes, bad]), np.append(tex, FURNITURE_TEXTURES[0]),
                np.append(rooms, tile_room[i]))

    monkeypatch.setattr(H, "_place_furniture", sabotage)
    world, layout = H.generate_house_with_layout(5, "blocked")
    assert not np.any(np.all(np.isclose(layout.furniture, placed["bad"]), axis=1))
    probes = layout.door_probes().reshape(-1, 2)
    rc = world.grid.to_cell(probes)
    assert world.grid.reachable[rc[:, 0], rc[:, 1]].all()
    assert len(layout.furniture) == placed["count"] - 1   # only the culprit went


def test_other_configs_respect_the_area_range():
    cfg = HouseConfig(area_m2=(120.0, 200.0), p_l_shape=0.0)
    for seed in (1, 2):
        w, layout = generate_house_with_layout(seed, "small", cfg)
        assert 120.0 <= w.free_area_m2 <= 200.0
        assert layout.shape == "rect"


def test_unknown_world_names_close_matches_and_the_listing_command():
    with pytest.raises(TopodrakeError) as err:
        load_world("train-99")
    msg = str(err.value)
    assert "\n" not in msg and len(msg) <= 200 and "train-99" in msg
    assert "train-95" in msg and "topodrake world list" in msg
    assert msg.count("train-") <= 6           # the name asked for and at most 5 matches
    with pytest.raises(TopodrakeError):
        load_world_pkg("kitchen")


@pytest.mark.parametrize("suffix", [".yaml", ".yml", ".json"])
def test_missing_map_file(tmp_path, suffix):
    missing = tmp_path / f"nowhere{suffix}"
    with pytest.raises(TopodrakeError, match="does not exist"):
        load_world(str(missing))
