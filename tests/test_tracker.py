"""The route tracker: odometry along the taught legs, C_WP's answers as gated fixes."""

from dataclasses import replace

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.navigation.follower import (Answers, FollowerConfig, FollowerState, Mode,
                                           follower_step)
from topodrake.navigation.tracker import (TrackerConfig, anchor_in_car, diagonal_cov, fix, fix_pose,
                                          propagate, pursuit_point, reanchor, reanchor_cov, route_frames,
                                          start_from_answer)
from topodrake.se2 import compose, relative

CFG = TrackerConfig()


def test_route_frames_compose_legs_and_split_at_unknown_ones():
    legs = np.array([[1.0, 0.0, np.pi / 2], [1.0, 0.0, 0.0], [np.nan] * 3, [2.0, 0.0, 0.0]])
    frames, seg, approach = route_frames([legs, np.zeros((0, 3))])   # the second: one anchor
    assert np.isnan(approach[[0, 3, 5]]).all()
    np.testing.assert_allclose(approach[2, -1], frames[2], atol=1e-12)
    np.testing.assert_allclose(frames[:3], [[0, 0, 0], [1, 0, np.pi / 2], [1, 1, np.pi / 2]],
                               atol=1e-12)
    np.testing.assert_allclose(frames[3:5], [[0, 0, 0], [2, 0, 0]])
    assert seg.tolist() == [0, 0, 0, 1, 1, -1]


def test_propagate_moves_the_pose_by_odometry_and_grows_the_variance():
    rel, var = np.array([[0.5, 0.0, 0.0]]), diagonal_cov(0.01, 0.01)
    before, after = np.array([[3.0, 1.0, np.pi / 2]]), np.array([[3.0, 2.0, np.pi / 2]])
    rel2, var2 = propagate(rel, var, before, after, CFG)
    np.testing.assert_allclose(rel2, [[1.5, 0.0, 0.0]], atol=1e-12)
    cov, cov2 = var.reshape(3, 3), var2.reshape(3, 3)
    assert (np.diag(cov2) > np.diag(cov)).all()
    # driving 1 m ahead, a heading error becomes a sideways error: y and heading correlate
    assert cov2[1, 1] > cov[1, 1] + cov[2, 2] * 0.9 and cov2[1, 2] > 0.9 * cov[2, 2]
    np.testing.assert_allclose(cov2, cov2.T)


def exact_answer(car, anchor):
    seen = relative(car, anchor)
    return seen[:, :2], seen[:, 2]


def test_an_exact_answer_pulls_a_wrong_prior_to_the_truth():
    anchor = np.array([[2.0, 0.0, 0.3]])
    truth = np.array([[0.2, 0.1, 0.05]])
    rel, var = truth + [[0.3, -0.2, 0.1]], diagonal_cov(0.3 ** 2, 0.2 ** 2)
    independent = replace(CFG, repeats=1.0)          # answers whose errors do not repeat
    for _ in range(10):
        rel, var, ok = fix(rel, var, anchor, *exact_answer(truth, anchor), independent)
        assert ok[0]
    before, after = np.hypot(0.3, -0.2), np.hypot(*(rel - truth)[0, :2])
    assert after < 0.3 * before                  # a Kalman average of the prior and the answers
    assert abs(rel[0, 2] - truth[0, 2]) < 0.02


def test_an_answer_far_off_the_prior_is_outvoted():
    anchor = np.array([[1.5, 0.0, 0.0]])
    truth = np.zeros((1, 3))
    var = diagonal_cov(0.05 ** 2, 0.05 ** 2)
    wrong = np.array([[0.0, 1.5]])                       # 90 deg off
    rel, var2, ok = fix(truth, var, anchor, wrong, np.zeros(1), CFG)
    assert not ok[0]
    np.testing.assert_array_equal(rel, truth)
    np.testing.assert_array_equal(var2, var)


def test_a_start_from_one_answer_and_reanchoring_keep_the_cars_pose():
    car = np.array([[0.3, -0.2, 0.4]])
    anchor = np.array([[1.0, 0.5, -0.2]])             # both in some common frame
    rel, _ = start_from_answer(*exact_answer(car, anchor), CFG)   # the car in the anchor's frame
    np.testing.assert_allclose(compose(anchor, rel), car, atol=1e-12)
    other = np.array([[2.0, 2.0, 1.0]])
    np.testing.assert_allclose(compose(other, reanchor(rel, anchor, other)), car, atol=1e-12)
    np.testing.assert_allclose(anchor_in_car(rel, np.zeros((1, 3))),
                               relative(car, anchor), atol=1e-12)


class Straight:
    """A route of anchors 1 m apart along x from the origin; C_WP's answers
    are exact but toward ``bad`` anchors, where they point 90 deg left; RE
    always 0.95, overlaps 0.7."""

    def __init__(self, n, bad=()):
        self.frames = np.column_stack([np.arange(n, dtype=float), np.zeros(n), np.zeros(n)])
        self.bad = set(bad)
        self.car = np.zeros((1, 3))

    def anchor_frames(self, cars, anchors):
        return self.frames[anchors], np.zeros(len(anchors), np.int64), \
            np.full((len(anchors), 1, 3), np.nan)

    def __call__(self, cars, anchors, cwp, re):
        m = len(anchors)
        wp, h = exact_answer(np.repeat(self.car, m, 0), self.frames[anchors])
        for i, a in enumerate(anchors):
            if a in self.bad:
                wp[i] = [0.0, np.hypot(*wp[i])]
        return Answers(wp, np.full((m, 2), 0.7), np.full(m, 0.95), h)


def drive(ev, state, car, **cfg):
    ev.car = car[None, :3]
    return follower_step(state, np.array([len(ev.frames)]), car[None], ev,
                         FollowerConfig.from_dict(cfg))


def drive_along(ev, xs, **cfg):
    """The follower's state after driving a fresh car along x = ``xs``."""
    car = np.zeros(5)
    s = FollowerState.initial(1)
    for x in xs:
        car[0] = x
        s, _ = drive(ev, s, car, **cfg)
    return s


def test_the_follower_replaces_a_waypoint_that_disagrees_with_the_tracked_anchor():
    ev = Straight(6, bad={3})
    car = np.array([0.0, 0.0, 0.0, 0.0, 0.0])
    s = FollowerState.initial(1)
    for x in (0.0, 0.6, 1.2):                     # the tracker starts and follows anchors 1, 2
        car[0] = x
        s, out = drive(ev, s, car, odometry_check=True)
    assert s.mode[0] == Mode.FOLLOW and s.ref[0] >= 0
    car[0] = 2.2                                  # past anchor 2: anchor 3 is active, C_WP wrong
    before = s.copy()
    s, out = drive(ev, s, car, odometry_check=True)
    assert s.active[0] == 3
    np.testing.assert_allclose(out.waypoint[0], [3.0, 0.0], atol=0.05)   # the tracked anchor
    assert out.held[0] and out.target[0] == -1      # the follower's own waypoint: C_WP's not driven
    # (the wrong answer lies inside the turning circle: without backing up, to see it driven)
    plain, out_plain = drive(ev, before, car, odometry_check=False, reverse_inside_turn=-1.0)
    assert plain.active[0] == 3
    assert out_plain.waypoint[0, 1] > 0.5          # without the check the car turns left
    assert not out_plain.held[0] and out_plain.target[0] == 3


def test_dead_reckoning_drives_to_the_tracked_anchor():
    ev = Straight(6)
    car = np.array([0.0, 0.0, 0.0, 0.0, 0.0])
    s = FollowerState.initial(1)
    for x in (0.0, 0.6):
        car[0] = x
        s, _ = drive(ev, s, car, odometry_check=True)
    s.mode[:] = Mode.DEAD_RECKONING
    s.waypoint[:] = [[0.0, 5.0]]
    car[0] = 0.4

    class LowRe(Straight):
        def __call__(self, cars, anchors, cwp, re):
            a = super().__call__(cars, anchors, cwp, re)
            a.probability[:] = 0.1
            return a

    low = LowRe(6)
    low.car = car[None, :3]
    s, out = follower_step(s, np.array([6]), car[None], low,
                           FollowerConfig.from_dict({"odometry_check": True}))
    assert s.mode[0] == Mode.DEAD_RECKONING
    np.testing.assert_allclose(out.waypoint[0], low.frames[s.active[0], :2], atol=0.05)


def test_the_pursuit_point_follows_the_taught_path_round_a_corner():
    # taught poses into an anchor 2 m ahead and 2 m left: first straight on, then left
    path = np.array([[0.5, 0, 0], [1.0, 0, 0], [1.5, 0, 0], [2.0, 0, np.pi / 2],
                     [2.0, 0.5, np.pi / 2], [2.0, 1.0, np.pi / 2], [2.0, 1.5, np.pi / 2]])
    anchor = np.array([[2.0, 2.0, np.pi / 2]])
    car = np.zeros((1, 3))
    aim = pursuit_point(car, path[None], anchor, 1.0)
    np.testing.assert_allclose(aim, [[1.0, 0.0]])              # along the path, not the chord
    car_on = np.array([[2.0, 0.4, np.pi / 2]])
    np.testing.assert_allclose(pursuit_point(car_on, path[None], anchor, 1.0), [[1.1, 0.0]],
                               atol=1e-12)
    unknown = np.full((1, 7, 3), np.nan)
    np.testing.assert_allclose(pursuit_point(car, unknown, anchor, 1.0), [[2.0, 2.0]])


def test_the_papers_follower_turns_our_rules_off():
    paper = FollowerConfig.paper().check()
    assert not paper.tracker.odometry_check and FollowerConfig().tracker.odometry_check
    assert paper.lookahead == 5 and paper.p_search == 0.92
    assert paper.dead_reckoning.dr_back_anchors == -1
    # no distance condition: an anchor 2 m off with high proximity counts as visited
    ev = Straight(6)
    ev.car = np.zeros((1, 3))
    s = FollowerState.initial(1)
    s.mode[:], s.active[:], s.visited[:] = Mode.FOLLOW, 1, 0
    ours, _ = follower_step(s, np.array([6]), np.zeros((1, 5)), ev, FollowerConfig())
    theirs, _ = follower_step(s, np.array([6]), np.zeros((1, 5)), ev, paper)
    assert ours.visited[0] == 0 and theirs.visited[0] >= 2


def test_repeated_answers_do_not_make_the_tracker_overconfident():
    """C_WP's error toward one anchor repeats from one period to the next: a
    run of identical biased answers moves the estimate only part of the way
    to the bias, and the sigmas stay above their floors."""
    anchor = np.array([[1.5, 0.0, 0.0]])
    truth = np.zeros((1, 3))
    biased = exact_answer(truth + [[0.0, 0.25, 0.0]], anchor)       # 0.25 m off, every period
    moved = {}
    for repeats in (1.0, 10.0):
        cfg = replace(CFG, repeats=repeats)
        rel, var = truth.copy(), diagonal_cov(0.2 ** 2, 0.1 ** 2)
        for _ in range(10):
            rel, var, ok = fix(rel, var, anchor, *biased, cfg)
            assert ok[0]
        moved[repeats] = abs(rel[0, 1])
        d = np.diag(var.reshape(3, 3))
        assert d[0] >= cfg.floor_m ** 2 - 1e-12 and d[2] >= cfg.floor_rad ** 2 - 1e-12
    assert moved[10.0] < 0.6 * moved[1.0]
    assert moved[1.0] > 0.15                     # one-shot answers: most of the way to the bias


def test_the_waypoint_alone_corrects_a_wrong_heading():
    """An anchor's bearing depends on the car's heading: exact waypoints
    (no heading head) pull a wrong heading to the truth once odometry has
    correlated heading and position."""
    truth = np.zeros((1, 3))
    rel = np.array([[0.0, 0.0, 0.15]])                       # 8.6 deg off
    var = diagonal_cov(0.05 ** 2, 0.2 ** 2)
    independent = replace(CFG, repeats=1.0)
    anchors = np.array([[1.5, 0.8, 0.0], [1.5, -0.8, 0.0]])  # one on each side
    for k in range(20):
        a = anchors[[k % 2]]
        rel, var, ok = fix(rel, var, a, exact_answer(truth, a)[0], np.full(1, np.nan), independent)
        assert ok[0]
    assert abs(rel[0, 2]) < 0.03 and np.hypot(*rel[0, :2]) < 0.05


def test_reanchoring_turns_the_covariance_with_the_frame():
    var = diagonal_cov(0.0, 0.0)
    var.reshape(3, 3)[0, 0] = 0.04                           # uncertain along x of the old frame
    old, new = np.zeros((1, 3)), np.array([[1.0, 2.0, np.pi / 2]])
    cov = reanchor_cov(var, old, new).reshape(3, 3)
    np.testing.assert_allclose(np.diag(cov), [0.0, 0.04, 0.0], atol=1e-12)  # now along y


class _FixedAnswer:
    """A stateless lidar C_WP stand-in: target features are the anchors' own
    centre scans; every answer is ``waypoint`` with ``heading``."""

    observation, k, frame_step = "lidar", 0, 3

    def __init__(self, waypoint, heading):
        self.waypoint, self.heading = np.asarray(waypoint, float), float(heading)

    def encode_target(self, context):
        return np.asarray(context, np.float64)

    def predict(self, observation, target):
        from topodrake.contract.waypoint import WaypointPrediction

        n = len(np.asarray(observation))
        return WaypointPrediction(np.repeat(self.waypoint[None], n, 0), np.full(n, self.heading),
                                  np.ones((n, 2)))


def _route_with_a_gap(n=5, gap=2):
    from topodrake.contract.route import Route, teach_legs

    poses = np.column_stack([np.arange(4 * n) * 0.25, np.zeros(4 * n), np.zeros(4 * n)])
    anchors = np.arange(0, 4 * n, 4)
    legs, paths = teach_legs(poses, anchors)
    legs[gap] = np.nan                      # a hop between drives: no taught leg
    paths[gap] = np.nan
    scans = np.ones((n, 1, 8), np.float32)
    return Route(scans, poses[anchors], modality="lidar", legs=legs, leg_paths=paths)


def test_hops_without_a_leg_take_c_wps_answer_as_their_leg():
    from topodrake.navigation.evaluate import encode_routes

    route = _route_with_a_gap()
    reach = _FixedAnswer([0.0, 0.0], 0.0)
    plain = encode_routes([route], reach, reach)
    assert len(set(plain.segments)) == 2                   # the gap splits the route in two
    feats = encode_routes([route], _FixedAnswer([0.9, 0.1], 0.2), reach, legs_m=2.0)
    assert set(feats.segments) == {0}                       # one segment across the gap
    # anchors after the gap sit where the answer put them, then follow the taught legs
    gap_end = compose(feats.frames[2][None], np.array([0.9, 0.1, 0.2]))[0]
    np.testing.assert_allclose(feats.frames[3], gap_end, atol=1e-9)
    np.testing.assert_allclose(feats.frames[4], compose(gap_end[None], np.array([1.0, 0, 0]))[0],
                               atol=1e-9)
    np.testing.assert_allclose(feats.frames[:3], plain.frames[:3], atol=1e-12)
    # the hop's path is the straight line, ending at the anchor
    np.testing.assert_allclose(feats.approach[3, -1], gap_end, atol=1e-9)
    assert np.all(np.isfinite(feats.approach[3]))
    # an answer as long as the limit or longer is a direction, not a place: no leg
    far = encode_routes([route], _FixedAnswer([2.5, 0.0], 0.0), reach, legs_m=2.0)
    assert len(set(far.segments)) == 2
    assert route.legs[2, 0] != route.legs[2, 0]              # the route itself is left as it was


def test_an_a_star_c_wp_estimates_a_missing_leg_where_it_sees_the_anchor():
    from topodrake.learning.waypoint.policy import AStarOracle
    from topodrake.navigation.evaluate import encode_routes
    from topodrake.contract.route import Route
    from topodrake.world import load_world

    world = load_world("test-0")
    rng = np.random.default_rng(0)
    while True:
        a = world.sample_free_pose(rng)
        b = compose(a[None], np.array([1.2, 0.2, 0.3]))[0]
        along = a[None, :2] + np.linspace(0, 1, 12)[:, None] * (b[:2] - a[:2])[None]
        if world.grid.clearance_at(along).min() > 0.4:         # in the open: b in plain sight
            break
    poses = np.vstack([a, b])
    route = Route(poses[:, None], poses, modality="pose")
    oracle = AStarOracle(world, k=0)
    feats = encode_routes([route], oracle, oracle, legs_m=2.0)
    assert feats.segments.tolist() == [0, 0]
    np.testing.assert_allclose(feats.frames[1], relative(a[None], b[None])[0], atol=0.1)


def test_legs_m_is_checked_and_off_for_the_paper():
    import pytest

    from topodrake.errors import TopodrakeError

    assert FollowerConfig().tracker.legs_m > 0 and FollowerConfig.paper().tracker.legs_m == 0
    with pytest.raises(TopodrakeError, match="legs_m"):
        FollowerConfig.from_dict({"legs_m": -1.0})


def test_the_drake_follower_joins_the_legs_as_the_engine_does():
    from systems.follower import FollowerFsm
    from topodrake.navigation.evaluate import encode_routes

    route = _route_with_a_gap()
    policy, reach = _FixedAnswer([0.9, 0.1], 0.2), _FixedAnswer([0.0, 0.0], 0.0)
    for legs_m in (0.0, 2.0):
        fsm = FollowerFsm(route, policy, reach, FollowerConfig.from_dict({"legs_m": legs_m}))
        engine = encode_routes([route], policy, reach, legs_m=legs_m)
        got = fsm._routes[0].features
        np.testing.assert_array_equal(got.segments, engine.segments)
        np.testing.assert_allclose(got.frames, engine.frames)
        assert len(set(got.segments)) == (1 if legs_m else 2)


def test_a_scan_fix_pulls_the_tracked_pose_to_it_and_outvotes_a_far_one():
    truth = np.array([[0.4, -0.1, 0.2]])
    rel, var = truth + [[0.25, 0.2, -0.1]], diagonal_cov(0.2 ** 2, 0.1 ** 2)
    rel2, var2, ok = fix_pose(rel, var, truth, CFG)
    assert ok[0]
    assert np.hypot(*(rel2 - truth)[0, :2]) < 0.1 * np.hypot(0.25, 0.2)   # a sharp measurement
    assert (np.diag(var2.reshape(3, 3)) < np.diag(var.reshape(3, 3))).all()
    far, _, ok_far = fix_pose(truth, diagonal_cov(0.05 ** 2, 0.03 ** 2), truth + [[1.0, 0, 0]], CFG)
    assert not ok_far[0]
    np.testing.assert_array_equal(far, truth)
    nan, _, ok_nan = fix_pose(rel, var, np.full((1, 3), np.nan), CFG)
    assert not ok_nan[0] and np.array_equal(nan, rel)


class Scanned(Straight):
    """:class:`Straight` whose anchors keep scans: a registration returns the
    car's true pose in the anchor's frame, pinned unless ``slides``."""

    slides = False

    def scan_fixes(self, cars, anchors, guess):
        truth = relative(self.frames[anchors], np.repeat(self.car, len(anchors), 0))
        return truth, np.full(len(anchors), not self.slides)


def test_scan_fixes_correct_a_track_that_drifted():
    ev = Scanned(6)
    car = np.array([0.0, 0.0, 0.0, 0.0, 0.0])
    s = FollowerState.initial(1)
    for x in (0.0, 0.6, 1.2):
        car[0] = x
        s, _ = drive(ev, s, car)
    assert s.ref[0] >= 0
    truth = relative(ev.frames[s.ref], car[None, :3])
    drifted = s.copy()
    drifted.rel[:] = truth + [[0.0, 0.4, 0.1]]           # odometry drifted sideways ...
    drifted.var[:] = diagonal_cov(0.3 ** 2, 0.1 ** 2)    # ... as far as it could
    drifted.misses[:] = 3
    fixed, _ = drive(ev, drifted, car)
    ref_truth = relative(ev.frames[fixed.ref], car[None, :3])
    assert np.hypot(*(fixed.rel - ref_truth)[0, :2]) < 0.1 and fixed.misses[0] == 0
    unfixed, _ = drive(ev, drifted, car, scan_fix=False)
    assert np.hypot(*(unfixed.rel - ref_truth)[0, :2]) > 0.2
    ev.slides = True                                     # a corridor: the fit is not used
    slid, _ = drive(ev, drifted, car)
    assert np.hypot(*(slid.rel - ref_truth)[0, :2]) > 0.2
    assert not FollowerConfig.paper().tracker.scan_fix


def test_dead_reckoning_refuses_an_anchor_a_sure_tracker_puts_far_away():
    """RE in Dead reckoning rates a look-alike anchor 4 m on above p_follow;
    a tracker the scans pin says it is 4 m away, so the car stays in Dead
    reckoning rather than skipping the anchors between."""

    class LookAlike(Scanned):
        lost = False

        def __call__(self, cars, anchors, cwp, re):
            a = super().__call__(cars, anchors, cwp, re)
            if self.lost:
                a.probability[:] = np.where(np.asarray(anchors) == 5, 0.99, 0.1)
            return a

    ev = LookAlike(7)
    car = np.array([0.0, 0.0, 0.0, 0.0, 0.0])
    s = FollowerState.initial(1)
    for x in (0.0, 0.6):
        car[0] = x
        s, _ = drive(ev, s, car)
    assert s.mode[0] == Mode.FOLLOW and s.visited[0] == 0 and s.ref[0] >= 0
    ev.lost = True
    s.mode[:], s.dr_count[:] = Mode.DEAD_RECKONING, 30       # the window now reaches anchor 5
    car[0] = 0.8
    sure, _ = drive(ev, s, car)
    assert sure.mode[0] == Mode.DEAD_RECKONING and sure.active[0] < 5
    jumped, _ = drive(ev, s, car, tracked_reach_m=0.0)
    assert jumped.mode[0] == Mode.FOLLOW and jumped.active[0] == 5


def test_a_sure_tracker_keeps_following_where_re_doubts_a_near_anchor():
    """RE's rating of every anchor falls below p_follow (a view it doubts);
    a tracker the scans pin puts the active anchor within ``sure_follow_m``,
    so the car keeps following instead of driving its held waypoint blind."""

    class Doubting(Scanned):
        doubt = False

        def __call__(self, cars, anchors, cwp, re):
            a = super().__call__(cars, anchors, cwp, re)
            if self.doubt:
                a.probability[:] = 0.5
            return a

    modes = {}
    for reach in (2.5, 0.0):
        ev = Doubting(7)
        s = drive_along(ev, (0.0, 0.6), sure_follow_m=reach)
        assert s.mode[0] == Mode.FOLLOW and s.ref[0] >= 0
        ev.doubt = True
        s, _ = drive(ev, s, np.array([0.8, 0.0, 0.0, 0.0, 0.0]), sure_follow_m=reach)
        modes[reach] = s.mode[0]
    assert modes[2.5] == Mode.FOLLOW and modes[0.0] == Mode.DEAD_RECKONING
    # left None, the setting is the C_WP's own (the evaluator's, from its policy)
    for own, mode in ((2.5, Mode.FOLLOW), (None, Mode.DEAD_RECKONING)):
        ev = Doubting(7)
        if own is not None:
            ev.sure_follow_m = own
        s = drive_along(ev, (0.0, 0.6))
        ev.doubt = True
        s, _ = drive(ev, s, np.array([0.8, 0.0, 0.0, 0.0, 0.0]))
        assert s.mode[0] == mode
    with pytest.raises(TopodrakeError, match="sure_follow_m"):
        FollowerConfig.from_dict({"sure_follow_m": -1.0})
    assert FollowerConfig.paper().tracker.sure_follow_m == 0.0


def test_the_registration_cwp_chooses_its_own_sure_follow_reach():
    """The registration C_WP turns the rule on through its evaluator; a
    learned or oracle C_WP leaves it off."""
    from topodrake.navigation.evaluate import Evaluator
    from topodrake.navigation.follower import sure_follow_m
    from topodrake.registration.policy import RegistrationPolicy

    class Plain:
        observation = "lidar"

    default = FollowerConfig()
    reg = Evaluator.__new__(Evaluator)
    reg.policy = RegistrationPolicy()
    plain = Evaluator.__new__(Evaluator)
    plain.policy = Plain()
    assert sure_follow_m(default, reg) == RegistrationPolicy.sure_follow_m > 0
    assert sure_follow_m(default, plain) == 0.0
    assert sure_follow_m(FollowerConfig.from_dict({"sure_follow_m": 0.0}), reg) == 0.0


def test_a_sure_tracker_ends_the_route_at_the_goal():
    """C_WP's overlaps toward the goal (0.7) stay below p_goal: only the
    tracker, pinned by the scans, can tell the car stands on the goal."""
    outcomes = {}
    for sure in (0.1, 0.0):
        ev = Scanned(4)
        car = np.array([0.0, 0.0, 0.0, 0.0, 0.0])
        s = FollowerState.initial(1)
        for x in np.arange(0.0, 3.0, 0.2):
            car[0] = x
            s, _ = drive(ev, s, car, tracked_sure_m=sure)
        assert s.active[0] == 3
        outcomes[sure] = s.mode[0]
    assert outcomes[0.1] == Mode.REACHED and outcomes[0.0] == Mode.FOLLOW



def test_a_sure_tracker_outvotes_a_here_toward_an_anchor_far_away():
    class Here(Scanned):
        def __call__(self, cars, anchors, cwp, re):
            a = super().__call__(cars, anchors, cwp, re)
            far = np.asarray(anchors) == 2
            a.waypoint[far], a.overlap[far] = [0.1, 0.0], 0.9      # "here", 1.4 m short of it
            return a

    visited = {sure: drive_along(Here(6), (0.0, 0.3, 0.6), tracked_sure_m=sure).visited[0]
               for sure in (0.1, 0.0)}
    assert visited[0.1] < 2 and visited[0.0] == 2


def test_a_sure_tracker_refuses_a_goal_c_wp_calls_reached_short_of_it():
    """Near a wall C_WP's waypoint toward the goal is short while the goal
    is still 0.7-0.9 m off, and the follower stopped there; a tracker the
    scans pin refuses that "here" where it puts the goal farther than
    ``tracked_goal_m``."""
    class ShortAtGoal(Scanned):
        def __call__(self, cars, anchors, cwp, re):
            a = super().__call__(cars, anchors, cwp, re)
            goal = np.asarray(anchors) == len(self.frames) - 1
            a.waypoint[goal], a.overlap[goal] = [0.1, 0.0], 0.9
            return a

    modes = {limit: drive_along(ShortAtGoal(4), (0.0, 0.6, 1.2, 1.6, 2.2),   # 0.8 m short
                                tracked_goal_m=limit).mode[0] for limit in (0.5, 0.0)}
    assert modes[0.5] != Mode.REACHED
    assert modes[0.0] == Mode.REACHED                        # C_WP's word alone
    with pytest.raises(TopodrakeError, match="tracked_goal_m"):
        FollowerConfig.from_dict({"tracked_goal_m": -1.0})
