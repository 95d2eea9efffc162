"""Training C_WP at scale: packed trajectories, the plain YAML loader, the worker-fed trainer."""

from __future__ import annotations

import json

import numpy as np
import pytest

from topodrake.errors import TopodrakeError
from topodrake.apps.train_cli import expand_worlds
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


def test_scale_run_needs_whole_camera_images_and_matching_variants():
    run = ScaleRunConfig()
    run.train.network = NetworkConfig(modality="camera", image_size=32)
    with pytest.raises(TopodrakeError, match="camera's 64x64 images as they are"):
        run.validate()
    run.scale.pool_max = -1
    run.train.network.image_size = 64
    with pytest.raises(TopodrakeError, match="pool_max must be >= 0"):
        run.validate()
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
    assert [c["samples_seen_after"] for c in card["calls"]] == [256]
    # a resumed call goes on counting, makes shards it has not made before, and
    # keeps the card's history and what was written into it by hand
    hand = {**json.loads((out / "card.json").read_text()), "notes": ["measured in the loop"]}
    (out / "card.json").write_text(json.dumps(hand))
    card = train_at_scale(_tiny_run(pack, 512), out, minutes=5, progress=False)
    assert card["samples_seen"] == 512 and card["scale"]["next_shard"] == 4
    assert [c["samples_seen_after"] for c in card["calls"]] == [256, 512]
    assert card["notes"] == ["measured in the loop"]
    assert json.loads((out / "card.json").read_text())["calls"] == card["calls"]
    changed = _tiny_run(pack, 1024)
    changed.train.lr = 0.5
    with pytest.raises(TopodrakeError, match="was trained with lr"):
        train_at_scale(changed, out, minutes=5, progress=False)


def test_camera_scale_run_trains_through_a_ring_pool(test0_drives, tmp_path):
    """A camera C_WP trains at scale from uint8 images; a pool smaller than
    the shards made keeps the newest samples."""
    from topodrake.learning.waypoint.policy import LearnedWaypointPolicy

    _, drives = test0_drives
    pack = pack_trajectories(drives, tmp_path / "t.npz")
    run = _tiny_run(pack, 192)
    run.train.network = NetworkConfig(modality="camera", channels=[4, 8], feature_dim=16,
                                      combine_channels=16, hidden=16)
    run.scale.variants, run.scale.pool_max = {}, 50
    card = train_at_scale(run, tmp_path / "cam", minutes=5, progress=False)
    assert card["modality"] == "camera" and card["samples_seen"] == 192
    assert card["call"]["pool"] == 50
    policy = LearnedWaypointPolicy.from_checkpoint(tmp_path / "cam" / "checkpoint.pt")
    assert policy.observation == "camera"


def test_pool_storage_becomes_the_networks_input():
    """The device-side conversion equals the CPU batcher's, for both sensors."""
    import torch

    from topodrake.learning.data import to_network_input
    from topodrake.learning.waypoint.scale_data import as_network_input
    from topodrake.sensing.config import LidarConfig

    rng = np.random.default_rng(0)
    images = rng.integers(0, 256, (2, 3, 64, 64, 3), dtype=np.uint8)
    cam = NetworkConfig(modality="camera")
    torch.testing.assert_close(as_network_input(torch.from_numpy(images), "camera"),
                               to_network_input(images, cam, LidarConfig()))
    lidar = LidarConfig()
    ranges = rng.uniform(0.1, 12.0, (2, 3, lidar.beams))
    from topodrake.learning.waypoint.scale_data import normalised

    stored = torch.from_numpy(normalised(ranges, lidar.range_m))
    want = to_network_input(ranges, NetworkConfig(**TINY), lidar)
    torch.testing.assert_close(as_network_input(stored, "lidar"), want, atol=2e-3, rtol=0)


def test_pool_ring_replaces_the_oldest_samples():
    import torch

    from topodrake.learning.waypoint.scale_data import Pool

    pool = Pool(5, (2,), torch.float16, 3, "cpu")
    part = {k: np.zeros((3, 2)) for k in ("waypoint", "overlap")}
    for first in (0, 3, 6):
        part["heading_diff"] = np.full(3, 0.1 * first)
        obs = np.arange(first, first + 3, dtype=np.float16)[:, None].repeat(2, 1)
        pool.add(part, obs, np.full((3, 3), first, np.int64))
    # 9 samples made in shards of 3 into 5 places: the oldest four were replaced
    assert pool.n == 5
    assert pool.cur[:, 0].tolist() == [5.0, 6.0, 7.0, 8.0, 4.0]
    assert pool.ctx_rows[:, 0].tolist() == [3, 6, 6, 6, 3]
    np.testing.assert_allclose(pool.heading[1].tolist(), [np.cos(0.6), np.sin(0.6)], rtol=1e-6)


def test_shipped_scale_configs_load():
    from pathlib import Path

    from topodrake.learning.networks import WaypointNetwork, input_size
    from topodrake.learning.waypoint.scale import load_scale_config

    root = Path(__file__).resolve().parents[1] / "configs"
    names = sorted(root.glob("scale_*.yaml"))
    assert {p.name for p in names} >= {"scale_lidar_k5.yaml", "scale_lidar_k5_wide.yaml",
                                      "scale_camera_k5.yaml"}
    for path in names:
        run = load_scale_config(path)
        for net in [run.train.network, *run.scale.variants.values()]:
            WaypointNetwork(net, input_size(net, run.train.lidar.beams))
    assert len(load_scale_config(root / "scale_lidar_k5.yaml").train.data.train_worlds) == 96


def test_frames_are_rendered_row_for_row(test0_drives, tmp_path):
    """Every trajectory frame's observation, rendered by the workers, lands in
    its own row on the device, for both sensors."""
    from topodrake.learning.config import TrainConfig
    from topodrake.learning.waypoint.scale_data import (gather_frames, init_worker, normalised,
                                                        render_world)
    from topodrake.sensing.camera import Camera
    from topodrake.sensing.lidar import Lidar

    world, drives = test0_drives
    pack = pack_trajectories(drives, tmp_path / "t.npz")
    packed = load_packed_trajectories(pack)
    rows = np.random.default_rng(0).choice(len(packed.poses), 7, replace=False)
    for modality in ("camera", "lidar"):
        train = TrainConfig().to_dict()
        train["network"]["modality"], train["shard_samples"] = modality, 10
        init_worker(str(pack), ["test-0"], train)
        cfg = TrainConfig()
        frames = gather_frames(map(render_world, [0]), packed, modality, cfg.camera,
                                cfg.lidar, "cpu")
        assert len(frames) == len(packed.poses)
        if modality == "camera":
            want = Camera(world, cfg.camera).render(packed.poses[rows])
        else:
            want = normalised(Lidar(world, cfg.lidar).scan(packed.poses[rows]), cfg.lidar.range_m)
        np.testing.assert_array_equal(frames[rows].numpy(), want)
