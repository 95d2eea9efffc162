"""map refit: a planning study's recorded drives folded into a map's edges."""

import json

import pytest

from cli_run import one_line, run
from topodrake.topomap.mapfile import load_map
from topodrake.topomap.recalibrate import edge_posterior
from topodrake.topomap.sources import make_scorer


@pytest.fixture
def reg_map(small_map):
    return small_map("lidar_reg")


def _trial(t, chain, visited, success, outcome, house="test-0", method="lidar_reg"):
    return {"house": house, "method": method, "trial": t, "planned": True,
            "plan_probability": 0.9, "plan_anchors": len(chain), "plan_vertices": chain,
            "visited": visited, "active": visited + 1, "success": success, "outcome": outcome}


def test_refit_folds_passed_and_failed_hops_into_the_edges(capsys, tmp_path, reg_map):
    m = load_map(reg_map, make_scorer("lidar_reg"))
    chain = [int(v) for v in m.trajectories[0].chain[:6]]
    study = tmp_path / "planning.json"
    study.write_text(json.dumps({"command": "c", "trials": [
        _trial(0, chain, 5, True, "goal"),                       # passes all five hops
        _trial(1, chain, 2, False, "dead_reckoning_gave_up"),    # passes two, fails the third
        _trial(2, chain, 3, False, "timeout"),                   # passes three, blames none
        _trial(3, chain, 0, False, "collision", method="lidar")]}))   # another method
    out = tmp_path / "refit.tdmap"
    code, text, _ = run(capsys, "map", "refit", reg_map, study, "--method", "lidar_reg",
                        "--out", out, "--json")
    summary = json.loads(text)
    assert code == 0 and summary["trials"] == 3 and summary["edges_driven"] == 5
    assert summary["passes"] == 5 + 2 + 3 and summary["failures"] == 1
    back = load_map(out, make_scorer("lidar_reg"))
    hop = back.graph.edges[chain[2], chain[3]]
    assert (hop["passed"], hop["failed"]) == (2, 1)
    assert hop["p"] == pytest.approx(float(edge_posterior(m.graph.edges[chain[2], chain[3]]["p"],
                                                          2, 1)))
    assert back.graph.edges[chain[0], chain[1]]["passed"] == 3


def test_refit_refuses_records_of_another_map_house_or_age(capsys, tmp_path, reg_map):
    study = tmp_path / "planning.json"
    out = tmp_path / "never.tdmap"
    study.write_text(json.dumps({"trials": [_trial(0, [10_000, 10_001], 1, True, "goal")]}))
    code, _, err = run(capsys, "map", "refit", reg_map, study, "--method", "lidar_reg",
                       "--out", out)
    one_line(code, err, "planned on another map")
    study.write_text(json.dumps({"trials": [_trial(0, [1, 2], 1, True, "goal",
                                                   house="test-1")]}))
    code, _, err = run(capsys, "map", "refit", reg_map, study, "--method", "lidar_reg",
                       "--out", out)
    one_line(code, err, "no trials of lidar_reg in test-0")
    old = _trial(0, [1, 2], 1, True, "goal")
    del old["plan_vertices"]
    study.write_text(json.dumps({"trials": [old]}))
    code, _, err = run(capsys, "map", "refit", reg_map, study, "--method", "lidar_reg",
                       "--out", out)
    one_line(code, err, "recorded before")
    assert not out.exists()
