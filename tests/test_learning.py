"""C_WP learning: samples, networks, cached inference, checkpoints, training, WaypointNet."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from topodrake.errors import TopodrakeError
from topodrake.learning.networks import NetworkConfig, WaypointNetwork, camera_input, input_size
from topodrake.learning.samples import SampleSet, TrajectorySet, expert_waypoint_labels, make_samples

torch.set_num_threads(1)

WORLD = "train-00"
TINY = dict(channels=[8, 8, 16], feature_dim=16, combine_channels=16, hidden=16)


@pytest.fixture(scope="module")
def trajectories():
    from topodrake.rollout import ExpertRollout, RolloutConfig
    from topodrake.world import load_world

    world = load_world(WORLD)
    p = world.places
    pairs = [(0, 3), (2, 5), (4, 1), (6, 8)]
    res = ExpertRollout(world, RolloutConfig(t_max_s=90.0)).run(
        np.array([p[i] for i, _ in pairs]), np.array([p[j, :2] for _, j in pairs]))
    drives = [(0, res.trajectory(i)["poses"], res.trajectory(i)["controls"])
              for i in range(len(pairs)) if res.success[i]]
    assert len(drives) >= 3
    return TrajectorySet.from_drives([WORLD], drives)


@pytest.fixture(scope="module")
def samples(trajectories):
    return make_samples(trajectories, 300, seed=3)


# ---------------------------------------------------------------- samples

def test_trajectory_replay_matches_poses(trajectories):
    st = trajectories.states
    assert st.shape[1] == 5 and np.all(np.abs(st[:, 3]) <= 0.5 + 1e-9)
    assert np.all(np.abs(st[:, 4]) <= 0.36 + 1e-9)
    assert np.array_equal(st[:, :3], trajectories.poses)


def test_samples_obey_constraints(samples, trajectories):
    from topodrake.sensing.overlap import mutual_overlap
    from topodrake.world import load_world

    world = load_world(WORLD)
    s = samples
    assert len(s) == 300
    assert np.all((s.distance >= -0.5) & (s.distance <= 3.0))
    # the target frame lies at the drawn arc-length distance along the same trajectory
    for i in range(len(s)):
        p = trajectories.poses[trajectories.rows(int(s.traj[i]))]
        arc = np.concatenate([[0], np.cumsum(np.hypot(*np.diff(p[:, :2], axis=0).T))])
        assert abs(arc[s.tgt[i]] - arc[s.src[i]] - s.distance[i]) < 0.06
    # both overlaps above 0.1, and they are the geometric overlaps of the stored poses
    assert np.all(s.overlap > 0.1)
    tgt = trajectories.poses[s.target_rows()]
    assert np.allclose(mutual_overlap(world, s.src_pose, tgt), s.overlap, atol=1e-6)
    # jitter: sideways only, clipped to 1 m, heading N(0, 9 deg), collision-free
    base = trajectories.poses[trajectories.traj_offsets[s.traj] + s.src]
    d = s.src_pose[:, :2] - base[:, :2]
    c, sn = np.cos(base[:, 2]), np.sin(base[:, 2])
    along, lateral = c * d[:, 0] + sn * d[:, 1], -sn * d[:, 0] + c * d[:, 1]
    assert np.allclose(along, 0, atol=1e-9) and np.all(np.abs(lateral) <= 1.0 + 1e-9)
    assert 0.15 < lateral.std() < 0.45
    dth = s.src_pose[:, 2] - base[:, 2]
    assert np.degrees(np.abs(dth)).max() < 60 and 5 < np.degrees(dth.std()) < 13
    assert world.grid.is_free(s.src_pose[:, :2]).all()
    # labels: no longer than the target distance; heading difference wrapped
    dist = np.hypot(*(tgt[:, :2] - s.src_pose[:, :2]).T)
    assert np.all(np.hypot(*s.waypoint.T) <= dist + 1e-5)
    assert np.all(np.abs(s.heading_diff) <= np.pi)
    wp, valid = expert_waypoint_labels(world, s.src_pose[:20], tgt[:20, :2])
    assert valid.all() and np.allclose(wp, s.waypoint[:20], atol=1e-5)
    assert np.all(np.abs(s.control[:, 1]) <= 3.2 + 1e-6)


def test_waypoint_label_is_in_the_source_frame(box_world):
    # open space, car facing +y, target 2 m to its right (+x): waypoint (0, -2)
    wp, valid = expert_waypoint_labels(box_world, np.array([[2.0, 3.0, np.pi / 2]]),
                                       np.array([[4.0, 3.0]]))
    assert valid[0]
    assert np.allclose(wp[0], [0.0, -2.0], atol=0.06)
    # shortened to the target distance even when the expert would look farther
    wp, _ = expert_waypoint_labels(box_world, np.array([[2.0, 3.0, 0.0]]), np.array([[2.5, 3.0]]))
    assert np.hypot(*wp[0]) <= 0.5 + 1e-9 and wp[0, 0] > 0.45


def test_a_source_in_a_walls_margin_drives_out_along_astar_when_snapped(box_world):
    # 0.15 m from the partition's face (inside its 0.2 m margin), the target behind it
    src, tgt = np.array([[4.75, 5.0, 0.0]]), np.array([[5.5, 5.0]])
    _, valid = expert_waypoint_labels(box_world, src, tgt)
    assert not valid[0]                                  # the labels' rule: no path
    wp, valid = expert_waypoint_labels(box_world, src, tgt, start_snap_m=0.3)
    assert valid[0]
    end = src[0, :2] + wp[0]                             # heading 0: car frame = world frame
    assert end[0] < 4.9 and end[1] > 5.3                 # up toward the gap, not through the wall


def test_context_rows_clamped_and_ordered(samples, trajectories):
    rows = samples.context_rows(2, 3)
    assert rows.shape == (len(samples), 5)
    lo = trajectories.traj_offsets[samples.traj]
    hi = trajectories.traj_offsets[samples.traj + 1] - 1
    assert np.all(rows >= lo[:, None]) and np.all(rows <= hi[:, None])
    assert np.all(np.diff(rows, axis=1) >= 0)
    assert np.array_equal(rows[:, 2], samples.target_rows())
    assert np.array_equal(samples.context_rows(0)[:, 0], samples.target_rows())


def test_samples_deterministic_and_file_roundtrip(samples, trajectories, tmp_path):
    again = make_samples(trajectories, 300, seed=3)
    assert np.array_equal(again.src_pose, samples.src_pose)
    assert np.array_equal(again.waypoint, samples.waypoint)
    other = make_samples(trajectories, 50, seed=4)
    assert not np.array_equal(other.src_pose, samples.src_pose[:50])
    path = samples.save(tmp_path / "s.npz")
    back = SampleSet.load(path)
    assert np.array_equal(back.waypoint, samples.waypoint)
    assert np.array_equal(back.trajectories.poses, trajectories.poses)
    assert back.trajectories.worlds == [WORLD]
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a sample file")
    with pytest.raises(TopodrakeError, match="bad.npz"):
        SampleSet.load(bad)


# ---------------------------------------------------------------- networks

@pytest.mark.parametrize("modality", ["camera", "lidar"])
@pytest.mark.parametrize("k", [0, 2, 5])
def test_network_shapes(modality, k):
    cfg = NetworkConfig(modality=modality, k=k, image_size=32, **TINY)
    size = input_size(cfg, 64)
    net = WaypointNetwork(cfg, size)
    ch = 3 if modality == "camera" else 1
    shape = (ch, size, size) if modality == "camera" else (ch, size)
    out = net(torch.randn(4, *shape), torch.randn(4, 2 * k + 1, *shape))
    assert out["waypoint"].shape == (4, 2)
    assert out["heading"].shape == (4, 2)
    assert out["overlap_logits"].shape == (4, 2)
    assert "control" not in out
    direct = WaypointNetwork(NetworkConfig(modality=modality, k=k, output="control",
                                           image_size=32, **TINY), size)
    assert direct(torch.randn(2, *shape), torch.randn(2, 2 * k + 1, *shape))["control"].shape == (2, 2)


@pytest.mark.parametrize("modality", ["camera", "lidar"])
def test_cached_inference_equals_naive(modality):
    torch.manual_seed(0)
    cfg = NetworkConfig(modality=modality, k=2)       # default widths
    size = input_size(cfg, 64)
    net = WaypointNetwork(cfg, size).eval()
    shape = (3, size, size) if modality == "camera" else (1, size)
    cur, ctx = torch.rand(3, *shape) - 0.5, torch.rand(3, 5, *shape) - 0.5
    with torch.no_grad():
        naive = net(cur, ctx)
        cached = net.forward_cached(cur, net.encode_target(ctx))
        split = net.forward_split(cur, ctx)
        # one current observation against several cached targets
        one = net.forward_cached(cur[:1], net.encode_target(ctx))
        naive_one = net(cur[:1].expand(3, *shape), ctx)
        # several current observations against one cached target
        many = net.forward_cached(cur, net.encode_target(ctx[:1]))
        naive_many = net(cur, ctx[:1].expand(3, *ctx.shape[1:]))
    for key in naive:
        assert torch.allclose(naive[key], cached[key], atol=1e-5), key
        assert torch.allclose(naive[key], split[key], atol=1e-5), key
        assert torch.allclose(naive_one[key], one[key], atol=1e-5), key
        assert torch.allclose(naive_many[key], many[key], atol=1e-5), key


@pytest.mark.parametrize("modality,output,pool", [("camera", "waypoint", 1), ("lidar", "waypoint", 1),
                                                  ("camera", "control", 2), ("camera", "reach", 1)])
def test_inference_plan_equals_the_module(modality, output, pool):
    from topodrake.learning.inference import InferencePlan
    from topodrake.learning.networks import fold_batchnorm

    torch.manual_seed(2)
    cfg = NetworkConfig(modality=modality, output=output, k=2, first_pool=pool)
    size = input_size(cfg, 64)
    net = WaypointNetwork(cfg, size)
    net.train()
    shape = (3, size, size) if modality == "camera" else (1, size)
    net(torch.rand(8, *shape) - 0.5, torch.rand(8, 5, *shape) - 0.5)   # BatchNorm statistics
    model = fold_batchnorm(net.eval())
    plan = InferencePlan(model)
    cur, ctx = torch.rand(3, *shape) - 0.5, torch.rand(3, 5, *shape) - 0.5
    with torch.no_grad():
        ref = net(cur, ctx)
        naive = plan.naive(cur, ctx)
        cached = plan.cached(cur, plan.encode_target(ctx))
        one = plan.cached(cur[:1], plan.encode_target(ctx))      # one observation, 3 targets
        ref_one = net(cur[:1].expand(3, *shape), ctx)
        plan.chunk = 2                                           # 3 samples run as 2 + 1
        chunked = plan.cached(cur, plan.encode_target(ctx))
        one_chunked = plan.cached(cur[:1], plan.encode_target(ctx))
        # two views at once: the second against the targets' second block of frames
        flipped = cur.flip(-1)
        both = plan.cached_views([cur, flipped], torch.cat([plan.encode_target(ctx)] * 2, dim=1))
        ref_flipped = net(flipped, ctx)
    assert set(naive) == set(ref)
    for key in ref:
        assert torch.allclose(ref[key], naive[key], atol=1e-5), key
        assert torch.allclose(ref[key], cached[key], atol=1e-5), key
        assert torch.allclose(ref_one[key], one[key], atol=1e-5), key
        assert torch.allclose(ref[key], chunked[key], atol=1e-5), key
        assert torch.allclose(ref_one[key], one_chunked[key], atol=1e-5), key
        assert torch.allclose(ref[key], both[key][:, 0], atol=1e-5), key
        assert torch.allclose(ref_flipped[key], both[key][:, 1], atol=1e-5), key
    with pytest.raises(ValueError, match="BatchNorm"):
        InferencePlan(net)


@pytest.mark.parametrize("shape", [(5, 3, 17, 17), (4, 2, 16, 9), (6, 4, 31)])
@pytest.mark.parametrize("k", [2, 3])
def test_max_pool_is_torchs_pooling_to_the_bit_with_its_gradient(shape, k):
    from torch.nn import functional as F

    from topodrake.learning.networks import max_pool

    torch.manual_seed(0)
    x = torch.randn(*shape).relu().requires_grad_()    # after a ReLU: many tied zeros
    ref = (F.max_pool2d if len(shape) == 4 else F.max_pool1d)(x, k)
    with torch.no_grad():                                 # the strided views (inference)
        fast = max_pool(x, k)
    assert fast.shape == ref.shape and torch.equal(fast, ref)
    out = max_pool(x, k)                                  # in training, with its gradient
    assert torch.equal(out, ref)
    w = torch.randn(ref.shape)
    g_ref, = torch.autograd.grad((ref * w).sum(), x)
    g_out, = torch.autograd.grad((out * w).sum(), x)
    assert torch.equal(g_out, g_ref)
    assert max_pool(x, 1) is x


@pytest.mark.parametrize("modality", ["camera", "lidar"])
def test_batchnorm_split_and_folding_are_exact(modality):
    from topodrake.learning.networks import fold_batchnorm

    torch.manual_seed(3)
    cfg = NetworkConfig(modality=modality, k=2, norm="batch")
    size = input_size(cfg, 64)
    net = WaypointNetwork(cfg, size)
    shape = (3, size, size) if modality == "camera" else (1, size)
    cur, ctx = torch.rand(4, *shape) - 0.5, torch.rand(4, 5, *shape) - 0.5
    net.train()
    for _ in range(3):                      # non-trivial running statistics
        net(cur, ctx)
    net.eval()
    folded = fold_batchnorm(net)
    assert folded.cfg.norm == "none"
    assert not any(isinstance(m, torch.nn.BatchNorm2d | torch.nn.BatchNorm1d) for m in folded.modules())
    with torch.no_grad():
        ref = net(cur, ctx)
        for out in (net.forward_cached(cur, net.encode_target(ctx)), folded(cur, ctx),
                    folded.forward_cached(cur, folded.encode_target(ctx))):
            for key in ref:
                assert torch.allclose(ref[key], out[key], atol=1e-5), key


def test_policy_cached_equals_naive_on_rendered_images():
    from topodrake.learning.waypoint.policy import LearnedWaypointPolicy
    from topodrake.sensing.camera import Camera
    from topodrake.sensing.config import CameraConfig
    from topodrake.world import load_world

    world = load_world(WORLD)
    poses = world.sample_free_pose(np.random.default_rng(0), 12)
    images = Camera(world).render(poses)
    torch.manual_seed(1)
    cfg = NetworkConfig(k=5)
    policy = LearnedWaypointPolicy(WaypointNetwork(cfg, 64), CameraConfig())
    ctx = images[1:][None]
    a = policy.predict(images[:1], policy.encode_target(ctx))
    b = policy.predict_naive(images[:1], ctx)
    assert np.allclose(a.waypoint, b.waypoint, atol=1e-5)
    # features regathered by index_select (as the batched engine does when cars
    # stop) come back NCHW, not channels-last: same answers, at any batch size
    two = policy.encode_target(np.concatenate([ctx[:, ::-1], ctx]))
    regathered = two.index_select(0, torch.tensor([1, 0, 1]))
    assert regathered.is_contiguous() and not two.is_contiguous()      # NCHW vs channels-last
    c = policy.predict(np.repeat(images[:1], 3, 0), regathered)
    assert np.allclose(c.waypoint[[0, 2]], a.waypoint, atol=1e-5)
    assert not np.allclose(c.waypoint[1], a.waypoint[0], atol=1e-5)     # the other target
    assert np.allclose(policy.predict(images[:1], policy.encode_target(ctx)).waypoint, a.waypoint,
                       atol=1e-6)
    # Without BatchNorm (nothing to fold) the policy still freezes its own
    # copy: training the model further leaves it consistent, not stale.
    plain = WaypointNetwork(NetworkConfig(k=5, norm="none"), 64)
    frozen = LearnedWaypointPolicy(plain, CameraConfig())
    before = frozen.predict(images[:1], frozen.encode_target(ctx))
    with torch.no_grad():
        plain.encoder.first.weight.mul_(0.0)
    after = frozen.predict(images[:1], frozen.encode_target(ctx))
    assert np.array_equal(before.waypoint, after.waypoint)
    assert np.allclose(after.waypoint, frozen.predict_naive(images[:1], ctx).waypoint, atol=1e-5)
    assert np.allclose(a.overlap, b.overlap, atol=1e-6)
    assert np.allclose(a.heading_diff, b.heading_diff, atol=1e-5)
    # a 64 x 64 sensor image feeds a 32 x 32 network by 2 x 2 averaging
    x = camera_input(images[:2], 32)
    assert x.shape == (2, 3, 32, 32)
    assert abs(float(x[0, 0, 0, 0]) - (images[0, :2, :2, 0].mean() / 255.0 - 0.5)) < 1e-6


# ---------------------------------------------------------------- checkpoints and config

def test_checkpoint_roundtrip_and_refusals(tmp_path):
    from topodrake.learning.checkpoint import load_checkpoint, save_checkpoint
    from topodrake.learning.waypoint.policy import LearnedWaypointPolicy
    from topodrake.sensing.config import CameraConfig, LidarConfig

    torch.manual_seed(2)
    cfg = NetworkConfig(k=2, image_size=32, **TINY)
    net = WaypointNetwork(cfg, 32).eval()
    path = save_checkpoint(tmp_path / "c.pt", net, CameraConfig(), metrics={"loss": 1.5},
                           samples_seen=640, wall_time_s=12.5)
    ck = load_checkpoint(path, modality="camera", k=2, camera=CameraConfig())
    assert ck.meta["samples_seen"] == 640 and ck.meta["metrics"]["loss"] == 1.5
    assert ck.meta["image_size"] == 32 and ck.meta["modality"] == "camera"
    assert "git_revision" in ck.meta and ck.network == cfg
    x, c = torch.rand(2, 3, 32, 32), torch.rand(2, 5, 3, 32, 32)
    with torch.no_grad():
        assert torch.equal(net(x, c)["waypoint"], ck.model(x, c)["waypoint"])
    LearnedWaypointPolicy.from_checkpoint(path, modality="camera", k=2)
    for kwargs, what in (({"modality": "lidar"}, "modality"), ({"k": 5}, "context k"),
                         ({"lidar": LidarConfig()}, "modality"),
                         ({"camera": CameraConfig(hfov_deg=90.0)}, "hfov_deg"),
                         ({"camera": CameraConfig(width=48, height=48)}, "48x48"),
                         ({"output": "control"}, "output")):
        with pytest.raises(TopodrakeError, match=what) as e:
            load_checkpoint(path, **kwargs)
        assert str(path) in str(e.value) and "\n" not in str(e.value)
    for name, data in (("garbage.pt", b"\x00\x01 not a checkpoint"),
                       ("truncated.pt", path.read_bytes()[:200])):
        bad = tmp_path / name
        bad.write_bytes(data)
        with pytest.raises(TopodrakeError, match=name):
            load_checkpoint(bad)
    other = tmp_path / "other.pt"
    torch.save({"weights": torch.zeros(2)}, other)
    with pytest.raises(TopodrakeError, match="not a topodrake-waypoint-net"):
        load_checkpoint(other)
    with pytest.raises(TopodrakeError, match="does not exist"):
        load_checkpoint(tmp_path / "missing.pt")


def test_yaml_configs_load(tmp_path):
    from pathlib import Path

    from topodrake.learning.config import load_train_config

    root = Path(__file__).resolve().parents[1] / "configs"
    names = sorted(p.name for p in root.glob("waypoint_*.yaml"))
    assert {"waypoint_camera_k0.yaml", "waypoint_camera_k2.yaml", "waypoint_camera_k5.yaml",
            "waypoint_lidar_k5.yaml", "waypoint_direct_k0.yaml"} <= set(names)
    for name in names:
        cfg = load_train_config(root / name)
        WaypointNetwork(cfg.network, input_size(cfg.network, cfg.lidar.beams))
    assert load_train_config(root / "waypoint_direct_k0.yaml").network.output == "control"
    bad = tmp_path / "bad.yaml"
    bad.write_text("network: {modality: camera, widht: 3}\n")
    with pytest.raises(TopodrakeError, match="bad.yaml"):
        load_train_config(bad)
    bad.write_text("network: {modality: sonar}\n")
    with pytest.raises(TopodrakeError, match="modality"):
        load_train_config(bad)
    with pytest.raises(TopodrakeError, match="does not exist"):
        load_train_config(tmp_path / "nope.yaml")


# ---------------------------------------------------------------- training

def _tiny_config(**kw):
    from topodrake.learning.config import TrainConfig

    from topodrake.sensing.config import CameraConfig

    kw.setdefault("lr", 3e-3)
    cfg = TrainConfig(network=NetworkConfig(k=1, image_size=16, **TINY), batch_size=32,
                      camera=CameraConfig(width=16, height=16),
                      epoch_samples=100000, val_every_samples=100000,
                      checkpoint_every_s=1e9, threads=1, **kw)
    cfg.data.train_samples = 240
    return cfg


def test_tiny_training_reduces_loss_and_resumes(samples, tmp_path, capsys):
    from topodrake.learning.waypoint.train import train_waypoint

    train, val = samples.subset(np.arange(240)), samples.subset(np.arange(240, 300))
    first = train_waypoint(_tiny_config(max_samples=32), tmp_path, samples=(train, val),
                           progress=True)
    assert first.samples_seen == 32
    out, err = capsys.readouterr()      # progress goes to stderr: stdout stays the --json's
    assert out == "" and "trained camera k=1 waypoint" in err
    more = train_waypoint(_tiny_config(max_samples=1280), tmp_path, samples=(train, val),
                          progress=False, command="topodrake train waypoint --config c.yaml --out x")
    assert more.samples_seen == 1280
    assert more.metrics["loss"] < 0.85 * first.metrics["loss"]
    import json
    card = json.loads((tmp_path / "card.json").read_text())
    assert card["samples_seen"] == 1280 and card["command"].endswith("--out x")
    assert card["data"]["train_samples"] == 240 and card["wall_time_s"] > 0
    from topodrake.fileio import file_sha256
    assert card["sha256"] == file_sha256(tmp_path / "checkpoint.pt")    # checked on load
    # the shipped file holds no optimizer state; resume.pt beside it does
    blob = torch.load(tmp_path / "checkpoint.pt", weights_only=True)
    assert "optimizer" not in blob and (tmp_path / "resume.pt").is_file()
    assert oct((tmp_path / "checkpoint.pt").stat().st_mode & 0o777) != oct(0o600)
    # same seed, same data: the uninterrupted run lands on the same weights
    straight = train_waypoint(_tiny_config(max_samples=1280), tmp_path / "b", samples=(train, val),
                              progress=False)
    assert abs(straight.metrics["loss"] - more.metrics["loss"]) < 1e-4
    # a checkpoint of another config is not resumed
    other = _tiny_config(max_samples=1280)
    other.network.k = 2
    with pytest.raises(TopodrakeError, match="context k|network.k"):
        train_waypoint(other, tmp_path, samples=(train, val), progress=False)



def test_warm_start_begins_from_the_given_checkpoint_and_refuses_another_network(samples, tmp_path):
    from topodrake.learning.waypoint.train import train_waypoint

    train, val = samples.subset(np.arange(240)), samples.subset(np.arange(240, 300))
    base = train_waypoint(_tiny_config(max_samples=1280), tmp_path / "base", samples=(train, val),
                          progress=False)
    init = str(tmp_path / "base" / "checkpoint.pt")
    # one batch at a tiny learning rate: the warm run starts where the base ended
    warm = train_waypoint(_tiny_config(max_samples=32, init=init, lr=1e-9), tmp_path / "warm",
                          samples=(train, val), progress=False)
    cold = train_waypoint(_tiny_config(max_samples=32, lr=1e-9), tmp_path / "cold",
                          samples=(train, val), progress=False)
    assert abs(warm.metrics["loss"] - base.metrics["loss"]) < 0.02 * base.metrics["loss"]
    assert cold.metrics["loss"] > 1.2 * warm.metrics["loss"]
    import json
    card = json.loads((tmp_path / "warm" / "card.json").read_text())
    assert card["init"]["checkpoint"] == init and card["init"]["samples_seen"] == 1280
    other = _tiny_config(max_samples=32, init=init)
    other.network.k = 2
    with pytest.raises(TopodrakeError, match="cannot start from .*network"):
        train_waypoint(other, tmp_path / "other", samples=(train, val), progress=False)
    with pytest.raises(TopodrakeError, match="does not exist"):
        train_waypoint(_tiny_config(init=str(tmp_path / "none.pt")), tmp_path / "none",
                       samples=(train, val), progress=False)


# ---------------------------------------------------------------- Drake

def _run(built, start, seconds):
    from pydrake.systems.analysis import ApplySimulatorConfig, Simulator, SimulatorConfig

    sim = Simulator(built.diagram)
    ApplySimulatorConfig(SimulatorConfig(integration_scheme="runge_kutta2", max_step_size=0.1,
                                         use_error_control=False, target_realtime_rate=0.0,
                                         publish_every_time_step=False), sim)
    ctx = sim.get_mutable_context()
    built.car.GetMyMutableContextFromRoot(ctx).SetContinuousState(np.array([*start, 0.0, 0.0]))
    sim.AdvanceTo(seconds)
    return sim, ctx


def test_waypoint_net_oracle_drives_to_target(box_world):
    from topodrake.learning.waypoint.policy import AStarOracle, TargetContext
    from topodrake.systems.scenario import Scenario
    from topodrake.systems.waypoint_net import build_waypoint_diagram

    oracle = AStarOracle(box_world, k=1)
    calls = {"predict": 0, "encode": 0}
    predict, encode = oracle.predict, oracle.encode_target
    oracle.predict = lambda *a: (calls.__setitem__("predict", calls["predict"] + 1), predict(*a))[1]
    oracle.encode_target = lambda *a: (calls.__setitem__("encode", calls["encode"] + 1), encode(*a))[1]
    tposes = np.array([[3.85, 4.0, 0.0], [4.0, 4.0, 0.0], [4.15, 4.0, 0.0]])
    built = build_waypoint_diagram(Scenario(world="box"), oracle, world=box_world,
                                   target=TargetContext(key=3, poses=tposes))
    sim, ctx = _run(built, [1.5, 3.5, 0.3], 6.0)
    log = built.pose_logger.FindLog(ctx).data().T
    assert np.hypot(*(log[:, :2] - [4.0, 4.0]).T).min() < 0.27
    # sample and hold: one prediction per 0.1 s period, the target encoded twice at most
    assert calls["predict"] <= 62 and calls["encode"] <= 2
    cache = built.waypoint_net.GetMyContextFromRoot(ctx).get_abstract_state(0).get_value()
    assert cache.key == 3


@pytest.mark.parametrize("modality,output", [("camera", "waypoint"), ("lidar", "waypoint"),
                                             ("camera", "control")])
def test_waypoint_net_matches_policy(box_world, modality, output):
    from topodrake.contract.frames import context_frames
    from topodrake.learning.waypoint.policy import LearnedWaypointPolicy, make_target_context
    from topodrake.sensing.config import CameraConfig, LidarConfig
    from topodrake.systems.scenario import Scenario
    from topodrake.systems.waypoint_net import build_waypoint_diagram

    torch.manual_seed(5)
    cfg = NetworkConfig(modality=modality, output=output, k=1, image_size=32, **TINY)
    sensor = CameraConfig() if modality == "camera" else LidarConfig()
    policy = LearnedWaypointPolicy(WaypointNetwork(cfg, input_size(cfg, 64)), sensor)
    line = np.column_stack([np.linspace(2.5, 4.0, 11), np.full(11, 4.0), np.zeros(11)])
    target = make_target_context(box_world, line, 5, 1, modality=modality, key=1)
    assert np.allclose(target.poses[:, 0], [2.8, 3.25, 3.7])     # frames 2, 5, 8
    assert list(context_frames(11, 1, 2)) == [0, 0, 1, 4, 7]     # clamped at the start
    built = build_waypoint_diagram(Scenario(world="box"), policy, world=box_world, target=target)
    sim, ctx = _run(built, [1.5, 4.0, 0.0], 0.35)
    obs = built.diagram.GetOutputPort("image" if modality == "camera" else "ranges").Eval(ctx)
    net = built.waypoint_net
    net_ctx = net.GetMyContextFromRoot(ctx)
    expect = policy.predict_naive(np.asarray(obs)[None], target.observations[None])
    assert np.allclose(net.waypoint_local_port.Eval(net_ctx), expect.waypoint[0], atol=1e-5)
    assert np.allclose(built.diagram.GetOutputPort("overlap").Eval(ctx), expect.overlap[0],
                       atol=1e-6)
    if output == "control":
        assert np.allclose(net.controls_port.Eval(net_ctx), expect.controls[0], atol=1e-5)
        assert np.allclose(built.diagram.GetOutputPort("controls").Eval(ctx), expect.controls[0],
                           atol=1e-5)


def test_waypoint_net_reuses_what_the_target_carries_only_for_its_own_policy_and_observation(
        box_world):
    from topodrake.learning.waypoint.policy import (LearnedWaypointPolicy, TargetContext,
                                                    WaypointPrediction, make_target_context)
    from topodrake.sensing.config import CameraConfig
    from topodrake.systems.scenario import Scenario
    from topodrake.systems.waypoint_net import build_waypoint_diagram

    torch.manual_seed(5)
    cfg = NetworkConfig(k=1, image_size=32, **TINY)
    policy = LearnedWaypointPolicy(WaypointNetwork(cfg, input_size(cfg, 64)), CameraConfig())
    other = LearnedWaypointPolicy(WaypointNetwork(cfg, input_size(cfg, 64)), CameraConfig())
    line = np.column_stack([np.linspace(2.5, 4.0, 11), np.full(11, 4.0), np.zeros(11)])
    target = make_target_context(box_world, line, 5, 1, modality="camera", key=1)
    built = build_waypoint_diagram(Scenario(world="box"), policy, world=box_world, target=target)
    sim, ctx = _run(built, [1.5, 4.0, 0.0], 0.35)
    obs = np.asarray(built.diagram.GetOutputPort("image").Eval(ctx))
    net = built.waypoint_net
    net_ctx = net.GetMyContextFromRoot(ctx)
    source_ctx = built.target_source.GetMyContextFromRoot(ctx)
    computed = np.array(net.waypoint_local_port.Eval(net_ctx))
    made = WaypointPrediction(np.array([[0.123, -0.456]]), np.zeros(1), np.full((1, 2), 0.5))

    def local(**carried):
        built.target_source.set_target(source_ctx, TargetContext(
            key=1, observations=target.observations, **carried))
        return np.array(net.waypoint_local_port.Eval(net_ctx))

    assert np.allclose(local(by=policy, prediction=made, observed=obs), made.waypoint[0])
    changed = obs.copy()
    changed[0, 0, 0] ^= 1
    assert np.allclose(local(by=policy, prediction=made, observed=changed), computed, atol=1e-5)
    assert np.allclose(local(by=other, prediction=made, observed=obs), computed, atol=1e-5)
    # carried features are used instead of encoding the context, but only from
    # the same policy (shifted features change the answer)
    own = policy.encode_target(target.observations[None])
    assert np.allclose(local(by=policy, features=own), computed, atol=1e-5)
    assert not np.allclose(local(by=policy, features=own + 3.0), computed, atol=1e-4)
    assert np.allclose(local(by=other, features=own + 3.0), computed, atol=1e-5)


def test_cli_parsers_refuse_a_missing_config(tmp_path):
    import argparse

    from topodrake.apps.train_cli import add_bench_parser, add_train_parser

    p = argparse.ArgumentParser()
    sub = p.add_subparsers(dest="command", required=True)
    add_train_parser(sub)
    add_bench_parser(sub.add_parser("bench").add_subparsers(dest="bench_command", required=True))
    args = p.parse_args(["train", "waypoint", "--config", str(tmp_path / "none.yaml"),
                         "--out", str(tmp_path / "out")])
    with pytest.raises(TopodrakeError, match="none.yaml"):
        args.func(args)
    assert p.parse_args(["bench", "networks", "--json"]).json


def test_config_diff_on_resume_reaches_into_lists_and_ignores_later_none_fields():
    from topodrake.learning.waypoint.train import _diff

    old = {"lr": 1e-3, "labels": {"more": [{"seed": 10, "pairs": 5}]}}
    assert _diff(old, {"lr": 1e-3, "labels": {"more": [{"seed": 10, "pairs": 5, "worlds": None}]}}) is None
    assert _diff(old, {"lr": 1e-3, "labels": {"more": [{"seed": 11, "pairs": 5}]}}) == (
        "labels.more.0.seed", 10, 11)
    assert _diff(old, {"lr": 1e-3, "labels": {"more": []}})[0] == "labels.more"
