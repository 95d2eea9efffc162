"""Training C_WP at scale: packed trajectories, the plain YAML loader, the worker-fed trainer."""

from __future__ import annotations

import json

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.learning.cli import expand_worlds
from topodrake.learning.networks import NetworkConfig
from topodrake.learning.samples import TrajectorySet
from topodrake.learning.trajpack import load_packed_trajectories, pack_trajectories
from topodrake.learning.waypoint.scale import ScaleConfig, ScaleRunConfig, train_at_scale
from topodrake.typed_yaml import _plain_load

TINY = dict(modality="lidar", channels=[8, 8, 16], feature_dim=16, combine_channels=16, hidden=16,
            first_pool=1)


def _random_set(seed=0) -> TrajectorySet:
    rng = np.random.default_rng(seed)
    lengths = [5, 1, 40]
    poses = [np.cumsum(rng.normal(0, 0.1, (n, 3)), axis=0) + [120.0, -35.0, 0.0] for n in lengths]
    offsets = np.concatenate([[0], np.cumsum(lengths)])
    p = np.concatenate(poses)
    states = np.zeros((len(p), 5))
    states[:, :3] = p
    return TrajectorySet(["a", "b"], np.array([0, 1, 1], np.int32), offsets, p, states)


def test_packed_trajectories_round_trip_within_rounding(tmp_path):
    ts = _random_set()
    path = pack_trajectories(ts, tmp_path / "t.npz")
    back = load_packed_trajectories(path)
    assert back.worlds == ts.worlds
    np.testing.assert_array_equal(back.traj_offsets, ts.traj_offsets)
    np.testing.assert_array_equal(back.traj_world, ts.traj_world)
    err = np.abs(back.poses - ts.poses).max(axis=0)
    assert err[0] <= 5e-4 + 1e-9 and err[1] <= 5e-4 + 1e-9 and err[2] <= 5e-5 + 1e-9
    assert (back.states[:, 3:] == 0).all() and np.array_equal(back.states[:, :3], back.poses)


def test_packed_trajectories_refuse_other_files(tmp_path):
    with pytest.raises(TopodrakeError, match="does not exist"):
        load_packed_trajectories(tmp_path / "none.npz")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(TopodrakeError, match="corrupt or not a trajectory pack file"):
        load_packed_trajectories(bad)
    np.savez(tmp_path / "other.npz", format=np.array("something-else"))
    with pytest.raises(TopodrakeError, match="is not a topodrake-trajpack file"):
        load_packed_trajectories(tmp_path / "other.npz")


def test_plain_yaml_loader_builds_nested_dataclasses():
    text = """
train:
  network: {modality: lidar, k: 2, channels: [4, 4]}
  lr: 1
scale:
  shard_samples: 10
  variants:
    wide: {modality: lidar, k: 2, hidden: 32}
"""
    run = _plain_load(ScaleRunConfig, text, "cfg")
    assert run.train.network.channels == [4, 4] and run.train.network.k == 2
    assert isinstance(run.train.lr, float) and run.train.lr == 1.0
    assert run.train.batch_size == 64                       # a default kept
    assert isinstance(run.scale.variants["wide"], NetworkConfig)
    assert run.scale.variants["wide"].hidden == 32
    with pytest.raises(TopodrakeError, match="unknown key 'shardz'"):
        _plain_load(ScaleRunConfig, "scale: {shardz: 3}", "cfg")


def test_expand_worlds_ranges_keep_width():
    assert expand_worlds("train-08..train-11,test-0") == ["train-08", "train-09", "train-10",
                                                         "train-11", "test-0"]
    with pytest.raises(TopodrakeError, match="not a range"):
        expand_worlds("train-05..train-01")


def test_scale_run_needs_lidar_and_matching_variants():
    with pytest.raises(TopodrakeError, match="lidar"):
        ScaleRunConfig().validate()
    run = ScaleRunConfig()
    run.train.network = NetworkConfig(**TINY)
    run.scale.variants = {"w": NetworkConfig(**{**TINY, "k": 2})}
    with pytest.raises(TopodrakeError, match="share the main network's"):
        run.validate()


def _tiny_run(pack, max_samples: int) -> ScaleRunConfig:
    run = ScaleRunConfig(scale=ScaleConfig(trajectories=str(pack), shard_samples=40,
                                           shards_per_world=2, workers=1, min_pool=40,
                                           device="cpu",
                                           variants={"wide": NetworkConfig(**{**TINY, "hidden": 24})}))
    t = run.train
    t.network = NetworkConfig(**TINY)
    t.data.train_worlds, t.data.val_worlds = ["test-0"], ["test-0"]
    t.data.val_samples = 30
    t.batch_size, t.max_samples, t.val_every_samples = 32, max_samples, 128
    return run


def test_scale_trainer_trains_resumes_with_new_shards(test0_drives, tmp_path):
    from topodrake.learning.waypoint.policy import LearnedWaypointPolicy

    _, drives = test0_drives
    pack = pack_trajectories(drives, tmp_path / "t.npz")
    out = tmp_path / "run"
    card = train_at_scale(_tiny_run(pack, 256), out, minutes=5, progress=False)
    assert card["samples_seen"] == 256 and card["scale"]["next_shard"] == 2
    assert {"val", "val_paper"} <= set(card["metrics"])
    for folder in (out, out / "wide"):
        policy = LearnedWaypointPolicy.from_checkpoint(folder / "checkpoint.pt")
        assert policy.k == 5
    assert json.loads((out / "wide" / "card.json").read_text())["config"]["network"]["hidden"] == 24
    # a resumed call goes on counting and makes shards it has not made before
    card = train_at_scale(_tiny_run(pack, 512), out, minutes=5, progress=False)
    assert card["samples_seen"] == 512 and card["scale"]["next_shard"] == 4
    changed = _tiny_run(pack, 1024)
    changed.train.lr = 0.5
    with pytest.raises(TopodrakeError, match="was trained with lr"):
        train_at_scale(changed, out, minutes=5, progress=False)


def test_shipped_scale_configs_load():
    from pathlib import Path

    from topodrake.learning.networks import WaypointNetwork, input_size
    from topodrake.learning.waypoint.scale import load_scale_config

    root = Path(__file__).resolve().parents[1] / "configs"
    names = sorted(root.glob("scale_*.yaml"))
    assert {p.name for p in names} >= {"scale_lidar_k5.yaml", "scale_lidar_k5_wide.yaml"}
    for path in names:
        run = load_scale_config(path)
        for net in [run.train.network, *run.scale.variants.values()]:
            WaypointNetwork(net, input_size(net, run.train.lidar.beams))
    assert len(load_scale_config(root / "scale_lidar_k5.yaml").train.data.train_worlds) == 96
