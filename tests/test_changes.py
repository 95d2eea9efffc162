"""Changed worlds: per-car boxes, walkers and closed passages seen by the
sensors, counted in collisions and driven past by the batched engine."""

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.world.changes import CarChanges, WorldChanges, place_changes


@pytest.fixture(scope="module")
def oracles(box_world):
    from topodrake.learning.waypoint.policy import AStarOracle
    from topodrake.navigation.evaluate import GeometricReachability

    return AStarOracle(box_world, k=1, frame_step=3), GeometricReachability(box_world, k=1)


@pytest.fixture(scope="module")
def route(box_world, oracles):
    from topodrake.contract.route import route_from_trajectory
    from topodrake.rollout import ExpertRollout, RolloutConfig

    r = ExpertRollout(box_world, RolloutConfig(t_max_s=60.0)).run(np.array([[1.0, 1.5, 0.3]]),
                                                                  np.array([[8.0, 2.0]]))
    poses = r.trajectory(0)["poses"]
    anchors = np.r_[np.arange(0, len(poses) - 1, 10), len(poses) - 1]
    return route_from_trajectory(box_world, poses, anchors, oracles[0])


def test_changes_parse_check_and_label():
    assert WorldChanges.parse("boxes=3, people=2") == WorldChanges(boxes=3, people=2)
    assert WorldChanges.parse("none") == WorldChanges() and not WorldChanges().any
    assert WorldChanges(blocked=1).label == "blocked=1" and WorldChanges().label == "none"
    for bad, msg in (("boxes", "expected"), ("chairs=2", "expected"), ("boxes=two", "whole"),
                     ("blocked=2", "at most 1"), ("people=-1", ">= 0")):
        with pytest.raises(TopodrakeError, match=msg):
            WorldChanges.parse(bad)


def test_a_car_s_own_box_is_seen_by_its_lidar_and_camera_only(box_world):
    from topodrake.sensing.camera import Camera
    from topodrake.sensing.lidar import Lidar

    poses = np.array([[2.0, 5.0, 0.0], [2.0, 5.0, 0.0]])
    ch = CarChanges.of([np.array([[3.0, 4.7, 3.6, 5.3]]), None])
    lidar, camera = Lidar(box_world), Camera(box_world)
    plain = lidar.scan(poses)
    seen = lidar.scan(poses, ch.faces([0, 1]))
    ahead = np.argmin(np.abs(lidar.config.beam_angles()))
    assert seen[0, ahead] == pytest.approx(3.0 - 2.0 - lidar.config.forward_m, abs=0.01)
    assert plain[0, ahead] > 2.5                       # the world has no box there
    np.testing.assert_array_equal(seen[1], plain[1])   # the other car's world is unchanged
    img, ref = camera.render(poses, ch.faces([0, 1])), camera.render(poses)
    mid = img.shape[2] // 2
    assert (img[0, :, mid] != ref[0, :, mid]).any()
    np.testing.assert_array_equal(img[1], ref[1])
    np.testing.assert_array_equal(camera.render(poses, ch.faces([0, 1])[:, :0]), ref)


def test_touching_counts_a_box_under_the_car_and_not_one_beside_it():
    from topodrake.vehicle import VehicleConfig

    ch = CarChanges.of([np.array([[2.1, 4.9, 2.4, 5.1]]), np.array([[2.1, 6.0, 2.4, 6.3]])])
    states = np.array([[2.0, 5.0, 0.0, 0.0, 0.0], [2.0, 5.0, 0.0, 0.0, 0.0]])
    np.testing.assert_array_equal(ch.touching([0, 1], states, VehicleConfig()), [True, False])
    assert not CarChanges.of([None]).touching([0], states[:1], VehicleConfig()).any()


def test_car_changes_pad_take_and_refuse_bad_shapes():
    ch = CarChanges.of([np.zeros((0, 4)), np.array([[0, 0, 1, 1], [2, 2, 3, 3.0]])])
    assert ch.fixed.shape == (2, 8, 8) and np.isnan(ch.fixed[0]).all()
    sub = ch.take([1])
    assert len(sub) == 1 and np.isfinite(sub.fixed).all()
    block = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 0.1], [0.0, 0.1]])
    assert CarChanges.of(None, [block]).fixed.shape == (1, 4, 8)
    with pytest.raises(TopodrakeError, match="N, S, 8"):
        CarChanges(np.zeros((2, 3)))


def test_changes_are_placed_per_trial_from_its_own_seed(box_world):
    path = np.array([[1.0, 1.5], [3.0, 7.5], [7.0, 7.5], [8.0, 2.0]])
    spec = WorldChanges(boxes=2)
    one, placed_one = place_changes(box_world, [path], spec, [7])
    two, placed_two = place_changes(box_world, [None, path], spec, [3, 7])
    assert placed_one[0] == placed_two[1] and placed_two[0] is None
    np.testing.assert_array_equal(one.fixed[0], two.fixed[1][:len(one.fixed[0])])
    boxes = np.array(placed_one[0]["boxes"])
    assert boxes.shape == (2, 4)


def test_the_engine_drives_each_car_in_its_own_changed_world(box_world, route, oracles):
    from topodrake.navigation.engine import NAV_COLLISION, NavigationEngine

    starts = np.array([[1.0, 1.8, 0.5], [1.0, 1.8, 0.5]])
    engine = NavigationEngine(box_world, *oracles)
    plain = engine.run(starts, [route, route])
    # a box on the route of car 0 only, in the gap above the partition
    ch = CarChanges.of([np.array([[4.6, 7.6, 5.2, 8.2]]), None])
    changed = engine.run(starts, [route, route], changes=ch)
    k = int(plain.steps[1])
    np.testing.assert_array_equal(changed.poses[1, :k + 1], plain.poses[1, :k + 1])
    assert not np.array_equal(changed.poses[0], plain.poses[0])
    assert changed.outcome[0] != NAV_COLLISION        # the RMP steers round what its lidar sees
    walled = CarChanges.of([np.array([[1.5, 1.0, 1.9, 3.0]]), None])
    hit = engine.run(starts, [route, route], changes=walled)
    path = hit.poses[0, :int(hit.steps[0]) + 1, :2]
    assert not ((path[:, 0] > 1.5) & (path[:, 0] < 1.9) & (path[:, 1] > 1.0)
                & (path[:, 1] < 3.0)).any()           # never drives through the box


# -- the same changes in the Drake diagram -----------------------------------------------------

@pytest.mark.parametrize("kind", ["lidar", "camera"])
def test_drake_sensors_see_extra_faces_only_where_connected(box_world, kind):
    """Unconnected, the ``extra`` port changes nothing: the world alone, as before."""
    from pydrake.common.value import AbstractValue
    from pydrake.systems.analysis import Simulator

    from topodrake.sensing.camera import Camera
    from topodrake.sensing.lidar import Lidar
    from topodrake.systems.sensors import CameraSensor, LidarSensor

    pose = np.array([2.0, 5.0, 0.0])
    extra = CarChanges.of([np.array([[3.0, 4.7, 3.6, 5.3]])]).faces([0])

    def sample(connected: bool) -> np.ndarray:
        sensor = LidarSensor(box_world) if kind == "lidar" else CameraSensor(box_world)
        context = sensor.CreateDefaultContext()
        sensor.pose_port.FixValue(context, pose)
        if connected:
            sensor.extra_port.FixValue(context, AbstractValue.Make(extra[0]))
        Simulator(sensor, context).AdvanceTo(0.05)      # the sample of t = 0, held
        port = sensor.ranges_port if kind == "lidar" else sensor.image_port
        return np.array(port.Eval(context))

    direct = Lidar(box_world).scan if kind == "lidar" else Camera(box_world).render
    plain, seen = sample(False), sample(True)
    np.testing.assert_array_equal(plain, direct(pose[None])[0])
    np.testing.assert_array_equal(seen, direct(pose[None], extra)[0])
    assert not np.array_equal(plain, seen)


class _Spy:
    """A Meshcat that notes each call it forwards."""

    def __init__(self, real):
        self.real, self.calls = real, []

    def __getattr__(self, name):
        def call(*args, **kwargs):
            self.calls.append((name, args))
            return getattr(self.real, name)(*args, **kwargs)
        return call


def test_drake_meshcat_draws_the_box_and_a_walker_that_walks(box_world, route, oracles):
    import base64
    import re

    from topodrake.apps.drive import make_recorder
    from topodrake.systems.navigation import (NavigationRunner, NavigationScenario,
                                              make_navigation_diagram)

    viewer = _Spy(make_recorder())
    sc = NavigationScenario(world="box", camera_enabled=False, t_max_s=8.0,
                            changes=WorldChanges(boxes=1, people=1))
    built = make_navigation_diagram(sc, route, viewer, world=box_world, policy=oracles[0],
                                    reach=oracles[1])
    result = NavigationRunner(built).run([1.0, 1.8, 0.5], seed=4)
    drawn = {args[0]: type(args[1]).__name__ for name, args in viewer.calls if name == "SetObject"}
    assert drawn["/topodrake/changes/still/0"] == "Box"
    assert drawn["/topodrake/changes/walkers/0/body"] == "Cylinder"
    steps = [(args[2], args[1].translation()[:2]) for name, args in viewer.calls
             if name == "SetTransform" and args[0] == "/topodrake/changes/walkers/0"]
    times = [t for t, _ in steps]
    assert times[-1] == pytest.approx(result.time_s) and len(steps) > 70
    walked = np.array([xy for _, xy in steps])
    assert np.hypot(*(walked[-1] - walked[0])) > 0.5          # it moves in the recording
    viewer.StopRecording()
    viewer.PublishRecording()
    html = viewer.StaticHtml()
    blobs = b"".join(base64.b64decode(b) for b in
                     re.findall(r"octet-binary;base64,([A-Za-z0-9+/=]+)", html))
    assert b"/topodrake/changes/walkers/0" in blobs and b"/topodrake/changes/still/0" in blobs

