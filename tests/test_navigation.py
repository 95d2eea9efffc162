"""Navigation: routes, FollowerFsm and WaypointSelect on one context, the
batched engine, and its parity with the Drake navigation diagram (oracles)."""

import numpy as np
import pytest

from topodrake.errors import TopodrakeError


@pytest.fixture(scope="module")
def drive(box_world):
    """An expert drive around the partition of the box world."""
    from topodrake.rollout import ExpertRollout, RolloutConfig

    r = ExpertRollout(box_world, RolloutConfig(t_max_s=60.0)).run(np.array([[1.0, 1.5, 0.3]]),
                                                                  np.array([[8.0, 2.0]]))
    assert r.success[0]
    return r.trajectory(0)["poses"]


@pytest.fixture(scope="module")
def oracles(box_world):
    from topodrake.learning.waypoint.policy import AStarOracle
    from topodrake.navigation.evaluate import GeometricReachability

    return AStarOracle(box_world, k=1, frame_step=3), GeometricReachability(box_world, k=1)


@pytest.fixture(scope="module")
def route(box_world, drive, oracles):
    from topodrake.contract.route import route_from_trajectory

    anchors = np.r_[np.arange(0, len(drive) - 1, 10), len(drive) - 1]
    return route_from_trajectory(box_world, drive, anchors, oracles[0])


def test_route_from_observations_takes_clamped_context_frames():
    from topodrake.contract.route import route_from_observations

    obs = np.arange(20)[:, None] * np.ones((1, 4))          # "lidar" frames numbered 0..19
    poses = np.column_stack([np.arange(20.0), np.zeros(20), np.zeros(20)])
    r = route_from_observations(obs, poses, np.array([0, 9, 19]), k=2, frame_step=3,
                                modality="lidar")
    assert r.contexts[:, :, 0].tolist() == [[0, 0, 0, 3, 6], [3, 6, 9, 12, 15], [13, 16, 19, 19, 19]]
    np.testing.assert_array_equal(r.goal_pose, [19, 0, 0])
    with pytest.raises(TopodrakeError, match="anchors"):
        route_from_observations(obs, poses, np.array([0, 25]), 2, 3, "lidar")


def test_network_context_takes_the_middle_frames():
    from types import SimpleNamespace

    from topodrake.navigation.evaluate import network_context

    ctx = np.arange(2 * 11).reshape(2, 11)
    k0 = SimpleNamespace(k=0, frame_step=3, observation="camera")
    k2 = SimpleNamespace(k=2, frame_step=3, observation="camera")
    assert network_context(ctx, 5, 3, k0).tolist() == [[5], [16]]
    assert network_context(ctx, 5, 3, k2).tolist() == [[3, 4, 5, 6, 7], [14, 15, 16, 17, 18]]
    with pytest.raises(TopodrakeError, match="frame step"):
        network_context(ctx, 5, 3, SimpleNamespace(k=2, frame_step=2, observation="camera"))


def test_engine_follows_a_route_to_its_end(box_world, route, oracles):
    from topodrake.navigation.engine import NAV_REACHED, NavigationEngine
    from topodrake.navigation.follower import Mode

    starts = np.array([[1.0, 1.8, 0.5], [1.1, 1.4, 0.2]])
    res = NavigationEngine(box_world, *oracles).run(starts, [route, route], seeds=[1, 2])
    assert (res.outcome == NAV_REACHED).all()
    assert (res.distance_to_goal_m < 1.0).all()
    assert res.distance_driven_m(0) > 8.0                  # around the partition
    k = int(res.steps[0])
    assert (res.modes[0, :k] == Mode.FOLLOW).mean() > 0.5
    assert res.active[0, k - 1] >= len(route) - 2


def test_follower_fsm_on_one_context(box_world, route, oracles, drive):
    from topodrake.navigation.follower import FollowerState, Mode
    from topodrake.systems.follower import FollowerFsm

    from topodrake.navigation.follower import FollowerConfig

    fsm = FollowerFsm(route, *oracles, FollowerConfig(reverse_inside_turn=-1.0))
    ctx = fsm.CreateDefaultContext()
    car = np.array([*drive[0], 0.0, 0.0])
    fsm.state_port.FixValue(ctx, car)
    target = fsm.target_port.Eval(ctx)
    assert target.key == 0                               # Search picked the anchor under the car
    np.testing.assert_allclose(target.poses, route.contexts[0])
    assert np.isnan(fsm.held_waypoint_port.Eval(ctx)).all()       # WaypointNet's answer drives
    # backing up (the default): the anchor under the car lies inside its turning circle, so
    # the follower holds a point behind the car instead
    backing = FollowerFsm(route, *oracles)
    backing_ctx = backing.CreateDefaultContext()
    backing.state_port.FixValue(backing_ctx, car)
    held = backing.held_waypoint_port.Eval(backing_ctx)
    ahead = np.array([np.cos(car[2]), np.sin(car[2])])
    assert np.dot(held - car[:2], ahead) == pytest.approx(-1.0)
    assert fsm.mode_port.Eval(ctx)[0] == Mode.FOLLOW
    # the decision is a cache entry: nothing is committed before the periodic update
    s = fsm.follower_state(ctx)
    assert isinstance(s, FollowerState) and s.mode[0] == 0 and s.active[0] == -1


def test_follower_fsm_commit_and_termination(box_world, route, oracles, drive):
    from pydrake.systems.analysis import Simulator

    from topodrake.navigation.follower import Mode
    from topodrake.systems.follower import FollowerFsm

    fsm = FollowerFsm(route, *oracles)
    sim = Simulator(fsm)
    ctx = sim.get_mutable_context()
    fsm.state_port.FixValue(ctx, np.array([*drive[0], 0.0, 0.0]))
    sim.AdvanceTo(0.15)                                  # one commit at t = 0.1
    s = fsm.follower_state(ctx)
    assert s.mode[0] == Mode.FOLLOW and s.active[0] == 0
    # at the goal the follower visits the last anchor and ends the run
    fsm.state_port.FixValue(ctx, np.array([*drive[-1], 0.0, 0.0]))
    s.visited[:] = len(route) - 2
    s.active[:] = len(route) - 1
    status = sim.AdvanceTo(5.0)
    assert fsm.follower_state(ctx).mode[0] == Mode.REACHED
    assert status.reason() == status.ReturnReason.kReachedTerminationCondition
    assert ctx.get_time() < 1.0


def test_waypoint_select_prefers_the_held_waypoint():
    from topodrake.systems.follower import WaypointSelect

    sel = WaypointSelect()
    ctx = sel.CreateDefaultContext()
    sel.net_port.FixValue(ctx, [1.0, 2.0])
    sel.held_port.FixValue(ctx, [np.nan, np.nan])
    np.testing.assert_array_equal(sel.waypoint_port.Eval(ctx), [1.0, 2.0])
    sel.held_port.FixValue(ctx, [5.0, 6.0])
    np.testing.assert_array_equal(sel.waypoint_port.Eval(ctx), [5.0, 6.0])


@pytest.mark.parametrize("noise_std,manoeuvres,start", [
    (0.0, False, [1.0, 1.8, 0.5]), (0.33, False, [1.0, 1.8, 0.5]),
    (0.33, True, [1.88, 1.92, -0.31])])     # a start from which the car makes a manoeuvre
def test_drake_diagram_and_engine_drive_the_same_path(box_world, route, oracles, noise_std,
                                                      manoeuvres, start):
    from topodrake.navigation.engine import NAV_OUTCOMES, NavigationConfig, NavigationEngine
    from topodrake.navigation.follower import FollowerConfig
    from topodrake.rollout import RolloutConfig
    from topodrake.systems.navigation import (NavigationRunner, NavigationScenario,
                                              make_navigation_diagram)

    follower = FollowerConfig(manoeuvres=manoeuvres)
    sc = NavigationScenario(world="box", noise_std=noise_std, camera_enabled=False, t_max_s=40.0,
                            follower=follower)
    built = make_navigation_diagram(sc, route, world=box_world, policy=oracles[0],
                                    reach=oracles[1])
    asked = []
    compute = built.waypoint_net.compute
    built.waypoint_net.compute = lambda *a: (asked.append(1), compute(*a))[1]
    drake = NavigationRunner(built).run(start, seed=3)
    assert not asked          # WaypointNet always took the follower's C_WP answer
    noise = np.zeros((1, 400, 2))
    noise[0, :len(drake.noise)] = drake.noise
    engine = NavigationEngine(box_world, *oracles, NavigationConfig(
        follower=follower, rollout=RolloutConfig(noise_std=noise_std, t_max_s=40.0)))
    res = engine.run(np.array([start]), [route], noise=noise)
    k = int(res.steps[0])
    assert k == round(drake.time_s / 0.1) and k > 100     # same periods, a real drive
    dev = np.linalg.norm(drake.poses[:k + 1, :2] - res.poses[0, :k + 1, :2], axis=1)
    assert dev.max() <= 1e-6
    assert drake.outcome == NAV_OUTCOMES[int(res.outcome[0])] == "reached"
    np.testing.assert_array_equal(drake.modes[:k], res.modes[0, :k])
    assert (res.manoeuvres is not None) == manoeuvres
    assert not manoeuvres or res.manoeuvres[0] >= 1


@pytest.mark.parametrize("seed,outcome", [(0, "timeout"), (4, "collision")])
def test_drake_diagram_and_engine_drive_the_same_path_in_a_changed_world(box_world, route,
                                                                         oracles, seed, outcome):
    """One box and one walker placed on the route from the run's seed: the
    WorldChangesSource moves the walker as the engine does, the sensors of
    each period (the lidar and the recorded camera) see them where the
    engine's do, and (seed 4) the car runs into the walker, a collision in
    both.
    (Manoeuvres off: their search breaks near ties on the last bits of the
    pose, so changed worlds with manoeuvres agree only up to such a tie.)"""
    from topodrake.navigation.engine import NAV_OUTCOMES, NavigationConfig, NavigationEngine
    from topodrake.navigation.follower import FollowerConfig
    from topodrake.rollout import RolloutConfig
    from topodrake.sensing.camera import Camera
    from topodrake.sensing.lidar import Lidar
    from topodrake.systems.navigation import (NavigationRunner, NavigationScenario,
                                              make_navigation_diagram)
    from topodrake.vehicle import in_collision
    from topodrake.world.changes import CarChanges, WorldChanges

    follower = FollowerConfig(manoeuvres=False)
    start = np.array([1.0, 1.8, 0.5])
    sc = NavigationScenario(world="box", camera_enabled=False, t_max_s=40.0, follower=follower,
                            changes=WorldChanges(boxes=1, people=1))
    built = make_navigation_diagram(sc, route, world=box_world, policy=oracles[0],
                                    reach=oracles[1], record_sensors=True)
    runner = NavigationRunner(built)
    drake = runner.run(start, seed=seed)
    frames = built.recorder.frames()
    held = built.changes.held(built.changes.GetMyContextFromRoot(runner.simulator.get_context()))
    engine = NavigationEngine(box_world, *oracles, NavigationConfig(
        follower=follower, rollout=RolloutConfig(t_max_s=40.0)))
    changes, placed = sc.place_changes(box_world, route, start, seed)
    walker_start = changes.walkers.xy[0, 0].copy()
    assert drake.changes == placed and len(placed["boxes"]) == 1
    seen = [changes.faces([0])[0]]          # what the engine's sensors see in each period
    res = engine.run(start[None], [route], changes=changes,
                     progress=lambda k, n: seen.append(changes.faces([0])[0]))
    k = int(res.steps[0])
    assert k == round(drake.time_s / 0.1) and k > 100
    dev = np.linalg.norm(drake.poses[:k + 1, :2] - res.poses[0, :k + 1, :2], axis=1)
    assert dev.max() <= 1e-9
    assert drake.outcome == NAV_OUTCOMES[int(res.outcome[0])] == outcome
    np.testing.assert_array_equal(drake.modes[:k], res.modes[0, :k])
    # the diagram's sensors of period j saw the walker where the engine's did
    assert len(frames["t"]) == k
    poses, extra = frames["state"][:, :3], np.stack(seen[:k])
    np.testing.assert_array_equal(frames["ranges"], Lidar(box_world, sc.lidar).scan(poses, extra))
    np.testing.assert_array_equal(frames["image"], Camera(box_world, sc.camera).render(poses,
                                                                                       extra))
    # the walker walked, and the same way in both
    np.testing.assert_allclose(held.walkers.xy, changes.walkers.xy, atol=1e-9)
    assert np.hypot(*(held.walkers.xy[0, 0] - walker_start)) > 0.5
    plain = engine.run(start[None], [route])
    assert not np.allclose(plain.poses[0, :k + 1], res.poses[0, :k + 1])
    if outcome == "collision":          # with the walker, not the walls or the box
        x = np.r_[drake.poses[-1], 0.0, 0.0][None]
        assert not in_collision(x, box_world.grid.clearance_at, sc.vehicle)[0]
        assert not CarChanges.of([np.array(placed["boxes"])]).touching([0], x, sc.vehicle)[0]
        assert held.touching([0], x, sc.vehicle)[0]


def test_a_navigation_scenario_refuses_bad_odometry():
    from topodrake.odometry import OdometryConfig
    from topodrake.systems.navigation import NavigationScenario

    with pytest.raises(TopodrakeError, match="odometry scale_std"):
        NavigationScenario(world="box", odometry=OdometryConfig(scale_std=-0.1))


def test_a_navigation_scenario_takes_changes_from_yaml_and_refuses_bad_ones(tmp_path):
    from topodrake.systems.navigation import NavigationScenario
    from topodrake.typed_yaml import load_typed
    from topodrake.world.changes import WorldChanges

    (tmp_path / "s.yaml").write_text("world: box\nchanges: {boxes: 1, people: 2}\n")
    sc = load_typed(NavigationScenario, tmp_path / "s.yaml", "scenario").validate()
    assert sc.changes == WorldChanges(boxes=1, people=2) and not NavigationScenario().changes.any
    with pytest.raises(TopodrakeError, match="changes: people must be a whole number >= 0"):
        NavigationScenario(world="box", changes=WorldChanges(people=-1))


def test_runner_refuses_a_start_in_a_wall(box_world, route, oracles):
    from topodrake.systems.navigation import (NavigationRunner, NavigationScenario,
                                              make_navigation_diagram)

    sc = NavigationScenario(world="box", camera_enabled=False)
    runner = NavigationRunner(make_navigation_diagram(sc, route, world=box_world,
                                                      policy=oracles[0], reach=oracles[1]))
    with pytest.raises(TopodrakeError):
        runner.run([5.0, 3.0, 0.0])


def _bad_route(route):
    """A plan whose second anchor (the goal) lies behind the partition."""
    from topodrake.contract.route import Route

    return Route(route.contexts[[0, -1]], route.poses[[0, -1]], vertices=np.array([7, 8]),
                 modality=route.modality)


def test_a_car_in_dead_reckoning_is_replanned_without_the_failing_edge(box_world, route, oracles):
    """The follower cannot see the goal anchor of the bad plan and dead
    reckons; at its 5th period it asks for a plan without the failing edge
    (7, 8), takes it and reaches the goal; without replanning it gives up."""
    from topodrake.navigation.engine import NavigationConfig, NavigationEngine
    from topodrake.navigation.follower import FollowerConfig
    from topodrake.experiments.plan_trials import follow_routes
    from topodrake.navigation.replan import ReplanSchedule

    bad = _bad_route(route)
    follower = FollowerConfig.from_dict({"dr_max_iterations": 20})
    engine = NavigationEngine(box_world, *oracles, NavigationConfig(follower=follower))
    goal = route.poses[-1][None]
    asked = []

    def replan(i, pose, excluded):
        asked.append((i, pose, excluded))
        return None if (7, 8) not in excluded else route

    start = np.array([[1.0, 1.6, 0.4]])
    with pytest.raises(TopodrakeError, match="gives up at 20"):    # the default tries at 190
        follow_routes(engine, start, [bad], goal, t_max_s=60.0, replan=replan)
    res = follow_routes(engine, start, [bad], goal, t_max_s=60.0, replan=replan,
                        schedule=ReplanSchedule.paper())
    assert res.success[0] and res.outcome[0] == "goal" and res.plans[0] == 2
    assert res.excluded[0] == [(7, 8)] and len(asked) == 1
    assert np.hypot(*(asked[0][1][:2] - start[0, :2])) < 2.0     # replanned where it was lost
    none = follow_routes(engine, start, [bad], goal, t_max_s=60.0, replan=replan,
                         schedule=ReplanSchedule(first=5, max_replans=0))
    assert not none.success[0] and none.outcome[0] == "dead_reckoning_gave_up"
    assert none.plans[0] == 1 and len(asked) == 1


def test_replanning_in_the_drake_diagram_matches_the_engine(box_world, route, oracles):
    """The same bad plan and replanner in FollowerFsm: the diagram takes the
    new plan at the same period and drives the engine's path."""
    from topodrake.navigation.engine import NavigationConfig, NavigationEngine
    from topodrake.navigation.follower import FollowerConfig
    from topodrake.navigation.replan import Replanner, ReplanSchedule
    from topodrake.systems.navigation import (NavigationRunner, NavigationScenario,
                                              make_navigation_diagram)

    bad = _bad_route(route)
    plan = lambda i, pose, excluded: route if (7, 8) in excluded else None   # noqa: E731
    follower = FollowerConfig.from_dict({"dr_max_iterations": 20})
    start = np.array([1.0, 1.6, 0.4])
    sc = NavigationScenario(world="box", camera_enabled=False, follower=follower, t_max_s=60.0)
    with pytest.raises(TopodrakeError, match="gives up at 20"):
        make_navigation_diagram(sc, bad, world=box_world, policy=oracles[0], reach=oracles[1],
                                replanner=Replanner(plan, [bad]))
    replanner = Replanner(plan, [bad], ReplanSchedule.paper())
    runner = NavigationRunner(make_navigation_diagram(sc, bad, world=box_world, policy=oracles[0],
                                                      reach=oracles[1], replanner=replanner))
    drake = runner.run(start)
    assert drake.outcome == "reached" and drake.plans == 2 and drake.route is route
    assert replanner.excluded[0] == [(7, 8)]
    engine = NavigationEngine(box_world, *oracles, NavigationConfig(follower=follower))
    again = Replanner(plan, [bad], ReplanSchedule.paper())
    res = engine.run(start[None], [bad], t_max_s=60.0, replanner=again)
    assert NAV_OUTCOMES_OF(res) == "reached" and again.plans[0] == 2
    k = min(len(drake.poses), int(res.steps[0]) + 1)
    assert np.linalg.norm(drake.poses[:k, :2] - res.poses[0, :k, :2], axis=1).max() <= 1e-6
    # a second run of the same diagram starts again from the bad plan
    assert runner.run(start).plans == 2 and replanner.plans[0] == 2


def test_a_new_plan_is_taken_only_where_the_follower_s_search_would_start_it(box_world, route,
                                                                            oracles):
    """A plan whose anchors the car cannot see from where it is lost (the far
    end of the drive, behind the partition) is not taken, however sure the
    planner's start link: the car keeps dead reckoning and gives up, in the
    engine and in the Drake diagram alike, where taking it would have
    failed Search at once."""
    from topodrake.navigation.engine import NAV_OUTCOMES, NavigationConfig, NavigationEngine
    from topodrake.navigation.follower import FollowerConfig
    from topodrake.navigation.replan import Replanner, ReplanSchedule
    from topodrake.contract.route import Route
    from topodrake.systems.navigation import (NavigationRunner, NavigationScenario,
                                              make_navigation_diagram)

    bad = _bad_route(route)
    far = Route(route.contexts[-2:], route.poses[-2:], vertices=np.array([20, 21]),
                modality=route.modality, start_probability=0.99)
    asked = []

    def plan(i, pose, excluded):
        asked.append(i)
        return far

    follower = FollowerConfig.from_dict({"dr_max_iterations": 20})
    start = np.array([1.0, 1.6, 0.4])
    engine = NavigationEngine(box_world, *oracles, NavigationConfig(follower=follower))
    replanner = Replanner(plan, [bad], ReplanSchedule.paper())
    res = engine.run(start[None], [bad], t_max_s=60.0, replanner=replanner)
    assert NAV_OUTCOMES[int(res.outcome[0])] == "dead_reckoning_gave_up"
    assert replanner.plans[0] == 1 and len(asked) >= 3      # asked at every try, never taken
    sc = NavigationScenario(world="box", camera_enabled=False, follower=follower, t_max_s=60.0)
    fsm_replanner = Replanner(plan, [bad], ReplanSchedule.paper())
    drake = NavigationRunner(make_navigation_diagram(sc, bad, world=box_world, policy=oracles[0],
                                                     reach=oracles[1],
                                                     replanner=fsm_replanner)).run(start)
    assert drake.outcome != "reached" and drake.plans == 1 and drake.route is bad
    # the planner's start link alone (0.99 > p_search) would have taken it
    from topodrake.navigation.follower import FollowerState, Mode

    lost = FollowerState.initial(1, np.zeros((1, 0)))
    lost.mode[:], lost.dr_count[:] = Mode.DEAD_RECKONING, 5
    lone = Replanner(plan, [bad], ReplanSchedule.paper())
    assert [r for _, r, _ in lone.step(np.zeros(1, np.int64), lost, start[None],
                                    p_start=follower.p_search)] == [far]
    assert lone.step(np.zeros(1, np.int64), lost, start[None], p_start=follower.p_search,
                     startable=lambda r, new: False) == []


def NAV_OUTCOMES_OF(res):
    from topodrake.navigation.engine import NAV_OUTCOMES

    return NAV_OUTCOMES[int(res.outcome[0])]


def test_an_evaluator_is_freed_when_dropped_with_the_route_features_it_holds():
    """A period's Evaluator holds the batch's route features (a GB for camera
    routes): it must be freed as soon as the engine drops it, not at some
    later full garbage collection, or a replanning run keeps every version
    of the features it stacked."""
    import gc
    import weakref
    from types import SimpleNamespace

    from topodrake.navigation.evaluate import Evaluator, RouteFeatures
    from topodrake.sensing.lidar import LidarConfig

    beams = 8
    net = SimpleNamespace(observation="lidar")
    lidar = LidarConfig(beams=beams)
    feats = RouteFeatures(None, None, np.array([0, 2]), scans=np.ones((2, beams)))
    ev = Evaluator(net, net, feats, np.zeros(3, np.int64), np.ones((3, beams)), lidar=lidar)
    assert ev.scan_fixes is not None and ev.anchor_frames is not None
    gone, held = weakref.ref(ev), weakref.ref(feats)
    enabled = gc.isenabled()
    gc.disable()
    try:
        del ev, feats
        assert gone() is None and held() is None
    finally:
        if enabled:
            gc.enable()


def test_replanner_asks_on_schedule_and_discounts_the_current_plan():
    """Tries at Dead reckoning periods 5, 8, 11, ...; a worse plan is taken
    once 0.99 ** tries brings the current plan's probability below it; no
    more than max_replans new plans."""
    from topodrake.navigation.follower import FollowerState, Mode
    from topodrake.navigation.replan import Replanner, ReplanSchedule
    from topodrake.contract.route import Route

    sched = ReplanSchedule.paper()
    assert np.flatnonzero(sched.due(np.arange(15))).tolist() == [5, 8, 11, 14]
    cur = Route(np.zeros((3, 1)), np.zeros((3, 3)), vertices=np.array([1, 2, 3]), probability=0.5)
    worse = Route(np.zeros((2, 1)), np.zeros((2, 3)), vertices=np.array([4, 3]), probability=0.48)
    calls = []
    rp = Replanner(lambda i, pose, ex: calls.append(list(ex)) or worse, [cur],
                   ReplanSchedule(first=5, every=3, discount=0.99, max_replans=1))
    st = FollowerState.initial(1)
    st.mode[:], st.visited[:], st.active[:] = Mode.DEAD_RECKONING, 0, 1
    taken = []
    for count in range(5, 5 + 3 * 6, 3):
        st.dr_count[:] = count
        taken.append(len(rp.step(np.array([0]), st, np.zeros((1, 3)))))
        st.dr_count[:] = count + 1                       # not due: no call
        assert rp.step(np.array([0]), st, np.zeros((1, 3))) == []
    assert taken == [0, 0, 0, 0, 1, 0]
    # 0.5 * 0.99 ** t < 0.48 first at t = 5: four rejected tries, then taken
    assert len(calls) == 5 and calls[0] == [(1, 2)]
    assert rp.plans[0] == 2 and rp.routes[0] is worse and rp.excluded[0] == [(1, 2)]
    st.mode[:] = Mode.FOLLOW
    st.dr_count[:] = 5
    assert rp.step(np.array([0]), st, np.zeros((1, 3))) == []    # not dead reckoning
    st.mode[:] = Mode.DEAD_RECKONING
    assert rp.step(np.array([0]), st, np.zeros((1, 3))) == []    # max_replans reached
    assert len(calls) == 5
    rp.reset()
    assert rp.routes[0] is cur and rp.plans[0] == 1 and rp.excluded[0] == []
    # a plan the follower could not start (its start link below p_search) is not taken
    better = Route(np.zeros((2, 1)), np.zeros((2, 3)), probability=0.9, start_probability=0.7)
    rp = Replanner(lambda i, pose, ex: better, [cur], ReplanSchedule.paper())
    st.dr_count[:] = 5
    assert rp.step(np.array([0]), st, np.zeros((1, 3)), p_start=0.8) == []
    (car, route, start), = rp.step(np.array([0]), st, np.zeros((1, 3)), p_start=0.6)
    assert car == 0 and route is better and start.mode[0] == Mode.SEARCH   # it starts in Search
    with pytest.raises(TopodrakeError, match="discount"):
        ReplanSchedule(discount=1.5).check()


def test_the_default_schedule_asks_only_before_dead_reckoning_gives_up_and_takes_any_plan():
    """Tries fall in the last 10 periods before the follower's default
    give-up; a plan far worse than the current one is taken at the first
    try; the paper's schedule asks from the 5th period."""
    from topodrake.navigation.follower import FollowerConfig, FollowerState, Mode
    from topodrake.navigation.replan import Replanner, ReplanSchedule
    from topodrake.contract.route import Route

    give_up = FollowerConfig().dead_reckoning.dr_max_iterations
    tries = np.flatnonzero(ReplanSchedule().due(np.arange(give_up + 1))).tolist()
    assert tries and all(give_up - 10 <= t < give_up for t in tries)
    assert np.flatnonzero(ReplanSchedule.paper().due(np.arange(12))).tolist() == [5, 8, 11]
    with pytest.raises(TopodrakeError, match="return_to_anchor"):
        ReplanSchedule.from_json('{"return_to_anchor": "yes"}')
    assert ReplanSchedule.from_json('{"return_to_anchor": true}').return_to_anchor
    cur = Route(np.zeros((3, 1)), np.zeros((3, 3)), vertices=np.array([1, 2, 3]), probability=0.9)
    poor = Route(np.zeros((2, 1)), np.zeros((2, 3)), vertices=np.array([4, 3]), probability=0.1)
    st = FollowerState.initial(1)
    st.mode[:], st.visited[:], st.active[:] = Mode.DEAD_RECKONING, 0, 1
    st.dr_count[:] = tries[0]
    assert [r for _, r, _ in Replanner(lambda i, pose, ex: poor, [cur]).step(
        np.array([0]), st, np.zeros((1, 3)))] == [poor]
    assert Replanner(lambda i, pose, ex: poor, [cur], ReplanSchedule.paper()).step(
        np.array([0]), st, np.zeros((1, 3))) == []
    assert ReplanSchedule().check_against(give_up) == ReplanSchedule()
    with pytest.raises(TopodrakeError, match="gives up at 150"):
        ReplanSchedule().check_against(150)


def test_a_replanning_schedule_from_json_changes_only_the_fields_named():
    from topodrake.navigation.replan import ReplanSchedule

    assert ReplanSchedule.from_json(None) == ReplanSchedule()
    assert ReplanSchedule.from_json("paper") == ReplanSchedule.paper()
    s = ReplanSchedule.from_json('{"first": 100, "every": 10}')
    assert (s.first, s.every, s.discount) == (100, 10, ReplanSchedule().discount)
    assert s.due(np.array([99, 100, 105, 110])).tolist() == [False, True, False, True]
    for bad, why in (('[1]', "not a JSON object"), ('{"often": 2}', "often"),
                     ('{"every": 0}', "every"), ('{"first": ', "--replan")):
        with pytest.raises(TopodrakeError, match=why):
            ReplanSchedule.from_json(bad)


def test_a_run_passes_the_hops_before_its_last_visited_anchor_and_fails_the_next():
    from topodrake.navigation.replan import route_traversals

    r = np.array([7, 3, 9, 4, -1])                               # the last anchor is no vertex
    assert route_traversals(r, visited=2, active=3, reached=False) == ([(7, 3), (3, 9)], [(9, 4)])
    assert route_traversals(r, visited=2, active=3, reached=True) == ([(7, 3), (3, 9), (9, 4)], [])
    # out of time: the hop it was on is not blamed
    assert route_traversals(r, visited=2, active=3, reached=False, timed_out=True) == (
        [(7, 3), (3, 9)], [])
    # lost before the first anchor: nothing of the map was driven
    assert route_traversals(r, visited=-1, active=0, reached=False) == ([], [])
    # skipped ahead: the hops between count as passed, the failure is the hop it was on
    assert route_traversals(r, visited=3, active=4, reached=False) == (
        [(7, 3), (3, 9), (9, 4)], [])


def test_a_camera_follower_fsm_hands_the_car_s_lidar_scan_to_the_evaluator(box_world, drive,
                                                                          oracles, monkeypatch):
    """FollowerFsm of a camera C_WP takes the car's lidar scan on its
    ``ranges`` port (the diagram connects the lidar) and gives it to the
    Evaluator for the tracker's scan fixes; unconnected, it gives none."""
    import topodrake.systems.follower as follower_system
    from topodrake.contract.route import Route, route_from_trajectory
    from topodrake.sensing.config import LidarConfig
    from topodrake.sensing.lidar import Lidar

    class CameraOracle:
        """The A* oracle that says it observes images (it ignores them)."""
        observation, k, frame_step = "camera", 0, 1

        def encode_target(self, ctx):
            return np.zeros((len(ctx), 1))

        def predict(self, observation, target):
            from topodrake.contract.waypoint import WaypointPrediction

            n = len(observation)
            return WaypointPrediction(np.tile([[1.0, 0.0]], (n, 1)), np.zeros(n),
                                      np.full((n, 2), 0.5))

    anchors = np.r_[np.arange(0, len(drive) - 1, 10), len(drive) - 1]
    pose_route = route_from_trajectory(box_world, drive, anchors, oracles[0])
    scans = Lidar(box_world).scan(drive[anchors])
    route = Route(np.zeros((len(anchors), 1, 4, 4, 3), np.uint8), pose_route.poses,
                  modality="camera", legs=pose_route.legs, leg_paths=pose_route.leg_paths,
                  scans=scans)
    seen = []

    class Spy(follower_system.Evaluator):
        def __init__(self, *a, **kw):
            super().__init__(*a, **kw)
            seen.append(self.scan_fixes is not None and self.ranges is not None)

    monkeypatch.setattr(follower_system, "Evaluator", Spy)
    fsm = follower_system.FollowerFsm(route, CameraOracle(), oracles[1])
    assert fsm.ranges_port.size() == LidarConfig().beams
    ctx = fsm.CreateDefaultContext()
    fsm.state_port.FixValue(ctx, np.array([*drive[0], 0.0, 0.0]))
    fsm.observation_port.FixValue(ctx, np.zeros((64, 64, 3), np.uint8))
    fsm.decision(ctx)
    assert seen == [False]                     # no scan on the port: no fixes
    ctx = fsm.CreateDefaultContext()
    fsm.state_port.FixValue(ctx, np.array([*drive[0], 0.0, 0.0]))
    fsm.observation_port.FixValue(ctx, np.zeros((64, 64, 3), np.uint8))
    fsm.ranges_port.FixValue(ctx, Lidar(box_world).scan(drive[:1])[0])
    fsm.decision(ctx)
    assert seen == [False, True]


def test_a_tracked_car_with_no_plan_from_its_view_returns_to_its_anchor_and_plans_from_it():
    """With return_to_anchor, a car no plan starts for from its view takes a
    plan from the map vertex the tracker places it relative to, and starts it
    dead reckoning back to that anchor: held where odometry puts the anchor,
    tracked from the new route's first anchor; a car the tracker lost
    returns to the odometry pose of its last visit; without either, or
    without return_to_anchor, it takes nothing."""
    from topodrake.navigation.follower import FollowerState, Mode
    from topodrake.navigation.replan import Replanner, ReplanSchedule
    from topodrake.contract.route import Route

    cur = Route(np.zeros((3, 1)), np.zeros((3, 3)), vertices=np.array([1, 2, 3]), probability=0.5)
    back = Route(np.zeros((3, 1)), np.zeros((3, 3)), vertices=np.array([2, 5, 3]),
                 probability=0.4)
    asked = []

    def plan(i, pose, excluded, vertex=None):
        asked.append((vertex, list(excluded)))
        return back if vertex == 2 else None

    st = FollowerState.initial(1, 2)
    st.mode[:], st.visited[:], st.active[:], st.dr_count[:] = Mode.DEAD_RECKONING, 1, 2, 190
    st.ref[:], st.rel[:], st.odo[:] = 1, [1.0, 0.5, 0.3], [2.0, 3.0, 0.1]
    st.var[:] = np.eye(3).ravel() * 0.01
    assert Replanner(plan, [cur]).step(np.array([0]), st, np.zeros((1, 3))) == []
    assert asked == [(None, [(2, 3)])]
    rp = Replanner(plan, [cur], ReplanSchedule(return_to_anchor=True))
    (car, route, start), = rp.step(np.array([0]), st, np.zeros((1, 3)))
    assert route is back and asked[-1] == (2, [(2, 3)]) and rp.excluded[0] == [(2, 3)]
    assert start.mode[0] == Mode.DEAD_RECKONING and start.active[0] == 0 and start.visited[0] == -1
    assert start.ref[0] == 0 and start.dr_count[0] == 0 and start.track.shape == (1, 2)
    np.testing.assert_allclose(start.rel[0], st.rel[0])
    np.testing.assert_allclose(start.var[0], st.var[0])
    # the anchor, seen from the car at rel, lies at the held waypoint in the odometry frame
    np.testing.assert_allclose(start.waypoint[0],
                               st.odo[0, :2] + _anchor_offset(st.odo[0], st.rel[0]), atol=1e-12)
    assert rp.returns[0] == 1 and rp.plans[0] == 2
    # a vertex with no way on but the failing hop: the plan retries it, once
    retry = Replanner(lambda i, pose, ex, vertex=None: back if vertex == 2 and not ex else None,
                      [cur], ReplanSchedule(return_to_anchor=True))
    (_, route, _), = retry.step(np.array([0]), st, np.zeros((1, 3)))
    assert route is back and retry.excluded[0] == [(2, 3)]
    again = st.copy()                # failing again from vertex 2, on (2, 5) of the retried plan
    again.visited[:], again.active[:], again.ref[:] = 0, 1, 0
    assert retry.step(np.array([0]), again, np.zeros((1, 3))) == []   # (2, 3) stays excluded
    st.ref[:] = -1            # the tracker lost it, and no visit pose kept: nothing to return to
    rp = Replanner(plan, [cur], ReplanSchedule(return_to_anchor=True))
    assert rp.step(np.array([0]), st, np.zeros((1, 3))) == [] and rp.plans[0] == 1
    st.seen[:] = [4.0, 1.0, 0.2]      # ... with it, the car returns to where it marked it visited
    (_, route, start), = rp.step(np.array([0]), st, np.zeros((1, 3)))
    assert route is back and start.ref[0] == -1 and start.mode[0] == Mode.DEAD_RECKONING
    np.testing.assert_allclose(start.waypoint[0], [4.0, 1.0])


def test_the_oracle_relocalizes_a_car_no_plan_starts_for_at_the_vertex_it_sees():
    """With oracle_relocalize, a car no plan starts for from its view asks for
    a plan from the vertex the oracle locates it at, and dead reckons to that
    vertex's taught position given in its odometry frame; the oracle takes
    the nearest vertex the car sees and would face, never one behind a wall
    or turned away."""
    from topodrake.navigation.follower import FollowerState, Mode
    from topodrake.navigation.replan import (NEAREST, Replanner, ReplanSchedule,
                                             nearest_seen_vertex)
    from topodrake.contract.route import Route

    cur = Route(np.zeros((3, 1)), np.zeros((3, 3)), vertices=np.array([1, 2, 3]), probability=0.5)
    there = Route(np.zeros((2, 1)), np.array([[3.0, 1.0, 0.0], [5.0, 1.0, 0.0]]),
                  vertices=np.array([7, 8]), probability=0.3)
    asked = []

    def plan(i, pose, excluded, vertex=None):
        asked.append(vertex)
        return there if vertex == NEAREST else None

    st = FollowerState.initial(1, 2)
    st.mode[:], st.visited[:], st.active[:], st.dr_count[:] = Mode.DEAD_RECKONING, 1, 2, 190
    true, odo = np.array([[1.0, 1.0, 0.0]]), np.array([[11.0, 1.0, np.pi / 2]])
    assert Replanner(plan, [cur]).step(np.array([0]), st, true, odometry=odo) == []
    rp = Replanner(plan, [cur], ReplanSchedule(oracle_relocalize=True))
    (_, route, start), = rp.step(np.array([0]), st, true, odometry=odo)
    assert route is there and asked[-2:] == [None, NEAREST] and rp.returns[0] == 1
    assert start.mode[0] == Mode.DEAD_RECKONING and start.active[0] == 0 and start.visited[0] == -1
    # 2 m ahead of the car in truth is 2 m ahead of its odometry pose, which faces +y
    np.testing.assert_allclose(start.waypoint[0], [11.0, 3.0], atol=1e-12)

    free = lambda xy: np.where(np.abs(np.asarray(xy)[..., 0] - 2.0) < 0.1, 0.0, 1.0)  # noqa: E731
    vertices = np.array([[1.5, 0.0, 0.0],      # 1.5 m ahead, facing on: the nearest seen
                         [3.0, 0.0, 0.0],      # behind the wall at x = 2
                         [-1.0, 0.0, 0.0],     # behind the car, facing away from the way there
                         [0.0, 3.0, 1.5]])     # to the left, facing the way there
    assert nearest_seen_vertex(vertices, np.zeros(3), free) == 0
    assert nearest_seen_vertex(vertices[1:], np.zeros(3), free) == 2
    assert nearest_seen_vertex(vertices[1:3], np.zeros(3), free) is None
    assert nearest_seen_vertex(vertices, np.zeros(3), free, max_m=1.0) is None
    with pytest.raises(TopodrakeError, match="oracle_relocalize"):
        ReplanSchedule.from_json('{"oracle_relocalize": 1}')


def _anchor_offset(odo, rel):
    """Where an anchor lies from the car's odometry position, the car being
    at ``rel`` in the anchor's frame (worked out by hand)."""
    x, y, th = rel
    ax, ay = -(np.cos(th) * x + np.sin(th) * y), -(-np.sin(th) * x + np.cos(th) * y)
    c, s = np.cos(odo[2]), np.sin(odo[2])
    return np.array([c * ax - s * ay, s * ax + c * ay])


def _sub_route(route, rows, vertices, leg_rows):
    """Anchors ``rows`` of ``route`` as map ``vertices``; hop i keeps the
    route's leg ``leg_rows[i]`` (None: a hop without a leg)."""
    from topodrake.contract.route import Route

    nan = np.full_like(route.leg_paths[0], np.nan)
    paths = np.stack([nan if j is None else route.leg_paths[j] for j in leg_rows])
    return Route(route.contexts[rows], route.poses[rows], vertices=np.array(vertices),
                 modality=route.modality, legs=paths[:, -1], leg_paths=paths)


def test_a_car_lost_on_a_hop_returns_to_its_anchor_and_drives_a_plan_from_it(box_world, route,
                                                                            oracles):
    """A plan whose last hop jumps behind the partition: the car follows its
    first anchors, cannot see the goal and dead reckons; no plan starts from
    its view, so with return_to_anchor it takes the plan from the vertex it
    is tracked from, drives back to that anchor and round the partition to
    the goal, in the engine and the Drake diagram alike; without it it
    gives up."""
    from topodrake.navigation.engine import NAV_OUTCOMES, NavigationConfig, NavigationEngine
    from topodrake.navigation.follower import FollowerConfig
    from topodrake.navigation.replan import Replanner, ReplanSchedule
    from topodrake.systems.navigation import (NavigationRunner, NavigationScenario,
                                              make_navigation_diagram)

    n = len(route)
    bad = _sub_route(route, [0, 1, 2, n - 1], [10, 11, 12, 99], [0, 1, None])
    good = _sub_route(route, list(range(2, n)), [12, *range(13, 11 + n - 2), 99],
                      list(range(2, n - 1)))
    asked = []

    def plan(i, pose, excluded, vertex=None):
        asked.append((vertex, list(excluded)))
        return good if vertex == 12 and (12, 99) in excluded else None

    follower = FollowerConfig.from_dict({"dr_max_iterations": 40})
    # 0.2 rad left of the route's start pose: from that pose the walled blind cone turns
    # the car forward, and Follow and Dead reckoning then alternate without a give-up (limits.md)
    start = np.array([1.0, 1.5, 0.5])
    engine = NavigationEngine(box_world, *oracles, NavigationConfig(follower=follower))
    schedule = ReplanSchedule(first=20, every=3, return_to_anchor=True)
    replanner = Replanner(plan, [bad], schedule)
    res = engine.run(start[None], [bad], t_max_s=80.0, replanner=replanner)
    assert NAV_OUTCOMES[int(res.outcome[0])] == "reached" and replanner.plans[0] == 2
    assert (12, [(12, 99)]) in asked and replanner.routes[0] is good
    k = int(res.steps[0])
    assert np.hypot(*(res.poses[0, k, :2] - route.poses[-1, :2])) < 1.0
    sc = NavigationScenario(world="box", camera_enabled=False, follower=follower, t_max_s=80.0)
    fsm = Replanner(plan, [bad], schedule)
    drake = NavigationRunner(make_navigation_diagram(sc, bad, world=box_world, policy=oracles[0],
                                                     reach=oracles[1], replanner=fsm)).run(start)
    assert drake.outcome == "reached" and drake.plans == 2 and drake.route is good
    m = min(len(drake.poses), k + 1)
    assert np.linalg.norm(drake.poses[:m, :2] - res.poses[0, :m, :2], axis=1).max() <= 1e-6
    plain = Replanner(plan, [bad], ReplanSchedule(first=20, every=3))
    res = engine.run(start[None], [bad], t_max_s=80.0, replanner=plain)
    assert NAV_OUTCOMES[int(res.outcome[0])] == "dead_reckoning_gave_up" and plain.plans[0] == 1

