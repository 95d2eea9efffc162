"""The topological map: incremental building, planning, the map file, the CLI.

Most tests use a table scorer (RE given as a function of (drive, frame)
pairs) so each rule of the build is pinned exactly; the rest use the
geometric oracle on poses, which runs in a fraction of a second.
"""

import json
import math

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.topomap.build import add_trajectory, build_map
from topodrake.topomap.graph import MapConfig, TopoMap
from topodrake.topomap.mapfile import load_map, save_map
from topodrake.topomap.plan import plan_path
from topodrake.topomap.retrieval import PoseEmbedding, VertexIndex


class TableScorer:
    """RE from a rule over (drive, frame) observations; k = 0 (a context is one frame)."""

    observation = "table"
    k = 0
    frame_step = 1

    def __init__(self, rule, name="table"):
        self.rule = rule
        self.identity = {"reach": name}

    def features(self, observations):
        return {"x": np.asarray(observations, np.float64)}

    def score(self, feats, source, context_rows):
        x = feats["x"]
        a, b = x[np.asarray(source)], x[np.asarray(context_rows)[:, 0]]
        return np.array([self.rule(tuple(map(int, u)), tuple(map(int, v))) for u, v in zip(a, b)])


class FlatEmbedding:
    """Every vertex ties: retrieval returns them all (up to K)."""

    observation, dim, name = "table", 1, "flat"

    def embed(self, obs):
        return np.zeros((len(obs), 1), np.float32)

    def fingerprint(self):
        return self.name


def drive(d, n):
    return np.column_stack([np.full(n, d), np.arange(n)])


def same_drive_hops(a, b, reach=3):
    return 0.999 if a[0] == b[0] and 0 <= b[1] - a[1] <= reach else 0.1


def table_map(rule, **config):
    return TopoMap(TableScorer(rule), FlatEmbedding(), MapConfig.from_dict(config), world="table")


def test_a_drive_becomes_a_chain_of_anchors_linked_in_order():
    m = table_map(same_drive_hops)
    stats = add_trajectory(m, drive(0, 10))
    chain = m.trajectories[0].chain
    assert [m.graph.nodes[v]["frame"] for v in chain] == [0, 3, 6, 9]
    assert stats.anchors == 4 and len(m) == 4
    assert [(u, v) for u, v in m.graph.edges] == list(zip(chain[:-1], chain[1:]))
    assert all(d["kind"] == "trajectory" and d["p"] == pytest.approx(0.999)
               and d["weight"] == pytest.approx(-math.log(0.999)) for _, _, d in m.graph.edges(data=True))
    # only the anchors' contexts are kept (k = 0: the anchor frames themselves)
    assert len(m.bank) == 4 and m.raw_frames == 10


def test_max_hop_m_keeps_anchors_within_reach_along_the_drive():
    """RE trusts 3 frames ahead; with frames 1 m apart and hops capped at
    2 m (by the drive's odometry, or its poses without one) an anchor falls
    every 2 frames; uncapped (0), every 3. Camera and pose oracle maps are
    built alike whatever it says (a lidar-only setting)."""
    from topodrake.topomap.graph import LIDAR_ONLY, same_config

    class LidarTable(TableScorer):
        observation = "lidar"

    def frames(scorer, **config):
        m = TopoMap(scorer, FlatEmbedding(), MapConfig.from_dict(config), world="table")
        add_trajectory(m, drive(0, 10), np.c_[np.arange(10.0), np.zeros(10), np.zeros(10)])
        return [m.graph.nodes[v]["frame"] for v in m.trajectories[0].chain]

    lidar = LidarTable(same_drive_hops)
    assert frames(lidar, max_hop_m=2.0, teach_odometry="perfect") == [0, 2, 4, 6, 8, 9]
    assert frames(lidar, max_hop_m=2.0, teach_odometry="none") == [0, 2, 4, 6, 8, 9]
    assert frames(lidar, max_hop_m=0.0) == [0, 3, 6, 9]
    assert frames(TableScorer(same_drive_hops), max_hop_m=2.0) == [0, 3, 6, 9]   # not lidar
    assert "max_hop_m" in LIDAR_ONLY
    uncapped = MapConfig().updated(max_hop_m=0.0).flat()
    assert same_config(uncapped, MapConfig(), lidar=False)
    assert not same_config(uncapped, MapConfig(), lidar=True)


def parallel_drives(a, b, reach=3):
    """Drives 0 and 1 run side by side: from a frame, frames up to ``reach``
    ahead on either drive are reachable."""
    return 0.999 if 0 <= b[1] - a[1] <= reach else 0.1


def test_a_second_drive_along_the_first_reuses_its_vertices():
    m = table_map(parallel_drives)
    add_trajectory(m, drive(0, 10))
    stats = add_trajectory(m, drive(1, 10))
    assert stats.reused == 4 and stats.new_vertices == 0
    assert m.trajectories[1].chain == m.trajectories[0].chain
    assert len(m) == 4


def test_reuse_needs_both_hops_and_keeps_the_order_of_the_old_drive():
    # drive 1 can reach drive 0's vertices, but drive 0's vertices cannot reach drive 1's
    # next anchor: no reuse (both RE(prev, v) and RE(v, next) must pass)
    def one_way(a, b):
        if a[0] == 0 and b[0] == 1:
            return 0.1
        return parallel_drives(a, b)

    m = table_map(one_way)
    add_trajectory(m, drive(0, 10))
    stats = add_trajectory(m, drive(1, 10))
    assert stats.reused == 0 and stats.new_vertices == 4
    # order: a drive that runs backwards over drive 0 reuses at most one of its vertices
    m = table_map(lambda a, b: 0.999 if (a[0] == b[0] and 0 <= b[1] - a[1] <= 3)
                  or a[0] != b[0] else 0.1)
    add_trajectory(m, drive(0, 10))
    add_trajectory(m, drive(1, 10))
    for t in m.trajectories:
        pos = [m.graph.nodes[v]["pos"] for v in t.chain if m.graph.nodes[v]["traj"] == 0]
        assert pos == sorted(pos) and len(set(t.chain)) == len(t.chain)


def test_resume_rule_reuses_where_cross_drive_hops_are_shorter_than_a_drive_s_own():
    # two drives over the same places; RE trusts 3 frames ahead along a drive but
    # only 2 between drives. The paper's rule asks a reused vertex to reach the
    # next anchor, 3 ahead: never across drives. "resume" asks it to lead on to
    # the frame after the anchor it stands in for, and rescans from it.
    def shorter_across(a, b):
        reach = 3 if a[0] == b[0] else 2
        return 0.999 if 0 <= b[1] - a[1] <= reach else 0.1

    paper = table_map(shorter_across, reuse_rule="paper")
    add_trajectory(paper, drive(0, 10))
    stats = add_trajectory(paper, drive(1, 10))
    assert stats.reused == 0 and stats.new_vertices == 4

    m = table_map(shorter_across, reuse_rule="resume")
    add_trajectory(m, drive(0, 10))
    stats = add_trajectory(m, drive(1, 10))
    first = m.trajectories[0].chain
    # drive 1 runs along drive 0's four vertices, then keeps its own last frame
    assert m.trajectories[1].chain[:4] == first
    assert stats.reused == 4 and stats.new_vertices == 1
    new = m.trajectories[1].chain[4]
    assert m.graph.nodes[new]["traj"] == 1 and m.graph.nodes[new]["frame"] == 9
    # every trajectory edge of the chain is one RE trusts
    chain = m.trajectories[1].chain
    assert all(m.graph.edges[u, v]["p"] > 0.99 for u, v in zip(chain[:-1], chain[1:]) if u != v)
    with pytest.raises(TopodrakeError, match="reuse_rule"):
        MapConfig().updated(reuse_rule="greedy").validate()


def test_cross_edges_need_the_aligned_neighbours_to_pass_too():
    # drives side by side; the single pairs pass in both directions
    m = table_map(parallel_drives, reuse=False)
    add_trajectory(m, drive(0, 13))
    add_trajectory(m, drive(1, 13))
    c0, c1 = (t.chain for t in m.trajectories)
    cross = {(u, v) for u, v, kind in m.graph.edges(data="kind") if kind == "cross"}
    assert (c1[2], c0[2]) in cross and (c0[2], c1[2]) in cross and (c1[2], c0[3]) in cross

    # now only frame 6 of drive 1 sees drive 0 (a lone look-alike): the single pair
    # passes, its aligned neighbours do not, so no cross edge is made
    def lone(a, b):
        if a[0] != b[0]:
            return 0.999 if (a, b) in {((1, 6), (0, 6)), ((0, 6), (1, 6))} else 0.1
        return same_drive_hops(a, b)

    m = table_map(lone, reuse=False)
    add_trajectory(m, drive(0, 13))
    add_trajectory(m, drive(1, 13))
    assert not [1 for _, _, kind in m.graph.edges(data="kind") if kind == "cross"]
    # ... unless sequence matching looks at no neighbours
    m = table_map(lone, reuse=False, sequence_window=0)
    add_trajectory(m, drive(0, 13))
    add_trajectory(m, drive(1, 13))
    assert len([1 for _, _, kind in m.graph.edges(data="kind") if kind == "cross"]) == 2


def test_the_audit_counts_the_edges_retrieval_misses():
    class Unhelpful(FlatEmbedding):
        name = "unhelpful"

        def embed(self, obs):   # ranks drive 0's vertices last
            return np.asarray(obs, np.float32)[:, :1] * -100.0

    m = TopoMap(TableScorer(parallel_drives), Unhelpful(),
                MapConfig().updated(reuse=False, retrieval_k=2))
    stats = build_map(m, [(drive(0, 13), None, "a"), (drive(1, 13), None, "b")], progress=False,
                      audit=True)
    assert stats.exhaustive_edges > stats.found_edges and stats.recall < 1.0
    m = table_map(parallel_drives, reuse=False)
    stats = build_map(m, [(drive(0, 13), None, "a"), (drive(1, 13), None, "b")], progress=False,
                      audit=True)
    assert stats.recall == 1.0


def test_plan_takes_the_most_probable_path_and_reports_its_probability():
    m = table_map(same_drive_hops)
    add_trajectory(m, drive(0, 10))
    start, goal = np.array([0, 0]), np.array([0, 9])
    r = plan_path(m, start, goal)
    assert r.reachable
    frames = [m.graph.nodes[v]["frame"] for v in r.vertices]
    # the start links to vertices within reach (frames 0, 3), the goal from 6 and 9
    assert frames[0] in (0, 3) and frames[-1] in (6, 9)
    edges = list(zip(r.vertices[:-1], r.vertices[1:]))
    p = 0.999 * np.prod([m.graph.edges[e]["p"] for e in edges]) * 0.999
    assert r.probability == pytest.approx(p)
    assert r.route is not None and len(r.route) == len(r.vertices) + 1
    assert r.route.probability == pytest.approx(p)
    assert r.route.start_probability == pytest.approx(0.999)      # the start link's RE
    # temporary vertices and frames are gone afterwards
    assert -1 not in m.graph and -2 not in m.graph and len(m.bank) == 4


def test_planning_links_among_the_top_link_k_vertices_not_the_build_s_retrieval_k():
    m = table_map(same_drive_hops)
    add_trajectory(m, drive(0, 10))
    start, goal = np.array([0, 0]), np.array([0, 9])
    wide = plan_path(m, start, goal)
    assert wide.start_links == 2                                 # frames 0 and 3
    m.config = m.config.updated(link_k=1)
    narrow = plan_path(m, start, goal)
    assert narrow.start_links == 1 and narrow.goal_links <= 1
    with pytest.raises(TopodrakeError, match="link_k"):
        MapConfig().updated(link_k=0).validate()


def test_an_unreachable_goal_is_a_result_with_a_reason():
    m = table_map(same_drive_hops)
    add_trajectory(m, drive(0, 10))
    r = plan_path(m, np.array([0, 0]), np.array([5, 3]))
    assert not r.reachable and "goal" in r.reason and r.route is None
    r = plan_path(m, np.array([7, 0]), np.array([0, 9]))
    assert not r.reachable and "start" in r.reason
    # two separate drives: links exist on both sides but no path joins them
    add_trajectory(m, drive(2, 10))
    r = plan_path(m, np.array([2, 0]), np.array([0, 9]))
    assert not r.reachable and "no path" in r.reason


def test_a_goal_link_needs_the_goal_to_reach_back_unless_told_otherwise():
    """RE toward the goal's repeated image is overconfident; a link's
    probability is the smaller of RE(v, goal) and RE(goal, v)."""
    def overconfident_toward_the_goal(a, b):
        if b == (9, 9):                       # the goal: every vertex claims it
            return 0.98
        if a == (9, 9):                       # from the goal only frame 9 is in reach
            return 0.999 if b == (0, 9) else 0.2
        return same_drive_hops(a, b)

    m = table_map(overconfident_toward_the_goal)
    add_trajectory(m, drive(0, 10))
    r = plan_path(m, np.array([0, 0]), np.array([9, 9]))
    # the path runs the whole drive to the one vertex the goal reaches back
    assert r.reachable and [m.graph.nodes[v]["frame"] for v in r.vertices] == [3, 6, 9]
    m = table_map(overconfident_toward_the_goal, goal_mutual=False)
    add_trajectory(m, drive(0, 10))
    r = plan_path(m, np.array([0, 0]), np.array([9, 9]))
    assert r.reachable and r.vertices == []          # straight from the start to the goal


def test_plan_avoids_excluded_edges():
    m = table_map(parallel_drives, reuse=False)
    add_trajectory(m, drive(0, 13))
    add_trajectory(m, drive(1, 13))
    r = plan_path(m, np.array([0, 0]), np.array([0, 12]))
    banned = list(zip(r.vertices[:-1], r.vertices[1:]))
    r2 = plan_path(m, np.array([0, 0]), np.array([0, 12]), excluded_edges=banned[:1])
    assert r2.reachable and tuple(banned[0]) not in set(zip(r2.vertices[:-1], r2.vertices[1:]))


def test_switch_p_keeps_a_plan_on_one_drive_where_switching_gains_little():
    """RE rates the hops between two side-by-side drives above each drive's
    own, so the most probable path zigzags between them; each switch hands
    the follower's tracker over to another drive's frames, and with
    ``switch_p`` each counts its p times it, in the choice and the plan's
    probability: the plan stays on one drive."""
    def across_surer(a, b):
        if not 0 <= b[1] - a[1] <= 3:
            return 0.1
        return 0.95 if a[0] == b[0] else 0.999

    m = table_map(across_surer, reuse=False)
    add_trajectory(m, drive(0, 13))
    add_trajectory(m, drive(1, 13))

    def switches(r):
        return [m.graph.edges[e]["kind"] for e in zip(r.vertices[:-1], r.vertices[1:])
                if m.graph.edges[e]["kind"] != "trajectory"]

    start, goal = np.array([0, 0]), np.array([0, 12])
    m.config = m.config.updated(switch_p=1.0)          # off
    plain = plan_path(m, start, goal)
    assert plain.reachable and switches(plain)          # the zigzag
    m.config = m.config.updated(switch_p=0.9)
    kept = plan_path(m, start, goal)
    assert kept.reachable and not switches(kept)
    drives = {m.graph.nodes[v]["traj"] for v in kept.vertices}
    assert len(drives) == 1
    hops = [m.graph.edges[e]["p"] for e in zip(kept.vertices[:-1], kept.vertices[1:])]
    assert kept.probability == pytest.approx(kept.route.start_probability * np.prod(hops)
                                             * kept.route.edge_probability[-1])
    with pytest.raises(TopodrakeError, match="switch_p"):
        MapConfig().updated(switch_p=1.5).validate()


def test_map_config_is_checked():
    with pytest.raises(TopodrakeError, match="p_edge"):
        MapConfig().updated(p_edge=1.5).validate()
    with pytest.raises(TopodrakeError, match="retrieval_k"):
        MapConfig().updated(retrieval_k=0).validate()
    with pytest.raises(TopodrakeError, match="max_hop_m"):
        MapConfig().updated(max_hop_m=float("nan")).validate()
    with pytest.raises(TopodrakeError, match="reuse must be a ReuseConfig"):
        MapConfig(reuse={"p": 0.9}).validate()


def test_map_config_takes_nested_and_flat_settings():
    """The nested form and the flat names set the same settings; the flat
    form (map files, caches, records) lists every setting in the order map
    files have always stored them, a deleted rule's at its fixed value."""
    from topodrake.topomap.graph import FLAT, RETIRED, ReuseConfig

    nested = MapConfig.from_dict({"reuse": {"p": 0.9, "enabled": False}, "retrieval_k": 8,
                                  "links": {"near_m": 0}})
    flat = MapConfig.from_dict({"p_reuse": 0.9, "reuse": False, "retrieval_k": 8,
                                "start_near_m": 0})
    assert nested == flat == MapConfig(retrieval_k=8, reuse=ReuseConfig(enabled=False, p=0.9)
                                       ).updated(start_near_m=0.0)
    assert isinstance(flat.links.near_m, float)                 # an integer read as a number
    assert list(flat.flat()) == list(FLAT)
    assert MapConfig.from_dict(flat.flat()) == flat
    assert all(MapConfig().flat()[k] == v for k, v in RETIRED.items())
    assert MapConfig.from_dict({"reuse": MapConfig().reuse}) == MapConfig()
    assert MapConfig().updated(p_reuse=0.9).updated(reuse={"p": 0.5}).reuse.p == 0.5
    for bad, what in (({"p_resue": 0.9}, "unknown key 'p_resue' in MapConfig"),
                      ({"reuse": {"q": 1}}, "unknown key 'q' in reuse"),
                      ({"p_reuse": 0.9, "reuse": {"p": 0.8}}, "reuse.p .p_reuse. is given twice"),
                      ({"reuse_ahead": 4}, "reuse_ahead set a map rule that was deleted"),
                      ({"links": 3}, "links must be a mapping")):
        with pytest.raises(TopodrakeError, match=what):
            MapConfig.from_dict(bad)
    # a deleted rule's setting at its fixed value reads; a stored one, whatever its value
    assert MapConfig.from_dict({"scan_match_cross": False}) == MapConfig()
    assert MapConfig.from_dict({"scan_match_cross": True}, stored=True) == MapConfig()


def test_load_map_config_reads_nested_and_flat_yaml(tmp_path):
    from topodrake.topomap.graph import load_map_config

    (tmp_path / "nested.yaml").write_text("reuse: {p: 0.9}\njunction:\n  enabled: false\n"
                                          "scan_match: 0\n")
    (tmp_path / "flat.yaml").write_text("p_reuse: 0.9\njoin_ends: false\nscan_match: 0\n")
    nested, flat = (load_map_config(tmp_path / f"{n}.yaml") for n in ("nested", "flat"))
    assert nested == flat and flat.reuse.p == 0.9 and not flat.junction.enabled
    assert flat.flat()["scan_match"] == 0.0 and isinstance(flat.scan_match, float)
    assert load_map_config(None) == MapConfig()
    for text, what in (("p_resue: 0.9\n", "bad.yaml: unknown key 'p_resue' in MapConfig"),
                       ("reuse: {rule: greedy}\n", "reuse.rule .reuse_rule. must be one of"),
                       ("junction: {p: 1.5}\n", "junction.p .p_join. must be in"),
                       ("link_order: support\n", "link_order set a map rule that was deleted")):
        (tmp_path / "bad.yaml").write_text(text)
        with pytest.raises(TopodrakeError, match=what):
            load_map_config(tmp_path / "bad.yaml")
    with pytest.raises(TopodrakeError, match="map config file .*missing.yaml does not exist"):
        load_map_config(tmp_path / "missing.yaml")


def test_vertex_index_ranks_nearest_first_and_excludes():
    idx = VertexIndex(PoseEmbedding())
    idx.add(np.array([10, 11, 12]), PoseEmbedding().embed(np.array([[0, 0, 0], [5, 0, 0], [1, 0, 0]])))
    near = idx.search(PoseEmbedding().embed(np.array([[0.2, 0, 0]])), 2)[0]
    assert list(near) == [10, 12]
    assert list(idx.search(PoseEmbedding().embed(np.array([[0.2, 0, 0]])), 5, exclude=[10])[0]) == [12, 11]


# -- the oracle on a real house ------------------------------------------------------------

@pytest.fixture(scope="module")
def oracle_map(tmp_path_factory):
    """An oracle map of test-0 from three A* drives (poses as observations)."""
    from topodrake.topomap.scorer import OracleScorer
    from topodrake.world import load_world

    world = load_world("test-0")
    m = TopoMap(OracleScorer(world), PoseEmbedding(), world="test-0")
    for name, (i, j) in {"a": (0, 5), "b": (5, 0), "c": (0, 8)}.items():
        path = world.astar(world.places[i], world.places[j][:2])
        step = np.hypot(*np.diff(path, axis=0).T)
        s = np.concatenate([[0], np.cumsum(step)])
        t = np.arange(0, s[-1], 0.05)
        xy = np.column_stack([np.interp(t, s, path[:, 0]), np.interp(t, s, path[:, 1])])
        heading = np.arctan2(*np.gradient(xy, axis=0)[:, ::-1].T)
        poses = np.column_stack([xy, heading])
        add_trajectory(m, poses, poses, name)
    path = tmp_path_factory.mktemp("maps") / "t0.tdmap"
    save_map(m, path)
    return world, m, path


def test_oracle_map_links_shared_corridors_and_plans_between_places(oracle_map):
    world, m, _ = oracle_map
    kinds = m.edge_counts()
    assert kinds["trajectory"] > 0 and m.trajectories[2].chain[0] in m.trajectories[0].chain
    a, b = world.places[0], m.pose(m.trajectories[0].chain[-1:])[0]
    r = plan_path(m, a, b, start_pose=a, goal_pose=b)
    assert r.reachable and r.probability > 0.5
    # consecutive anchors of the route are close: every hop is one the oracle trusts
    hops = np.hypot(*np.diff(r.route.poses[:, :2], axis=0).T)
    assert hops.max() < 2.6


def test_map_file_round_trip(oracle_map):
    world, m, path = oracle_map
    m2 = load_map(path, m.scorer)
    assert sorted(m2.graph.nodes) == sorted(m.graph.nodes)
    assert {(u, v): round(p, 12) for u, v, p in m2.graph.edges(data="p")} == \
        {(u, v): round(p, 12) for u, v, p in m.graph.edges(data="p")}
    assert [t.chain for t in m2.trajectories] == [t.chain for t in m.trajectories]
    np.testing.assert_array_equal(m2.bank.observations, m.bank.observations)
    a, b = world.places[0], world.places[5]
    assert plan_path(m2, a, b).vertices == plan_path(m, a, b).vertices


def test_a_map_written_before_the_slacks_and_the_resume_rule_loads_with_the_paper_s_rules(oracle_map, tmp_path):
    world, m, path = oracle_map
    with np.load(path) as z:
        arrays = {name: z[name] for name in z.files}
    meta = json.loads(bytes(arrays.pop("meta")).decode())
    meta["version"] = 4                 # a file of then: no checksum
    arrays.pop("checksum")
    assert meta["config"].pop("sparsify_slack") == MapConfig().sparsify.slack
    assert meta["config"].pop("reuse_slack") == 0.0
    assert meta["config"].pop("reuse_rule") == MapConfig().reuse.rule == "resume"
    old = tmp_path / "old.tdmap"
    with open(old, "wb") as f:
        np.savez_compressed(f, meta=np.frombuffer(json.dumps(meta).encode(), np.uint8), **arrays)
    old_config = load_map(old, m.scorer).config
    assert old_config.sparsify.slack == 0.0 and old_config.reuse.rule == "paper"
    assert load_map(path, m.scorer).config.sparsify == MapConfig().sparsify
    with pytest.raises(TopodrakeError, match="sparsify_slack"):
        MapConfig().updated(sparsify_slack=1.0).validate()


def test_map_files_that_do_not_fit_are_refused_in_one_line(oracle_map, tmp_path):
    from topodrake.topomap.scorer import OracleConfig, OracleScorer

    world, m, path = oracle_map
    data = path.read_bytes()
    cut = tmp_path / "cut.tdmap"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(TopodrakeError, match="truncated") as e:
        load_map(cut, m.scorer)
    assert "\n" not in str(e.value)
    other = OracleScorer(world, config=OracleConfig(reach_m=1.0))
    with pytest.raises(TopodrakeError, match="built for the reachability estimator"):
        load_map(path, other)
    # an unknown version
    newer = _with_meta(path, tmp_path / "newer.tdmap", lambda meta: meta.update(version=99))
    with pytest.raises(TopodrakeError, match="version 99"):
        load_map(newer, m.scorer)


def test_map_cli_info_plan_and_plot(oracle_map, tmp_path, capsys):
    from topodrake.apps.cli import main

    world, m, path = oracle_map
    assert main(["map", "info", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["vertices"] == len(m) and info["edges"] == m.n_edges
    assert info["keep_ratio"] == pytest.approx(len(m) / m.raw_frames, abs=1e-5)
    assert {"raw_frames", "checkpoints", "config", "version"} <= set(info)
    s, g = world.places[0], world.places[5]
    arg = lambda p: ",".join(f"{v:.4f}" for v in p)
    png = tmp_path / "plan.png"
    assert main(["map", "plan", str(path), "--start", arg(s), "--goal", arg(g), "--json",
                 "--plot", str(png)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["path"] and 0.0 < out["probability"] <= 1.0 and png.stat().st_size > 0
    # a goal no drive went near: exit status 1 and the reason
    far = world.places[3]
    assert main(["map", "plan", str(path), "--start", arg(s), "--goal", arg(far), "--json"]) == 1
    assert json.loads(capsys.readouterr().out)["reachable"] is False
    assert main(["map", "plan", str(path), "--start", "1,2", "--goal", arg(g)]) == 2
    assert "X,Y,YAW" in capsys.readouterr().err
    assert main(["map", "plot", str(path), "--out", str(tmp_path / "m.png")]) == 0


def test_a_map_built_for_one_re_is_refused_with_another(tmp_path, capsys):
    from topodrake.apps.cli import main
    from topodrake.topomap.sources import make_scorer, shipped_checkpoint
    from topodrake.topomap.sources import drive_observations
    from topodrake.topomap.embedding import ThumbnailEmbedding
    from topodrake.world import load_world

    world = load_world("test-0")
    start = world.places[0]
    poses = np.array([[start[0] + 0.05 * i * np.cos(start[2]), start[1] + 0.05 * i * np.sin(start[2]),
                       start[2]] for i in range(30)])
    scorer = make_scorer("camera")
    m = TopoMap(scorer, ThumbnailEmbedding("camera"), world="test-0")
    add_trajectory(m, drive_observations(world, scorer, poses), poses, "straight")
    path = tmp_path / "cam.tdmap"
    save_map(m, path)
    assert m.identity["reach"] == "checkpoints/reach_camera_k5/checkpoint.pt"
    base = shipped_checkpoint("reach_camera_k5_base")
    with pytest.raises(TopodrakeError, match="built for the reachability estimator"):
        load_map(path, make_scorer("camera", reach=base, controller=shipped_checkpoint("camera_k5")))
    pose = ",".join(f"{v:.4f}" for v in start)
    code = main(["map", "plan", str(path), "--start", pose, "--goal", pose,
                 "--reach", str(base), "--controller", str(shipped_checkpoint("camera_k5"))])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "built for" in err and len(err.splitlines()) == 1


def test_sequence_retrieval_ranks_by_the_aligned_neighbours_too():
    class LookAlike(FlatEmbedding):
        """Frames embed by their index; drive 0 sits a little off, and drive
        2 looks like the others at frame 6 only."""
        name = "look-alike"
        dim = 2

        def embed(self, obs):
            o = np.asarray(obs, np.float64)
            x = o[:, 1] + 0.3 * (o[:, 0] == 0)
            y = 50.0 * ((o[:, 0] == 2) & (o[:, 1] != 6))
            return np.column_stack([x, y]).astype(np.float32)

    def linked(sequence):
        m = TopoMap(TableScorer(parallel_drives), LookAlike(),
                    MapConfig().updated(reuse=False, retrieval_k=1, sequence_retrieval=sequence))
        for d in (0, 2, 1):
            add_trajectory(m, drive(d, 13))
        x = m.trajectories[2].chain[2]          # drive 1, frame 6
        return {m.graph.nodes[v]["traj"] for v in m.graph.successors(x)
                if m.graph.edges[x, v]["kind"] == "cross"}

    assert linked(sequence=False) == {1}        # drive 2 (its second drive added): the look-alike
    assert linked(sequence=True) == {0}


def test_shipped_checkpoints_resolve_from_any_working_folder(tmp_path, monkeypatch):
    from topodrake.topomap.sources import resolve_checkpoint

    monkeypatch.chdir(tmp_path)
    assert resolve_checkpoint("checkpoints/camera_k5/checkpoint.pt").is_file()
    (tmp_path / "checkpoints" / "camera_k5").mkdir(parents=True)
    mine = tmp_path / "checkpoints" / "camera_k5" / "checkpoint.pt"
    mine.write_bytes(b"x")
    assert resolve_checkpoint("checkpoints/camera_k5/checkpoint.pt").resolve() == mine.resolve()
    assert not resolve_checkpoint("no/such.pt").exists()


def test_failed_edges_are_lowered_and_the_next_plan_goes_around_them():
    from topodrake.topomap.recalibrate import PRIOR_WEIGHT, edge_posterior, record_traversals

    m = table_map(parallel_drives, reuse=False)
    add_trajectory(m, drive(0, 13))
    add_trajectory(m, drive(1, 13))
    r = plan_path(m, np.array([0, 0]), np.array([0, 12]))
    edge = tuple(int(v) for v in r.vertices[1:3])
    before = m.graph.edges[edge]["p"]
    # each failure counts; edges the map does not hold are skipped
    changed = record_traversals(m, failed=[edge, edge, (10_000, 10_001)])
    after = PRIOR_WEIGHT * before / (PRIOR_WEIGHT + 2)
    assert changed == [{"edge": list(edge), "p_before": round(before, 6),
                        "p_after": round(after, 6), "passed": 0, "failed": 2}]
    assert m.graph.edges[edge]["weight"] == pytest.approx(-np.log(after))
    r2 = plan_path(m, np.array([0, 0]), np.array([0, 12]))
    assert edge not in set(zip(r2.vertices[:-1], r2.vertices[1:]))
    # passes later raise it again from RE's rating, not from the lowered value
    record_traversals(m, passed=[edge] * 6)
    assert m.graph.edges[edge]["p"] == pytest.approx(float(edge_posterior(before, 6, 2)))
    assert m.graph.edges[edge]["p_re"] == before
    with pytest.raises(TopodrakeError, match="prior weight"):
        record_traversals(m, failed=[edge], prior_weight=0.0)
    with pytest.raises(TopodrakeError, match=">= 0"):
        edge_posterior(0.9, -1, 0)


def test_experience_on_edges_survives_the_map_file(oracle_map, tmp_path):
    from topodrake.topomap.recalibrate import experience_summary, record_traversals

    _, m, path = oracle_map
    m = load_map(path, m.scorer)                   # a copy: the fixture's map stays as built
    edges = list(m.graph.edges)[:4]
    record_traversals(m, passed=edges[:2], failed=[edges[2], edges[2]])
    back = load_map(save_map(m, tmp_path / "m.tdmap"), m.scorer)
    for e in edges[:3]:
        for key in ("p", "p_re", "passed", "failed"):
            assert back.graph.edges[e][key] == pytest.approx(m.graph.edges[e][key])
    assert "p_re" not in back.graph.edges[edges[3]]
    assert experience_summary(back) == {"edges_driven": 3, "passes": 2, "failures": 2}


def test_trajectory_edges_carry_the_drive_s_odometry_and_plans_hand_it_on():
    """A drive's trajectory edges carry its odometry between the anchors it
    placed (a relative transform; with wheel odometry it drifts a little),
    a drive that reuses the vertices leaves their legs, and a plan's route has the legs
    of its hops (none into the goal view)."""
    from topodrake.se2 import relative

    t = np.arange(10) * 0.3
    poses = np.column_stack([2.0 + t * np.cos(0.4), 1.0 + t * np.sin(0.4), np.full(10, 0.4)])
    exact = table_map(parallel_drives, teach_odometry="perfect")
    add_trajectory(exact, drive(0, 10), poses)
    chain = exact.trajectories[0].chain
    frames = [exact.graph.nodes[v]["frame"] for v in chain]
    legs, paths = exact.legs(chain)
    np.testing.assert_allclose(legs, relative(poses[frames[:-1]], poses[frames[1:]]), atol=1e-12)
    np.testing.assert_allclose(paths[:, -1], legs, atol=1e-12)
    wheel = table_map(same_drive_hops)
    add_trajectory(wheel, drive(0, 10), poses)
    drift = wheel.legs(wheel.trajectories[0].chain)[0]
    assert 0 < np.abs(drift - legs).max() < 0.05
    none = table_map(same_drive_hops, teach_odometry="none")
    add_trajectory(none, drive(0, 10), poses)
    assert not np.isfinite(none.legs(none.trajectories[0].chain)[0]).any()
    # a second drive along the first reuses its vertices: the edges keep the first one's legs
    add_trajectory(exact, drive(1, 10), poses + [0.0, 0.2, 0.1])
    assert exact.trajectories[1].chain == chain
    np.testing.assert_allclose(exact.legs(chain)[0], legs)
    r = plan_path(exact, drive(0, 1)[0], drive(0, 10)[9])
    assert r.reachable and len(r.route.legs) == len(r.route) - 1
    hops = r.route.legs[:-1]
    np.testing.assert_allclose(hops, exact.legs(r.vertices)[0])
    assert np.isfinite(hops).all() and not np.isfinite(r.route.legs[-1]).any()
    with pytest.raises(TopodrakeError, match="teach_odometry"):
        MapConfig().updated(teach_odometry="gps").validate()


def test_map_files_keep_the_legs_and_read_version_1_without_them(oracle_map, tmp_path):
    world, m, path = oracle_map
    m2 = load_map(path, m.scorer)
    for u, v, d in m.graph.edges(data=True):
        if "leg" in d:
            np.testing.assert_array_equal(m2.graph.edges[u, v]["leg"], d["leg"])
            np.testing.assert_array_equal(m2.graph.edges[u, v]["leg_path"], d["leg_path"])
        else:
            assert "leg" not in m2.graph.edges[u, v]
    assert sum("leg" in d for _, _, d in m.graph.edges(data=True)) > 0
    with np.load(path) as z:
        arrays = {name: z[name] for name in z.files if not name.startswith("edge_leg")}
    meta = json.loads(bytes(arrays.pop("meta")).decode())
    meta["version"] = 1
    old = tmp_path / "v1.tdmap"
    with open(old, "wb") as f:
        np.savez_compressed(f, meta=np.frombuffer(json.dumps(meta).encode(), np.uint8), **arrays)
    m1 = load_map(old, m.scorer)
    assert m1.n_edges == m.n_edges
    assert not any("leg" in d for _, _, d in m1.graph.edges(data=True))


def test_legs_across_a_reused_vertex_carry_its_registered_offset():
    """A hop into or out of a vertex another drive placed: the drive's
    odometry between its frames there, with the vertex's pose in the drive's
    frame (registered) at that end; without that pose the hop has no leg."""
    from topodrake.se2 import compose, invert, relative
    from topodrake.topomap.build import _teach_legs, drive_odometry

    t = np.arange(12) * 0.25
    poses = np.column_stack([1.0 + t, np.full(12, 2.0), np.zeros(12)])
    chain = [("a", 0), ("v", 40), ("v", 41), ("a", 3)]
    anchors = np.array([0, 4, 8, 11])
    off = {1: np.array([0.1, -0.05, 0.02]), 2: np.array([-0.2, 0.1, -0.03])}
    odo = drive_odometry("perfect", poses, seed=0)
    np.testing.assert_array_equal(odo, poses)
    assert drive_odometry("none", poses, 0) is None and drive_odometry("wheel", None, 0) is None
    legs = _teach_legs(odo, chain, anchors, [0, 1, 2], offsets=off)
    drive = relative(poses[anchors[:-1]], poses[anchors[1:]])
    np.testing.assert_allclose(legs[0][0], compose(drive[:1], off[1][None])[0], atol=1e-12)
    np.testing.assert_allclose(legs[1][0], compose(compose(invert(off[1][None]), drive[1:2]),
                                                   off[2][None])[0], atol=1e-12)
    np.testing.assert_allclose(legs[2][0], compose(invert(off[2][None]), drive[2:3])[0], atol=1e-12)
    for leg, path in legs:
        np.testing.assert_allclose(path[-1], leg)           # the taught poses end at the vertex
    assert _teach_legs(odo, chain, anchors, [0, 2], offsets={1: off[1]})[1] == (None, None)


def test_the_shipped_lidar_map_s_legs_agree_with_where_its_anchors_were_taken():
    """The shipped demo map (lidar): most trajectory edges, those across
    reused vertices included, carry legs, and they agree with the anchors'
    recorded poses (metadata) to centimetres."""
    from topodrake.se2 import relative
    from topodrake.topomap.sources import ROOT, open_map

    path = ROOT / "checkpoints" / "demo_map" / "map.tdmap"
    m = open_map(path).topomap
    edges = [(u, v, d) for u, v, d in m.graph.edges(data=True) if d["kind"] == "trajectory"]
    with_legs = [(u, v, d["leg"]) for u, v, d in edges if "leg" in d]
    assert len(with_legs) > 0.8 * len(edges)
    err = np.array([np.hypot(*(leg[:2] - relative(m.pose([u]), m.pose([v]))[0, :2]))
                    for u, v, leg in with_legs])
    assert np.median(err) < 0.02 and np.quantile(err, 0.9) < 0.1


def test_a_map_file_opens_with_the_world_scorer_and_checkpoints_it_was_built_for(
        oracle_map, tmp_path, capsys):
    """open_map: an oracle map gets the geometric oracle and no checkpoints;
    the shipped lidar map its recorded RE and C_WP and the plan calibration
    beside that RE; a map whose RE is not here is refused in the one line
    every command that opens a map prints."""
    from topodrake.apps.cli import main
    from topodrake.learning.reachability.estimator import Reachability
    from topodrake.topomap.scorer import LearnedScorer, OracleScorer
    from topodrake.topomap.sources import REGISTRATION, ROOT, open_map

    world, m, path = oracle_map
    oracle = open_map(path)
    assert isinstance(oracle.scorer, OracleScorer) and oracle.world.name == world.name
    assert sorted(oracle.topomap.graph.nodes) == sorted(m.graph.nodes)
    assert (oracle.reach, oracle.controller, oracle.calibration) == (None, None, None)
    assert oracle.meta["modality"] == "pose" and oracle.meta["world"] == "test-0"

    shipped = ROOT / "checkpoints" / "demo_map" / "map.tdmap"
    learned = open_map(shipped)
    assert isinstance(learned.scorer, LearnedScorer) and learned.scorer.observation == "lidar"
    assert isinstance(learned.scorer.reach, Reachability)
    assert learned.reach == ROOT / "checkpoints" / "reach_lidar_reg" / "checkpoint.pt"
    assert learned.controller == REGISTRATION
    assert learned.calibration is not None and learned.calibration.method == "lidar_reg"
    assert learned.topomap.scorer is learned.scorer and learned.world.name == "test-0"

    # the same map, its RE recorded where none is
    moved = _with_meta(shipped, tmp_path / "moved.tdmap", lambda meta: meta["identity"].update(
        reach="checkpoints/nowhere/checkpoint.pt"))
    want = (f"{moved} was built for the reachability estimator "
            f"{ROOT / 'checkpoints' / 'nowhere' / 'checkpoint.pt'}, which does not exist here; "
            f"pass it with --reach/--controller")
    with pytest.raises(TopodrakeError) as e:
        open_map(moved)
    assert str(e.value) == want
    pose = ",".join(f"{v:.4f}" for v in world.places[0])
    for argv in (["map", "plan", str(moved), "--start", pose, "--goal", pose],
                 ["navigate", str(moved), "--start", pose, "--goal", pose]):
        assert main(argv) == 2
        assert capsys.readouterr().err == f"topodrake: error: {want}\n"
    # navigate follows learned maps only
    assert main(["navigate", str(path), "--start", pose, "--goal", pose]) == 2
    assert "is an oracle map; navigate follows learned maps" in capsys.readouterr().err


def test_a_stored_config_from_before_a_setting_reads_as_the_same_config():
    """A map cache keeps maps written before a setting existed whose default
    builds the same map; a map built by a deleted rule is another map."""
    from topodrake.topomap.graph import same_config

    old = {k: v for k, v in MapConfig().flat().items() if k != "reuse_ahead"}
    assert same_config(old, MapConfig())
    assert not same_config({**old, "reuse_ahead": 4}, MapConfig())
    assert not same_config({**old, "p_reuse": 0.9}, MapConfig())
    assert not same_config(None, MapConfig())


def _with_meta(path, out, edit):
    """A copy of map file ``path`` at ``out`` with its metadata changed by ``edit(meta)``."""
    import io
    import json
    import zipfile

    with zipfile.ZipFile(path) as z:
        files = {n: z.read(n) for n in z.namelist()}
    meta = json.loads(np.load(io.BytesIO(files["meta.npy"])).tobytes())
    edit(meta)
    buf = io.BytesIO()
    np.save(buf, np.frombuffer(json.dumps(meta).encode(), np.uint8))
    files["meta.npy"] = buf.getvalue()
    with zipfile.ZipFile(out, "w") as z:
        for n, b in files.items():
            z.writestr(n, b)
    return out


def test_a_map_keeps_the_scans_taken_with_its_frames_and_plans_hand_them_on(tmp_path):
    """A camera drive's lidar scans ride along: the bank keeps those of the
    frames it keeps (rows aligned with the observations), a drive without
    them gets none (NaN), a plan's route carries its vertices' scans and
    none for the goal view, and the map file keeps them."""
    m = table_map(same_drive_hops)
    scans = np.arange(40, dtype=np.float64).reshape(10, 4)
    add_trajectory(m, drive(0, 10), scans=scans)
    kept = m.bank.observations[:, 1].astype(int)
    np.testing.assert_array_equal(m.bank.scans, scans[kept])
    r = plan_path(m, np.array([0, 0]), np.array([0, 9]))
    frames = [m.graph.nodes[v]["frame"] for v in r.vertices]
    np.testing.assert_array_equal(r.route.scans[:-1], scans[frames])
    assert np.isnan(r.route.scans[-1]).all() and len(r.route.scans) == len(r.route)
    assert len(m.bank.scans) == len(m.bank)           # the plan's temporary rows are gone
    add_trajectory(m, drive(1, 4))
    assert np.isnan(m.bank.scans[len(kept):]).all()
    with pytest.raises(TopodrakeError, match="beams"):
        add_trajectory(m, drive(2, 3), scans=np.zeros((3, 5)))
    plain = table_map(same_drive_hops)
    add_trajectory(plain, drive(0, 10))
    assert plain.bank.scans is None
    assert plan_path(plain, np.array([0, 0]), np.array([0, 9])).route.scans is None


def test_a_camera_map_file_keeps_its_scans(oracle_map, tmp_path):
    world, m, _ = oracle_map
    from topodrake.topomap.graph import TopoMap

    copy = TopoMap(m.scorer, m.embedding, m.config, world=m.world, identity=m.identity)
    poses = np.array([world.places[0], world.places[1]], np.float64)
    scans = np.array([[1.0, np.inf, 2.0], [3.0, 4.0, np.inf]])
    add_trajectory(copy, poses, poses, scans=scans)
    path = save_map(copy, tmp_path / "scans.tdmap")
    back = load_map(path, m.scorer)
    np.testing.assert_array_equal(back.bank.scans, copy.bank.scans)
    assert load_map(save_map(m, tmp_path / "none.tdmap"), m.scorer).bank.scans is None


def test_a_reuse_must_lie_where_the_drive_s_odometry_puts_it():
    """Drive 2 looks like drive 0 frame for frame but goes elsewhere: after
    reusing drive 0's first vertex, RE would let it reuse the rest, but
    the map's legs put them where drive 2's odometry does not go."""
    from types import SimpleNamespace

    import networkx as nx

    from topodrake.topomap.build import loop_consistent

    def canonical(a):
        return (0, a[1]) if a[0] in (1, 2) else a

    def copies(a, b):
        ca, cb = canonical(a), canonical(b)
        return 0.999 if ca[0] == cb[0] and 0 <= cb[1] - ca[1] <= 3 else 0.1

    steps = np.arange(10.0)
    poses = [np.column_stack([steps, np.zeros(10), np.zeros(10)]),
             np.column_stack([steps, np.full(10, 0.05), np.zeros(10)]),
             np.column_stack([np.zeros(10), steps, np.zeros(10)])]

    def build(**config):
        m = table_map(copies, teach_odometry="perfect", **config)
        for d in range(3):
            add_trajectory(m, drive(d, 10), poses[d])
        return m

    def foreign(m, d):
        return [v for v in m.trajectories[d].chain if m.graph.nodes[v]["traj"] != d]

    off, on = build(loop_check_m=0.0), build()
    assert len(foreign(off, 1)) == len(off.trajectories[1].chain)   # drive 1 is drive 0 again
    assert len(foreign(on, 1)) == len(on.trajectories[1].chain)     # ... and checks out
    assert len(foreign(off, 2)) == len(off.trajectories[2].chain)   # RE alone: all of drive 0
    assert foreign(on, 2) == [on.trajectories[0].chain[0]]          # only the shared start

    # the check itself, on legs w -> a -> v along x
    g = nx.DiGraph()
    g.add_edge(0, 1, leg=np.array([1.0, 0.0, 0.0]))
    g.add_edge(2, 1, leg=np.array([-1.0, 0.0, 0.0]))                # read backwards
    g.add_node(3)
    m = SimpleNamespace(graph=g, config=MapConfig())
    assert loop_consistent(m, 0, 2, np.array([2.0, 0.3, 0.0]))
    assert not loop_consistent(m, 0, 2, np.array([2.0, 3.0, 0.0]))  # 3 m > 1.5 + 0.1 * 4.0
    assert loop_consistent(m, 0, 2, np.array([2.0, 1.8, 0.0]))      # 1.8 m < 1.5 + 0.1 * 4.7
    assert loop_consistent(m, 0, 3, np.array([50.0, 0.0, 0.0]))     # no legs join them
    assert loop_consistent(m, 0, 0, np.zeros(3)) and not loop_consistent(m, 0, 0, np.ones(3) * 2)
    with pytest.raises(TopodrakeError, match="loop_check_m"):
        MapConfig().updated(loop_check_m=-1.0).validate()


def test_a_plan_from_a_vertex_starts_there_and_avoids_the_excluded_edges():
    """plan_from_vertex: the path starts at the vertex given (no start link
    from a view, probability 1 for it) and takes another way round an
    excluded edge; a vertex not in the map is refused."""
    from topodrake.topomap.plan import plan_from_vertex

    m = table_map(parallel_drives, reuse=False)
    add_trajectory(m, drive(0, 13))
    add_trajectory(m, drive(1, 13))
    r = plan_path(m, np.array([0, 0]), np.array([0, 12]))
    v = r.vertices[1]
    f = plan_from_vertex(m, v, np.array([0, 12]))
    assert f.reachable and f.vertices[0] == v and f.route.start_probability == 1.0
    assert f.route.vertices[0] == v and f.probability >= r.probability
    first = (f.vertices[0], f.vertices[1])
    g = plan_from_vertex(m, v, np.array([0, 12]), excluded_edges=[first])
    assert g.reachable and g.vertices[0] == v and first not in set(zip(g.vertices[:-1],
                                                                        g.vertices[1:]))
    with pytest.raises(TopodrakeError, match="not a vertex"):
        plan_from_vertex(m, 10 ** 6, np.array([0, 12]))
