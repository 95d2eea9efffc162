"""What a drive or a plan reports: one set of outcome names judged by the
studies' success rule, the exit status, the distance to the goal and one
count of anchors."""

import json

import pytest

from topodrake.apps.cli import main
from topodrake.navigation.outcomes import (
    EXIT_FAILED,
    SUCCESS_M,
    drive_outcome,
    exit_status,
    judge_outcome,
)


@pytest.fixture
def oracle_map(small_map):
    """A small oracle map of test-0 (the drives between places 4 and 9)."""
    return small_map("oracle")


def test_the_success_rule_is_the_studies():
    assert judge_outcome("reached", SUCCESS_M) == "reached"
    assert judge_outcome("reached", SUCCESS_M + 0.01) == "false_reached"
    assert judge_outcome("timeout", 0.1) == "timeout"
    assert drive_outcome("success", 0.2) == "reached"          # the expert's name
    assert drive_outcome("reached", 0.798) == "false_reached"
    assert exit_status("reached") == 0
    for outcome in ("false_reached", "collision", "timeout", "search_failed",
                    "dead_reckoning_gave_up"):
        assert exit_status(outcome) == EXIT_FAILED == 3


def test_drive_exits_3_when_the_expert_does_not_arrive(capsys, tmp_path):
    sc = tmp_path / "s.yaml"
    sc.write_text("world: test-0\nstart_place: 0\ngoal_place: 5\nt_max_s: 1.0\n"
                  "camera_enabled: false\n")
    code = main(["drive", str(sc)])
    summary = json.loads(capsys.readouterr().out)
    assert code == 3 and summary["outcome"] == "timeout"
    assert summary["distance_to_goal_m"] > SUCCESS_M


def test_map_plan_counts_the_anchors_a_car_follows(capsys, oracle_map):
    from topodrake.world import load_world

    p = load_world("test-0").places
    start, goal = (",".join(f"{v:.4f}" for v in p[i]) for i in (4, 9))
    assert main(["map", "plan", str(oracle_map), "--start", start, "--goal", goal, "--json"]) == 0
    plan = json.loads(capsys.readouterr().out)
    assert plan["reachable"] and plan["anchors"] == len(plan["path"]) + 1
    assert main(["map", "plan", str(oracle_map), "--start", start, "--goal", goal]) == 0
    text = capsys.readouterr().out
    assert text.startswith(f"plan of {plan['anchors']} anchors ({len(plan['path'])} map vertices "
                           f"and the goal)")


def test_bench_map_says_why_and_shows_progress(capsys, oracle_map):
    assert main(["bench", "map", str(oracle_map), "--queries", "4", "--json"]) == 0
    out, err = capsys.readouterr()
    result = json.loads(out)
    assert result["queries"] == 4
    assert sum(result["unreachable_why"].values()) == 4 - result["reachable"]
    assert all("(" not in why for why in result["unreachable_why"])
    assert "bench map: loading" in err and "plan queries" in err
    assert main(["bench", "map", str(oracle_map), "--queries", "2", "--quiet"]) == 0
    assert capsys.readouterr().err == ""
