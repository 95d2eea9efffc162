"""RegistrationPolicy: taught frames from scans, tracking with odometry, and
following taught routes in both executors."""

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.se2 import compose, invert
from topodrake.registration.policy import RegistrationConfig, RegistrationPolicy

K, STEP = 5, 3


@pytest.fixture(scope="module")
def house():
    from topodrake.world import load_world

    return load_world("test-0")


@pytest.fixture(scope="module")
def drives(house):
    """Noise-free expert drives between places of the test house."""
    from topodrake.rollout import ExpertRollout, RolloutConfig

    p = house.places
    pairs = [(0, 3), (2, 5), (4, 1), (6, 8)]
    res = ExpertRollout(house, RolloutConfig(t_max_s=120.0)).run(
        np.array([p[i] for i, _ in pairs]), np.array([p[j, :2] for _, j in pairs]))
    out = [res.trajectory(i)["poses"] for i in range(len(pairs)) if res.success[i]]
    assert len(out) >= 3
    return out


@pytest.fixture(scope="module")
def policy():
    return RegistrationPolicy(RegistrationConfig(k=K, frame_step=STEP))


def _contexts(house, poses, anchors):
    from topodrake.contract.frames import context_frames
    from topodrake.sensing.lidar import Lidar

    rows = context_frames(len(poses), np.asarray(anchors), K, STEP)
    return Lidar(house).scan(poses[rows.ravel()]).reshape(*rows.shape, -1), rows


def test_taught_frames_come_from_the_scans(house, drives, policy):
    poses = drives[0]
    anchors = np.arange(0, len(poses), 20)
    ctx, rows = _contexts(house, poses, anchors)
    feats = policy.encode_target(ctx)
    assert feats.shape == (len(anchors), 2 * K + 1, 4 + ctx.shape[2])
    np.testing.assert_array_equal(feats[:, K, :4], [[0, 0, 0, 1]] * len(anchors))
    np.testing.assert_array_equal(feats[:, :, 4:], ctx)
    truth = np.stack([compose(np.repeat(invert(poses[a]), 2 * K + 1, axis=0), poses[r])
                      for a, r in zip(anchors, rows)])
    ok = feats[:, :, 3] > 0.5
    assert ok.mean() > 0.85
    err = np.hypot(*(feats[..., :2] - truth[..., :2]).T).T
    assert np.quantile(err[ok], 0.95) < 0.05
    assert np.quantile(np.abs(feats[..., 2] - truth[..., 2])[ok], 0.95) < np.radians(2.0)
    with pytest.raises(TopodrakeError, match="lidar ranges"):
        policy.encode_target(ctx[:, :3])


def test_config_and_queries_are_checked(policy):
    with pytest.raises(TopodrakeError, match="lookahead"):
        RegistrationConfig(lookahead_m=0.0).check()
    with pytest.raises(TopodrakeError, match="odometry_error"):
        RegistrationConfig(odometry_error=(0.1,)).check()
    # odometry with a scale error: each period's motion is stretched
    biased = RegistrationPolicy(RegistrationConfig(odometry_error=(0.1, -0.5)))
    move = biased._motion(np.array([1.0, 2.0, np.pi / 2]), np.array([1.0, 3.0, np.pi / 2 + 0.2]))
    np.testing.assert_allclose(move, [1.1, 0.0, 0.1], atol=1e-12)
    track = policy.initial_track(1)
    with pytest.raises(TopodrakeError, match="registration queries"):
        policy.predict_tracked(np.ones((2, 64)), np.ones((1, 2 * K + 1, 68)), track,
                               np.zeros(2, np.int64), np.arange(2), np.zeros((2, 3)))


def test_tracks_with_odometry_and_holds_through_a_failed_registration(house, drives, policy):
    from topodrake.sensing.lidar import Lidar

    poses = drives[0]
    a = 60
    ctx, _ = _contexts(house, poses, [a])
    feats = policy.encode_target(ctx)
    lidar = Lidar(house)
    track = policy.initial_track(1)
    keys, cars = np.array([7]), np.zeros(1, np.int64)
    # the car drives the taught path from 0.6 m before the anchor, off by 0.15 m
    path = [compose(poses[i], np.array([0.0, 0.15, 0.05]))[0] for i in range(a - 12, a + 1, 2)]
    for i, p in enumerate(path):
        pred = policy.predict_tracked(lidar.scan(p[None]), feats, track, cars, keys, p[None])
        truth = compose(invert(poses[a]), p)[0]
        slot = track[0].reshape(policy.config.slots, -1)[0]
        assert slot[0] == 7
        np.testing.assert_allclose(slot[1:3], truth[:2], atol=0.05)
        # the waypoint leads toward the anchor, no farther than it
        anchor_in_car = compose(invert(truth), np.zeros(3))[0]
        assert np.hypot(*pred.waypoint[0]) <= np.hypot(*anchor_in_car[:2]) + 0.05
        assert i == len(path) - 1 or pred.waypoint[0, 0] > 0
        if i >= policy.config.confirm:
            assert pred.overlap[0].min() > 0.5       # confirmed: overlaps reported
    # a scan that registers to nothing: the estimate is held, moved by the odometry
    moved = compose(path[-1], np.array([0.2, 0.0, 0.0]))
    held = policy.predict_tracked(np.full((1, 64), np.inf), feats, track, cars, keys, moved)
    slot = track[0].reshape(policy.config.slots, -1)[0]
    truth = compose(invert(poses[a]), moved)[0]
    np.testing.assert_allclose(slot[1:3], truth[:2], atol=0.06)
    assert slot[9] == 1 and np.all(held.overlap == 0.0)
    # a fresh policy state from the stateless call still answers (it searches the frames)
    fresh = policy.predict(lidar.scan(poses[a - 3][None]), feats)
    assert np.hypot(*fresh.waypoint[0]) < 0.5


def test_an_unregistered_anchor_is_approached_from_the_last_tracked_one(house, drives, policy):
    """The follower may skip an anchor (it advances to the one after the
    next): an anchor the car cannot register yet is approached along the exit
    of the nearest earlier anchor it tracks, not only the one just before,
    and straight ahead only when it tracks none."""
    from topodrake.sensing.lidar import Lidar

    poses = drives[0]
    a = 60
    feats = policy.encode_target(_contexts(house, poses, [a])[0])
    lidar = Lidar(house)
    track = policy.initial_track(1)
    cars = np.zeros(1, np.int64)
    for i in range(a - 12, a + 1, 2):
        policy.predict_tracked(lidar.scan(poses[i][None]), feats, track, cars, np.array([7]),
                               poses[i][None])
    blind = np.full((1, policy.sensor.beams), np.inf)      # registers to nothing
    car = compose(poses[a], np.array([0.3, 0.0, 0.0]))
    answers = {}
    for key in (8, 9):
        t = track.copy()
        answers[key] = policy.predict_tracked(blind, feats, t, cars, np.array([key]), car).waypoint[0]
    np.testing.assert_allclose(answers[9], answers[8])
    assert not np.allclose(answers[9], [policy.config.lookahead_m, 0.0])
    cold = policy.predict_tracked(blind, feats, policy.initial_track(1), cars, np.array([9]), car)
    np.testing.assert_allclose(cold.waypoint[0], [policy.config.lookahead_m, 0.0])


def test_follows_taught_routes_in_the_house(house, drives, policy):
    """A route of anchors every 25 frames of an expert drive, followed by
    the batched engine from a jittered start with the geometric oracle RE:
    the registration controller covers most of each drive."""
    from topodrake.navigation.chains import follow_chains_once
    from topodrake.navigation.engine import NavigationConfig, NavigationEngine
    from topodrake.navigation.evaluate import GeometricReachability
    from topodrake.rollout import RolloutConfig
    from topodrake.sensing.lidar import Lidar

    lidar = Lidar(house)
    obs = [lidar.scan(d) for d in drives]
    chains = [np.unique(np.r_[np.arange(0, len(d), 25), len(d) - 1]) for d in drives]
    engine = NavigationEngine(house, policy, GeometricReachability(house, k=K, frame_step=STEP),
                              NavigationConfig(rollout=RolloutConfig(noise_std=0.0)))
    res, watch = follow_chains_once(engine, drives, obs, chains, K, STEP, list(range(len(drives))))
    cover = np.array([watch.cover(i) for i in range(len(drives))])
    assert cover.mean() >= 0.8, cover
    assert (cover > 0.95).sum() >= len(drives) // 2, cover
    # the same drives past a box each, placed on each drive from its own seed
    from topodrake.world.changes import WorldChanges

    res2, watch2, placed = follow_chains_once(engine, drives, obs, chains, K, STEP,
                                              list(range(len(drives))),
                                              changes=WorldChanges(boxes=1))
    assert len(placed) == len(drives)
    for d, p in zip(drives, placed):
        if p is not None:                 # on the drive, away from its ends
            c = np.mean(np.reshape(p["boxes"], (2, 2)), axis=0)
            assert np.hypot(*(d[:, :2] - c).T).min() < 0.2
            assert np.hypot(*(d[[0, -1], :2] - c).T).min() > 0.9
    assert not np.array_equal(res2.poses, res.poses)


def _box_route(box_world):
    """(route, registration C_WP, geometric RE): an expert drive across the
    box world as a route of every 10th frame."""
    from topodrake.navigation.evaluate import GeometricReachability
    from topodrake.contract.route import route_from_trajectory
    from topodrake.rollout import ExpertRollout, RolloutConfig

    drive = ExpertRollout(box_world, RolloutConfig(t_max_s=60.0)).run(
        np.array([[1.0, 1.5, 0.3]]), np.array([[8.0, 2.0]])).trajectory(0)["poses"]
    pol = RegistrationPolicy(RegistrationConfig(k=1, frame_step=3))
    anchors = np.r_[np.arange(0, len(drive) - 1, 10), len(drive) - 1]
    return route_from_trajectory(box_world, drive, anchors, pol), pol, \
        GeometricReachability(box_world, k=1)


def test_drake_diagram_and_engine_drive_the_same_path(box_world):
    """The per-car tracking state rides in the follower state: the Drake
    navigation diagram and the batched engine drive the same path."""
    from topodrake.navigation.engine import NAV_OUTCOMES, NavigationConfig, NavigationEngine
    from topodrake.rollout import RolloutConfig
    from topodrake.systems.navigation import (NavigationRunner, NavigationScenario,
                                              make_navigation_diagram)

    route, pol, reach = _box_route(box_world)
    start = [1.0, 1.8, 0.5]
    sc = NavigationScenario(world="box", noise_std=0.0, camera_enabled=False, t_max_s=40.0)
    built = make_navigation_diagram(sc, route, world=box_world, policy=pol, reach=reach)
    drake = NavigationRunner(built).run(start, seed=3)
    engine = NavigationEngine(box_world, pol, reach, NavigationConfig(
        rollout=RolloutConfig(noise_std=0.0, t_max_s=40.0)))
    res = engine.run(np.array([start]), [route])
    k = int(res.steps[0])
    assert k == round(drake.time_s / 0.1) and k > 100
    dev = np.linalg.norm(drake.poses[:k + 1, :2] - res.poses[0, :k + 1, :2], axis=1)
    assert dev.max() <= 1e-6
    assert drake.outcome == NAV_OUTCOMES[int(res.outcome[0])] == "reached"
    np.testing.assert_array_equal(drake.modes[:k], res.modes[0, :k])


@pytest.mark.parametrize("manoeuvres,start", [(False, [1.0, 1.8, 0.5]),
                                               (True, [1.88, 1.92, -0.31])])
def test_drake_diagram_and_engine_drive_alike_on_odometry_that_drifts(box_world, manoeuvres,
                                                                       start):
    """Under odometry that drifts the diagram's follower, the registration
    C_WP and the manoeuvres read the OdometrySensor as the engine's read its
    Odometry: the same drive, and not the drive on the true pose."""
    from topodrake.navigation.engine import NAV_OUTCOMES, NavigationConfig, NavigationEngine
    from topodrake.navigation.follower import FollowerConfig
    from topodrake.odometry import OdometryConfig
    from topodrake.rollout import RolloutConfig
    from topodrake.systems.navigation import (NavigationRunner, NavigationScenario,
                                              make_navigation_diagram)

    drift = OdometryConfig(scale_std=0.1, turn_scale_std=0.2, heading_bias_std_deg_per_m=5.0)
    follower = FollowerConfig(manoeuvres=manoeuvres)
    sc = NavigationScenario(world="box", camera_enabled=False, t_max_s=40.0, follower=follower,
                            odometry=drift)
    route, pol, reach = _box_route(box_world)
    built = make_navigation_diagram(sc, route, world=box_world, policy=pol, reach=reach)
    assert built.odometry is not None
    runner = NavigationRunner(built)
    drake = runner.run(start, seed=3, odometry_seed=5)
    engine = NavigationEngine(box_world, pol, reach, NavigationConfig(
        follower=follower, rollout=RolloutConfig(t_max_s=40.0), odometry=drift))
    res = engine.run(np.array([start]), [route], odometry_seeds=[5])
    k = int(res.steps[0])
    assert k == round(drake.time_s / 0.1) and k > 50
    dev = np.linalg.norm(drake.poses[:k + 1, :2] - res.poses[0, :k + 1, :2], axis=1)
    assert dev.max() <= 1e-6
    assert drake.outcome == NAV_OUTCOMES[int(res.outcome[0])]
    np.testing.assert_array_equal(drake.modes[:k], res.modes[0, :k])
    # what the follower read had drifted from the true pose
    ctx = built.odometry.GetMyContextFromRoot(runner.simulator.get_context())
    odo = built.odometry.odometry_port.Eval(ctx)[:2]
    assert np.hypot(*(odo - drake.poses[-1, :2])) > 0.05


def test_the_odometry_sensor_integrates_what_the_engine_integrates():
    """Fed a held state per period, OdometrySensor's output in period k is
    the odometry pose the engine's Odometry reaches after k periods."""
    from pydrake.systems.analysis import Simulator

    from topodrake.odometry import OdometryConfig, odometry_along
    from topodrake.systems.odometry import OdometryFrame, OdometrySensor

    t = np.linspace(0.0, 1.0, 21)
    poses = np.column_stack([2.0 * t, np.sin(3.0 * t), 0.5 + 3.0 * np.cos(3.0 * t) * 0.3])
    sensor = OdometrySensor(OdometryConfig.wheel(), 0.1)
    sim = Simulator(sensor)
    ctx = sim.get_mutable_context()
    sensor.set_start(ctx, poses[0], seed=11)
    expected = odometry_along(poses, OdometryConfig.wheel(), 11)
    sensor.state_port.FixValue(ctx, np.r_[poses[0], 0.2, 0.1])
    sim.AdvanceTo(0.05)
    np.testing.assert_allclose(sensor.odometry_port.Eval(ctx), np.r_[poses[0], 0.2, 0.1])
    for k in range(1, len(poses)):
        sim.AdvanceTo(k * 0.1 + 0.05)        # the update at k * 0.1 read period k - 1's state
        sensor.state_port.FixValue(ctx, np.r_[poses[k], 0.2, 0.1])
        np.testing.assert_allclose(sensor.odometry_port.Eval(ctx)[:3], expected[k], atol=1e-12)
    assert np.hypot(*(expected[-1, :2] - poses[-1, :2])) > 1e-3      # it drifted
    # a waypoint 1 m ahead of the odometry pose lies 1 m ahead of the true pose
    frame = OdometryFrame()
    fc = frame.CreateDefaultContext()
    odo = sensor.odometry_port.Eval(ctx)
    frame.odometry_port.FixValue(fc, odo)
    frame.state_port.FixValue(fc, np.r_[poses[-1], 0.0, 0.0])
    frame.waypoint_in_port.FixValue(fc, odo[:2] + [np.cos(odo[2]), np.sin(odo[2])])
    np.testing.assert_allclose(frame.waypoint_port.Eval(fc),
                               poses[-1, :2] + [np.cos(poses[-1, 2]), np.sin(poses[-1, 2])],
                               atol=1e-12)


def test_trajectory_following_study_has_a_lidar_reg_entry(tmp_path):
    import json

    from study_run import run_study

    rc, out, err = run_study("trajectory_following", "--controllers", "lidar_reg",
                             "--trajectories", "1", "--worlds", "test-0", "--p", "0.99",
                             "--data", tmp_path / "data", "--out", tmp_path / "out", "--json",
                             "--quiet")
    assert rc == 0, err
    summary = json.loads(out.strip().splitlines()[-1])
    entry = summary["lidar_reg"]
    assert set(entry) == {"cover", "cover_noisy", "cover_subsampled", "cover_oracle",
                          "cover_oracle_re", "anchors_per_m"}
    assert entry["cover_oracle_re"] is None                   # not in the default runs
    assert all(0.0 <= entry[k] <= 1.0 for k in ("cover", "cover_noisy", "cover_oracle"))
    assert entry["anchors_per_m"] > 0
    rc, _, err = run_study("trajectory_following", "--controllers", "lidar_nope", "--data",
                           tmp_path / "data")
    assert rc == 2
    assert "unknown controllers ['lidar_nope']" in err


def test_label_rollouts_carry_each_cars_tracking_state(house, drives, policy):
    """PolicyRollout (RE's label rollouts) asks a stateful C_WP through
    ``predict_tracked``, one state row per car kept from period to period,
    with the car's pose as odometry: hops along the taught drive succeed."""
    from topodrake.rollout import SUCCESS, PolicyRollout, RolloutConfig

    seen = []

    class Spy(RegistrationPolicy):
        def predict_tracked(self, observation, target, track, cars, keys, odometry):
            before = track[cars, 1].copy()             # slot 0's estimate x, before the query
            seen.append((id(track), np.asarray(cars).copy(), np.asarray(keys).copy(), before))
            return super().predict_tracked(observation, target, track, cars, keys, odometry)

    spy = Spy(policy.config)
    starts, targets, anchors = [], [], []
    for d in drives:
        for a in range(30, len(d) - 5, 40):
            starts.append(d[a - 15])
            targets.append(d[a])
            anchors.append((d, a))
    ctx = np.concatenate([_contexts(house, d, [a])[0] for d, a in anchors])
    res = PolicyRollout(house, spy, RolloutConfig(noise_std=0.0, t_max_s=20.0)).run(
        np.array(starts), np.array(targets), spy.encode_target(ctx))
    assert (res.outcome == SUCCESS).mean() >= 0.8, res.outcome
    assert len({s[0] for s in seen}) == 1                # one state array for the whole run
    assert all(np.all(s[2] == 0) for s in seen)          # each car's target is its anchor 0
    assert not np.isfinite(seen[0][3]).any()             # fresh at the start ...
    assert np.isfinite(seen[2][3]).mean() >= 0.8         # ... then carried over


def test_a_tracked_start_drives_where_a_cold_one_is_blind(house, drives, policy):
    """A label rollout started tracked (``tracked_start``: the following car's
    state) holds the estimate it was given and drives on by odometry where
    no scan registers; a cold start without any fit drives straight ahead."""
    from topodrake.learning.reachability.labels import ReachLabelConfig, tracked_starts

    poses = drives[0]
    a = 60
    feats = policy.encode_target(_contexts(house, poses, [a])[0])
    # the car 1.5 m before the anchor and off the path: the anchor is ahead and to the left
    start = compose(poses[a], np.array([-1.5, -0.6, 0.3]))
    track = tracked_starts(policy, start, poses[a][None], np.array([3]),
                           ReachLabelConfig(tracked_error_m=0.0, tracked_error_rad=0.0))
    slot = track[0].reshape(policy.config.slots, -1)[0]
    np.testing.assert_allclose(slot[1:4], [-1.5, -0.6, 0.3], atol=1e-9)
    blind = np.full((1, 64), np.inf)
    warm = policy.predict_tracked(blind, feats, track, [0], [0], start)
    cold = policy.predict_tracked(blind, feats, policy.initial_track(1), [0], [0], start)
    anchor_in_car = compose(invert(start), poses[a][None])[0]
    assert np.hypot(*(warm.waypoint[0] - anchor_in_car[:2])) < 0.2
    np.testing.assert_allclose(cold.waypoint[0], [policy.config.lookahead_m, 0.0])
    # untracked rows (another drive's target) start cold; the error is seeded
    cfg = ReachLabelConfig()
    two = tracked_starts(policy, np.repeat(start, 2, 0), np.repeat(poses[a][None], 2, 0),
                         np.array([3, 4]), cfg, tracked=np.array([True, False]))
    again = tracked_starts(policy, start, poses[a][None], np.array([3]), cfg)
    np.testing.assert_array_equal(two[0], again[0])
    assert not np.isfinite(two[1, 1:4]).any() and two[1, 0] == -1
    with pytest.raises(TopodrakeError, match="initial_track"):
        from topodrake.rollout import PolicyRollout

        PolicyRollout(house, policy).run(start, poses[a][None], feats, initial_track=two)


def test_drake_waypoint_diagram_and_label_rollouts_drive_the_same_path(house, drives, policy):
    """Table I's Drake diagram keeps the registration C_WP's track in the
    WaypointNet's state and commits it once a period: it drives the same
    path as the batched label rollouts, noise included."""
    from topodrake.learning.waypoint.policy import make_target_context, target_input
    from topodrake.rollout import PolicyRollout, RolloutConfig
    from topodrake.se2 import compose
    from topodrake.systems.run import TargetRunner
    from topodrake.systems.scenario import Scenario
    from topodrake.systems.waypoint_net import build_waypoint_diagram

    poses, a = drives[0], 80
    start, goal = compose(poses[a - 25], np.array([0.0, 0.1, 0.05]))[0], poses[a]
    target = make_target_context(house, poses, a, K, frame_step=STEP, modality="lidar", key=5)
    runner = TargetRunner(build_waypoint_diagram(Scenario(world=house.name, noise_std=0.33,
                                                          camera_enabled=False), policy,
                                                 world=house))
    drake = runner.run(start, goal, target, seed=4, t_max_s=20.0)
    noise = np.zeros((1, 200, 2))
    noise[0, :len(drake.noise)] = drake.noise
    batched = PolicyRollout(house, policy, RolloutConfig(noise_std=0.33)).run(
        start[None], goal[None], policy.encode_target(target_input(policy, target)),
        t_max_s=20.0, noise=noise)
    k = int(batched.steps[0])
    assert k == round(drake.time_s / 0.1) and k > 10
    dev = np.linalg.norm(drake.poses[:k + 1, :2] - batched.poses[0, :k + 1, :2], axis=1)
    assert dev.max() <= 0.01
    assert drake.success and batched.success[0]
    # the committed track: the target's slot with an estimate confirmed period after period
    net = runner.built.waypoint_net
    ctx = net.GetMyContextFromRoot(runner.simulator.get_context())
    slot = ctx.get_abstract_state(net.track_index).get_value()[0].reshape(policy.config.slots,
                                                                           -1)[0]
    assert slot[0] == 5 and np.isfinite(slot[1:4]).all() and slot[13] >= policy.config.confirm
    # a second run on the same runner starts from a fresh track again
    again = runner.run(start, goal, target, seed=4, t_max_s=20.0)
    np.testing.assert_array_equal(again.poses, drake.poses)


def test_a_fresh_anchor_takes_its_prediction_from_the_legs(house, drives, policy):
    """Handing over from a tracked anchor to the next one uses the route's
    legs (the teach drive's odometry between the two), not a registration of
    their taught frames: with a scan that registers to nothing, the new
    anchor's estimate is exactly the tracked one carried by the legs, and its
    confirmation carries over."""
    from topodrake.sensing.lidar import Lidar
    from topodrake.se2 import relative

    poses = drives[0]
    a, b = 60, 75
    ctx, _ = _contexts(house, poses, [a, b])
    feats = policy.encode_target(ctx)
    lidar = Lidar(house)
    cars = np.zeros(1, np.int64)
    legs_pose = np.array([[0.0, 0.0, 0.0], relative(poses[a][None], poses[b][None])[0]])
    legs_pose[1, :2] += [0.06, -0.03]          # the teach drive's odometry, a little off
    legs_seg = np.zeros(2)

    def query(track, p, key, scan=None):
        row = key - 7
        return policy.predict_tracked(lidar.scan(p[None]) if scan is None else scan,
                                      feats[row:row + 1], track, cars, np.array([key]), p[None],
                                      legs=(legs_pose[row:row + 1], legs_seg[row:row + 1]))

    track = policy.initial_track(1)
    path = [poses[i] for i in range(a - 9, a + 1, 3)]
    for p in path:
        query(track, p, 7)
    row = track[0].reshape(policy.config.slots, -1)
    assert row[0, 13] >= policy.config.confirm          # anchor a confirmed
    est_a = row[0, 1:4].copy()
    confirmed = track.copy()
    query(track, path[-1], 8, scan=np.full((1, 64), np.inf))
    row = track[0].reshape(policy.config.slots, -1)
    expected = relative(legs_pose[1][None], est_a[None])[0]
    np.testing.assert_allclose(row[1, 1:4], expected, atol=1e-9)
    # the confirmation carries over: the new anchor's first fit reports its overlaps
    assert query(confirmed, path[-1], 8).overlap[0].min() > 0.3
    # without legs the same query has no estimate to start from but a registration's
    plain = policy.initial_track(1)
    for p in path:
        policy.predict_tracked(lidar.scan(p[None]), feats[:1], plain, cars, np.array([7]), p[None])
    policy.predict_tracked(np.full((1, 64), np.inf), feats[1:], plain, cars, np.array([8]),
                           path[-1][None])
    other = plain[0].reshape(policy.config.slots, -1)[1, 1:4]
    assert not np.allclose(other, expected, atol=1e-3)


def test_a_search_fit_a_neighbouring_anchor_refuses_is_not_taken(house, drives, policy):
    """Where a corridor repeats, a search can fit one anchor's taught frames
    metres off; the legs then put the car beside the neighbouring anchor's
    frames, whose registration fails. A search fit is kept only where a
    neighbour of the segment within reach registers too."""
    from dataclasses import replace

    from topodrake.sensing.lidar import Lidar
    from topodrake.se2 import relative

    poses = drives[0]
    a, b = 60, 66
    ctx, _ = _contexts(house, poses, [a, b])
    elsewhere, _ = _contexts(house, drives[1], [len(drives[1]) // 2])
    lidar = Lidar(house)
    legs = (np.array([[0.0, 0.0, 0.0], relative(poses[a][None], poses[b][None])[0]]), np.zeros(2))
    car = poses[b - 2]

    def search(pol, feats):
        track = pol.initial_track(1)
        pol.predict_tracked(np.repeat(lidar.scan(car[None]), 2, 0), feats, track,
                            np.zeros(2, np.int64), np.array([7, 8]), np.repeat(car[None], 2, 0),
                            legs=legs)
        return track[0].reshape(pol.config.slots, -1)[:, 1:4]     # slots: anchor a, anchor b

    same = search(policy, policy.encode_target(ctx))
    assert np.isfinite(same[1]).all()                   # b found, and a fits there too
    truth = relative(poses[b][None], car[None])[0]
    assert np.hypot(*(same[1, :2] - truth[:2])) < 0.1
    mixed = policy.encode_target(np.concatenate([elsewhere, ctx[1:]]))
    assert not np.isfinite(search(policy, mixed)[1]).all()     # a's frames refuse the fit
    off = RegistrationPolicy(replace(policy.config, search_check_m=0.0))
    assert np.isfinite(search(off, mixed)[1]).all()
    with pytest.raises(TopodrakeError, match="search_check_m"):
        RegistrationConfig(search_check_m=-1.0).check()


def test_the_handover_settings_leave_the_re_fingerprint_alone():
    """RE's labels come from rollouts toward one target, where the handover
    along a route's legs never acts: an RE stays valid whatever those
    settings are, and any other setting changes the fingerprint."""
    from topodrake.learning.reachability.controllers import registration_identity

    base = registration_identity(RegistrationPolicy())["sha1"]
    assert registration_identity(RegistrationPolicy(RegistrationConfig(
        handover=False, handover_m=5.0, search_check_m=0.0,
        start_slides=False)))["sha1"] == base
    assert registration_identity(RegistrationPolicy(RegistrationConfig(confirm=2)))["sha1"] != base
    assert registration_identity()["sha1"] == base


def test_a_goal_watch_ends_the_drake_drive_at_the_goal(box_world):
    """With ``goal_watch_m`` the navigation diagram stops, reached, once the
    car is that close to the route's goal, as the planning study's trials
    do; without it the same drive goes on until the follower stops."""
    from topodrake.systems.navigation import (NavigationRunner, NavigationScenario,
                                              make_navigation_diagram)

    route, pol, reach = _box_route(box_world)
    sc = NavigationScenario(world="box", noise_std=0.0, camera_enabled=False, t_max_s=40.0)
    runner = NavigationRunner(make_navigation_diagram(sc, route, world=box_world, policy=pol,
                                                      reach=reach))
    start = [1.0, 1.8, 0.5]
    plain = runner.run(start, seed=3)
    watched = runner.run(start, seed=3, goal_watch_m=2.0)
    gap = np.hypot(*(watched.poses[:, :2] - route.goal_pose[:2]).T)
    assert watched.outcome == "reached" and gap[-1] <= 2.0
    assert (gap[:-2] > 2.0).all()            # (the last pose is logged and appended both)
    assert watched.time_s < plain.time_s
    assert np.allclose(watched.poses[:-1], plain.poses[:len(watched.poses) - 1])


def test_a_route_start_in_a_corridor_takes_the_fit_that_slides():
    """At a route's start the car stands at the view its start link names,
    but in a corridor the search refuses every fit (it could sit anywhere
    along the corridor) and the car would drive straight ahead, blind. With
    the route's legs, a car with no estimate yet takes the fit from the
    identity onto the anchor's own scan even where it slides: the walls pin
    the side and the heading, the start link the rest."""
    from dataclasses import replace

    from topodrake.rollout import ExpertRollout, RolloutConfig
    from topodrake.sensing.lidar import Lidar
    from topodrake.se2 import relative
    from topodrake.world import load_world

    world = load_world("test-3")
    start = world.places[9]
    res = ExpertRollout(world, RolloutConfig(t_max_s=60.0)).run(start[None], world.places[3, :2][None])
    poses = res.trajectory(0)["poses"]
    ctx, _ = _contexts(world, poses, [0])
    lidar = Lidar(world)
    car = compose(poses[0][None], np.array([[0.0, 0.3, -0.16]]))[0]      # 0.3 m beside it
    scan = lidar.scan(car[None])
    legs = (np.zeros((1, 3)), np.zeros(1))

    def estimate(pol, with_legs=True):
        track = pol.initial_track(1)
        pol.predict_tracked(scan, pol.encode_target(ctx), track, np.zeros(1, np.int64),
                            np.zeros(1, np.int64), np.zeros((1, 3)),
                            legs=legs if with_legs else None)
        return track[0].reshape(pol.config.slots, -1)[0, 1:4]

    from topodrake.registration.icp import register

    fit = register(scan.astype(np.float64), ctx[0, K][None].astype(np.float64))
    assert fit.accepted[0] and fit.constraint[0] < RegistrationConfig().slide_constraint
    pol = RegistrationPolicy(RegistrationConfig(k=K, frame_step=STEP))
    est = estimate(pol)
    truth = relative(poses[0][None], car[None])[0]
    assert np.hypot(*(est[:2] - truth[:2])) < 0.05 and abs(est[2] - truth[2]) < 0.03
    assert not np.isfinite(estimate(pol, with_legs=False)).any()
    off = RegistrationPolicy(replace(pol.config, start_slides=False))
    assert not np.isfinite(estimate(off)).any()
