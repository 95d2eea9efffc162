"""Traces of single planning trials: the same trial the study drives, timed mode by mode."""

from __future__ import annotations

import json

import numpy as np
import pytest

from topodrake.errors import TopodrakeError


@pytest.fixture(scope="module")
def placed_box():
    """The box world with two places, and an oracle map of the expert's drives between them."""
    from topodrake.rollout import ExpertRollout, RolloutConfig
    from topodrake.topomap.build import build_map
    from topodrake.topomap.graph import TopoMap
    from topodrake.topomap.retrieval import default_embedding
    from topodrake.topomap.scorer import OracleScorer
    from topodrake.world.walls import WallSet
    from topodrake.world.world import world_from_walls

    places = np.array([[1.5, 2.0, np.pi / 2], [7.5, 2.0, -np.pi / 2]])
    boxes = np.array([[0, 0, 10, 0.2], [0, 9.8, 10, 10], [0, 0, 0.2, 10],
                      [9.8, 0, 10, 10], [4.9, 0, 5.1, 6]], dtype=float)
    world = world_from_walls("placed-box", WallSet.from_boxes(boxes, np.arange(5)),
                             places=places)
    res = ExpertRollout(world, RolloutConfig(t_max_s=60.0)).run(places[[0, 1]], places[[1, 0], :2])
    assert res.success.all()
    m = TopoMap(OracleScorer(world), default_embedding("pose"), world="placed-box")
    build_map(m, [(res.trajectory(i)["poses"], res.trajectory(i)["poses"], f"d{i}")
                  for i in range(2)], progress=False)
    return world, m


def _stub_house(monkeypatch, world, topomap):
    """The planning study's house and plans, in the placed box world."""
    from topodrake.experiments import plan_study, plan_trace
    from topodrake.topomap.plan import plan_path

    def house(seed, jobs, sc, quiet=True):
        return jobs[seed], world, [], 0

    def plan_routes(method, spec, w, drives, indices, starts, places, goals, sc, tag,
                    limits=None, progress=False):
        plans = [plan_path(topomap, starts[t], places[g], start_pose=starts[t],
                           goal_pose=places[g]) for t, g in enumerate(goals)]
        return ([p.route if p.reachable else None for p in plans],
                np.array([p.probability if p.reachable else 0.0 for p in plans]), {}, None,
                [None] * len(plans))
    for module in (plan_study, plan_trace):      # each holds its own import of them
        monkeypatch.setattr(module, "_house", house)
        monkeypatch.setattr(module, "plan_routes", plan_routes)
    return plan_routes


def test_a_trace_drives_the_study_s_trial_and_times_its_modes(placed_box, monkeypatch, tmp_path):
    from topodrake.experiments import plan_study
    from topodrake.navigation.follower import MODES
    from topodrake.experiments.plan_scenario import PlanningScenario
    from topodrake.experiments.plan_trace import plot_trace, trace_trials
    from topodrake.experiments.plan_trials import jittered_starts, trial_pairs

    world, topomap = placed_box
    _stub_house(monkeypatch, world, topomap)
    sc = PlanningScenario(seed=0, data=str(tmp_path), odometry="wheel", time_limit=60.0)
    traces = trace_trials("placed-box", "oracle_full", [2, 0], sc)
    assert [t.trial for t in traces] == [2, 0]

    # the study's own trials: its pairs and jittered starts for this house's seed
    seed = plan_study.house_seed(0, "placed-box")
    pairs = trial_pairs(2, 3, seed)
    starts = jittered_starts(world, world.places, pairs, seed)
    for t in traces:
        assert (t.start_place, t.goal_place) == tuple(pairs[t.trial])
        np.testing.assert_allclose(t.poses[0], starts[t.trial])
        assert t.success and t.outcome in ("goal", "reached")
        assert t.final_distance_m <= 0.54
        assert len(t.poses) == len(t.modes) + 1 == len(t.active) + 1
        segs = t.segments()
        # the spans cover the run end to end, each one mode, and change mode between them
        assert segs[0]["from_s"] == 0.0
        assert segs[-1]["to_s"] == pytest.approx(len(t.modes) * t.dt)
        assert all(a["to_s"] == b["from_s"] for a, b in zip(segs, segs[1:]))
        assert all(a["mode"] != b["mode"] for a, b in zip(segs, segs[1:]))
        assert {s["mode"] for s in segs} <= set(MODES) and "follow" in {s["mode"] for s in segs}
        np.testing.assert_allclose(segs[-1]["end_pose"], t.poses[-1], atol=1e-3)
        doc = t.to_json()
        assert json.loads(json.dumps(doc))["segments"] == json.loads(json.dumps(segs))
        assert len(doc["route_poses"]) == len(doc["plan_vertices"]) > 0
    plot_trace(world, traces[0], tmp_path / "trace.png")
    assert (tmp_path / "trace.png").stat().st_size > 0


def test_a_trace_refuses_what_it_cannot_drive_in_one_line(placed_box, monkeypatch, tmp_path):
    from topodrake.experiments.plan_scenario import PlanningScenario
    from topodrake.experiments.plan_trace import trace_trials

    sc = PlanningScenario(seed=0, data=str(tmp_path))
    with pytest.raises(TopodrakeError, match="unknown method 'nope'"):
        trace_trials("placed-box", "nope", [0], sc)
    with pytest.raises(TopodrakeError, match="'ours_replan' is not traced"):
        trace_trials("placed-box", "ours_replan", [0], sc)
    with pytest.raises(TopodrakeError, match="'sptm' is not traced"):
        trace_trials("placed-box", "sptm", [0], sc)


def test_the_study_traces_one_method_in_one_house(placed_box, monkeypatch, tmp_path, capsys, patch_everywhere):
    import importlib.util
    from pathlib import Path

    world, topomap = placed_box
    _stub_house(monkeypatch, world, topomap)
    patch_everywhere("topodrake.world.load_world", lambda spec: world)
    spec = importlib.util.spec_from_file_location(
        "planning_study", Path(__file__).parents[1] / "studies" / "planning.py")
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    code = study.main(["--world", "placed-box", "--methods", "oracle_full", "--trace", "1",
                       "--time-limit", "60", "--out", str(tmp_path), "--quiet"])
    assert code == 0
    printed = capsys.readouterr().out
    assert printed.startswith("trial 1: place ") and " follow " in printed
    doc = json.loads((tmp_path / "trace.json").read_text())
    assert [t["trial"] for t in doc["traces"]] == [1] and doc["scenario"]["time_limit"] == 60.0
    assert (tmp_path / "trace-1.png").exists()
    # two methods, or a bad trial list, are refused in one line
    assert study.main(["--world", "placed-box", "--methods", "oracle_full,lidar", "--trace", "1",
                       "--out", str(tmp_path), "--quiet"]) == 2
    assert "--trace needs one house" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        study.main(["--world", "placed-box", "--methods", "oracle_full", "--trace", "1,x"])
