"""On-policy states, their expert labels, DAgger's config and the follower benchmark's inputs."""

import json
from dataclasses import replace

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.learning.onpolicy.states import (OnPolicyConfig, collect_visited, concat_samples,
                                                label_visited, pick_drives, samples_from_fields)
from topodrake.learning.samples import TrajectorySet, expert_waypoint_labels, make_samples

LIDAR = "checkpoints/lidar_k5/checkpoint.pt"
LIDAR_RE = "checkpoints/reach_lidar_k5/checkpoint.pt"


@pytest.fixture(scope="module")
def drives(test0_drives):
    """Two expert drives of test-0 as a TrajectorySet, and the world."""
    return test0_drives


@pytest.fixture(scope="module")
def networks():
    from topodrake.learning.reachability.estimator import Reachability
    from topodrake.learning.waypoint.policy import LearnedWaypointPolicy

    return LearnedWaypointPolicy.from_checkpoint(LIDAR), Reachability.from_checkpoint(LIDAR_RE, LIDAR)


@pytest.fixture(scope="module")
def visited(drives, networks):
    world, trajs = drives
    policy, reach = networks
    cfg = OnPolicyConfig(drives_per_world=2, noisy_share=0.5, every=3)
    return collect_visited(world, trajs, np.arange(2), policy, reach, cfg, seed=5)


def test_visited_states_aim_at_their_chains_anchors_in_order(drives, networks, visited):
    world, trajs = drives
    _, reach = networks
    assert len(visited) > 20
    assert len(visited.cover) == 2 and all(0.0 <= c <= 1.0 for c in visited.cover)
    for t in range(2):
        poses = trajs.poses[trajs.rows(t)]
        chain = reach.sparsify(reach.observe(world, poses), p=0.99)
        sel = visited.traj == t
        assert sel.any()
        assert set(visited.anchor[sel]) <= set(chain.tolist())
        pos = np.searchsorted(chain, visited.anchor[sel])
        nxt = np.where(pos + 1 < len(chain), chain[np.minimum(pos + 1, len(chain) - 1)], -1)
        np.testing.assert_array_equal(visited.next_anchor[sel], nxt)
    # cars are stopped once more than 1 m off their drive; a period moves < 0.1 m
    assert visited.off_path_m.max() < 1.2
    assert visited.noisy.any() and not visited.noisy.all()


def test_collecting_is_deterministic_in_the_seed(drives, networks, visited):
    world, trajs = drives
    policy, reach = networks
    cfg = OnPolicyConfig(drives_per_world=2, noisy_share=0.5, every=3)
    again = collect_visited(world, trajs, np.arange(2), policy, reach, cfg, seed=5)
    np.testing.assert_array_equal(again.state, visited.state)
    np.testing.assert_array_equal(again.anchor, visited.anchor)


def test_labels_are_the_experts_waypoints_toward_the_active_and_next_anchor(drives, visited):
    world, trajs = drives
    cfg = OnPolicyConfig()
    cfg = replace(cfg, samples=replace(cfg.samples, min_overlap=-1.0))   # keep every state
    fields = label_visited(world, trajs, visited, cfg)
    has = visited.next_anchor >= 0
    # every state gets a label toward its anchor and the one after it,
    # unless A* has no path from it there
    anchor_pose = trajs.poses[trajs.traj_offsets[visited.traj] + visited.anchor]
    _, reachable = expert_waypoint_labels(world, visited.state[:, :3], anchor_pose[:, :2])
    next_pose = trajs.poses[trajs.traj_offsets[visited.traj[has]] + visited.next_anchor[has]]
    _, reachable_next = expert_waypoint_labels(world, visited.state[has, :3], next_pose[:, :2])
    assert reachable.mean() > 0.9
    assert len(fields["traj"]) == int(reachable.sum()) + int(reachable_next.sum())
    tgt = trajs.poses[trajs.traj_offsets[fields["traj"]] + fields["tgt"]]
    wp, valid = expert_waypoint_labels(world, fields["src_pose"], tgt[:, :2])
    assert valid.all()
    np.testing.assert_allclose(fields["waypoint"], wp)
    # the next-anchor labels are there too, and ``src`` is the drive frame nearest the state
    assert set(fields["tgt"].tolist()) >= set(visited.next_anchor[visited.next_anchor >= 0].tolist())
    ref = trajs.poses[trajs.traj_offsets[fields["traj"]] + fields["src"]]
    near = [np.hypot(*(trajs.poses[trajs.rows(t)][:, :2] - p[:2]).T).min()
            for t, p in zip(fields["traj"], fields["src_pose"])]
    np.testing.assert_allclose(np.hypot(*(ref[:, :2] - fields["src_pose"][:, :2]).T), near)
    without = label_visited(world, trajs, visited, replace(cfg, next_anchor=False))
    assert len(without["traj"]) < len(fields["traj"])


def test_sample_sets_over_other_houses_join_with_their_targets_kept(drives, visited):
    world, trajs = drives
    onp = samples_from_fields(trajs, [label_visited(world, trajs, visited)], {"x": 1})
    other = TrajectorySet(["test-9"], trajs.traj_world, trajs.traj_offsets, trajs.poses + 100.0,
                          trajs.states)
    base = make_samples(TrajectorySet(["test-0"], trajs.traj_world, trajs.traj_offsets,
                                      trajs.poses, trajs.states), 30, seed=1)
    moved = replace(onp, trajectories=other)
    both = concat_samples([base, moved])
    assert len(both) == len(base) + len(moved)
    assert both.trajectories.worlds == ["test-0", "test-9"]
    rows = both.target_rows()
    np.testing.assert_array_equal(both.trajectories.poses[rows[:len(base)]],
                                  trajs.poses[base.target_rows()])
    np.testing.assert_array_equal(both.trajectories.poses[rows[len(base):]],
                                  other.poses[moved.target_rows()])
    with pytest.raises(TopodrakeError, match="share worlds"):
        concat_samples([base, base])


def test_drives_are_picked_per_world_and_seeded(drives):
    _, trajs = drives
    a = pick_drives(trajs, 0, 1, seed=4)
    assert len(a) == 1 and np.array_equal(a, pick_drives(trajs, 0, 1, seed=4))
    assert len(pick_drives(trajs, 0, 10, seed=4)) == 2
    with pytest.raises(TopodrakeError, match="no drives"):
        pick_drives(TrajectorySet(["a", "b"], trajs.traj_world, trajs.traj_offsets, trajs.poses,
                                  trajs.states), 1, 1, seed=0)


def test_onpolicy_config_refuses_bad_values():
    with pytest.raises(TopodrakeError, match="p_sparsify"):
        OnPolicyConfig(p_sparsify=1.0).validate()
    with pytest.raises(TopodrakeError, match="noisy_share"):
        OnPolicyConfig(noisy_share=1.5).validate()
    with pytest.raises(TopodrakeError, match=">= 1"):
        OnPolicyConfig(every=0).validate()


def test_dagger_config_names_what_is_wrong(tmp_path):
    from topodrake.learning.onpolicy.dagger import DaggerConfig, load_dagger_config

    assert DaggerConfig().validate().round_worlds(1) == [f"train-{i:02d}" for i in range(24, 36)]
    with pytest.raises(TopodrakeError, match="there are 96"):
        DaggerConfig(rounds=8).validate()
    with pytest.raises(TopodrakeError, match="also base houses"):
        DaggerConfig(first_world=6).validate()
    with pytest.raises(TopodrakeError, match="init checkpoint"):
        DaggerConfig(init=str(tmp_path / "none.pt")).validate()
    bad = tmp_path / "d.yaml"
    bad.write_text("rounds: two\n")
    with pytest.raises(TopodrakeError, match=str(bad)):
        load_dagger_config(bad)
    shipped = load_dagger_config("configs/dagger_lidar_k5.yaml")
    assert shipped.train.network.modality == "lidar" and shipped.rounds * 12 + 12 <= 96
    assert load_dagger_config("configs/dagger_camera_k5.yaml").train.network.modality == "camera"
    with pytest.raises(TopodrakeError, match="has network channels"):
        DaggerConfig(init="checkpoints/lidar_k5/checkpoint.pt").validate()


def test_dagger_refuses_an_output_folder_of_another_run(tmp_path):
    from topodrake.learning.onpolicy.dagger import DaggerConfig, run_dagger

    (tmp_path / "dagger.json").write_text(json.dumps({"config": {"seed": 99}, "rounds": []}))
    with pytest.raises(TopodrakeError, match="another config"):
        run_dagger(DaggerConfig(), tmp_path, tmp_path / "data", progress=False)


def test_follower_bench_controllers_parse_with_overrides(tmp_path):
    from topodrake.experiments.bench_onpolicy import CONTROLLERS, parse_controllers

    got = parse_controllers("lidar_k5", ["lidar_k5=x.pt"])
    assert got == {"lidar_k5": ("x.pt", *CONTROLLERS["lidar_k5"][1:])}
    with pytest.raises(TopodrakeError, match="unknown controllers"):
        parse_controllers("lidar_k9", [])
    both = parse_controllers("lidar_k5", ["lidar_k5=x.pt"], ["lidar_k5=r.pt"])
    assert both == {"lidar_k5": ("x.pt", "r.pt", "x.pt")}
    with pytest.raises(TopodrakeError, match="NAME=CHECKPOINT"):
        parse_controllers("lidar_k5", ["camera_k5=x.pt"])


def test_the_oracle_c_wp_follows_the_learned_res_chains(drives, networks):
    """A pose oracle beside a sensor RE reads the anchors' poses from the
    route (the mixed ablation of the follower benchmark and the studies)."""
    from topodrake.learning.waypoint.policy import AStarOracle

    world, trajs = drives
    _, reach = networks
    cfg = OnPolicyConfig(drives_per_world=2, noisy_share=0.0)
    got = collect_visited(world, trajs, np.arange(2), AStarOracle(world, k=5), reach, cfg, seed=5)
    assert len(got) > 0 and got.cover.mean() > 0.6


def test_a_dagger_card_carries_the_rounds_up_to_its_network():
    from topodrake.learning.onpolicy.dagger import dagger_card

    state = {"config": {"init": "a.pt"}, "rounds": [
        {"round": 0, "worlds": ["train-12"], "train_wall_time_s": 600.0},
        {"round": 1, "worlds": ["train-24"], "train_wall_time_s": 300.0},
        {"round": 2, "worlds": ["train-36"], "train_wall_time_s": 300.0}]}
    card = dagger_card({"data": {"train_worlds": ["train-00"]}, "metrics": {}}, state, 1)
    assert card["data"]["onpolicy_worlds"] == ["train-12", "train-24"]
    assert card["data"]["train_worlds"] == ["train-00"]
    assert card["dagger"]["train_wall_time_s"] == 900.0 and len(card["dagger"]["rounds"]) == 2


@pytest.mark.parametrize("name,modality", [("lidar_k5_dagger", "lidar"),
                                           ("camera_k5_dagger", "camera")])
def test_the_shipped_dagger_c_wps_load_with_their_cards(name, modality):
    from topodrake.learning.waypoint.policy import LearnedWaypointPolicy

    policy = LearnedWaypointPolicy.from_checkpoint(f"checkpoints/{name}/checkpoint.pt",
                                                   modality=modality, k=5)
    assert policy.observation == modality
    card = json.loads(open(f"checkpoints/{name}/card.json").read())
    assert card["data"]["onpolicy_worlds"] and card["command"].startswith("topodrake train dagger")
    assert card["dagger"]["rounds"][-1]["round"] == len(card["dagger"]["rounds"]) - 1


def test_follower_state_labels_are_re_logits_and_c_wp_rollouts(drives, networks, visited):
    import torch

    from topodrake.learning.onpolicy.calibration import follower_probability, label_visited_reach
    from topodrake.learning.reachability.labels import target_contexts

    world, trajs = drives
    policy, reach = networks
    labels = label_visited_reach(world, trajs, visited, policy, reach, 12,
                                 np.random.default_rng(0), seed=1)
    assert len(labels.logit) == len(labels.label) == 12
    assert set(np.unique(labels.label)) <= {0.0, 1.0}
    # the same states drawn again: the logits are RE's own, the probability its calibrated one
    pick = np.random.default_rng(0).permutation(len(visited))[:12]
    vs = visited.subset(pick)
    feats = reach.encode_target(target_contexts(world, reach, trajs, vs.traj, vs.anchor))
    obs = reach.observe(world, vs.state[:, :3])
    np.testing.assert_allclose(labels.logit, reach.logit(obs, feats), atol=1e-5)
    np.testing.assert_allclose(torch.sigmoid(torch.as_tensor(labels.logit) / reach.temperature),
                               reach.probability(obs, feats), atol=1e-6)
    a, b = reach.anchor_platt
    expect = 1 / (1 + np.exp(-(a * labels.logit + b))) if reach.follower_platt is None else \
        1 / (1 + np.exp(-(reach.follower_platt[0] * labels.logit + reach.follower_platt[1])))
    np.testing.assert_allclose(follower_probability(reach, labels.logit), expect)
    # deterministic in the seed
    again = label_visited_reach(world, trajs, visited, policy, reach, 12,
                                np.random.default_rng(0), seed=1)
    np.testing.assert_array_equal(again.label, labels.label)


def test_follower_state_labels_toward_the_anchor_after(drives, networks, visited):
    from topodrake.learning.onpolicy.calibration import label_visited_reach
    from topodrake.learning.reachability.labels import target_contexts

    world, trajs = drives
    policy, reach = networks
    pick = np.random.default_rng(0).permutation(len(visited))[:12]
    vs = visited.subset(pick)
    nxt = np.where(vs.next_anchor >= 0, vs.next_anchor, vs.anchor)
    assert np.any(nxt != vs.anchor)
    ahead = label_visited_reach(world, trajs, visited, policy, reach, 12,
                                np.random.default_rng(0), seed=1, ahead=True)
    feats = reach.encode_target(target_contexts(world, reach, trajs, vs.traj, nxt))
    np.testing.assert_allclose(ahead.logit, reach.logit(reach.observe(world, vs.state[:, :3]),
                                                        feats), atol=1e-5)
