"""The follower state machine (batched functions) with scripted network answers."""

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.navigation.follower import (Answers, FollowerConfig, FollowerState, Mode, Reason,
                                           follower_step, outcome_of)


class Scripted:
    """Answers from per-car tables over anchors: RE ``p``, proximity
    ``prox`` (both overlaps) and the waypoint length ``dist`` (straight ahead)."""

    def __init__(self, p, prox, dist):
        self.p, self.prox, self.dist = (np.atleast_2d(np.asarray(x, float)) for x in (p, prox, dist))
        self.calls = []

    def __call__(self, cars, anchors, cwp, re):
        self.calls.append((np.array(cars), np.array(anchors), cwp, re))
        m = len(cars)
        wp = np.column_stack([self.dist[cars, anchors], np.zeros(m)])
        ov = np.repeat(self.prox[cars, anchors][:, None], 2, axis=1)
        return Answers(wp if cwp else np.full((m, 2), np.nan), ov if cwp else np.full((m, 2), np.nan),
                       self.p[cars, anchors] if re else np.full(m, np.nan))


CAR = np.array([[1.0, 2.0, 0.0, 0.0, 0.0]])


def step(state, ev, n_anchors, car=CAR, **cfg):
    return follower_step(state, np.full(len(state), n_anchors), np.repeat(car, len(state), 0), ev,
                         FollowerConfig.from_dict(cfg))


def test_search_picks_the_best_anchor_above_p_search_and_drives_toward_it():
    ev = Scripted(p=[0.5, 0.95, 0.99, 0.93, 0.2], prox=[0.3] * 5, dist=[1.5] * 5)
    s, out = step(FollowerState.initial(1), ev, 5)
    assert s.mode[0] == Mode.FOLLOW and s.active[0] == 2 and s.visited[0] == 1
    assert out.target[0] == 2
    np.testing.assert_allclose(out.waypoint[0], [2.5, 2.0])      # 1.5 m ahead of the car, world frame
    np.testing.assert_allclose(s.waypoint[0], [2.5, 2.0])


def test_search_takes_the_first_anchor_where_re_passes_it():
    """A plan links the car's view to the route's first anchor; a look-alike
    further on may rate higher. With ``search_first`` Search takes the first
    anchor where RE passes p_search (two cars: one where it passes, one where
    it does not)."""
    ev = Scripted(p=[[0.85, 0.9, 0.99, 0.2], [0.6, 0.95, 0.99, 0.2]], prox=[[0.3] * 4] * 2,
                  dist=[[1.5] * 4] * 2)
    s, _ = step(FollowerState.initial(2), ev, 4, search_first=True)
    assert list(s.active) == [0, 2] and list(s.visited) == [-1, 1]
    assert s.best_p[0] == pytest.approx(0.85)
    s, _ = step(FollowerState.initial(2), ev, 4)             # on by default
    assert list(s.active) == [0, 2]
    s, _ = step(FollowerState.initial(2), ev, 4, search_first=False)   # off: the best anchor
    assert list(s.active) == [2, 2]


def test_search_gives_up_below_p_search():
    ev = Scripted(p=[0.5, 0.79, 0.2], prox=[0.9] * 3, dist=[0.1] * 3)
    s, out = step(FollowerState.initial(1), ev, 3)
    assert s.mode[0] == Mode.FAILED and s.reason[0] == Reason.SEARCH_FAILED
    assert outcome_of(s) == ["search_failed"]
    assert np.isnan(out.waypoint).all() and out.target[0] == -1
    assert s.best_p[0] == pytest.approx(0.79)


def following(active=1, visited=0):
    s = FollowerState.initial(1)
    s.mode[:] = Mode.FOLLOW
    s.active[:] = active
    s.visited[:] = visited
    s.waypoint[:] = [[9.0, 9.0]]
    return s


def test_follow_marks_close_anchors_visited_and_uses_the_lookahead_window():
    # anchors 1 and 2 are close (proximity > 0.65, waypoint < visit_m); 3 is far
    ev = Scripted(p=[0.99] * 10, prox=[0.9, 0.9, 0.8, 0.5, 0.3, 0.3, 0.3, 0.3, 0.3, 0.3],
                  dist=[0.1, 0.2, 0.3, 1.0, 2.0, 2.0, 2.0, 2.0, 2.0, 2.0])
    s, out = step(following(), ev, 10, lookahead=5)
    assert s.visited[0] == 2 and s.active[0] == 3 and s.mode[0] == Mode.FOLLOW
    cars, anchors, cwp, re = ev.calls[0]
    assert cwp and not re and anchors.tolist() == [1, 2, 3, 4, 5]    # lookahead 5 after visited 0
    np.testing.assert_allclose(out.waypoint[0], [2.0, 2.0])          # C_WP toward anchor 3


def test_high_proximity_far_away_does_not_count_as_visited():
    ev = Scripted(p=[0.99, 0.99, 0.5, 0.5], prox=[0.9] * 4, dist=[2.0] * 4)   # a straight corridor
    s, _ = step(following(active=1, visited=0), ev, 4)
    assert s.visited[0] == 0 and s.active[0] == 1
    ev.p[0, 2] = 0.95              # the paper's advance rule: the one after, reachable and near
    s, _ = step(following(active=1, visited=0), ev, 4)
    assert s.visited[0] == 0 and s.active[0] == 2


def test_visiting_the_last_anchor_ends_the_plan():
    ev = Scripted(p=[0.99] * 3, prox=[0.9] * 3, dist=[0.1] * 3)
    s, out = step(following(active=2, visited=1), ev, 3)
    assert s.mode[0] == Mode.REACHED and outcome_of(s) == ["reached"]
    assert np.isnan(out.waypoint).all()


def test_a_passed_anchor_counts_as_visited_but_a_passed_goal_does_not():
    # the waypoint points backwards (negative length = behind the car)
    ev = Scripted(p=[0.99] * 3, prox=[0.9] * 3, dist=[-0.6] * 3)
    s, _ = step(following(active=1, visited=0), ev, 3)
    assert s.visited[0] == 1 and s.mode[0] == Mode.FOLLOW and s.active[0] == 2
    s, out = step(following(active=2, visited=1), ev, 3)
    assert s.mode[0] == Mode.FOLLOW and s.visited[0] == 1          # beside the goal is not at it
    np.testing.assert_allclose(out.waypoint[0], [0.4, 2.0])   # C_WP turns the car back to it


def test_low_re_enters_dead_reckoning_holding_the_waypoint_in_the_odometry_frame():
    ev = Scripted(p=[0.99, 0.5, 0.5, 0.5], prox=[0.3] * 4, dist=[1.0] * 4)
    s, out = step(following(), ev, 4)
    assert s.mode[0] == Mode.DEAD_RECKONING and s.dr_count[0] == 0
    held = s.waypoint[0].copy()
    np.testing.assert_allclose(held, [2.0, 2.0])            # this period's C_WP waypoint, world frame
    # the car moves and turns: the held waypoint stays put in the world
    moved = np.array([[1.5, 2.5, 1.0, 0.3, 0.0]])
    s2, out2 = step(s, ev, 4, car=moved)
    assert s2.mode[0] == Mode.DEAD_RECKONING and s2.dr_count[0] == 1
    np.testing.assert_allclose(out2.waypoint[0], held)
    assert out2.target[0] == -1                             # C_WP is not asked for a target


def test_dead_reckoning_widens_its_search_and_returns_to_follow():
    p = np.full(12, 0.5)
    ev = Scripted(p=p, prox=[0.3] * 12, dist=[1.0] * 12)
    s = following(active=1, visited=0)
    s.mode[:] = Mode.DEAD_RECKONING
    s.waypoint[:] = [[3.0, 2.0]]
    s.dr_count[:] = 25                                      # widened twice, by 2 anchors each
    s, _ = step(s, ev, 12, lookahead=3, dr_widen_every=10, dr_back_anchors=0)
    _, anchors, _, re = ev.calls[-1]
    # forward only: next (1) .. next + 3 - 1 + 2 * 2, never the visited anchor 0 behind
    assert re and anchors.tolist() == [1, 2, 3, 4, 5, 6, 7]
    assert s.mode[0] == Mode.DEAD_RECKONING and s.dr_count[0] == 26
    ev.p[0, 4] = 0.95                                       # an anchor ahead becomes reachable
    s, out = step(s, ev, 12, lookahead=3, dr_widen_every=10, dr_back_anchors=0)
    assert s.mode[0] == Mode.FOLLOW and s.active[0] == 4 and s.visited[0] == 3 and s.dr_count[0] == 0
    assert out.target[0] == 4


def test_dead_reckoning_gives_up_after_max_iterations():
    ev = Scripted(p=np.full(5, 0.1), prox=[0.3] * 5, dist=[1.0] * 5)
    s = following()
    s.mode[:] = Mode.DEAD_RECKONING
    s.waypoint[:] = [[50.0, 2.0]]
    for _ in range(7):
        s, _ = step(s, ev, 5, dr_max_iterations=7)
    assert s.mode[0] == Mode.FAILED and s.reason[0] == Reason.DEAD_RECKONING_GAVE_UP
    assert outcome_of(s) == ["dead_reckoning_gave_up"]


def test_a_batch_of_followers_equals_each_follower_alone():
    rng = np.random.default_rng(0)
    n, a = 6, 8
    p = rng.uniform(0.85, 1.0, (n, a))
    prox = rng.uniform(0.3, 1.0, (n, a))
    dist = rng.uniform(0.1, 2.0, (n, a))
    cars = np.column_stack([rng.uniform(0, 5, (n, 2)), rng.uniform(-3, 3, n), np.zeros((n, 2))])
    batch = FollowerState.initial(n)
    alone = [FollowerState.initial(1) for _ in range(n)]
    for _ in range(6):
        batch, out = follower_step(batch, np.full(n, a), cars, Scripted(p, prox, dist))
        for i in range(n):
            alone[i], o = follower_step(alone[i], [a], cars[i:i + 1],
                                        Scripted(p[i:i + 1], prox[i:i + 1], dist[i:i + 1]))
            np.testing.assert_array_equal(out.waypoint[i], o.waypoint[0])
            assert out.target[i] == o.target[0]
    for i in range(n):
        np.testing.assert_array_equal(FollowerState.to_vector(batch.take([i])),
                                      alone[i].to_vector())
    assert len(set(batch.mode.tolist())) > 1               # the cars took different branches


def test_state_vector_round_trip_and_config_checks():
    s = following(active=3, visited=2)
    s.dr_count[:] = 4
    back = FollowerState.from_vector(s.to_vector())
    np.testing.assert_array_equal(back.to_vector(), s.to_vector())
    assert FollowerState.initial(2).mode.tolist() == [Mode.SEARCH, Mode.SEARCH]
    with pytest.raises(TopodrakeError, match="p_follow"):
        FollowerConfig(p_follow=1.5).check()
    with pytest.raises(TopodrakeError, match="lookahead"):
        FollowerConfig(lookahead=0).check()
    assert [int(m) for m in Mode] == [0, 1, 2, 3, 4]          # stored in Drake state and arrays


def test_settings_come_from_a_dict_nested_or_flat():
    """Overrides name a field nested as the config is, or flat for a field
    of a nested config (every name is unique in the tree); an unknown key
    is refused naming it, and a bad value by the check."""
    from dataclasses import fields

    assert len(fields(FollowerConfig)) <= 15
    assert FollowerConfig.from_dict(None) == FollowerConfig() == FollowerConfig.from_dict({})
    nested = FollowerConfig.from_dict({"tracker": {"scan_fix": False},
                                       "dead_reckoning": {"dr_max_iterations": 20},
                                       "manoeuvre": {"expert": {"horizon_s": 2.0}}})
    flat = FollowerConfig.from_dict({"scan_fix": False, "dr_max_iterations": 20,
                                     "horizon_s": 2.0})
    assert nested == flat and not flat.tracker.scan_fix
    assert flat.dead_reckoning.dr_max_iterations == 20 and flat.manoeuvre.expert.horizon_s == 2.0
    assert FollowerConfig.from_dict({"p_follow": 0.5, "visit_m": 0.5}).visit.visit_m == 0.5
    assert FollowerConfig().tracker.scan_fix                   # the default is left alone
    for bad, name in (({"p_folow": 0.5}, "p_folow"), ({"tracker": {"p_follow": 0.5}}, "p_follow"),
                      ({"pass_turn_deg": 90}, "pass_turn_deg")):
        with pytest.raises(TopodrakeError, match=f"setting '{name}' names no setting"):
            FollowerConfig.from_dict(bad)
    with pytest.raises(TopodrakeError, match="tracker"):
        FollowerConfig.from_dict({"tracker": 3})
    from topodrake.navigation.follower import _nested_fields
    from topodrake.navigation.tracker import TrackerConfig

    names = _nested_fields(FollowerConfig())                  # flat keys name one field each
    assert all(len(paths) == 1 for paths in names.values())
    assert not set(names) & {f.name for f in fields(FollowerConfig)}
    given = TrackerConfig(scan_fix=False)
    assert FollowerConfig.from_dict({"tracker": given}).tracker == given
    with pytest.raises(TopodrakeError, match="visit_m must be > 0"):
        FollowerConfig.from_dict({"visit": {"visit_m": 0.0}})


def test_an_anchor_not_reached_for_stall_periods_is_skipped_but_never_the_last():
    # anchor 1 stays 1 m ahead (an obstacle stands on it), RE keeps trusting it
    ev = Scripted(p=[0.99] * 4, prox=[0.3] * 4, dist=[1.0] * 4)
    s = following(active=1, visited=0)
    for k in range(4):
        s, _ = step(s, ev, 4, stall_periods=5)
        assert s.active[0] == 1 and s.visited[0] == 0 and s.stall[0] == k + 1
    s, _ = step(s, ev, 4, stall_periods=5)
    assert s.stall[0] == 5 and s.active[0] == 1
    s, out = step(s, ev, 4, stall_periods=5)          # skipped: anchor 2 is active
    assert s.visited[0] == 1 and s.active[0] == 2 and s.stall[0] == 0 and out.target[0] == 2
    last = following(active=3, visited=2)
    for _ in range(8):
        last, _ = step(last, ev, 4, stall_periods=5)
    assert last.active[0] == 3 and last.visited[0] == 2 and last.mode[0] == Mode.FOLLOW


def test_an_anchor_stood_on_at_another_heading_counts_as_visited():
    # close (0.2 m) but the views overlap only 0.4 (the car turned at a junction)
    ev = Scripted(p=[0.99] * 4, prox=[0.9, 0.4, 0.4, 0.4], dist=[0.0, 0.2, 1.5, 2.5])
    s, _ = step(following(active=1, visited=0), ev, 4)
    assert s.visited[0] == 1 and s.active[0] == 2
    s, _ = step(following(active=1, visited=0), ev, 4, p_visited_close=0.5)
    assert s.visited[0] == 0 and s.active[0] == 1           # the rule's own threshold


def test_a_short_waypoint_toward_an_anchor_that_looks_farther_than_an_earlier_one_is_no_visit():
    # C_WP says "here" toward anchor 2 (a room away), while anchor 1 looks nearer
    ev = Scripted(p=[0.99] * 5, prox=[0.9, 0.6, 0.45, 0.3, 0.3], dist=[0.0, 1.0, 0.3, 2.0, 2.5])
    s, _ = step(following(active=1, visited=0), ev, 5)
    assert s.visited[0] == 0 and s.active[0] == 1
    ev.prox[0, 2] = 0.6             # as near as anchor 1: the car stands on anchor 2
    s, _ = step(following(active=1, visited=0), ev, 5)
    assert s.visited[0] == 2 and s.active[0] == 3
    ev.prox[0, 2] = 0.45            # the strict rule needs no comparison
    s, _ = step(following(active=1, visited=0), ev, 5, p_visited=0.4)
    assert s.visited[0] == 2
    # a later anchor that looks nearer (the car at a junction faces it) does not block a visit
    ev = Scripted(p=[0.99] * 5, prox=[0.9, 0.4, 0.6, 0.3, 0.3], dist=[0.0, 0.2, 1.0, 2.0, 2.5])
    s, _ = step(following(active=1, visited=0), ev, 5)
    assert s.visited[0] == 1 and s.active[0] == 2


def test_the_goal_needs_a_high_proximity_to_end_the_route():
    ev = Scripted(p=[0.99] * 3, prox=[0.9, 0.9, 0.7], dist=[0.0, 0.0, 0.2])
    s, _ = step(following(active=2, visited=1), ev, 3)
    assert s.mode[0] == Mode.FOLLOW and s.visited[0] == 1        # a short waypoint is not arriving
    ev.prox[0, 2] = 0.8
    s, _ = step(following(active=2, visited=1), ev, 3)
    assert s.mode[0] == Mode.REACHED


def test_dead_reckoning_on_the_active_anchor_marks_it_visited_and_heads_on():
    # RE sees nothing; the car stands at its held waypoint, on the active anchor 1
    ev = Scripted(p=[0.3] * 4, prox=[0.1] * 4, dist=[0.0, 0.1, 1.5, 2.5])
    s = following(active=1, visited=0)
    s.mode[:] = Mode.DEAD_RECKONING
    s.waypoint[:] = CAR[:, :2]
    s, out = step(s, ev, 4)
    assert s.mode[0] == Mode.DEAD_RECKONING and s.visited[0] == 1 and s.active[0] == 2
    np.testing.assert_allclose(out.waypoint[0], [2.5, 2.0])  # C_WP's leg toward anchor 2


def test_dead_reckoning_may_search_backwards_as_the_paper_does():
    ev = Scripted(p=np.full(12, 0.5), prox=[0.3] * 12, dist=[1.0] * 12)
    s = following(active=3, visited=2)
    s.mode[:] = Mode.DEAD_RECKONING
    s.waypoint[:] = [[3.0, 2.0]]
    s.dr_count[:] = 25
    step(s, ev, 12, lookahead=3, dr_widen_every=10, dr_back_anchors=-1)
    _, anchors, _, _ = ev.calls[-1]
    assert anchors.tolist() == [1, 2, 3, 4, 5, 6, 7]       # next (3) - 2 .. next + 3 - 1 + 2
    # ours reaches back one anchor at most; forward only widens two ahead instead
    step(s, ev, 12, lookahead=3, dr_widen_every=10, dr_back_anchors=1)
    assert ev.calls[-1][1].tolist() == [2, 3, 4, 5, 6, 7]
    step(s, ev, 12, lookahead=3, dr_widen_every=10, dr_back_anchors=0)
    assert ev.calls[-1][1].tolist() == [3, 4, 5, 6, 7, 8, 9]
    with pytest.raises(TopodrakeError, match="dr_back_anchors"):
        FollowerConfig.from_dict({"dr_back_anchors": -2})


def test_the_goal_in_sight_ends_the_route_in_dead_reckoning_too():
    """RE often doubts the last metre: a car in Dead reckoning whose C_WP
    sees the goal close and alike has arrived; a far or unlike goal does not end it."""
    def dead_reckoning_near_the_goal():
        s = following(active=3, visited=2)
        s.mode[:] = Mode.DEAD_RECKONING
        s.waypoint[:] = [[50.0, 2.0]]
        return s

    ev = Scripted(p=[0.3] * 4, prox=[0.1, 0.1, 0.1, 0.8], dist=[3.0, 2.0, 1.0, 0.2])
    s, _ = step(dead_reckoning_near_the_goal(), ev, 4)
    assert s.mode[0] == Mode.REACHED and s.visited[0] == 3 and outcome_of(s) == ["reached"]
    for prox, dist in ((0.8, 0.5), (0.6, 0.2)):
        ev.prox[0, 3], ev.dist[0, 3] = prox, dist
        s, _ = step(dead_reckoning_near_the_goal(), ev, 4)
        assert s.mode[0] == Mode.DEAD_RECKONING


def test_the_goal_distance_is_its_own_setting():
    ev = Scripted(p=[0.99] * 3, prox=[0.9, 0.9, 0.9], dist=[0.0, 0.0, 0.4])
    s, _ = step(following(active=2, visited=1), ev, 3)
    assert s.mode[0] == Mode.FOLLOW
    s, _ = step(following(active=2, visited=1), ev, 3, goal_m=0.45)
    assert s.mode[0] == Mode.REACHED


class Beside(Scripted):
    """Scripted answers whose waypoint toward every anchor lies at ``point`` (car frame)."""

    def __init__(self, point, n_anchors=4):
        super().__init__(p=[0.99] * n_anchors, prox=[0.2] * n_anchors, dist=[1.0] * n_anchors)
        self.point = np.asarray(point, float)

    def __call__(self, cars, anchors, cwp, re):
        ans = super().__call__(cars, anchors, cwp, re)
        if cwp:
            ans.waypoint = np.tile(self.point, (len(cars), 1))
        return ans


def test_inside_turn_marks_points_the_car_circles_driving_forward():
    from topodrake.navigation.follower import inside_turn
    from topodrake.vehicle import VehicleConfig

    r = VehicleConfig().turn_radius()
    assert r == pytest.approx(0.16 / np.tan(0.36))
    pts = np.array([[0.0, 0.6], [0.0, -0.5], [0.2, 0.45], [2.0, 0.0], [1.0, 0.6], [-0.1, 0.9],
                    [0.3, 0.0]])
    np.testing.assert_array_equal(inside_turn(pts, r, 0.0),
                                  [True, True, True, False, False, False, False])
    # the widened circle takes in points just outside it
    assert not inside_turn(np.array([[0.0, 0.88]]), r, 0.0)[0]
    assert inside_turn(np.array([[0.0, 0.88]]), r, 0.1)[0]


def test_a_waypoint_beside_the_car_is_driven_as_a_point_behind_it():
    car = np.array([[1.0, 2.0, np.pi / 2, 0.0, 0.0]])          # facing +y
    s, out = step(following(active=1, visited=0), Beside([0.0, 0.6]), 4, car=car)
    assert s.mode[0] == Mode.FOLLOW and out.held[0]                           # the follower's own
    np.testing.assert_allclose(out.waypoint[0], [1.0, 1.0], atol=1e-9)   # 1 m behind the car
    np.testing.assert_allclose(s.waypoint[0], [0.4, 2.0], atol=1e-9)     # C_WP's, kept as held
    np.testing.assert_allclose(out.local[0], [0.0, 0.6])                 # the answer itself
    # off, or a waypoint the car can turn onto: driven as C_WP gave it
    s, out = step(following(active=1, visited=0), Beside([0.0, 0.6]), 4, car=car,
                  reverse_inside_turn=-1.0)
    np.testing.assert_allclose(out.waypoint[0], [0.4, 2.0], atol=1e-9)
    assert not out.held[0]
    s, out = step(following(active=1, visited=0), Beside([1.0, 0.6]), 4, car=car)
    np.testing.assert_allclose(out.waypoint[0], [0.4, 3.0], atol=1e-9)
    assert not out.held[0]
    assert FollowerConfig.paper().reverse_inside_turn < 0
    with pytest.raises(TopodrakeError, match="turn_radius_m"):
        FollowerConfig(turn_radius_m=0.0).check()


def test_dead_reckoning_waypoints_are_not_backed_up():
    s = following(active=1, visited=0)
    s.mode[:] = Mode.DEAD_RECKONING
    s.waypoint[:] = [[1.0, 2.6]]                   # held, 0.6 m beside the car (facing +x)
    ev = Scripted(p=[0.5] * 4, prox=[0.2] * 4, dist=[1.0] * 4)
    s, out = step(s, ev, 4)
    assert s.mode[0] == Mode.DEAD_RECKONING and out.held[0]
    np.testing.assert_allclose(out.waypoint[0], [1.0, 2.6])


def test_backing_up_brings_the_car_onto_a_target_it_would_circle():
    """Closed loop with the RMP: a target beside the car is reached within
    80 periods when the car backs up first; driving forward at full lock
    it circles it for longer."""
    from topodrake.navigation.follower import back_up_inside_turn
    from topodrake.rmp import RmpConfig, rmp_controls
    from topodrake.vehicle import VehicleConfig, vehicle_step, world_to_car

    veh, rmp, cfg = VehicleConfig(), RmpConfig(), FollowerConfig()

    def closest(target, back_up, periods=80):
        state, best = np.zeros((1, 5)), np.inf
        for _ in range(periods):
            wp = back_up_inside_turn(target, state, cfg)[0] if back_up else target
            local = world_to_car(wp[:, None], state)[:, 0]
            state = vehicle_step(state, rmp_controls(state, local, None, None, rmp, veh), veh)
            best = min(best, float(np.hypot(*(state[0, :2] - target[0]))))
        return best

    for target in ([[0.0, 0.6]], [[0.0, -0.5]]):
        target = np.array(target)
        assert closest(target, back_up=True) < 0.2
        assert closest(target, back_up=False) > 0.2


def test_the_follower_keeps_the_odometry_pose_at_which_it_marked_an_anchor_visited(box_world):
    """``seen`` holds the car's odometry pose of the period in which its last
    visited anchor changed, and stays while it does not."""
    from topodrake.navigation.follower import FollowerState, Mode, follower_step

    class Here:                  # every anchor is right here: each period marks one visited
        anchor_frames = None

        def __call__(self, cars, anchors, cwp, re):
            from topodrake.navigation.follower import Answers

            m = len(cars)
            return Answers(np.zeros((m, 2)) + [0.1, 0.0], np.full((m, 2), 0.9),
                           np.full(m, 0.99))

    st = FollowerState.initial(1)
    st.mode[:], st.active[:], st.visited[:] = Mode.FOLLOW, 1, 0
    car = np.array([[2.0, 3.0, 0.5, 0.0, 0.0]])
    new, _ = follower_step(st, np.array([6]), car, Here())
    assert new.visited[0] > 0
    np.testing.assert_allclose(new.seen[0], car[0, :3])
    back = FollowerState.from_vector(new.to_vector())
    np.testing.assert_allclose(back.seen, new.seen)
