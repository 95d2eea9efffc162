"""Reachability labels from closed-loop rollouts (A* oracle on the box world)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.learning.reachability.labels import (ReachLabelConfig, draw_pairs,
                                                    label_reachability, load_reach_labels,
                                                    time_limits)
from topodrake.learning.samples import TrajectorySet


@pytest.fixture(scope="module")
def two_lines(box_world):
    """Two straight 'expert' trajectories of the box world: along y = 8
    (above the partition) and along y = 2 left of it."""
    a = np.arange(1.0, 9.0, 0.05)
    b = np.arange(1.0, 4.5, 0.05)
    pa = np.column_stack([a, np.full_like(a, 8.0), np.zeros_like(a)])
    pb = np.column_stack([b, np.full_like(b, 2.0), np.zeros_like(b)])
    poses = np.concatenate([pa, pb])
    states = np.column_stack([poses, np.zeros((len(poses), 2))])
    return TrajectorySet(["box"], np.array([0, 0], np.int32), np.array([0, len(a), len(poses)]),
                         poses, states)


CFG = ReachLabelConfig(distance_min_m=-0.5, distance_max_m=2.0, batch=4, chunk=5)


def test_pairs_mix_same_and_other_trajectories(box_world, two_lines):
    pairs = draw_pairs(box_world, two_lines, np.array([0, 1]), 200, np.random.default_rng(0), CFG)
    assert len(pairs["src"]) == 200
    same = pairs["same"]
    assert 0.5 < same.mean() < 0.7                        # probability 0.6
    assert np.all(pairs["traj"][same] == pairs["src_traj"][same])
    assert np.all(pairs["traj"][~same] != pairs["src_traj"][~same])
    # same-trajectory targets lie within the distance range along the line
    rows_s = two_lines.traj_offsets[pairs["src_traj"]] + pairs["src"]
    rows_t = two_lines.traj_offsets[pairs["traj"]] + pairs["tgt"]
    d = two_lines.poses[rows_t, 0] - two_lines.poses[rows_s, 0]
    assert d[same].min() >= -0.5 - 0.05 and d[same].max() <= 2.0 + 0.05
    # sources are jittered off the line, into free space
    assert np.abs(pairs["src_pose"][:, 1] - two_lines.poses[rows_s, 1]).max() > 0.05
    assert box_world.grid.is_free(pairs["src_pose"][:, :2]).all()



def test_a_share_of_sources_sits_on_the_expert_pose(box_world, two_lines):
    from dataclasses import replace

    def on_pose(share, n=300):
        pairs = draw_pairs(box_world, two_lines, np.array([0, 1]), n, np.random.default_rng(1),
                           replace(CFG, unjittered_sources=share))
        base = two_lines.poses[two_lines.traj_offsets[pairs["src_traj"]] + pairs["src"]]
        return np.all(pairs["src_pose"] == base, axis=1)

    assert not on_pose(0.0).any()
    assert 0.2 < on_pose(0.3).mean() < 0.4
    assert on_pose(1.0).all()
    with pytest.raises(TopodrakeError, match="unjittered_sources"):
        ReachLabelConfig(unjittered_sources=1.5).validate()

def test_time_limit_is_astar_length_over_v_min(box_world):
    # around the partition (x in [4.9, 5.1], y < 6): much longer than the 2 m straight line
    t = time_limits(box_world, np.array([[4.0, 2.0, 0.0], [1.0, 8.0, 0.0]]),
                    np.array([[6.0, 2.0], [3.0, 8.0]]), CFG)
    assert t[1] == pytest.approx(2.0 / 0.25, abs=0.3)
    assert t[0] > 2.5 * 2.0 / 0.25
    assert np.allclose(t * 10, np.round(t * 10))          # whole control periods


def test_labels_resume_and_refuse_another_config(box_world, two_lines, tmp_path):
    from topodrake.learning.waypoint.policy import AStarOracle

    def oracle(world):
        return AStarOracle(world)

    loader = {"box": box_world}.__getitem__
    out = label_reachability(two_lines, oracle, tmp_path / "labels", 12, seed=3,
                             controller={"name": "oracle"}, config=CFG, load_world=loader,
                             progress=False)
    labels = load_reach_labels(out)
    assert len(labels) == 12
    assert set(np.unique(labels.outcome)) <= {0, 1, 2, 4}
    assert np.array_equal(labels.label, (labels.outcome == 0).astype(np.uint8))
    # the oracle reaches most targets on its own line; targets on the other
    # line start out of view and end as "lost" (outcome 4) or timeouts
    assert labels.label[labels.same].mean() > 0.7
    assert labels.label[~labels.same].mean() < labels.label[labels.same].mean()
    # resume: drop the last chunk from the manifest, run again, same labels
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["chunks"] == ["000-00000.npz", "000-00001.npz", "000-00002.npz"]
    manifest["chunks"] = manifest["chunks"][:2]
    (out / "manifest.json").write_text(json.dumps(manifest))
    label_reachability(two_lines, oracle, out, 12, seed=3, controller={"name": "oracle"},
                       config=CFG, load_world=loader, progress=False)
    again = load_reach_labels(out)
    for key in ("label", "outcome", "src_pose", "t_max", "tgt"):
        assert np.array_equal(again.fields[key], labels.fields[key]), key
    with pytest.raises(TopodrakeError, match="another controller"):
        label_reachability(two_lines, oracle, out, 12, seed=3, controller={"name": "net"},
                           config=CFG, load_world=loader, progress=False)
    with pytest.raises(TopodrakeError, match="not a topodrake-reach-labels"):
        (tmp_path / "foreign").mkdir()
        (tmp_path / "foreign" / "manifest.json").write_text('{"format": "other"}')
        load_reach_labels(tmp_path / "foreign")


def test_anchor_hops_are_checked_by_closed_loop_rollouts(box_world):
    from topodrake.learning.waypoint.policy import AStarOracle
    from topodrake.experiments.hops import anchor_hop_success

    # a 'drive' along y = 2 whose last frame lies behind the partition wall
    # (x in [4.9, 5.1], y < 6): that hop starts with nothing in common in view
    poses = np.array([[3.0, 2.0, 0.0], [3.6, 2.0, 0.0], [4.2, 2.0, 0.0], [6.0, 2.0, 0.0]])
    ok = anchor_hop_success(box_world, AStarOracle(box_world), poses, np.array([0, 2, 3]),
                            runs=3, seed=5, config=CFG)
    assert ok.shape == (2, 3)
    assert ok[0].all() and not ok[1].any()
    assert anchor_hop_success(box_world, AStarOracle(box_world), poses, np.array([1]),
                              config=CFG).shape == (0, 4)
    with pytest.raises(TopodrakeError, match="increasing frame indices"):
        anchor_hop_success(box_world, AStarOracle(box_world), poses, np.array([0, 5]), config=CFG)


def test_controller_sparsify_passes_frames_by_the_controllers_own_runs(box_world):
    from topodrake.learning.waypoint.policy import AStarOracle
    from topodrake.experiments.hops import controller_sparsify

    # frames 0.2 m apart along y = 2, the last one behind the partition wall:
    # every hop is made except those to the last frame (a blind start)
    x = np.arange(3.0, 4.5, 0.2)
    poses = np.column_stack([np.append(x, 6.0), np.full(len(x) + 1, 2.0), np.zeros(len(x) + 1)])
    anchors, rollouts = controller_sparsify(box_world, AStarOracle(box_world), poses, runs=2,
                                            max_hop=3, seed=1, config=CFG)
    # 0 -> 3 -> 6 (max_hop), 6 -> 7 (8 fails), then 8 as the last frame
    assert anchors.tolist() == [0, 3, 6, 7, 8]
    assert rollouts == 2 * (3 + 3 + 2 + 1)          # frames beyond max_hop are not driven
    longer, _ = controller_sparsify(box_world, AStarOracle(box_world), poses, runs=2, max_hop=7,
                                    seed=1, config=CFG)
    assert longer.tolist() == [0, 7, 8]
    with pytest.raises(TopodrakeError, match="failures < runs"):
        controller_sparsify(box_world, AStarOracle(box_world), poses, runs=2, failures=2)


def test_label_sets_join_over_shared_or_other_houses(box_world, two_lines, tmp_path):
    from dataclasses import replace

    from topodrake.learning.reachability.labels import concat_reach_labels
    from topodrake.learning.waypoint.policy import AStarOracle

    loader = {"box": box_world}.__getitem__
    made = [load_reach_labels(label_reachability(
        two_lines, lambda w: AStarOracle(w), tmp_path / name, n, seed=seed, config=cfg,
        load_world=loader, progress=False))
        for name, n, seed, cfg in (("a", 6, 1, CFG), ("b", 4, 2, replace(CFG, unjittered_sources=1.0)))]
    both = concat_reach_labels(made)
    assert len(both) == 10 and len(both.meta["parts"]) == 2
    assert np.array_equal(both.src_pose, np.concatenate([made[0].src_pose, made[1].src_pose]))
    # a set over other houses brings its trajectories along
    loader = {"box": box_world, "box2": box_world}.__getitem__
    other = TrajectorySet(["box2"], np.array([0], np.int32), np.array([0, 100]),
                          two_lines.poses[100:200], two_lines.states[100:200])
    third = load_reach_labels(label_reachability(other, lambda w: AStarOracle(w), tmp_path / "c", 3,
                                                 config=CFG, load_world=loader, progress=False))
    joined = concat_reach_labels(made + [third])
    t = joined.trajectories
    assert t.worlds == ["box", "box2"] and t.count == 3 and len(joined) == 13
    for part, rows in ((made[0], slice(0, 6)), (third, slice(10, 13))):
        pt = part.trajectories
        want = pt.poses[pt.traj_offsets[part.traj] + part.tgt]
        got = t.poses[t.traj_offsets[joined.traj[rows]] + joined.tgt[rows]]
        assert np.array_equal(got, want)
        assert np.array_equal(t.traj_world[joined.src_traj[rows]],
                              [t.worlds.index(pt.worlds[w]) for w in pt.traj_world[part.src_traj]])
    # a set over houses the others partly cover shares their drives
    mixed = load_reach_labels(label_reachability(
        TrajectorySet.concat([other, two_lines]), lambda w: AStarOracle(w), tmp_path / "m", 4,
        seed=3, config=CFG, load_world=loader, progress=False))
    joined = concat_reach_labels(made + [third, mixed])
    t, pt = joined.trajectories, mixed.trajectories
    assert t.worlds == ["box", "box2"] and t.count == 3 and len(joined) == 17
    rows = slice(13, 17)
    assert np.array_equal(t.poses[t.traj_offsets[joined.traj[rows]] + joined.tgt[rows]],
                          pt.poses[pt.traj_offsets[mixed.traj] + mixed.tgt])
    assert np.array_equal([t.worlds[w] for w in t.traj_world[joined.src_traj[rows]]],
                          [pt.worlds[w] for w in pt.traj_world[mixed.src_traj]])
    # but one house cannot stand for two sets of drives
    same_house = TrajectorySet(["box"], np.array([0], np.int32), np.array([0, 100]),
                               two_lines.poses[:100], two_lines.states[:100])
    with pytest.raises(TopodrakeError, match="disagree on the drives of box"):
        concat_reach_labels([made[0], load_reach_labels(label_reachability(
            same_house, lambda w: AStarOracle(w), tmp_path / "d", 3, config=CFG, load_world=loader,
            progress=False))])
