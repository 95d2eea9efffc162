"""Controller evaluation: pair sampling, the target runner, the study's statistics."""

from __future__ import annotations

import json

import numpy as np
import pytest

from study_run import run_study
from topodrake.errors import TopodrakeError
from topodrake.learning.samples import TrajectorySet
from topodrake.learning.waypoint.evaluation import PairConfig, sample_controller_pair
from topodrake.experiments.success_table import run_block, summarize, wilson


@pytest.fixture(scope="module")
def line_set(box_world):
    """One straight 'expert' trajectory along y = 8 in the box world, 5 cm apart."""
    x = np.arange(1.0, 9.0, 0.05)
    poses = np.column_stack([x, np.full_like(x, 8.0), np.zeros_like(x)])
    states = np.column_stack([poses, np.full_like(x, 0.5), np.zeros_like(x)])
    return TrajectorySet(["box"], np.array([0], np.int32), np.array([0, len(x)]), poses, states)


def test_pairs_follow_the_protocol_and_depend_on_the_seed_only(box_world, line_set):
    from topodrake.sensing.overlap import mutual_overlap

    worlds = {"box": box_world}
    pairs = [sample_controller_pair(line_set, s, worlds) for s in range(40)]
    again = [sample_controller_pair(line_set, s, worlds) for s in range(40)]
    assert pairs == again
    d = np.array([p.distance_m for p in pairs])
    assert d.min() >= -1.0 - 0.05 and d.max() <= 3.0 + 0.05
    assert (d < 0).any() and (d > 1.5).any()          # behind and well ahead both occur
    for p in pairs:
        a, b = line_set.poses[p.source], line_set.poses[p.target]
        assert mutual_overlap(box_world, a[None], b[None])[0].min() > 0.1
        # straight line: the A* length is the distance, so t_max = 10 s + |d| / 0.3
        assert p.t_max_s == pytest.approx(10.0 + abs(p.distance_m) / 0.3, abs=0.5)


def test_pairs_refused_without_room(box_world, line_set):
    short = TrajectorySet(["box"], np.array([0], np.int32), np.array([0, 2]),
                          line_set.poses[:2], line_set.states[:2])
    with pytest.raises(TopodrakeError, match="no controller pair"):
        sample_controller_pair(short, 0, {"box": box_world},
                               PairConfig(min_distance_m=2.0, max_distance_m=3.0, tries=20))


@pytest.fixture(scope="module")
def oracle_runner(box_world):
    from topodrake.learning.waypoint.policy import AStarOracle
    from topodrake.systems.run import TargetRunner
    from topodrake.systems.scenario import Scenario
    from topodrake.systems.waypoint_net import build_waypoint_diagram

    built = build_waypoint_diagram(Scenario(world="box", noise_std=0.33), AStarOracle(box_world),
                                   world=box_world)
    return TargetRunner(built)


def _target(pose, key):
    from topodrake.contract.waypoint import TargetContext

    return TargetContext(key=key, poses=np.asarray([pose], float))


def test_target_runner_reaches_a_target_ahead(oracle_runner):
    start, goal = [1.5, 3.0, 0.0], [4.0, 3.0, 0.0]
    r = oracle_runner.run(start, goal, _target(goal, 1), seed=5, t_max_s=20.0)
    assert r.success and not r.collision
    assert r.reached_by in ("distance", "overlap")
    assert r.distance_to_goal_m < 0.27 or r.overlap.min() > 0.7
    assert r.time_s > 1.0                      # 2.5 m away: not solved at the start
    assert len(r.noise) >= int(r.time_s / 0.1) - 1 and np.abs(r.noise).max() > 0


def test_target_runner_times_out_behind_a_wall(oracle_runner):
    # The target is on the far side of the partition (x in [4.9, 5.1], y < 6):
    # the car cannot get there in 2 s, and no overlap through the wall.
    start, goal = [4.0, 1.0, 0.0], [6.0, 1.0, 0.0]
    r = oracle_runner.run(start, goal, _target(goal, 2), seed=1, t_max_s=2.0)
    assert r.timeout and not r.success and r.reached_by == ""
    assert r.time_s == pytest.approx(2.0)


def test_target_runner_refuses_a_start_in_a_wall(oracle_runner):
    with pytest.raises(TopodrakeError, match="start .* wall"):
        oracle_runner.run([5.0, 3.0, 0.0], [4.0, 3.0, 0.0], _target([4.0, 3.0, 0.0], 3))
    with pytest.raises(TopodrakeError, match="outside the map"):
        oracle_runner.run([4.0, 3.0, 0.0], [40.0, 3.0, 0.0], _target([4.0, 3.0, 0.0], 4))


def test_target_runner_accepts_poses_near_walls(oracle_runner):
    # 0.15 m from the partition face at x = 4.9: inside the c-space margin
    # (0.2 m) but the car's body (sideways to the wall) is clear of it.
    start = [4.75, 3.0, 1.5708]
    r = oracle_runner.run(start, [4.75, 4.0, 1.5708], _target([4.75, 4.0, 1.5708], 5),
                          seed=0, t_max_s=1.0)
    assert not r.collision


def test_wilson_interval_and_summary():
    lo, hi = wilson(95, 100)
    assert lo < 0.95 < hi and hi - lo < 0.12
    lo4, hi4 = wilson(380, 400)
    assert hi4 - lo4 < hi - lo                     # more trials, tighter interval
    assert wilson(0, 10)[0] == 0.0 and wilson(10, 10)[1] == 1.0
    results = ([{"outcome": "success", "time_s": 0.1}] * 2 + [{"outcome": "success", "time_s": 4.0}] * 5
               + [{"outcome": "collision", "time_s": 2.0}] * 2 + [{"outcome": "timeout", "time_s": 9.0}])
    s = summarize(results)
    assert s["success"] == 0.7 and s["collisions"] == 2 and s["timeouts"] == 1
    assert s["immediate_successes"] == 2 and s["success_nontrivial"] == pytest.approx(5 / 8)


def test_study_refuses_a_missing_checkpoint(tmp_path):
    code, _, err = run_study("controller_success", "--controllers", "camera_k5", "--checkpoints",
                             tmp_path, "--trials", "2")
    assert code == 2
    assert "no checkpoint" in err


def test_study_blocks_are_reused_only_for_the_same_settings(tmp_path, monkeypatch, patch_everywhere):
    import topodrake.montecarlo as mc

    calls = []

    def fake_run_trials(fn, seeds, **kw):
        calls.append(kw["noise_std"])
        return [{"outcome": "success", "time_s": 1.0, "seed": s} for s in seeds]

    patch_everywhere("topodrake.montecarlo.run_trials", fake_run_trials)
    args = {"seed": 0, "data": "data", "runs_dir": tmp_path, "workers": 1, "quiet": True}
    first = run_block("oracle", "clean", "oracle", 0.0, [1, 2, 3], **args)
    again = run_block("oracle", "clean", "oracle", 0.0, [1, 2, 3], **args)
    assert first == again and calls == [0.0]
    run_block("oracle", "clean", "oracle", 0.33, [1, 2, 3], **args)     # other noise: rerun
    run_block("oracle", "clean", "oracle", 0.33, [1, 2, 3, 4], **args)  # other trials: rerun
    assert calls == [0.0, 0.33, 0.33]
    ck = tmp_path / "ck.pt"
    ck.write_bytes(b"weights-a")
    run_block("net", "clean", str(ck), 0.0, [1], **args)
    ck.write_bytes(b"weights-b")                                            # retrained: rerun
    run_block("net", "clean", str(ck), 0.0, [1], **args)
    assert len(calls) == 5


def test_target_runner_stops_when_the_target_is_lost(box_world):
    from topodrake.learning.waypoint.policy import AStarOracle
    from topodrake.systems.run import TargetRunner
    from topodrake.systems.scenario import Scenario
    from topodrake.systems.waypoint_net import build_waypoint_diagram

    built = build_waypoint_diagram(Scenario(world="box"), AStarOracle(box_world), world=box_world)
    runner = TargetRunner(built, overlap_lost=0.05)
    # behind the partition and facing away: no overlap at all from the start
    r = runner.run([4.0, 1.0, 3.14], [6.0, 1.0, 0.0], _target([6.0, 1.0, 0.0], 9), t_max_s=20.0)
    assert r.lost and r.outcome == "lost" and not r.timeout and r.time_s < 1.0


def test_study_runs_the_registration_controller_without_a_checkpoint(tmp_path):
    """``lidar_reg`` (the registration C_WP) needs no checkpoint folder; its
    blocks are keyed by the controller's settings and sources."""
    out = tmp_path / "out"
    code, stdout, err = run_study("controller_success", "--controllers", "lidar_reg",
                                  "--checkpoints", tmp_path / "none", "--trials", "3",
                                  "--workers", "1", "--out", out, "--json", "--quiet")
    assert code == 0, err
    summary = json.loads(stdout.strip().splitlines()[-1])
    assert set(summary) == {"lidar_reg"}
    assert all(0.0 <= summary["lidar_reg"][c] <= 1.0 for c in ("clean", "noisy"))
    details = json.loads((out / "controller_success_details.json").read_text())
    assert details["checkpoints"] == {"lidar_reg": "registration"}
    block = json.loads((out / "controller_success_runs" / "lidar_reg-clean.json").read_text())
    assert block["key"]["checkpoint"].startswith("registration-")
    assert len(block["results"]) == 3


def test_the_default_scenario_is_the_table_i_run_and_every_named_scenario_loads():
    from study_run import check_scenarios

    from topodrake.experiments.success_table import SuccessTableStudy

    check_scenarios("controller_success", SuccessTableStudy, ("default", "oracle_check"),
                    {"default": ["--trials", "400", "--json"],
                     "oracle_check": ["--controllers", "oracle"]})
