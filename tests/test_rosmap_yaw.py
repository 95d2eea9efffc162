"""ROS maps whose origin has a yaw (rotated SLAM exports) load in the ROS map
frame: the same free area as the unrotated map, at the rotated coordinates."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from topodrake.world import load_world
from topodrake.world.rosmap import rotate_raster

YUJIN = Path(__file__).resolve().parent / "data" / "maps" / "yujin_rnd_extended"


def _rotated_copy(tmp_path: Path, yaw: float) -> Path:
    meta = yaml.safe_load((YUJIN / "map.yaml").read_text())
    shutil.copy(YUJIN / meta["image"], tmp_path / meta["image"])
    meta["origin"] = [25.9, 48.5, yaw]
    out = tmp_path / "map.yaml"
    out.write_text(yaml.safe_dump(meta))
    return out


@pytest.fixture(scope="module")
def plain():
    return load_world(str(YUJIN / "map.yaml"))


def _to_rotated(plain, points, yaw):
    """World points of the unrotated map in the frame of its copy at origin
    (25.9, 48.5, yaw): both share the image's lower-left corner."""
    meta = yaml.safe_load((YUJIN / "map.yaml").read_text())
    local = points - np.asarray(meta["origin"][:2])
    c, s = math.cos(yaw), math.sin(yaw)
    return local @ np.array([[c, s], [-s, c]]) + (25.9, 48.5)


@pytest.mark.parametrize("yaw", [math.pi / 2, math.pi, -math.pi / 2])
def test_quarter_turns_keep_the_free_area_exactly(tmp_path, plain, yaw):
    world = load_world(str(_rotated_copy(tmp_path, yaw)))
    assert world.free_area_m2 == pytest.approx(plain.free_area_m2, abs=1e-9)
    # Free points of the plain map are free at their rotated coordinates.
    pts = plain.places[:, :2]
    moved = _to_rotated(plain, pts, yaw)
    assert np.all(world.grid.clearance_at(moved) > 0)
    assert np.allclose(world.grid.clearance_at(moved), plain.grid.clearance_at(pts), atol=1e-6)


def test_slam_yaw_3_14_loads_with_the_same_free_area(tmp_path, plain):
    path = _rotated_copy(tmp_path, 3.14)
    world = load_world(str(path))
    assert world.free_area_m2 == pytest.approx(plain.free_area_m2, rel=0.01)
    moved = _to_rotated(plain, plain.places[:, :2], 3.14)
    assert np.mean(world.grid.clearance_at(moved) > 0) >= 0.9
    # The rotated map lies to the lower left of its origin (yaw ~ pi).
    assert np.all(world.bbox[1] <= np.array([25.9, 48.5]) + 0.1)


def test_rotate_raster_quarter_turn_is_rot90():
    occ = np.zeros((3, 5), bool)
    occ[0, 4] = True                                      # bottom-right pixel
    out, corner = rotate_raster(occ, 0.5, [1.0, 2.0, math.pi / 2])
    # Row 0 is the bottom, so a counter-clockwise turn is numpy's clockwise one.
    assert out.shape == (5, 3) and np.array_equal(out, np.rot90(occ, -1))
    assert out[4, 2]                                      # now top-right
    assert np.allclose(corner, [1.0 - 1.5, 2.0])
    same, c0 = rotate_raster(occ, 0.5, [1.0, 2.0, 0.0])
    assert same is occ or np.array_equal(same, occ)
    assert np.allclose(c0, [1.0, 2.0])
