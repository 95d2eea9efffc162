import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.sensing.camera import Camera
from topodrake.sensing.config import CameraConfig, LidarConfig
from topodrake.sensing.lidar import Lidar
from topodrake.sensing.overlap import image_overlap, mutual_overlap
from topodrake.sensing.raycast import cast_rays
from topodrake.sensing.scene import scene_of


def test_ray_hits_nearest_face(box_world):
    scene = scene_of(box_world)
    t, face, s = cast_rays(scene, np.array([[2.0, 3.0], [2.0, 8.0], [2.0, 3.0]]),
                           np.array([[1.0, 0.0], [1.0, 0.0], [-1.0, 0.0]]))
    assert np.allclose(t, [4.9 - 2.0, 9.8 - 2.0, 2.0 - 0.2])
    assert (face >= 0).all() and ((0 <= s) & (s <= 1)).all()


def test_ray_outside_the_map_misses(box_world):
    t, face, _ = cast_rays(scene_of(box_world), np.array([[50.0, 50.0]]), np.array([[1.0, 0.0]]))
    assert np.isinf(t[0]) and face[0] == -1


def test_camera_depth_matches_geometry(box_world):
    cam = Camera(box_world)
    c = cam.config
    d = cam.render_depth(np.array([[2.0, 3.0, 0.0]]))[0]
    # Centre columns look at the partition face x = 4.9 (z-depth, not range).
    mid = c.height // 2
    assert np.allclose(d[mid, c.width // 2 - 4: c.width // 2 + 4], 4.9 - 2.0 - c.forward_m, atol=1e-4)
    # Bottom row sees the floor at height / y_n.
    yn = (c.height - 1 - c.cy) / c.fx
    assert d[-1, 32] == pytest.approx(c.height_m / yn, rel=1e-4)
    # Top row sees the ceiling.
    yn_top = (0 - c.cy) / c.fx
    assert d[0, 32] == pytest.approx((c.height_m - box_world.wall_height) / yn_top, rel=1e-4)


def test_camera_rgb_is_textured_deterministic_and_batched(box_world):
    cam = Camera(box_world)
    poses = np.array([[2.0, 3.0, 0.0], [7.0, 7.0, 2.0], [2.5, 8.0, -1.0]])
    imgs = cam.render(poses)
    assert imgs.shape == (3, 64, 64, 3) and imgs.dtype == np.uint8
    assert np.array_equal(imgs, cam.render(poses))
    assert np.array_equal(imgs[1], cam.render(poses[1])[0])
    assert not np.array_equal(imgs[0], imgs[1])
    assert len(np.unique(imgs[0].reshape(-1, 3), axis=0)) > 20   # textures, shading


def test_camera_config_changes_resolution(box_world):
    cfg = CameraConfig(width=32, height=24, hfov_deg=90)
    img = Camera(box_world, cfg).render(np.array([2.0, 3.0, 0.0]))
    assert img.shape == (1, 24, 32, 3)


def test_bad_poses_are_refused(box_world):
    with pytest.raises(TopodrakeError, match="shape"):
        Camera(box_world).render(np.zeros((2, 2)))
    with pytest.raises(TopodrakeError, match="NaN"):
        Lidar(box_world).scan(np.array([[np.nan, 0, 0]]))


def test_lidar_ranges(box_world):
    lid = Lidar(box_world, LidarConfig(beams=3, fov_deg=180, range_m=10.0))
    r = lid.scan(np.array([[2.0, 3.0, 0.0]]))[0]
    ox = 2.0 + lid.config.forward_m
    # Beams at -90, 0, +90 deg: floor wall, partition, then the top wall.
    assert r == pytest.approx([3.0 - 0.2, 4.9 - ox, 9.8 - 3.0], abs=1e-4)
    short = Lidar(box_world, LidarConfig(beams=3, fov_deg=180, range_m=5.0))
    assert np.isinf(short.scan(np.array([[2.0, 3.0, 0.0]]))[0, 2])
    pts, ok = short.points(np.array([[2.0, 3.0, 0.0]]))
    assert ok[0].tolist() == [True, True, False]
    assert pts[0, 1] == pytest.approx([4.9, 3.0], abs=1e-4)


def test_lidar_default_beams(box_world):
    r = Lidar(box_world).scan(box_world.sample_free_pose(np.random.default_rng(0), 10))
    assert r.shape == (10, 64)
    assert (r[np.isfinite(r)] > 0).all() and (r[np.isfinite(r)] <= 10.0).all()


def test_overlap_properties(box_world):
    a = np.array([[2.0, 3.0, 0.0]] * 4)
    b = np.array([[2.0, 3.0, 0.0], [2.0, 3.0, np.pi], [2.0, 3.0, 0.5], [2.0, 3.0, 1.2]])
    r = image_overlap(box_world, a, b)
    assert r[0] == pytest.approx(1.0)
    assert r[1] == pytest.approx(0.0)
    assert r[0] > r[2] > r[3]     # overlap falls as the heading turns away
    m = mutual_overlap(box_world, a[:3], b[:3])
    assert m.shape == (3, 2)
    # Pure rotation about the same point is symmetric.
    assert m[2, 0] == pytest.approx(m[2, 1], abs=0.02)


def test_overlap_respects_occlusion(box_world):
    # Same heading, but b stands behind the partition: it sees none of a's view.
    a = np.array([[7.0, 3.0, np.pi]])
    b = np.array([[3.0, 3.0, np.pi]])
    assert image_overlap(box_world, a, b)[0] == pytest.approx(0.0)
    assert image_overlap(box_world, b, b)[0] == pytest.approx(1.0)


def test_observe_dispatches_on_the_modality(box_world):
    from topodrake.sensing.observe import observe

    poses = np.array([[1.0, 1.0, 0.3], [2.0, 1.5, -1.0]])
    assert np.array_equal(observe(box_world, "camera", poses), Camera(box_world).render(poses))
    lidar = LidarConfig(beams=32)
    scans = observe(box_world, "lidar", poses, lidar)
    assert scans.shape == (2, 32) and np.array_equal(scans, Lidar(box_world, lidar).scan(poses))
    with pytest.raises(ValueError, match="modality 'sonar'"):
        observe(box_world, "sonar", poses)
