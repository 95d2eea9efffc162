"""Drives that meet at a place join there; start and goal links agree on one place."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.topomap.build import add_trajectory
from topodrake.topomap.graph import MapConfig, TopoMap
from topodrake.experiments.joining import join_trial, joining_triples, summarize
from topodrake.topomap.mapfile import load_map, save_map
from topodrake.topomap.plan import link_groups, plan_path

from test_topomap import FlatEmbedding, TableScorer, drive, same_drive_hops


def meeting_drives(a, b, both_ways=(0.95, 0.95)):
    """Drive 0 arrives where drive 1 departs: frame 9 of drive 0 and frame 0
    of drive 1 are one place, which RE sees with ``both_ways`` (arrival ->
    departure, departure -> arrival); the drives diverge on either side."""
    if (a, b) == ((0, 9), (1, 0)):
        return both_ways[0]
    if (a, b) == ((1, 0), (0, 9)):
        return both_ways[1]
    return same_drive_hops(a, b)


def table_map(rule, **config):
    return TopoMap(TableScorer(rule), FlatEmbedding(), MapConfig.from_dict(config), world="table")


def test_an_arrival_and_a_departure_at_one_place_join_by_a_junction_edge():
    m = table_map(meeting_drives)
    add_trajectory(m, drive(0, 10))
    stats = add_trajectory(m, drive(1, 10))
    end, start = m.trajectories[0].chain[-1], m.trajectories[1].chain[0]
    assert stats.junctions == 1
    assert m.graph.edges[end, start]["kind"] == "junction"
    assert m.graph.edges[end, start]["p"] == pytest.approx(0.95)
    assert not m.graph.has_edge(start, end)             # only the way a car drives on
    r = plan_path(m, np.array([0, 0]), np.array([1, 9]))
    assert r.reachable and end in r.vertices and start in r.vertices
    # sequence matching alone cannot join them: the drives diverge around the place
    m = table_map(meeting_drives, join_ends=False)
    add_trajectory(m, drive(0, 10))
    add_trajectory(m, drive(1, 10))
    assert not plan_path(m, np.array([0, 0]), np.array([1, 9])).reachable


def test_a_junction_is_made_whichever_drive_comes_first():
    m = table_map(meeting_drives)
    add_trajectory(m, drive(1, 10))
    stats = add_trajectory(m, drive(0, 10))
    end, start = m.trajectories[1].chain[-1], m.trajectories[0].chain[0]
    assert stats.junctions == 1 and m.graph.edges[end, start]["kind"] == "junction"


def test_a_junction_needs_the_views_to_agree_both_ways():
    for both_ways in ((0.95, 0.3), (0.3, 0.95), (0.65, 0.95)):
        m = table_map(lambda a, b, w=both_ways: meeting_drives(a, b, w))
        add_trajectory(m, drive(0, 10))
        assert add_trajectory(m, drive(1, 10)).junctions == 0, both_ways
    m = table_map(lambda a, b: meeting_drives(a, b, (0.65, 0.95)), p_join=0.6)
    add_trajectory(m, drive(0, 10))
    assert add_trajectory(m, drive(1, 10)).junctions == 1
    with pytest.raises(TopodrakeError, match="p_join"):
        MapConfig().updated(p_join=1.0).validate()
    with pytest.raises(TopodrakeError, match="join_ends"):
        MapConfig().updated(join_ends="yes").validate()


def test_map_files_keep_junction_edges_and_refuse_unknown_edge_kinds(tmp_path):
    m = table_map(meeting_drives)
    add_trajectory(m, drive(0, 10))
    add_trajectory(m, drive(1, 10))
    path = tmp_path / "m.tdmap"
    save_map(m, path)
    m2 = load_map(path, m.scorer, embedding=FlatEmbedding())
    assert m2.edge_counts() == m.edge_counts() and m2.edge_counts()["junction"] == 1
    with np.load(path) as z:
        arrays = {name: z[name] for name in z.files}
    arrays["edge_kind"] = np.full_like(arrays["edge_kind"], 7)
    bad = tmp_path / "bad.tdmap"
    with open(bad, "wb") as f:
        np.savez_compressed(f, **arrays)
    with pytest.raises(TopodrakeError, match="edge kind 7"):
        load_map(bad, m.scorer, embedding=FlatEmbedding())


# ---------------------------------------------------------------- start and goal links

def look_alike_start(a, b):
    """The start view (5, 0) reaches drive 0's frames 0 and 3, and frame 24
    of the same drive looks just like it; the goal is frame 29."""
    if a == (5, 0):
        return 0.999 if b in ((0, 0), (0, 3), (0, 24)) else 0.1
    return same_drive_hops(a, b)


def test_start_links_agree_on_one_place_and_skip_a_look_alike_far_along_the_map():
    m = table_map(look_alike_start, link_consensus=False)
    add_trajectory(m, drive(0, 30))
    frame = lambda r: [m.graph.nodes[v]["frame"] for v in r.vertices]
    r = plan_path(m, np.array([5, 0]), np.array([0, 29]))
    assert frame(r)[0] == 24                          # the look-alike: a shorter plan
    m.config = MapConfig().updated(link_consensus=True)
    r = plan_path(m, np.array([5, 0]), np.array([0, 29]))
    assert frame(r)[0] in (0, 3) and r.start_links == 2
    assert r.probability < 0.999 ** 3                 # the whole drive, hop by hop


def test_link_groups_gather_around_the_most_probable_links_and_do_not_chain():
    m = table_map(same_drive_hops)
    add_trajectory(m, drive(0, 30))                   # ten anchors, frames 0, 3, ..., 27
    v = m.trajectories[0].chain
    groups = link_groups(m, [(v[0], 0.9), (v[1], 0.9), (v[8], 0.97)], hops=3)
    assert [[u for u, _ in g] for g in groups] == [[v[8]], [v[0], v[1]]]
    groups = link_groups(m, [(v[0], 0.97), (v[2], 0.9), (v[8], 0.97)], hops=3)
    assert [[u for u, _ in g] for g in groups] == [[v[0], v[2]], [v[8]]]
    # a chain of links, each within reach of the next, is not one place
    chained = link_groups(m, [(v[i], 0.9) for i in (0, 3, 6, 9)], hops=3)
    assert [[u for u, _ in g] for g in chained] == [[v[0], v[3]], [v[6], v[9]]]
    assert link_groups(m, [], hops=3) == []


def test_when_the_most_trusted_place_leads_nowhere_the_plan_starts_at_the_next():
    def dead_end_look_alike(a, b):
        if a == (5, 0):      # the start sees drive 2 (a dead end) best, drive 0 nearly as well
            return {(2, 0): 0.999, (0, 0): 0.95}.get(b, 0.1)
        return same_drive_hops(a, b)

    m = table_map(dead_end_look_alike)
    add_trajectory(m, drive(0, 10))
    add_trajectory(m, drive(2, 10))
    r = plan_path(m, np.array([5, 0]), np.array([0, 9]))
    assert r.reachable and m.graph.nodes[r.vertices[0]]["traj"] == 0


def direct_look_alike(start_sees):
    """The start view (5, 0) reaches drive 0's frames ``start_sees`` and
    looks just like the goal view (0, 29) (both ways); the goal is reached
    from frames 24 and 27."""
    def rule(a, b):
        if a == (5, 0):
            return 0.999 if b in (*start_sees, (0, 29)) else 0.1
        if a == (0, 29):
            return 0.999 if b in ((5, 0), (0, 24), (0, 27)) else 0.1
        return same_drive_hops(a, b)
    return rule


def test_a_direct_start_goal_link_needs_the_ends_links_to_be_one_place():
    start, goal = np.array([5, 0]), np.array([0, 29])
    far = table_map(direct_look_alike(((0, 0), (0, 3))), direct_check=False)
    add_trajectory(far, drive(0, 30))
    r = plan_path(far, start, goal)
    assert r.reachable and r.vertices == []           # the look-alike: straight to the goal
    far.config = MapConfig().updated(direct_check=True)
    r = plan_path(far, start, goal)
    assert r.reachable and [far.graph.nodes[v]["frame"] for v in r.vertices][0] in (0, 3)
    assert far.graph.nodes[r.vertices[-1]]["frame"] in (24, 27)
    # where the start's links are the goal's place, the direct link stays
    near = table_map(direct_look_alike(((0, 24),)), direct_check=True)
    add_trajectory(near, drive(0, 30))
    assert plan_path(near, start, goal).vertices == []
    with pytest.raises(TopodrakeError, match="direct_check"):
        MapConfig().updated(direct_check="yes").validate()


# ---------------------------------------------------------------- the joining study

def test_joining_triples_are_distinct_seeded_and_a_prefix_of_a_longer_study():
    t = joining_triples(10, 40, seed=3)
    assert t.shape == (40, 3) and all(len(set(row)) == 3 for row in t.tolist())
    assert t.min() >= 0 and t.max() < 10
    np.testing.assert_array_equal(joining_triples(10, 12, seed=3), t[:12])
    assert not np.array_equal(joining_triples(10, 40, seed=4), t)
    with pytest.raises(TopodrakeError, match="3 places"):
        joining_triples(2, 5, seed=0)


def line_world():
    """Drive 0 runs x = 0..9 from place 0 to place 1, drive 1 x = 9..18 from
    place 1 to place 2 (1 cm aside, y = 0.01); a table observation is
    (drive, frame) of a pose."""
    places = np.array([[0.0, 0, 0], [9.0, 0, 0], [18.0, 0.01, 0]])
    drives = {(0, 1): np.column_stack([np.arange(10.0), np.zeros((10, 2))]),
              (1, 2): np.column_stack([9.0 + np.arange(10.0), np.full(10, 0.01), np.zeros(10)])}

    def observe(poses):
        p = np.asarray(poses)
        second = p[:, 1] > 0.005
        return np.column_stack([second, np.where(second, p[:, 0] - 9, p[:, 0])]).astype(int)

    return SimpleNamespace(places=places, grid=open_grid(-2.0, -2.0, 24.0, 8.0)), drives, observe


def open_grid(x0, y0, w, h, wall_x=None):
    """An open floor of ``w`` x ``h`` m from (x0, y0), with a wall across
    it at ``wall_x`` where given."""
    from topodrake.world.grid import OccupancyGrid

    occupied = np.zeros((int(h / 0.1), int(w / 0.1)), bool)
    if wall_x is not None:
        occupied[:, int((wall_x - x0) / 0.1)] = True
    return OccupancyGrid(occupied, np.array([x0, y0]), 0.1)


def test_a_map_of_two_drives_through_a_place_plans_across_it():
    world, drives, observe = line_world()
    drive_of = lambda s, g: SimpleNamespace(poses=drives[(s, g)]) if (s, g) in drives else None
    joined = join_trial(world, lambda: table_map(meeting_drives), drive_of, observe, (0, 1, 2))
    assert joined.planned and joined.joined and joined.junctions == 1
    assert joined.false_link_m == 0.0 and joined.longest_link_m <= 3.0
    apart = join_trial(world, lambda: table_map(meeting_drives, join_ends=False), drive_of,
                       observe, (0, 1, 2))
    assert not apart.planned and not apart.joined and "no path" in apart.reason
    missing = join_trial(world, lambda: table_map(meeting_drives), drive_of, observe, (2, 1, 0))
    assert not missing.planned and "no expert drive" in missing.reason
    s = summarize([joined, apart, missing])
    assert s["joined_triples"] == s["planned"] == round(1 / 3, 4)
    assert s["false_steps"] == 0.0


def test_a_joining_map_keeps_the_scans_its_drives_took_where_given():
    """Camera maps in the study keep their drives' lidar scans, as built by
    ``topodrake map build``: the scans taken at each drive's poses."""
    world, drives, observe = line_world()
    drive_of = lambda s, g: SimpleNamespace(poses=drives[(s, g)]) if (s, g) in drives else None
    made, asked = [], []

    def make():
        made.append(table_map(meeting_drives))
        return made[-1]

    def scan(poses):
        asked.append(np.asarray(poses))
        return np.repeat(np.asarray(poses)[:, :1], 8, axis=1)     # a scan per pose

    r = join_trial(world, make, drive_of, observe, (0, 1, 2), scan)
    assert r.planned and r.joined
    kept = made[0].bank.scans
    assert kept is not None and kept.shape[1] == 8
    np.testing.assert_array_equal(asked[0], drives[(0, 1)])
    np.testing.assert_array_equal(asked[1], drives[(1, 2)])
    assert len(asked) == 3 and asked[2].shape == (2, 3)           # and the two views' scans
    join_trial(world, make, drive_of, observe, (0, 1, 2))
    assert made[1].bank.scans is None


def test_a_start_link_to_a_look_alike_far_along_the_map_is_a_false_step():
    world, drives, observe = line_world()
    drive_of = lambda s, g: SimpleNamespace(poses=drives[(s, g)]) if (s, g) in drives else None

    def start_looks_like_the_second_drive(a, b):
        if a == (0, 0):
            return 0.999 if b == (1, 6) else 0.1
        return meeting_drives(a, b)

    r = join_trial(world, lambda: table_map(start_looks_like_the_second_drive),
                   drive_of, observe, (0, 1, 2))
    assert r.planned and r.false_step and not r.joined
    assert r.false_link_kind == "start" and r.false_link_m == pytest.approx(np.hypot(15, 0.01))
    assert r.record()["false_step"] and summarize([r])["false_steps"] == 1.0


def test_a_hop_through_a_vertex_reused_in_a_look_alike_place_is_a_false_step():
    """A drive's own hop is false where its vertex is not within reach of
    where the drive's odometry (the hop's leg) puts it, or, without a leg,
    of the vertex before."""
    import networkx as nx

    from topodrake.experiments.joining import plan_links

    world = SimpleNamespace(grid=open_grid(-2.0, -2.0, 26.0, 10.0))
    poses = {0: [0.0, 0.0, 0.0], 1: [1.0, 0.0, 0.0], 2: [20.0, 5.0, 0.0], 3: [21.0, 5.0, 0.0]}
    g = nx.DiGraph()
    g.add_edge(0, 1, kind="trajectory", leg=np.array([1.0, 0.0, 0.0]))
    g.add_edge(1, 2, kind="trajectory", leg=np.array([1.0, 0.0, 0.0]))   # the drive went 1 m
    g.add_edge(2, 3, kind="trajectory", leg=np.array([1.0, 0.0, 0.0]))
    m = SimpleNamespace(graph=g, pose=lambda vs: np.array([poses[v] for v in vs]))
    plan = SimpleNamespace(vertices=[0, 1, 2, 3])
    links = plan_links(world, m, plan, [0, 0, 0], [21.0, 5.0, 0.0])
    assert links["false_link_kind"] == "reuse"
    assert links["false_link_m"] == pytest.approx(np.hypot(18.0, 5.0))
    assert links["longest_link_m"] == pytest.approx(0.0)        # the start and goal links are true
    del g.edges[1, 2]["leg"]                                     # no leg: from the vertex before
    links = plan_links(world, m, plan, [0, 0, 0], [21.0, 5.0, 0.0])
    assert links["false_link_m"] == pytest.approx(np.hypot(19.0, 5.0))
    poses[2], poses[3] = [2.0, 0.0, 0.0], [3.0, 0.0, 0.0]      # where the drive went: no false step
    g.edges[1, 2]["leg"] = np.array([1.0, 0.0, 0.0])
    assert plan_links(world, m, plan, [0, 0, 0], [3.0, 0.0, 0.0])["false_link_m"] == 0.0


def test_a_link_is_false_where_its_ends_are_out_of_reach_not_where_it_is_long():
    """Ends 7 m apart across an open floor are within reach; 3 m apart
    through a wall with no door they are not; farther than the oracle's
    reach they never are."""
    from topodrake.experiments.link_truth import REACH_M, within_reach

    open_floor = SimpleNamespace(grid=open_grid(-1.0, -3.0, 14.0, 6.0))
    assert within_reach(open_floor, [0.0, 0.0], [7.0, 0.0])
    assert not within_reach(open_floor, [0.0, 0.0], [REACH_M + 0.5, 0.0])
    walled = SimpleNamespace(grid=open_grid(-1.0, -3.0, 14.0, 6.0, wall_x=1.5))
    assert not within_reach(walled, [0.0, 0.0], [3.0, 0.0])
    assert within_reach(walled, [0.0, 0.0], [1.0, 1.0])       # the same side of the wall
    door = open_grid(-1.0, -3.0, 14.0, 6.0, wall_x=1.5)
    door.occupied[25:35, :] = False                             # a 1 m door in the wall at y -0.5..0.5
    assert within_reach(SimpleNamespace(grid=door), [0.0, 1.0], [3.0, 1.0])


def test_a_lidar_junction_carries_the_departure_s_pose_registered_in_the_arrival_s_frame():
    from topodrake.se2 import relative
    from topodrake.topomap.build import _junction_legs
    from topodrake.topomap.retrieval import default_embedding
    from topodrake.topomap.sources import drive_observations, make_scorer
    from topodrake.world import load_world

    world = load_world("test-0")
    place = np.asarray(world.places[3], np.float64)
    s = np.linspace(0.0, 1.5, 16)
    ahead = np.array([np.cos(place[2]), np.sin(place[2])])
    arrive = np.column_stack([place[:2] - np.outer(s[::-1], ahead), np.full(16, place[2])])
    start = place + np.array([-0.05 * ahead[1], 0.05 * ahead[0], 0.05])    # 5 cm aside, 3 deg
    onward = np.array([np.cos(start[2]), np.sin(start[2])])
    depart = np.column_stack([start[:2] + np.outer(s, onward), np.full(16, start[2])])
    scorer = make_scorer("lidar", world)
    m = TopoMap(scorer, default_embedding(scorer.observation), MapConfig().updated(reuse=False),
                world="test-0")
    for name, poses in (("arrive", arrive), ("depart", depart)):
        add_trajectory(m, drive_observations(world, scorer, poses), poses, name)
    u, x = m.trajectories[0].chain[-1], m.trajectories[1].chain[0]
    (leg, path), = _junction_legs(m, np.array([u]), np.array([x]))
    truth = relative(m.pose([u]).reshape(1, 3), m.pose([x]).reshape(1, 3))[0]
    np.testing.assert_allclose(leg, truth, atol=0.01)
    np.testing.assert_allclose(path[0], 0.0)
    np.testing.assert_allclose(path[-1], leg)
    m.config = MapConfig().updated(teach_odometry="none")      # a map that keeps no odometry
    assert _junction_legs(m, np.array([u]), np.array([x])) == [(None, None)]


def test_the_default_scenario_is_the_figures_run():
    from study_run import check_scenarios

    from topodrake.experiments.joining import JoiningStudy

    check_scenarios("map_joining", JoiningStudy, ("default",), {"default": ["--json"]})
