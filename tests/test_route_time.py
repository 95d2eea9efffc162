"""Plans for a time limit: the driving-time model, its fit and the planner's choice."""

import math

import networkx as nx
import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.topomap.plan import GOAL, START, within_time
from topodrake.topomap.route_time import (DrivingTime, edge_metres, fit_driving_time,
                                          leg_metres, path_metres)


def test_on_time_falls_with_the_route_and_is_certain_without_a_limit():
    dt = DrivingTime(start_s=0.0, per_m_s=2.0, per_hop_s=0.0, spread=0.1)
    assert dt.seconds(30.0, 10) == pytest.approx(60.0)
    assert dt.on_time(30.0, 10, None) == 1.0
    assert dt.on_time(75.0, 10, 150.0) == pytest.approx(0.5)        # expected exactly the limit
    probs = [dt.on_time(m, 10, 150.0) for m in (20.0, 60.0, 70.0, 80.0, 120.0)]
    assert probs[0] > 0.999 and probs[-1] < 0.001
    assert all(a > b for a, b in zip(probs[:-1], probs[1:]))


@pytest.mark.parametrize("bad", [{"per_m_s": -1.0}, {"spread": 0.0}, {"start_s": math.nan}])
def test_driving_time_refuses_nonsense(bad):
    with pytest.raises(TopodrakeError, match="DrivingTime"):
        DrivingTime(**bad)


def test_leg_length_counts_from_the_hop_start():
    path = np.column_stack([np.linspace(0.5, 2.0, 4), np.zeros(4), np.zeros(4)])
    assert leg_metres(path) == pytest.approx(2.0)
    g = nx.DiGraph()
    g.add_edge(0, 1, leg_path=path)
    g.add_edge(1, 2)                                   # no leg: counts as the median
    metres, typical = edge_metres(g)
    assert metres == {(0, 1): pytest.approx(2.0)} and typical == pytest.approx(2.0)
    assert path_metres([0, 1, 2], metres, typical) == pytest.approx(4.0)
    assert edge_metres(nx.DiGraph())[1] == 1.0


def two_ways(long_hops: int, short_p: float) -> nx.DiGraph:
    """START -> GOAL by a long chain of sure hops or three hops, one doubtful."""
    g = nx.DiGraph()
    leg = np.array([[1.0, 0.0, 0.0]])
    chain = [START, *range(100, 100 + long_hops), GOAL]
    for u, v in zip(chain[:-1], chain[1:]):
        g.add_edge(u, v, p=0.9999, weight=-math.log(0.9999), leg_path=leg)
    short = [START, 1, 2, GOAL]
    for (u, v), p in zip(zip(short[:-1], short[1:]), (0.999, short_p, 0.999)):
        g.add_edge(u, v, p=p, weight=-math.log(p), leg_path=leg)
    return g


def test_a_plan_too_long_for_the_limit_gives_way_to_a_shorter_one():
    g = two_ways(72, 0.8)
    cost, path = nx.single_source_dijkstra(g, START, GOAL, weight="weight")
    assert len(path) == 74                            # the most probable path is the long one
    dt = DrivingTime(start_s=0.0, per_m_s=2.0, per_hop_s=0.0, spread=0.1)
    c, p, on_time = within_time(g, cost, path, "weight", 150.0, dt)
    assert p == [START, 1, 2, GOAL] and on_time > 0.999
    assert math.exp(-c) == pytest.approx(0.999 * 0.8 * 0.999)
    # with time to spare the most probable path stands
    c, p, on_time = within_time(g, cost, path, "weight", 1000.0, dt)
    assert p == path and c == cost
    # and a short way that is too doubtful does not replace a long one that may still arrive
    g = two_ways(72, 0.05)
    cost, path = nx.single_source_dijkstra(g, START, GOAL, weight="weight")
    assert within_time(g, cost, path, "weight", 150.0, dt)[1] == path


def test_the_fit_recovers_a_driving_time_with_late_plans_censored():
    rng = np.random.default_rng(0)
    truth = DrivingTime(start_s=5.0, per_m_s=2.0, per_hop_s=1.0, spread=0.1)
    metres = rng.uniform(5, 70, 600)
    hops = np.rint(metres * rng.uniform(0.6, 1.4, 600))
    mean = np.array([truth.seconds(m, h) for m, h in zip(metres, hops)])
    seconds = mean * (1 + truth.spread * rng.standard_normal(600))
    late = seconds > 150.0
    fit = fit_driving_time(metres, hops, np.where(late, 150.0, seconds), late, 150.0)
    assert late.sum() > 50                             # the censored plans matter here
    assert fit.per_m_s == pytest.approx(2.0, rel=0.15)
    assert fit.spread == pytest.approx(0.1, rel=0.2)
    with pytest.raises(TopodrakeError, match="arrivals"):
        fit_driving_time([1.0] * 4, [1] * 4, [2.0] * 4, [True] * 4, 150.0)


def test_plan_path_reports_its_time_and_refuses_a_bad_limit():
    from test_topomap import same_drive_hops, table_map, drive

    from topodrake.topomap.build import add_trajectory
    from topodrake.topomap.plan import plan_path

    m = table_map(same_drive_hops)
    add_trajectory(m, drive(0, 40))
    free = plan_path(m, np.array([0, 0]), np.array([0, 39]))
    assert free.reachable and free.on_time == 1.0 and free.route.on_time == 1.0
    dt = DrivingTime(start_s=0.0, per_m_s=0.0, per_hop_s=10.0, spread=0.1)
    hops = len(free.vertices) + 1
    tight = plan_path(m, np.array([0, 0]), np.array([0, 39]), time_limit_s=10.0 * hops,
                      driving=dt)
    assert tight.vertices == free.vertices                     # the only way there
    assert tight.on_time == pytest.approx(0.5) and tight.route.on_time == tight.on_time
    assert tight.summary()["on_time"] == pytest.approx(0.5)
    with pytest.raises(TopodrakeError, match="time limit"):
        plan_path(m, np.array([0, 0]), np.array([0, 39]), time_limit_s=0.0)
