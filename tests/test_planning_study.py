"""The planning study's pieces (studies/planning.py, topodrake.experiments.plan_trials,
plan_methods, plan_study and plan_results): trials, subsets, calibration, the summary, the
methods, and a tiny planned-and-followed run in the box world with the oracles."""

import json

import numpy as np
import pytest
from study_run import run_study

from topodrake.errors import TopodrakeError
from topodrake.experiments import plan_trials as pt
from topodrake.topomap.plan_calibration import calibration

# ---------------------------------------------------------------- trials

def test_trial_pairs_are_seeded_prefix_stable_and_never_a_place_with_itself():
    a = pt.trial_pairs(10, 200, seed=3)
    assert a.shape == (200, 2)
    assert (a[:, 0] != a[:, 1]).all()
    assert a.min() >= 0 and a.max() <= 9
    assert len({tuple(p) for p in a}) > 60                  # many of the 90 ordered pairs
    np.testing.assert_array_equal(a, pt.trial_pairs(10, 200, seed=3))
    np.testing.assert_array_equal(a[:50], pt.trial_pairs(10, 50, seed=3))
    assert not np.array_equal(a, pt.trial_pairs(10, 200, seed=4))
    two = pt.trial_pairs(2, 20, seed=0)
    assert {tuple(p) for p in two} == {(0, 1), (1, 0)}
    with pytest.raises(TopodrakeError, match="2 places"):
        pt.trial_pairs(1, 3, 0)


def test_jittered_starts_are_seeded_and_0_3_m_9_deg_off(box_world):
    places = np.array([[2.0, 2.0, 0.0], [8.0, 8.0, np.pi / 2], [2.0, 8.0, -np.pi / 2]])
    pairs = pt.trial_pairs(len(places), 12, seed=1)
    s = pt.jittered_starts(box_world, places, pairs, seed=1)
    np.testing.assert_array_equal(s, pt.jittered_starts(box_world, places, pairs, seed=1))
    base = places[pairs[:, 0]]
    np.testing.assert_allclose(np.hypot(*(s[:, :2] - base[:, :2]).T), 0.3, atol=1e-9)
    np.testing.assert_allclose(np.abs(s[:, 2] - base[:, 2]), np.radians(9.0), atol=1e-9)
    forward = np.einsum("ij,ij->i", s[:, :2] - base[:, :2],
                        np.column_stack([np.cos(base[:, 2]), np.sin(base[:, 2])]))
    np.testing.assert_allclose(forward, 0.0, atol=1e-9)     # moved sideways only


def test_pruned_subsets_are_seeded_sorted_nested_and_whole_at_one():
    a = pt.pruned_subset(90, 0.6, seed=0)
    assert len(a) == 54 and (np.diff(a) > 0).all()
    np.testing.assert_array_equal(a, pt.pruned_subset(90, 0.6, seed=0))
    assert not np.array_equal(a, pt.pruned_subset(90, 0.6, seed=1))
    assert set(pt.pruned_subset(90, 0.3, seed=0)) <= set(a)
    np.testing.assert_array_equal(pt.pruned_subset(90, 1.0, seed=5), np.arange(90))
    assert len(pt.pruned_subset(90, 0.001, seed=0)) == 1
    for bad in (0.0, 1.5, -0.1):
        with pytest.raises(TopodrakeError, match="fraction"):
            pt.pruned_subset(90, bad, 0)


# ---------------------------------------------------------------- analysis

def test_calibration_bins_and_ece_on_hand_made_data():
    p = [0.05, 0.05, 0.95, 0.95, 0.95, 0.95, 1.0, 0.55, float("nan")]
    s = [0, 0, 1, 1, 1, 0, 1, 1, 1]
    rows, ece = calibration(p, s, bins=10)
    assert len(rows) == 10 and rows[0]["lo"] == 0.0 and rows[-1]["hi"] == 1.0
    assert [r["count"] for r in rows] == [2, 0, 0, 0, 0, 1, 0, 0, 0, 5]   # nan left out, 1.0 in the last
    assert rows[0]["predicted"] == 0.05 and rows[0]["observed"] == 0.0
    assert rows[9]["predicted"] == 0.96 and rows[9]["observed"] == 0.8
    assert rows[1]["predicted"] is None
    want = (2 * 0.05 + 1 * 0.45 + 5 * 0.16) / 8
    assert ece == pytest.approx(want, abs=1e-4)
    perfect, e0 = calibration([0.25] * 4 + [0.75] * 4, [1, 0, 0, 0, 1, 1, 1, 0])
    assert e0 == 0.0
    assert calibration([], [])[1] is None
    with pytest.raises(TopodrakeError):
        calibration([0.5], [1, 0])


def test_summary_min_ours_margin_and_nulls():
    def house(ours, sptm, v):
        return {"methods": {"ours": {"success": ours, "vertices": v, "edges": 2 * v},
                            "lidar": {"success": 0.5}, "oracle": {"success": 0.9},
                            "sptm": {"success": sptm, "vertices": 3 * v}}}

    s = pt.summarize({"test-0": house(0.9, 0.4, 10), "test-1": house(0.8, 0.5, 20)}, 0.12, 0.95)
    assert s["houses"]["test-0"] == {"ours": 0.9, "lidar": 0.5, "sptm": 0.4, "oracle": 0.9,
                                     "vertices": 10, "edges": 20, "sptm_vertices": 30}
    assert s["min_ours"] == 0.8
    assert s["min_margin_over_sptm"] == pytest.approx(0.3)
    assert s["plan_probability_ece"] == 0.12 and s["pruned_60_over_peak"] == 0.95
    assert s["replanning_gain"] is None and s["changed_world"] is None
    json.dumps(s)
    # a changed world: each method's trials driven as mapped and changed, paired
    def rec(house, method, trial, success, outcome="goal"):
        return {"house": house, "method": method, "trial": trial, "success": success,
                "outcome": outcome}

    a, b = house(0.9, 0.4, 10), house(0.9, 0.4, 10)
    a["records"] = [rec("a", "ours_unchanged", t, True) for t in range(4)] + \
        [rec("a", "ours", 0, True), rec("a", "ours", 1, False, "collision"),
         rec("a", "ours", 2, False, "dead_reckoning_gave_up"), rec("a", "ours", 3, True)]
    b["records"] = [rec("b", "ours_unchanged", 0, False), rec("b", "ours", 0, True),
                    rec("b", "ours_unchanged", 1, True, "no_room"),
                    rec("b", "ours", 1, False, "no_room")]
    s = pt.summarize({"a": a, "b": b}, None, None)
    cw = s["changed_world"]["ours"]
    assert (cw["trials"], cw["success"], cw["unchanged"], cw["no_room"]) == (5, 0.6, 0.8, 1)
    assert cw["ratio"] == pytest.approx(0.75) and cw["collisions"] == 0.2
    assert cw["difference"]["mean"] == pytest.approx(-0.2) and cw["difference"]["pairs"] == 5
    assert cw["outcomes"] == {"collision": 1, "dead_reckoning_gave_up": 1, "goal": 3}
    only_lidar = pt.summarize({"h": {"methods": {"lidar": {"success": 0.5}}}}, None, None)
    assert only_lidar["min_ours"] is None and only_lidar["min_margin_over_sptm"] is None


def test_replanning_gain_is_the_smallest_gain_where_ours_is_below_0_97():
    def house(ours, replan):
        return {"methods": {"ours": {"success": ours, "vertices": 1, "edges": 1},
                            "ours_replan": {"success": replan}}}

    s = pt.summarize({"a": house(0.5, 0.6), "b": house(0.8, 0.85), "c": house(0.98, 0.9)},
                     None, None)
    assert s["replanning_gain"] == pytest.approx(0.05)      # "c" is above 0.97: not counted
    assert s["houses"]["a"]["ours_replan"] == 0.6
    assert pt.summarize({"c": house(0.98, 0.9)}, None, None)["replanning_gain"] is None


def test_replanning_gains_pair_each_method_with_its_replanning_twin_per_house():
    def house(lidar, replan, reg=None):
        m = {"lidar": {"success": lidar}, "lidar_replan": {"success": replan}}
        if reg is not None:
            m["lidar_reg"] = {"success": reg}      # no twin: not paired
        return {"methods": m}

    s = pt.summarize({"a": house(0.5, 0.7, 0.9), "b": house(0.8, 0.7)}, None, None)
    assert s["replanning_gains"] == {"lidar": {"min": pytest.approx(-0.1),
                                               "mean": pytest.approx(0.05)}}
    assert s["replanning_gain"] is None           # ours' figure needs ours
    assert pt.summarize({"a": house(0.5, 0.6)}, None, None)["replanning_gains"]["lidar"][
        "min"] == pytest.approx(0.1)


def test_longest_link_is_the_longest_true_step_of_start_anchors_and_goal():
    from topodrake.contract.route import Route

    route = Route(np.zeros((3, 1)), np.array([[1.0, 0, 0], [2.0, 0, 0], [np.nan, np.nan, np.nan]]))
    # start (0, 0) -> 1 -> 2 -> (unknown pose, skipped) -> goal place (8, 0)
    assert pt.longest_link_m([0.0, 0.0, 0.0], route, [8.0, 0.0, 0.0]) == pytest.approx(6.0)
    assert pt.longest_link_m([1.5, 0.0, 0.0], route, [2.5, 0.0, 0.0]) == pytest.approx(1.0)


def test_summary_averages_the_false_link_share_per_method():
    def house(share):
        return {"methods": {"ours": {"success": 0.5, "vertices": 1, "edges": 1,
                                     "false_link_plans": share},
                            "sptm": {"success": 0.1, "vertices": 1, "false_link_plans": None}}}

    s = pt.summarize({"a": house(0.2), "b": house(0.4)}, None, None)
    assert s["false_link_plans"] == {"ours": pytest.approx(0.3)}


def test_pruned_ratio():
    assert pt.pruned_ratio({"0.3": 0.4, "0.6": 0.72, "1": 0.8}) == 0.9
    assert pt.pruned_ratio({"0.3": 0.4, "1": 0.8}) is None
    assert pt.pruned_ratio({"0.6": 0.0, "1": 0.0}) is None
    assert pt.pruned_ratio({}) is None


def test_goal_watch_stops_cars_at_their_goal():
    w = pt.GoalWatch(np.array([[0.0, 0.0, 0.0], [5.0, 5.0, 0.0], [1.0, 1.0, 0.0]]))
    stop = w(0, np.array([0, 1]), np.array([[0.5, 0.0, 0, 0, 0], [4.0, 5.0, 0, 0, 0]]))
    assert stop.tolist() == [True, False]
    assert w.arrived.tolist() == [True, False, False]


def test_render_pose_route_gives_camera_contexts(box_world):
    from topodrake.contract.route import Route

    ctx = np.repeat(np.array([[[2.0, 2.0, 0.0]], [[3.0, 2.0, 0.0]]]), 3, axis=1)   # (2, 3, 3)
    r = pt.render_pose_route(box_world, Route(ctx, ctx[:, 1], probability=0.7, modality="pose"))
    assert r.modality == "camera" and r.contexts.shape[:2] == (2, 3)
    assert r.contexts.dtype == np.uint8 and r.contexts.shape[-1] == 3
    assert r.probability == 0.7


# ---------------------------------------------------------------- the study's command line

def test_study_refuses_bad_input_in_one_line(tmp_path):
    code, _, err = run_study("planning", "--houses", "no-such-house", "--out", tmp_path)
    assert code == 2
    assert err.startswith("error: unknown world") and err.count("\n") == 1
    code, _, err = run_study("planning", "--methods", "ours,magic", "--out", tmp_path)
    assert code == 2
    assert "unknown methods" in err
    code, _, err = run_study("planning", "--pruned-fractions", "0.5,2", "--out", tmp_path)
    assert code == 2
    assert "(0, 1]" in err
    code, _, err = run_study("planning", "--world", "test-0", "--houses", "test-1", "--out",
                             tmp_path)
    assert code == 2
    assert "not both" in err
    code, _, err = run_study("planning", "--trials", "0")     # refused by the option's type
    assert code == 2
    code, _, err = run_study("planning", "--experience-prior-weight", "0", "--out", tmp_path)
    assert code == 2 and "experience_prior_weight must be > 0" in err


# ---------------------------------------------------------------- the study's scenarios

def test_table2_is_the_default_run_and_every_named_scenario_loads():
    from topodrake.experiments.plan_scenario import HOUSES, PlanningScenario
    from topodrake.experiments.scenarios import load_scenario, scenario_names

    path = "studies/scenarios/planning.yaml"
    names = scenario_names(path)
    assert {"table2", "paper_protocol", "ceiling", "real_buildings"} <= set(names)
    assert load_scenario(PlanningScenario, path, "table2") == PlanningScenario()
    for name in names:
        load_scenario(PlanningScenario, path, name).resolved()
    paper = load_scenario(PlanningScenario, path, "paper_protocol")
    assert paper.trials == paper.pruned_trials == 1000 and len(paper.pruned_fractions) == 10
    assert load_scenario(PlanningScenario, path, "ceiling").methods == ["oracle_full"]
    real = load_scenario(PlanningScenario, path, "real_buildings").resolved()
    assert real.specs == [real.world] and real.world.endswith("map.yaml")
    assert real.time_rule == "route" and real.pruned_fractions == [] and real.houses == []
    # the text changes fields over the scenario, nested ones key by key
    sc = load_scenario(PlanningScenario, path, "table2",
                       "{trials: 7, changes: {boxes: 5}, follower: {legs_m: 0}}")
    assert (sc.trials, sc.changes.boxes, sc.changes.people, sc.houses) == (7, 5, 0, HOUSES)
    for name, changed in (("boxes", "boxes"), ("people", "people"), ("blocked", "blocked")):
        named = load_scenario(PlanningScenario, path, name)
        assert getattr(named.changes, changed) > 0 and "oracle_full" in named.methods
    with pytest.raises(TopodrakeError, match="blocked closes at most 1"):
        load_scenario(PlanningScenario, path, "table2", "{changes: {blocked: 2}}")
    # a planning.json gives back the scenario it ran (one written before scenarios: its config)
    from dataclasses import asdict

    assert PlanningScenario.from_record({"scenario": asdict(real)}) == real
    recorded = {**asdict(real), "changes": {"trials": 10, "boxes": 3}}   # ours_obstacles' boxes
    assert PlanningScenario.from_record({"scenario": recorded}) == real
    old = PlanningScenario.from_record({"config": {"houses": ["test-1"], "t_max_s": 300.0,
                                                   "route_time": True, "trials": 7}})
    assert (old.specs, old.time_limit, old.route_time, old.trials) == (["test-1"], 300.0, True, 7)
    with pytest.raises(TopodrakeError, match="unknown scenario 'nope'"):
        load_scenario(PlanningScenario, path, "nope")
    with pytest.raises(TopodrakeError, match="tirals"):
        load_scenario(PlanningScenario, path, "table2", "{tirals: 7}")


def test_the_command_line_builds_its_scenario_and_flags_change_it(tmp_path):
    """``--scenario table2 --json`` is the default run (printed, not run,
    with --print-config); flags and --scenario-text change it."""
    import yaml

    from topodrake.experiments.plan_scenario import PlanningScenario

    code, out, err = run_study("planning", "--scenario", "table2", "--json", "--print-config")
    assert code == 0, err
    assert yaml.safe_load(out) == yaml.safe_load(run_study("planning", "--print-config")[1])
    from dataclasses import asdict

    assert yaml.safe_load(out) == asdict(PlanningScenario().resolved())
    code, out, err = run_study(
        "planning", "--houses", "test-0", "--methods", "lidar_reg,oracle_full", "--trials", "100",
        "--pruned-fractions", "none", "--print-config")
    assert code == 0, err
    assert yaml.safe_load(out) == yaml.safe_load(
        run_study("planning", "--scenario", "outcome_check", "--print-config")[1])
    code, out, err = run_study(
        "planning", "--scenario", "real_buildings", "--scenario-text", "{trials: 20}",
        "--changes", "boxes=4", "--follower", '{"legs_m": 0}', "--replan", "paper", "--houses",
        "test-1", "--print-config")
    assert code == 0, err
    sc = yaml.safe_load(out)
    assert sc["world"] is None and sc["houses"] == ["test-1"] and sc["trials"] == 20
    assert sc["changes"] == {"boxes": 4, "people": 0, "blocked": 0}
    assert sc["follower"] == {"legs_m": 0}
    assert sc["replan"]["first"] == 5 and sc["time_rule"] == "route"
    (tmp_path / "off.yaml").write_text("scan_match: 0\n")
    code, out, err = run_study("planning", "--map-config", tmp_path / "off.yaml",
                               "--print-config")
    assert code == 0 and yaml.safe_load(out)["map"] == {"scan_match": 0.0}


def test_house_keys_and_seeds():
    from topodrake.experiments.map_cache import house_key
    from topodrake.experiments.plan_study import house_seed

    assert house_key("/x/maps/willow/map.yaml") == "willow-map"
    assert house_seed(0, "test-0") == house_seed(0, "test-0") != house_seed(1, "test-0")


# ---------------------------------------------------------------- end to end, oracles

def test_plan_and_follow_on_an_oracle_map_in_the_box_world(box_world):
    """Two expert drives make an oracle map; trials between three places are
    planned on it and followed by the A* oracle with the geometric RE."""
    from topodrake.learning.waypoint.policy import AStarOracle
    from topodrake.navigation.engine import NavigationEngine
    from topodrake.navigation.evaluate import GeometricReachability
    from topodrake.rollout import ExpertRollout, RolloutConfig
    from topodrake.topomap.build import build_map
    from topodrake.topomap.graph import TopoMap
    from topodrake.topomap.plan import plan_path
    from topodrake.topomap.retrieval import default_embedding
    from topodrake.topomap.scorer import OracleScorer

    places = np.array([[1.5, 2.0, np.pi / 2], [7.5, 2.0, np.pi / 2], [1.5, 8.0, np.pi / 2]])
    res = ExpertRollout(box_world, RolloutConfig(t_max_s=60.0)).run(places[[0, 1]],
                                                                    places[[1, 0], :2])
    assert res.success.all()
    scorer = OracleScorer(box_world)
    m = TopoMap(scorer, default_embedding("pose"), world="box")
    build_map(m, [(res.trajectory(i)["poses"], res.trajectory(i)["poses"], f"d{i}")
                  for i in range(2)], progress=False)
    # goals: where the drives ended (their headings), and a place off the map
    goals = np.array([res.trajectory(0)["poses"][-1], res.trajectory(1)["poses"][-1], places[2]])
    pairs = np.array([[0, 1], [1, 0], [0, 2]])
    starts = pt.jittered_starts(box_world, places, pairs, seed=0)
    plans = [plan_path(m, starts[t], goals[t], start_pose=starts[t], goal_pose=goals[t])
             for t in range(len(pairs))]
    assert plans[0].reachable and plans[1].reachable
    routes = [p.route if p.reachable else None for p in plans]
    engine = NavigationEngine(box_world, AStarOracle(box_world, k=5),
                              GeometricReachability(box_world, k=5))
    done = []
    out = pt.follow_routes(engine, starts, routes, goals, t_max_s=60.0, batch=2,
                           progress=done.append)
    # each trial's odometry errors come from its own seed, whatever batch it drives in
    asked = []
    run = engine.run
    engine.run = lambda *a, **kw: asked.append(kw["odometry_seeds"]) or run(*a, **kw)
    pt.follow_routes(engine, starts, routes, goals, t_max_s=1.0, batch=1,
                     odometry_seeds=[7, 8, 9])
    planned = [t for t in range(len(routes)) if routes[t] is not None]
    assert asked == [[[7, 8, 9][t]] for t in planned]
    asked.clear()
    pt.follow_routes(engine, starts, routes, goals, t_max_s=1.0, batch=2)
    assert sum(asked, []) == planned                  # default: the trial's index
    engine.run = run
    assert sum(done) == sum(r is not None for r in routes) and max(done) <= 2
    assert out.success[:2].all()
    assert (out.final_distance_m[:2] <= pt.SUCCESS_M).all()
    assert all(o in ("goal", "reached") for o in out.outcome[:2])
    if routes[2] is None:
        assert out.outcome[2] == "no_plan" and not out.success[2] and out.steps[2] == 0
    rows, ece = calibration([p.probability for p in plans if p.reachable],
                               out.success[[p.reachable for p in plans]])
    assert ece is not None and 0.0 <= ece <= 1.0

    # the same trials with 3 boxes the map never saw on each route, batched
    from topodrake.world.changes import WorldChanges, place_changes
    from topodrake.world.obstacles import densify

    seeds = [np.random.SeedSequence([0, t]) for t in range(len(pairs))]
    changes, placed = place_changes(box_world, pt.route_paths(starts, routes, goals),
                                    WorldChanges(boxes=3), seeds, starts)
    obst = pt.follow_routes(engine, starts, routes, goals, t_max_s=60.0, batch=2,
                            changes=changes)
    planned = [t for t in range(len(pairs)) if routes[t] is not None]
    for t in planned:
        boxes = np.array(placed[t]["boxes"])
        assert boxes.shape == (3, 4)
        centres = 0.5 * (boxes[:, :2] + boxes[:, 2:])
        route_xy = densify(np.vstack([starts[t][:2], routes[t].poses[:, :2], goals[t][:2]]), 0.05)
        gap = np.hypot(*(centres[:, None] - route_xy[None]).transpose(2, 0, 1)).min(axis=1)
        assert (gap < 0.2).all()                       # on the planned route
    assert obst.success[:2].any()                      # the A* oracle passes boxes
    assert set(obst.outcome[:2]) <= {"goal", "reached", "timeout", "collision",
                                     "dead_reckoning_gave_up", "search_failed"}
    if routes[2] is None:
        assert placed[2] is None and obst.outcome[2] == "no_plan"


def test_summary_reports_the_oracle_ablations():
    def house(full, follow, cwp, unplanned):
        return {"methods": {"oracle_full": {"success": full, "false_link_plans": 0.0},
                            "ours_oracle_follow": {"success": follow, "false_link_plans": 0.1},
                            "oracle_cwp": {"success": cwp}},
                "oracle_unplanned_pairs": unplanned}

    s = pt.summarize({"a": house(0.99, 0.9, 0.95, []), "b": house(0.97, 0.8, 0.96, [[1, 2]])},
                     None, None)
    assert s["min_oracle_full"] == 0.97 and s["min_ours_oracle_follow"] == 0.8
    assert s["min_oracle_cwp"] == 0.95 and s["oracle_unplanned_pairs"] == 1
    assert s["false_link_plans"]["ours_oracle_follow"] == pytest.approx(0.1)
    assert s["houses"]["a"]["oracle_full"] == 0.99
    assert pt.summarize({"h": {"methods": {"lidar": {"success": 0.5}}}}, None,
                        None)["oracle_unplanned_pairs"] is None


def test_pose_oracles_follow_a_route_of_images_by_its_anchor_poses(box_world):
    """ours_oracle_follow: a route planned on a camera map carries images; the
    oracles read its anchors' poses instead, and the engine drives it."""
    from topodrake.contract.route import Route
    from topodrake.learning.waypoint.policy import AStarOracle
    from topodrake.navigation.engine import NavigationEngine
    from topodrake.navigation.evaluate import GeometricReachability, encode_routes

    poses = np.array([[2.0, 2.0, 0.0], [3.0, 2.0, 0.0], [4.0, 2.5, 0.5]])
    images = np.zeros((3, 11, 8, 8, 3), np.uint8)          # stands for camera contexts
    route = Route(images, poses, modality="camera")
    policy, reach = AStarOracle(box_world, k=5), GeometricReachability(box_world, k=5)
    feats = encode_routes([route], policy, reach)
    np.testing.assert_allclose(feats.cwp, poses)
    np.testing.assert_allclose(feats.re, poses)
    engine = NavigationEngine(box_world, policy, reach)
    res = engine.run(np.array([[1.5, 2.0, 0.0]]), [route], t_max_s=30.0)
    assert res.outcome_name(0) == "reached"
    assert np.hypot(*(res.poses[0, res.steps[0], :2] - poses[-1, :2])) < 0.6


def test_engine_refuses_networks_of_two_sensors(box_world):
    from topodrake.navigation.engine import NavigationEngine

    class Net:
        k, frame_step = 0, 3

        def __init__(self, observation):
            self.observation = observation

    with pytest.raises(ValueError, match="C_WP observes camera, RE lidar"):
        NavigationEngine(box_world, Net("camera"), Net("lidar"))
    assert NavigationEngine(box_world, Net("pose"), Net("pose")).kind == "pose"


def test_summary_reports_each_map_methods_anchors_per_metre():
    houses = {"test-0": {"methods": {
        "lidar": {"success": 0.5, "vertices": 40, "edges": 90, "anchors_per_m": 0.3},
        "lidar_reg": {"success": 0.9, "vertices": 120, "edges": 300, "anchors_per_m": 0.8},
        "sptm": {"success": 0.2, "vertices": 500}}}}
    row = pt.summarize(houses, None, None)["houses"]["test-0"]
    assert row == {"lidar": 0.5, "lidar_reg": 0.9, "sptm": 0.2, "sptm_vertices": 500,
                   "lidar_anchors_per_m": 0.3, "lidar_reg_anchors_per_m": 0.8}


def test_false_links_count_links_only_and_long_steps_count_every_step():
    from topodrake.experiments import plan_study as study

    rec = lambda longest, false: {"outcome": "diverged", "success": False, "planned": True,
                                  "plan_probability": 0.5, "longest_link_m": longest,
                                  "false_link_m": false}
    # a long anchor hop of the drive itself (7 m) is no false link; a 6 m start link is
    rates = study._rates([rec(7.0, 0.0), rec(6.0, 6.0), rec(1.0, 0.0), rec(2.0, 0.0)])
    assert rates["false_link_plans"] == 0.25 and rates["long_step_plans"] == 0.5
    # SPTM's records judge every step (no link kinds)
    sptm = study._rates([rec(7.0, None), rec(1.0, None)])
    assert sptm["false_link_plans"] == 0.5 == sptm["long_step_plans"]


# ---------------------------------------------------------------- the methods

def test_the_method_registry_names_each_method_s_map_follower_and_drive():
    from dataclasses import FrozenInstanceError

    from topodrake.experiments.plan_methods import (
        FOLLOWERS,
        MAP_KINDS,
        METHODS,
        ORACLE_METHODS,
        Method,
    )

    assert list(METHODS) == ["ours", "lidar", "lidar_reg", "sptm", "oracle", "ours_replan",
                             "oracle_full", "ours_oracle_follow", "oracle_cwp",
                             "lidar_scale", "ours_scale", "lidar_oracle_follow",
                             "lidar_scale_oracle_re", "lidar_oracle_cwp", "lidar_replan",
                             "lidar_reg_replan", "oracle_full_replan", "lidar_reg_oracle_follow",
                             "lidar_reg_oracle_re"]
    assert ORACLE_METHODS == ("oracle_full", "ours_oracle_follow", "oracle_cwp",
                              "lidar_oracle_follow", "oracle_full_replan",
                              "lidar_reg_oracle_follow")
    for name, m in METHODS.items():
        assert m.name == name and m.map in MAP_KINDS and m.follower in FOLLOWERS
        assert m.followed_by == FOLLOWERS[m.follower]
        assert m.oracle == (name in ORACLE_METHODS)
    assert {n: m.drive for n, m in METHODS.items() if m.drive != "plain"} == \
        {"ours_replan": "replan", "lidar_replan": "replan",
         "lidar_reg_replan": "replan", "oracle_full_replan": "replan"}
    for name in ("ours_replan", "lidar_replan", "lidar_reg_replan", "oracle_full_replan"):
        plain = METHODS[name[:-len("_replan")]]
        assert (METHODS[name].map, METHODS[name].follower) == (plain.map, plain.follower)
    assert [n for n, m in METHODS.items() if m.renders_routes] == ["oracle", "oracle_cwp"]
    assert METHODS["sptm"].map == "sptm" and METHODS["ours_oracle_follow"].map == "camera"
    assert METHODS["lidar_scale"].map == METHODS["lidar_oracle_follow"].map == "lidar"
    assert METHODS["lidar_scale_oracle_re"].map == METHODS["lidar_oracle_cwp"].map == "lidar"
    assert METHODS["lidar_reg_oracle_follow"].map == METHODS["lidar_reg_oracle_re"].map == \
        "lidar_reg"
    with pytest.raises(ValueError, match="map kind"):
        Method("sonar", map="sonar", follower="camera")
    with pytest.raises(ValueError, match="drive"):
        Method("ours_fast", map="camera", follower="camera", drive="fast")
    with pytest.raises(FrozenInstanceError):
        METHODS["ours"].map = "lidar"


def _scenario(tmp_path, **changed):
    """The study's scenario (every method, 20 trials, pruned maps at 0.3, 0.6
    and 1) with ``changed`` fields."""
    from topodrake.experiments.plan_methods import METHODS
    from topodrake.experiments.plan_scenario import PlanningScenario

    return PlanningScenario(**{"methods": list(METHODS), "trials": 20,
                               "pruned_fractions": [0.3, 0.6, 1.0], **changed})


def test_the_study_writes_each_method_s_follower_into_its_config(tmp_path, monkeypatch, patch_everywhere):
    """The study's run with the houses' trials stubbed: it runs the library's
    house job, and planning.json records the scenario and describes each
    method's follower as its Method does."""
    from topodrake.experiments import plan_study
    from topodrake.experiments.plan_methods import METHODS
    from topodrake.experiments.plan_results import planning
    from topodrake.navigation.follower import FollowerConfig

    jobs_run = []

    def run_trials(job, seeds, *, jobs, scenario, **_):
        jobs_run.append(job)
        recs = [{"house": "test-0", "method": m, "planned": True, "plan_probability": 0.8,
                 "plan_anchors": 5, "success": t % 2 == 0, "outcome": "goal"}
                for m in scenario.methods for t in range(4)]
        return [{"house": "test-0", "world": jobs[s], "seed": s, "drives": 90, "records": recs,
                 "methods": {m: {"success": 0.5, "trials": 4} for m in scenario.methods}}
                for s in seeds]

    patch_everywhere("topodrake.montecarlo.run_trials", run_trials)
    doc = planning(_scenario(tmp_path, world="test-0", methods=["oracle_full", "lidar_reg"],
                             pruned_fractions=[]), "python studies/planning.py", quiet=True)
    assert jobs_run == [plan_study.house_job]
    assert doc["summary"]["houses"]["test-0"] == {"oracle_full": 0.5, "lidar_reg": 0.5}
    assert doc["config"]["followers"] == {
        "oracle_full": "A* oracle C_WP + geometric oracle RE",
        "lidar_reg": "registration C_WP (lidar teach and repeat) + its learned RE"}
    assert doc["config"]["followers"]["lidar_reg"] == METHODS["lidar_reg"].followed_by
    assert all(r["success_probability"] is not None for r in doc["trials"]
               if r["method"] == "lidar_reg")                     # its calibration ships
    json.dumps(doc)                                                # planning.json holds it
    assert doc["config"]["map"]["scan_match"] == 0.8               # the library's defaults
    assert doc["scenario"]["world"] == "test-0" and doc["scenario"]["houses"] == []
    assert doc["scenario"]["time_rule"] == "route"                 # a world's, resolved

    # other map settings reach the house jobs and the record
    seen = []
    patch_everywhere("topodrake.montecarlo.run_trials", lambda job, seeds, *, jobs, scenario, **kw:
                        seen.append(scenario.map_config()) or run_trials(
                            job, seeds, jobs=jobs, scenario=scenario, **kw))
    doc = planning(_scenario(tmp_path, world="test-0", methods=["lidar"], pruned_fractions=[],
                             map={"scan_match": 0}), "python studies/planning.py", quiet=True)
    assert doc["config"]["map"]["scan_match"] == 0 and doc["scenario"]["map"] == {"scan_match": 0}
    assert seen[0].scan_match == 0 and seen[0].reuse.p == 0.99

    # follower settings likewise; the engines drive with them
    seen.clear()
    patch_everywhere("topodrake.montecarlo.run_trials", lambda job, seeds, *, jobs, scenario, **kw:
                        seen.append(plan_study.navigation_config(scenario)) or run_trials(
                            job, seeds, jobs=jobs, scenario=scenario, **kw))
    doc = planning(_scenario(tmp_path, world="test-0", methods=["lidar"], pruned_fractions=[],
                             follower={"legs_m": 0}), "python studies/planning.py", quiet=True)
    assert doc["scenario"]["follower"] == {"legs_m": 0}
    assert seen[0].follower.tracker.legs_m == 0 and seen[0].follower.lookahead == 2
    assert plan_study.navigation_config(_scenario(tmp_path)).follower == FollowerConfig()
    code, _, err = run_study("planning", "--follower", '{"legs_m": -1}', "--out", tmp_path)
    assert code == 2 and "legs_m must be >= 0" in err and err.count("\n") == 1

    # the time limit likewise
    seen.clear()
    patch_everywhere("topodrake.montecarlo.run_trials", lambda job, seeds, *, jobs, scenario, **kw:
                        seen.append(scenario.time_limit) or run_trials(
                            job, seeds, jobs=jobs, scenario=scenario, **kw))
    doc = planning(_scenario(tmp_path, world="test-0", methods=["lidar"], pruned_fractions=[],
                             time_limit=300.0), "python studies/planning.py", quiet=True)
    assert seen == [300.0] and doc["scenario"]["time_limit"] == 300.0
    # plans are made for that limit, unless the paper's most probable paths are asked for
    sc = _scenario(tmp_path, time_limit=300.0)
    assert plan_study.plan_time_limit(sc) == 300.0
    assert plan_study.plan_time_limit(_scenario(tmp_path, paper_plans=True)) is None
    code, _, err = run_study("planning", "--time-limit", "0", "--out", tmp_path)
    assert code == 2 and "time" in err and err.count("\n") == 1

    # the cars' odometry likewise: wheel odometry that drifts unless the true pose is asked for
    seen.clear()
    patch_everywhere("topodrake.montecarlo.run_trials", lambda job, seeds, *, jobs, scenario, **kw:
                        seen.append(plan_study.navigation_config(scenario)) or run_trials(
                            job, seeds, jobs=jobs, scenario=scenario, **kw))
    doc = planning(_scenario(tmp_path, world="test-0", methods=["lidar"], pruned_fractions=[]),
                   "python studies/planning.py", quiet=True)
    assert doc["scenario"]["odometry"] == "wheel" and not seen[0].odometry.is_perfect
    doc = planning(_scenario(tmp_path, world="test-0", methods=["lidar"], pruned_fractions=[],
                             odometry="perfect"), "python studies/planning.py", quiet=True)
    assert doc["scenario"]["odometry"] == "perfect" and seen[1].odometry.is_perfect
    with pytest.raises(TopodrakeError, match="odometry must be one of wheel, perfect"):
        _scenario(tmp_path, odometry="gps").validate()
    code, _, err = run_study("planning", "--odometry", "gps", "--out", tmp_path)
    assert code == 2 and "--odometry" in err


def test_a_map_written_before_a_setting_it_reads_is_not_the_default_map():
    from topodrake.topomap.graph import LATER_DEFAULTS, MapConfig, same_config

    stored = {k: v for k, v in MapConfig().flat().items() if k not in LATER_DEFAULTS}
    stored["reuse_ahead"] = 0
    assert not same_config(stored, MapConfig())                 # scan_match reads as 0 (off)
    assert not same_config(stored, MapConfig(), lidar=False)    # camera_scans as off
    # written with every later setting it reads at today's default, a map is the default map;
    # a lidar map ignores the camera-only ones
    today = {k: MapConfig().flat()[k] for k in LATER_DEFAULTS}
    camera = {**stored, **today}
    assert same_config(camera, MapConfig(), lidar=False)
    other_legs = {**camera, "camera_legs": not MapConfig().camera.legs}
    assert same_config(other_legs, MapConfig())
    assert not same_config(other_legs, MapConfig(), lidar=False)
    assert not same_config({**camera, "p_join": 0.5}, MapConfig(), lidar=False)
    assert not same_config(None, MapConfig(), lidar=False)
    # a pose oracle map keeps no scans: a setting only maps with scans read leaves it alike
    before_cross_legs = {**camera, "cross_legs": False}
    assert not same_config(before_cross_legs, MapConfig(), lidar=False)
    assert same_config(before_cross_legs, MapConfig(), lidar=False, scans=False)


def test_maps_of_other_settings_are_cached_under_names_of_their_own(tmp_path):
    from topodrake.experiments.map_cache import config_tag, map_path
    from topodrake.topomap.graph import MapConfig

    assert config_tag("all", None) == config_tag("all", MapConfig()) == "all"
    off = config_tag("all", MapConfig(scan_match=0.0))
    assert off.startswith("all-cfg") and off == config_tag("all", MapConfig(scan_match=0.0))
    assert off != config_tag("all", MapConfig(scan_match=0.5))
    assert off == "all-cfg90c04386"                 # as before the settings were grouped
    assert map_path(tmp_path, "test-0", "lidar", off) != map_path(tmp_path, "test-0", "lidar", "all")
    # a camera map reads no lidar-only setting, a lidar map no camera-only one: each keeps
    # its name and its file
    uncapped = MapConfig().updated(max_hop_m=0.0)
    assert config_tag("all", uncapped, "camera") == "all"
    assert config_tag("all", uncapped.updated(p_join=0.5), "camera") == \
        config_tag("all", MapConfig().updated(p_join=0.5), "camera") != "all"
    flipped = MapConfig().updated(camera_scans=not MapConfig().camera.scans)
    assert config_tag("all", flipped, "lidar") == "all"
    assert config_tag("all", flipped, "camera") != "all"
    assert config_tag("all", MapConfig(scan_match=0.0), "camera") != "all"   # camera reads it too
    assert config_tag("all", MapConfig(scan_match=0.0), "lidar_reg") == off
    # settings only planning reads share the default map's file
    assert config_tag("all", MapConfig().updated(direct_check=False, switch_p=1.0)) == "all"
    (tmp_path / "bad.yaml").write_text("scan_match: 2\n")
    code, _, err = run_study("planning", "--map-config", str(tmp_path / "bad.yaml"), "--out",
                             tmp_path)
    assert code == 2 and "scan_match must be in [0, 1)" in err and err.count("\n") == 1


def test_the_lidar_scale_follower_drives_the_scale_c_wp_with_the_lidar_re():
    """``lidar_scale`` follows the lidar map with the C_WP trained at scale,
    its hops rated by the RE of the lidar k5 C_WP the map was built for."""
    from topodrake.experiments.plan_methods import networks
    from topodrake.topomap.sources import shipped_checkpoint

    cwp, reach = networks("lidar_scale")
    base_cwp, base_reach = networks("lidar")
    assert cwp.observation == base_cwp.observation == "lidar"
    assert cwp is not base_cwp and reach is not base_reach
    scale_params = sum(p.numel() for p in cwp.model.parameters())
    assert scale_params != sum(p.numel() for p in base_cwp.model.parameters())
    assert str(shipped_checkpoint("lidar_k5_scale")).endswith("lidar_k5_scale/checkpoint.pt")


def test_ours_scale_drives_the_camera_c_wp_at_scale_on_the_camera_map():
    """``ours_scale`` keeps ``ours``' camera map and RE and swaps in the camera
    C_WP trained at scale; its plan calibration ships beside that C_WP."""
    import torch

    from topodrake.experiments.plan_methods import (
        METHODS,
        networks,
        plan_calibration_path,
    )

    assert METHODS["ours_scale"].map == METHODS["ours"].map == "camera"
    cwp, reach = networks("camera_scale")
    base_cwp, base_reach = networks("camera")
    assert cwp.observation == base_cwp.observation == "camera"
    same = all(torch.equal(a, b) for a, b in zip(reach.model.state_dict().values(),
                                                  base_reach.model.state_dict().values()))
    differ = any(not torch.equal(a, b) for a, b in zip(cwp.model.state_dict().values(),
                                                        base_cwp.model.state_dict().values()))
    assert same and differ
    assert plan_calibration_path("ours_scale").parent.name == "camera_k5_scale"


def test_rescore_sets_the_shipped_calibration_against_recorded_trials(tmp_path):
    """``--rescore`` runs no trial: it reads recorded trials, attaches the
    shipped calibration's chance (lidar has one) and writes the table and
    figure; a trial recorded twice is refused in one line."""
    import json

    from topodrake.errors import TopodrakeError
    from topodrake.experiments.plan_methods import plan_calibration_of
    from topodrake.experiments.plan_results import rescore

    rng = np.random.default_rng(0)
    recs = [{"house": "test-0", "method": m, "map": "all", "trial": t, "planned": True,
             "plan_probability": float(rng.uniform(0.8, 1.0)), "plan_anchors": int(rng.integers(5, 30)),
             "success": bool(rng.random() < 0.3)} for m in ("lidar", "oracle_full") for t in range(40)]
    src = tmp_path / "planning.json"
    src.write_text(json.dumps({"command": "python studies/planning.py", "trials": recs}))
    out = tmp_path / "out"
    code, stdout, err = run_study("planning", "--rescore", src, "--out", out, "--json")
    assert code == 0, err
    summary = json.loads(stdout)
    table = json.loads((out / "plan_calibration.json").read_text())["calibration"]
    lidar = [r for r in recs if r["method"] == "lidar"]
    want = plan_calibration_of("lidar").predict([r["plan_probability"] for r in lidar],
                                               [r["plan_anchors"] for r in lidar])
    assert table["lidar"]["calibrated"] and not table["oracle_full"]["calibrated"]
    assert summary["plan_probability_ece_by_method"]["lidar"] == pytest.approx(
        calibration(np.round(want, 5), [r["success"] for r in lidar])[1], abs=1e-4)
    assert summary["planned_trials"] == {"lidar": 40, "oracle_full": 40}
    assert (out / "plan_calibration.png").stat().st_size > 10_000
    with pytest.raises(TopodrakeError, match="recorded twice"):
        rescore(f"{src},{src}", "python studies/planning.py")


def test_experience_rounds_plan_each_round_with_the_drives_before_folded_in(monkeypatch,
                                                                          patch_everywhere):
    """A method's trials in rounds: round r is planned with the passed and
    failed edges of rounds < r, and the records keep each trial's round."""
    from types import SimpleNamespace

    from topodrake.experiments import plan_study
    from topodrake.experiments.plan_scenario import PlanningScenario
    from topodrake.experiments.plan_trials import FollowResult

    class Planned:
        def __init__(self, vertices):
            self.vertices = np.array(vertices)
            self.poses = np.zeros((len(vertices), 3))

        def __len__(self):
            return len(self.vertices)

    seen, given, timed = [], [], []

    def plan_routes(method, spec, world, drives, indices, starts, places, goals, sc, tag,
                    experience=None, limits=None, progress=False):
        seen.append(None if experience is None else (list(experience[0]), list(experience[1])))
        given.append(list(limits))
        routes = [Planned([1, 2, 3]) for _ in starts]
        return routes, np.full(len(starts), 0.9), {"vertices": 3, "edges": 2}, None, \
            [{"false_link_m": 0.0}] * len(starts)

    def follow_routes(engine, starts, routes, goals, *a, **k):
        n = len(starts)
        # every car passes 1 -> 2 and fails on 2 -> 3
        return FollowResult(["dead_reckoning_gave_up"] * n, np.ones(n), np.zeros(n, bool),
                            np.full(n, 10), visited=np.ones(n, np.int64),
                            active=np.full(n, 2, np.int64))

    def trial_time_limits(sc, world, starts, goals):      # each trial's A* is done once
        timed.append(len(starts))
        return np.arange(len(starts)) + 100.0

    monkeypatch.setattr(plan_study, "plan_routes", plan_routes)
    monkeypatch.setattr(plan_study, "trial_time_limits", trial_time_limits)
    patch_everywhere("topodrake.experiments.plan_trials.follow_routes", follow_routes)
    monkeypatch.setattr(plan_study, "networks", lambda *a: (None, None))
    patch_everywhere("topodrake.navigation.engine.NavigationEngine",
                        lambda *a, **k: SimpleNamespace())
    world = SimpleNamespace(places=np.zeros((3, 3)))
    pairs = np.array([[0, 1], [1, 2], [2, 0], [0, 2]])
    sc = PlanningScenario(experience_rounds=2, batch=4, data="unused")
    stats, records = plan_study.run_method("lidar", "test-0", world, [], [], pairs,
                                           np.zeros((4, 3)), sc)
    assert seen == [None, ([(1, 2), (1, 2)], [(2, 3), (2, 3)])]
    assert timed == [4] and given == [[100.0, 101.0], [102.0, 103.0]]
    assert [r["time_limit_s"] for r in records] == [100.0, 101.0, 102.0, 103.0]
    assert [r["round"] for r in records] == [0, 0, 1, 1]
    assert all(r["plan_vertices"] == [1, 2, 3] and r["visited"] == 1 for r in records)
    assert stats["trials"] == 4 and stats["success"] == 0.0
    assert plan_study.success_by_round(records) == {"lidar": [0.0, 0.0]}
    # replanning and SPTM run as built; rounds below 1 are refused
    assert plan_study.experience_rounds("ours_replan", sc) == 1
    assert plan_study.experience_rounds("sptm", sc) == 1
    with pytest.raises(ValueError, match=">= 1"):
        plan_study.experience_rounds("lidar", PlanningScenario(experience_rounds=0))
    assert plan_study.round_bounds(10, 3).tolist() == [0, 3, 7, 10]


def test_the_lidar_ablations_swap_one_network_for_its_oracle():
    from topodrake.experiments.plan_methods import networks
    from topodrake.learning.waypoint.policy import AStarOracle
    from topodrake.navigation.evaluate import GeometricReachability
    from topodrake.world import load_world

    world = load_world("test-0")
    scale_cwp, scale_re = networks("lidar_scale")
    cwp, re = networks("lidar_scale_oracle_re", world)
    assert cwp is scale_cwp and isinstance(re, GeometricReachability)
    reg_cwp, reg_re = networks("lidar_reg")
    cwp, re = networks("lidar_reg_oracle_re", world)
    assert cwp is reg_cwp and isinstance(re, GeometricReachability) and re is not reg_re
    cwp, re = networks("oracle_cwp_lidar", world)
    assert isinstance(cwp, AStarOracle) and re is networks("lidar")[1]
    assert re.observation == "lidar"


def _recorded(path, method, successes):
    import json

    trials = [{"house": h, "method": method, "map": "all", "trial": t, "success": ok}
              for h, row in successes.items() for t, ok in enumerate(row)]
    path.write_text(json.dumps({"command": "test", "trials": trials}))
    return str(path)


def test_paired_runs_compare_the_same_trials_within_houses(tmp_path):
    from topodrake.errors import TopodrakeError
    from topodrake.experiments.plan_results import paired_runs

    before = _recorded(tmp_path / "a.json", "lidar", {"h0": [0] * 40, "h1": [1] * 20 + [0] * 20})
    after = _recorded(tmp_path / "b.json", "lidar", {"h0": [1] * 30 + [0] * 10,
                                                     "h1": [1] * 20 + [0] * 20})
    got = paired_runs(f"{before},{after}")["lidar"]
    assert got["houses"] == {"h0": [0.0, 0.75], "h1": [0.5, 0.5]}
    assert got["difference"]["mean"] == 0.375 and got["difference"]["pairs"] == 80
    lo, hi = got["difference"]["ci95"]
    assert 0.2 < lo < 0.375 < hi < 0.55
    # two methods by name, from the one file
    other = _recorded(tmp_path / "c.json", "lidar_scale", {"h0": [0] * 40, "h1": [0] * 40})
    named = paired_runs(f"{before}:lidar,{other}:lidar_scale")
    assert list(named) == ["lidar -> lidar_scale"]
    assert named["lidar -> lidar_scale"]["difference"]["mean"] == -0.25
    with pytest.raises(TopodrakeError, match="has no trials of ours"):
        paired_runs(f"{before}:ours,{after}")
    with pytest.raises(TopodrakeError, match="BEFORE.json"):
        paired_runs(before)


def test_paired_difference_resamples_within_strata():
    from topodrake.montecarlo import paired_difference

    same = paired_difference(np.zeros(50), np.zeros(50))
    assert same == {"mean": 0.0, "ci95": [0.0, 0.0], "pairs": 50}
    # one house all gained, one all lost: within houses nothing varies, so no spread
    strata = np.repeat(["a", "b"], 30)
    split = paired_difference(np.r_[np.zeros(30), np.ones(30)], np.r_[np.ones(30), np.zeros(30)],
                              strata)
    assert split["mean"] == 0.0 and split["ci95"] == [0.0, 0.0]
    pooled = paired_difference(np.r_[np.zeros(30), np.ones(30)], np.r_[np.ones(30), np.zeros(30)])
    assert pooled["ci95"][0] < -0.1 and pooled["ci95"][1] > 0.1
    with pytest.raises(ValueError):
        paired_difference([], [])


def test_a_cached_map_plans_with_the_callers_planning_settings(tmp_path, monkeypatch):
    """A map cached under one config is reused for a config that differs only
    in planning settings, and plans with the caller's."""
    from types import SimpleNamespace

    from topodrake.experiments import map_cache
    from topodrake.topomap.graph import MapConfig
    from topodrake.world import load_world

    world = load_world("test-0")
    drive = SimpleNamespace(poses=np.array([[1.0, 1.0, 0.0], [1.3, 1.0, 0.0], [1.6, 1.0, 0.0]]))
    monkeypatch.setattr(map_cache, "DEMO_SEED", 0)
    built, _ = map_cache.get_map("test-0", world, "oracle", [drive], [0], tmp_path, "all", False,
                                 MapConfig().updated(direct_check=True))
    again, build_s = map_cache.get_map("test-0", world, "oracle", [drive], [0], tmp_path, "all",
                                       False, MapConfig().updated(direct_check=False, switch_p=1.0))
    assert build_s == 0.0 and len(again) == len(built)
    assert not again.config.links.direct_check and again.config.plan.switch_p == 1.0


def test_a_cached_map_of_another_re_is_rebuilt_not_refused(tmp_path, monkeypatch, capsys,
                                                            patch_everywhere):
    """A checkpoint retrained under the same path makes its cached maps
    stale: the cache builds the map again for the RE it is given."""
    from types import SimpleNamespace

    from topodrake.experiments import map_cache
    from topodrake.topomap import sources
    from topodrake.world import load_world

    world = load_world("test-0")
    drive = SimpleNamespace(poses=np.array([[1.0, 1.0, 0.0], [1.3, 1.0, 0.0], [1.6, 1.0, 0.0]]))
    monkeypatch.setattr(map_cache, "DEMO_SEED", 0)
    built, first_s = map_cache.get_map("test-0", world, "oracle", [drive], [0], tmp_path, "all",
                                       False)
    assert first_s > 0.0
    make = sources.make_scorer

    def retrained(modality, w):
        scorer = make(modality, w)
        scorer.identity = {**scorer.identity, "retrained": True}
        return scorer

    patch_everywhere("topodrake.topomap.sources.make_scorer", retrained)
    capsys.readouterr()
    again, build_s = map_cache.get_map("test-0", world, "oracle", [drive], [0], tmp_path, "all",
                                       False)
    assert build_s > 0.0 and "rebuilding it" in capsys.readouterr().err
    assert again.identity.get("retrained") is True
    _, cached_s = map_cache.get_map("test-0", world, "oracle", [drive], [0], tmp_path, "all", False)
    assert cached_s == 0.0                          # the rebuilt map is reused


@pytest.mark.parametrize("modality", ["camera", "oracle"])
def test_a_map_keeps_its_drives_lidar_scans_and_one_cached_without_is_rebuilt(
        tmp_path, monkeypatch, modality):
    """A camera or pose oracle map built for a study keeps each kept frame's
    lidar scan as the drive's lidar took it (the route tracker's scan fixes;
    a route planned on it carries them); a cached map without scans is
    built again rather than planned without scan fixes."""
    from types import SimpleNamespace

    from topodrake.experiments import map_cache
    from topodrake.sensing.lidar import Lidar
    from topodrake.topomap.mapfile import save_map
    from topodrake.topomap.plan import plan_path
    from topodrake.world import load_world

    world = load_world("test-0")
    drive = SimpleNamespace(poses=np.array([[1.0, 1.0, 0.0], [1.3, 1.0, 0.0], [1.6, 1.0, 0.0]]))
    monkeypatch.setattr(map_cache, "DEMO_SEED", 0)
    built, _ = map_cache.get_map("test-0", world, modality, [drive], [0], tmp_path, "all", False)
    np.testing.assert_allclose(built.bank.scans, Lidar(world).scan(built.bank.poses))
    if modality == "oracle":
        poses = built.bank.poses
        goal = poses[-1] + [0.1, 0.05, 0.1]
        route = plan_path(built, poses[0], goal, start_pose=poses[0], goal_pose=goal).route
        assert route.scans is not None and np.isfinite(route.scans[:-1]).all()
        # every hop carries a leg, the goal link one from the poses the oracle observes
        from topodrake.se2 import relative

        assert np.isfinite(route.legs).all()
        np.testing.assert_allclose(route.legs[-1], relative(route.poses[-2], goal)[0], atol=1e-9)
    path = next(tmp_path.rglob("*.tdmap"))
    built.bank._scans = type(built.bank._scans)()             # as written before scans were kept
    save_map(built, path)
    again, build_s = map_cache.get_map("test-0", world, modality, [drive], [0], tmp_path, "all",
                                       False)
    assert build_s > 0 and again.bank.scans is not None


def test_the_registration_follower_asks_its_tracked_re_and_its_maps_keep_the_cold_one():
    from topodrake.experiments.plan_methods import FOLLOWER_REACH, networks
    from topodrake.topomap.sources import SHIPPED

    policy, reach = networks("lidar_reg")
    assert reach.name == FOLLOWER_REACH["lidar_reg"] == "reach_lidar_reg_tracked"
    assert SHIPPED["lidar_reg"][0] == "reach_lidar_reg"        # what its maps are built with
    assert networks("lidar")[1].name == SHIPPED["lidar"][0]    # the others ask their maps' RE


def test_each_trial_draws_its_own_odometry_errors_from_the_seed_and_house():
    from topodrake.experiments import plan_study
    from topodrake.experiments.plan_scenario import PlanningScenario as Sc
    from topodrake.odometry import OdometryConfig, odometry_errors

    a = plan_study.odometry_seeds(Sc(seed=0), "test-0", 5)
    assert a == plan_study.odometry_seeds(Sc(seed=0), "test-0", 5)          # repeatable
    assert a[:3] == plan_study.odometry_seeds(Sc(seed=0), "test-0", 3)      # a prefix
    assert len(set(a)) == 5
    assert plan_study.odometry_seeds(Sc(seed=0), "test-1", 5) != a
    assert plan_study.odometry_seeds(Sc(seed=1), "test-0", 5) != a
    errors = odometry_errors(OdometryConfig.wheel(), a)
    assert errors.shape == (5, 3) and len(np.unique(errors[:, 0])) == 5


def test_route_time_gives_each_trial_the_time_its_a_star_length_needs(box_world, tmp_path):
    """--route-time: the longer of the study's limit and A* length / 0.25 m/s per trial;
    without it every trial gets the study's limit."""
    from topodrake.experiments import plan_study
    from topodrake.experiments.plan_scenario import PlanningScenario as Sc
    from topodrake.experiments.plan_trials import T_MAX_S

    starts = np.array([[1.5, 2.0, 0.0], [1.5, 2.0, 0.0]])
    goals = np.array([[2.5, 2.0, 0.0], [7.5, 2.0, 0.0]])   # 1 m apart; around the partition
    fixed = plan_study.trial_time_limits(Sc(time_limit=10.0), box_world, starts, goals)
    assert fixed.tolist() == [10.0, 10.0]
    assert plan_study.trial_time_limits(Sc(), box_world, starts, goals).tolist() == [T_MAX_S] * 2
    route = plan_study.trial_time_limits(Sc(time_limit=10.0, time_rule="route"), box_world,
                                         starts, goals)
    length = np.hypot(*np.diff(box_world.astar(starts[1], goals[1, :2]), axis=0).T).sum()
    assert length > 12.0                                     # the way round the partition
    assert route[0] == 10.0                                  # 1 m needs 4 s: the limit holds
    assert route[1] == pytest.approx(length / 0.25, abs=0.11)
    # a run of route times has no one limit to fit the driving time against
    from topodrake.experiments.plan_timing import driving_time_fit

    run = tmp_path / "planning.json"
    run.write_text(json.dumps({"config": {"route_time": True, "t_max_s": 150.0}, "houses": {},
                               "trials": []}))
    with pytest.raises(TopodrakeError, match="--route-time"):
        driving_time_fit(str(run), "cmd")


def test_a_building_s_trials_get_their_route_time_and_the_houses_a_fixed_limit(tmp_path):
    """The time rule's default follows what is run: the test houses keep one
    limit, one --world building gives each trial its A* length's time; an
    explicit rule wins and a contradiction is named."""
    houses = _scenario(tmp_path, pruned_fractions=None)
    world = _scenario(tmp_path, world="test-0", methods=["lidar"], pruned_fractions=None)
    assert houses.resolved().time_rule == "fixed" and world.resolved().time_rule == "route"
    assert not houses.route_time and world.route_time
    assert _scenario(tmp_path, world="test-0", time_rule="fixed").resolved().time_rule == "fixed"
    assert houses.resolved().pruned_fractions == [0.3, 0.6, 1.0]
    assert houses.resolved().pruned_house == "test-0"
    assert world.resolved().pruned_fractions == [] and world.resolved().houses == []
    code, _, err = run_study("planning", "--route-time", "--time-rule", "fixed", "--out", tmp_path)
    assert code == 2 and "contradict" in err



def test_several_buildings_run_as_one_study_with_a_pooled_block(tmp_path):
    """``--worlds FOLDER`` takes every */map.yaml under it, timed by route
    and without pruned maps; the summary pools each method's trials over
    the buildings (each trial once, no_room left out)."""
    import yaml

    from topodrake.experiments import plan_trials as pt

    for name in ("b_two", "a_one"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "map.yaml").write_text("image: map.pgm\n")
    code, out, err = run_study("planning", "--worlds", tmp_path, "--methods", "oracle_full",
                               "--print-config")
    assert code == 0, err
    sc = yaml.safe_load(out)
    assert sc["houses"] == [str(tmp_path / "a_one" / "map.yaml"), str(tmp_path / "b_two" / "map.yaml")]
    assert sc["world"] is None and sc["time_rule"] == "route" and sc["pruned_fractions"] == []
    code, _, err = run_study("planning", "--worlds", tmp_path, "--houses", "test-0")
    assert code == 2 and "not two of them" in err
    (tmp_path / "empty").mkdir()
    code, _, err = run_study("planning", "--worlds", tmp_path / "empty")
    assert code == 2 and "no */map.yaml" in err

    def rec(house, trial, success, link=None, outcome="goal"):
        return {"house": house, "method": "m", "trial": trial, "success": success,
                "outcome": outcome, "planned": link is not None, "false_link_m": link,
                "plan_probability": 0.8 if link is not None else 0.0}

    refused = {**rec("b", 2, False, None), "uncovered": "goal"}
    houses = {"a": {"methods": {"m": {"success": 1.0}}, "records": [rec("a", 0, True, 0.0)]},
              "b": {"methods": {"m": {"success": 0.33}},
                    "records": [rec("b", 0, False, 6.0), rec("b", 1, True, 0.0),
                                refused, rec("b", 3, False, 0.0, "no_room")]}}
    s = pt.summarize(houses, None, None)
    # three plans at 0.8, two of them succeeded: ECE |0.8 - 2/3|
    assert s["pooled"]["m"] == {"trials": 4, "success": 0.5, "false_link_plans": round(1 / 3, 4),
                                "uncovered": 0.25, "plan_probability_ece": round(0.8 - 2 / 3, 4)}
    assert s["by_house"]["b"]["m"]["trials"] == 3 and s["by_house"]["a"]["m"]["success"] == 1.0
    assert s["by_house"]["a"]["m"]["plan_probability_ece"] == round(0.2, 4)
    assert pt.summarize({"a": houses["a"]}, None, None)["pooled"] is None
