"""Training RE on rollout labels; the RE checkpoint is tied to its controller."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from topodrake.errors import TopodrakeError

torch.set_num_threads(1)
WORLD = "train-00"


@pytest.fixture(scope="module")
def labels(tmp_path_factory):
    from topodrake.learning.reachability.labels import (ReachLabelConfig, label_reachability,
                                                        load_reach_labels)
    from topodrake.learning.samples import TrajectorySet
    from topodrake.learning.waypoint.policy import AStarOracle
    from topodrake.rollout import ExpertRollout, RolloutConfig
    from topodrake.world import load_world

    world = load_world(WORLD)
    p = world.places
    pairs = [(0, 3), (2, 5)]
    res = ExpertRollout(world, RolloutConfig(t_max_s=60.0)).run(
        np.array([p[i] for i, _ in pairs]), np.array([p[j, :2] for _, j in pairs]))
    drives = [(0, res.trajectory(i)["poses"], res.trajectory(i)["controls"])
              for i in range(len(pairs)) if res.success[i]]
    trajs = TrajectorySet.from_drives([WORLD], drives)
    cfg = ReachLabelConfig(distance_min_m=-0.5, distance_max_m=2.5, batch=32, chunk=64)
    out = tmp_path_factory.mktemp("labels")
    folder = label_reachability(trajs, lambda w: AStarOracle(w), out / "l", 64, seed=1,
                                controller={"name": "oracle"}, config=cfg, progress=False)
    return load_reach_labels(folder)


def _config(**kw):
    from topodrake.learning.networks import NetworkConfig
    from topodrake.learning.reachability.train import ReachTrainConfig

    cfg = ReachTrainConfig(network=NetworkConfig(output="reach", k=1, channels=[8, 8, 16],
                                                 feature_dim=16, combine_channels=16, hidden=16),
                           batch_size=16, lr=3e-3, epoch_samples=10 ** 6, val_every_samples=10 ** 6,
                           checkpoint_every_s=10 ** 6, **{"init": "scratch", **kw})
    cfg.labels.train_pairs = 64
    cfg.labels.val_pairs = 64
    return cfg


def test_more_label_sets_come_from_yaml_and_need_seeds_of_their_own():
    from topodrake.learning.reachability.train import ReachTrainConfig
    from topodrake.typed_yaml import load_typed_data

    text = ("labels:\n  seed: 0\n  more:\n    - train_pairs: 500\n      seed: 7\n"
            "      rollout: {unjittered_sources: 1.0}\n")
    cfg = load_typed_data(ReachTrainConfig, text, "config").validate()
    assert cfg.labels.more[0].train_pairs == 500
    assert cfg.labels.more[0].rollout.unjittered_sources == 1.0
    assert cfg.labels.rollout.unjittered_sources == 0.0
    clash = load_typed_data(ReachTrainConfig, text.replace("seed: 7", "seed: 1"), "config")
    with pytest.raises(TopodrakeError, match="seed of its own"):
        clash.validate()                                    # seed 1 is the validation set's
    houses = load_typed_data(ReachTrainConfig, text + "      worlds: [train-12, train-13]\n",
                             "config").validate()
    assert houses.labels.more[0].worlds == ["train-12", "train-13"]
    for bad in ("[]", "[train-12, test-0]"):
        with pytest.raises(TopodrakeError, match="outside data.val_worlds"):
            load_typed_data(ReachTrainConfig, text + f"      worlds: {bad}\n", "config").validate()


def test_labels_have_both_outcomes(labels):
    assert len(labels) == 64
    assert 0.1 < labels.label.mean() < 0.95


def test_training_fits_the_labels_and_ties_the_checkpoint_to_its_controller(labels, tmp_path):
    from topodrake.learning.reachability.controllers import controller_identity, load_reachability
    from topodrake.learning.reachability.train import (ReachBatcher, evaluate_reach,
                                                       train_reachability)

    ctrl = tmp_path / "cwp.pt"
    ctrl.write_bytes(b"controller weights")
    ident = controller_identity(ctrl)
    cfg = _config(max_samples=16)
    first = train_reachability(cfg, tmp_path / "re", labels=(labels, labels), controller=ident,
                               progress=False)
    cfg = _config(max_samples=1600)
    more = train_reachability(cfg, tmp_path / "re", labels=(labels, labels), controller=ident,
                              progress=False)
    assert more.samples_seen == 1600
    assert more.metrics["bce"] < 0.8 * first.metrics["bce"]
    for key in ("ece", "brier", "auroc", "accuracy"):
        assert key in more.metrics
    card = json.loads((tmp_path / "re" / "card.json").read_text())
    assert card["controller"]["sha1"] == ident["sha1"] and card["output"] == "reach"
    ck = load_reachability(tmp_path / "re" / "checkpoint.pt", ctrl)
    assert ck.network.output == "reach"
    # same metrics when evaluated again from the loaded checkpoint
    again = evaluate_reach(ck.model, ReachBatcher(labels, ck.network))
    assert again["bce"] == pytest.approx(more.metrics["bce"], abs=1e-4)
    other = tmp_path / "other.pt"
    other.write_bytes(b"another controller")
    with pytest.raises(TopodrakeError, match="trained for controller"):
        load_reachability(tmp_path / "re" / "checkpoint.pt", other)


def test_re_starts_from_its_controller_and_keeps_a_temperature_that_helps(labels, tmp_path):
    from topodrake.learning.checkpoint import save_checkpoint
    from topodrake.learning.networks import NetworkConfig, WaypointNetwork
    from topodrake.learning.reachability.controllers import (checkpoint_temperature,
                                                             controller_identity, load_reachability)
    from topodrake.learning.reachability.estimator import Reachability
    from topodrake.learning.reachability.train import init_from_controller, train_reachability
    from topodrake.sensing.config import CameraConfig

    tiny = dict(k=1, channels=[8, 8, 16], feature_dim=16, combine_channels=16, hidden=16)
    torch.manual_seed(5)
    cwp = WaypointNetwork(NetworkConfig(**tiny), 64)
    save_checkpoint(tmp_path / "cwp.pt", cwp, CameraConfig())
    ident = controller_identity(tmp_path / "cwp.pt")
    cfg = _config(max_samples=16, init="controller", temperature_scaling=True)
    train_reachability(cfg, tmp_path / "re", labels=(labels, labels), controller=ident,
                       progress=False)
    ck = load_reachability(tmp_path / "re" / "checkpoint.pt", tmp_path / "cwp.pt")
    theirs, mine = cwp.state_dict(), ck.model.state_dict()
    for key in ("encoder.first.weight", "combine.weight", "overlap.0.weight"):
        # one Adam step (lr 3e-3) away from the controller's weights
        assert (theirs[key] - mine[key]).abs().max() < 2 * cfg.lr
        assert (theirs[key] - mine[key]).abs().max() < 0.1 * theirs[key].abs().max()
    # the temperature is kept only if it lowers the validation BCE, and loading applies it
    card = json.loads((tmp_path / "re" / "card.json").read_text())
    t = checkpoint_temperature(ck.meta)
    assert t == card["temperature"] > 0
    if t != 1.0:
        assert card["calibrated_metrics"]["bce"] < card["metrics"]["bce"]
    assert Reachability.from_checkpoint(tmp_path / "re" / "checkpoint.pt",
                                        tmp_path / "cwp.pt").temperature == t
    # a controller of another profile cannot seed RE
    wide = WaypointNetwork(NetworkConfig(output="reach", **{**tiny, "channels": [8, 16, 16]}), 64)
    with pytest.raises(TopodrakeError, match="network profile differs"):
        init_from_controller(wide, tmp_path / "cwp.pt")


def test_re_warm_starts_from_an_earlier_re_of_the_same_controller_only(labels, tmp_path):
    from topodrake.fileio import file_sha1
    from topodrake.learning.reachability.controllers import controller_identity, load_reachability
    from topodrake.learning.reachability.train import (ReachBatcher, evaluate_reach,
                                                       train_reachability)

    ctrl, other = tmp_path / "cwp.pt", tmp_path / "other.pt"
    ctrl.write_bytes(b"controller weights")
    other.write_bytes(b"another controller")
    ident = controller_identity(ctrl)
    base = train_reachability(_config(max_samples=1600), tmp_path / "base",
                              labels=(labels, labels), controller=ident, progress=False)
    base_path = tmp_path / "base" / "checkpoint.pt"
    warm = train_reachability(_config(max_samples=16, init=str(base_path)), tmp_path / "warm",
                              labels=(labels, labels), controller=ident, progress=False)
    cold = train_reachability(_config(max_samples=16), tmp_path / "cold",
                              labels=(labels, labels), controller=ident, progress=False)
    # one Adam step (lr 3e-3) away from the earlier RE's weights, so about as good
    # (weights; the batch-norm statistics move by their momentum)
    theirs = dict(load_reachability(base_path, ctrl).model.named_parameters())
    mine = dict(load_reachability(tmp_path / "warm" / "checkpoint.pt", ctrl).model.named_parameters())
    assert set(theirs) == set(mine)
    for key in theirs:
        assert (theirs[key] - mine[key]).abs().max() <= 2 * 3e-3, key
    assert warm.metrics["bce"] < cold.metrics["bce"]
    assert warm.metrics["bce"] == pytest.approx(base.metrics["bce"], abs=0.1)
    card = json.loads((tmp_path / "warm" / "card.json").read_text())
    assert card["init"] == {"checkpoint": str(base_path), "sha1": file_sha1(base_path),
                            "samples_seen": 1600}
    assert json.loads((tmp_path / "cold" / "card.json").read_text())["init"] == "scratch"
    # an RE of another controller, or of another profile, is refused before any step
    with pytest.raises(TopodrakeError, match="trained for controller"):
        train_reachability(_config(max_samples=16, init=str(base_path)), tmp_path / "x",
                           labels=(labels, labels), controller=controller_identity(other),
                           progress=False)
    wide = _config(max_samples=16, init=str(base_path))
    wide.network.channels = [8, 16, 16]
    with pytest.raises(TopodrakeError, match="network profile differs"):
        train_reachability(wide, tmp_path / "y", labels=(labels, labels), controller=ident,
                           progress=False)
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()
    with pytest.raises(TopodrakeError, match="missing.pt does not exist"):
        train_reachability(_config(max_samples=16, init=str(tmp_path / "missing.pt")),
                           tmp_path / "z", labels=(labels, labels), controller=ident, progress=False)
    with pytest.raises(TopodrakeError, match="init must be"):
        _config(init="").validate()


def test_re_of_a_controller_warm_starts_the_re_of_its_fine_tuned_child(labels, tmp_path):
    from topodrake.fileio import file_sha1
    from topodrake.learning.checkpoint import save_checkpoint
    from topodrake.learning.networks import NetworkConfig, WaypointNetwork
    from topodrake.learning.reachability.controllers import controller_identity
    from topodrake.learning.reachability.train import controller_parent, train_reachability
    from topodrake.sensing.config import CameraConfig

    tiny = dict(k=1, channels=[8, 8, 16], feature_dim=16, combine_channels=16, hidden=16)
    net = WaypointNetwork(NetworkConfig(**tiny), 64)
    parent, child, stranger = tmp_path / "parent.pt", tmp_path / "child.pt", tmp_path / "s.pt"
    save_checkpoint(parent, net, CameraConfig())
    save_checkpoint(child, net, CameraConfig(), samples_seen=5,
                    extra={"init": {"checkpoint": str(parent), "sha1": file_sha1(parent)}})
    save_checkpoint(stranger, net, CameraConfig(), samples_seen=7)
    assert controller_parent(child) == file_sha1(parent)
    assert controller_parent(parent) is None
    base = train_reachability(_config(max_samples=16), tmp_path / "base", labels=(labels, labels),
                              controller=controller_identity(parent), progress=False)
    assert base.samples_seen == 16
    init = str(tmp_path / "base" / "checkpoint.pt")
    warm = train_reachability(_config(max_samples=16, init=init), tmp_path / "warm",
                              labels=(labels, labels), controller=controller_identity(child),
                              progress=False)
    assert warm.samples_seen == 16
    card = json.loads((tmp_path / "warm" / "card.json").read_text())
    assert card["init"]["checkpoint"] == init
    assert card["controller"]["sha1"] == file_sha1(child)
    # an unrelated controller still may not inherit it
    with pytest.raises(TopodrakeError, match="trained for controller"):
        train_reachability(_config(max_samples=16, init=init), tmp_path / "x",
                           labels=(labels, labels), controller=controller_identity(stranger),
                           progress=False)


def test_reach_batches_carry_the_starting_overlaps(labels):
    from topodrake.learning.reachability.train import ReachBatcher, start_overlaps
    from topodrake.sensing.overlap import mutual_overlap
    from topodrake.world import load_world

    ov = start_overlaps(labels)
    t = labels.trajectories
    tgt = t.poses[t.traj_offsets[labels.traj] + labels.tgt]
    want = mutual_overlap(load_world(WORLD), labels.src_pose, tgt)
    assert np.allclose(ov, want) and ov.shape == (len(labels), 2)
    # both kinds of pairs are present: ones that see each other and ones that do not
    assert (ov.min(axis=1) < 0.05).any() and (ov.min(axis=1) > 0.5).any()
    cfg = _config()
    b = ReachBatcher(labels, cfg.network).batch(np.array([3, 0, 7]))
    assert torch.allclose(b.overlap, torch.from_numpy(ov[[3, 0, 7]]).float())


def test_reach_config_is_checked(tmp_path):
    from topodrake.learning.reachability.train import load_reach_config

    bad = tmp_path / "re.yaml"
    bad.write_text("network: {output: waypoint}\n")
    with pytest.raises(TopodrakeError, match="output must be 'reach'"):
        load_reach_config(bad)
    good = tmp_path / "ok.yaml"
    good.write_text("network: {output: reach, k: 2}\ncontroller: x.pt\nlabels: {train_pairs: 100}\n")
    cfg = load_reach_config(good)
    assert cfg.network.k == 2 and cfg.labels.train_pairs == 100 and cfg.controller == "x.pt"


def test_cli_refuses_bad_reach_configs(tmp_path, capsys):
    from topodrake.apps.cli import main

    assert main(["train", "reachability", "--config", str(tmp_path / "none.yaml"),
                 "--out", str(tmp_path / "o")]) == 2
    assert "none.yaml" in capsys.readouterr().err
    cfg = tmp_path / "re.yaml"
    cfg.write_text(f"network: {{output: reach}}\ncontroller: {tmp_path / 'missing.pt'}\n")
    assert main(["train", "reachability", "--config", str(cfg), "--out", str(tmp_path / "o"),
                 "--data", str(tmp_path / "data")]) == 2
    assert "missing.pt does not exist" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()          # nothing half-written


def test_reachability_cached_pairwise_and_naive_agree():
    from topodrake.learning.networks import NetworkConfig, WaypointNetwork
    from topodrake.learning.reachability.estimator import Reachability
    from topodrake.sensing.camera import Camera
    from topodrake.sensing.config import CameraConfig
    from topodrake.world import load_world

    world = load_world(WORLD)
    rng = np.random.default_rng(0)
    images = Camera(world).render(world.sample_free_pose(rng, 30))
    torch.manual_seed(0)
    re = Reachability(WaypointNetwork(NetworkConfig(output="reach", k=2), 64), CameraConfig())
    feats = re.frame_features(images, batch=7)            # several feature batches
    src = np.array([0, 3, 29, 10])
    tgt = np.array([5, 0, 12, 29])
    rows = re.context_rows(30, tgt)
    assert rows.min() == 0 and rows.max() == 29            # clamped at both ends
    pair = re.pairwise(feats, src, rows, batch=3)
    naive = re.probability_naive(images[src], images[rows])
    cached = re.probability(images[src], re.encode_target(images[rows]))
    assert np.allclose(pair, naive, atol=1e-5) and np.allclose(cached, naive, atol=1e-5)
    assert np.all((pair > 0) & (pair < 1))
    # temperature scaling moves probabilities toward 0.5
    soft = Reachability(re.model, CameraConfig(), temperature=4.0)
    p_soft = soft.probability(images[src], soft.encode_target(images[rows]))
    assert np.all(np.abs(p_soft - 0.5) <= np.abs(cached - 0.5) + 1e-9)
    anchors = re.sparsify(images, p=0.5, feats=feats)
    assert anchors[0] == 0 and anchors[-1] == 29 and np.all(np.diff(anchors) > 0)
    # frames of one drive use the anchor calibration, other queries the temperature
    assert soft.anchor_platt == (0.25, 0.0)
    assert np.allclose(soft.pairwise(feats, src, rows), p_soft, atol=1e-5)
    both = Reachability(re.model, CameraConfig(), temperature=1.0, anchor_platt=(0.25, 2.0))
    z = np.log(p_soft / (1 - p_soft))                       # logits / 4
    assert np.allclose(both.pairwise(feats, src, rows), 1 / (1 + np.exp(-(z + 2.0))), atol=1e-5)
    assert np.allclose(both.probability(images[src], both.encode_target(images[rows])), cached)


def test_mirror_average_is_the_mean_of_the_pair_and_its_mirror_image_on_every_path():
    from topodrake.learning.networks import NetworkConfig, WaypointNetwork, mirrored
    from topodrake.learning.reachability.estimator import Reachability
    from topodrake.sensing.camera import Camera
    from topodrake.sensing.config import CameraConfig
    from topodrake.world import load_world

    world = load_world(WORLD)
    images = Camera(world).render(world.sample_free_pose(np.random.default_rng(1), 20))
    torch.manual_seed(1)
    model = WaypointNetwork(NetworkConfig(output="reach", k=1), 64).eval()
    with torch.no_grad():
        model.reach[2].weight.mul_(300.0)      # spread the untrained logits
    plain = Reachability(model, CameraConfig())
    both = Reachability(model, CameraConfig(), anchor_platt=(0.5, 1.0), mirror_average=True)
    src, tgt = np.array([0, 4, 19]), np.array([7, 19, 2])
    rows = both.context_rows(20, tgt)
    cur, ctx = both.to_input(images[src]), both.to_input(images[rows])
    with torch.no_grad():
        z = [model.forward_split(c, x)["reach_logit"][:, 0].numpy()
             for c, x in ((cur, ctx), (mirrored(cur), mirrored(ctx)))]
    want = 1 / (1 + np.exp(-(z[0] + z[1]) / 2))
    assert np.abs(z[0] - z[1]).max() > 0.01          # the mirror image is another pair
    assert np.allclose(plain.probability_naive(images[src], images[rows]),
                       1 / (1 + np.exp(-z[0])), atol=1e-5)
    assert np.allclose(both.probability_naive(images[src], images[rows]), want, atol=1e-5)
    target = both.encode_target(images[rows])
    assert target.shape[1] == 2 * plain.cfg.frames
    assert np.allclose(both.probability(images[src], target), want, atol=1e-5)
    feats = both.frame_features(images, batch=6)
    assert np.allclose(both.pairwise(feats, src, rows),
                       1 / (1 + np.exp(-(0.5 * (z[0] + z[1]) / 2 + 1.0))), atol=1e-5)
    # features or targets made for the plain RE are refused, not misread
    with pytest.raises(TopodrakeError, match="mirror images"):
        both.pairwise(plain.frame_features(images), src, rows)
    with pytest.raises(TopodrakeError, match="target features have"):
        both.probability(images[src], plain.encode_target(images[rows]))


def test_mirror_augment_flips_both_views_of_the_chosen_pairs_only(labels):
    from topodrake.learning.reachability.train import ReachBatcher, mirror_some

    b = ReachBatcher(labels, _config().network).batch(np.arange(8))
    assert mirror_some(b, 0.0) is b
    all_ = mirror_some(b, 1.0)
    assert torch.equal(all_.cur, b.cur.flip(-1)) and torch.equal(all_.ctx, b.ctx.flip(-1))
    some = mirror_some(b, 0.5, torch.Generator().manual_seed(3))
    flipped = torch.tensor([torch.equal(some.cur[i], b.cur[i].flip(-1)) for i in range(8)])
    kept = torch.tensor([torch.equal(some.cur[i], b.cur[i]) for i in range(8)])
    assert flipped.any() and kept.any() and torch.all(flipped ^ kept)
    for i in range(8):      # a pair's target context goes with its view
        assert torch.equal(some.ctx[i], b.ctx[i].flip(-1) if flipped[i] else b.ctx[i])
    assert torch.equal(some.label, b.label) and torch.equal(some.overlap, b.overlap)
    assert torch.equal(b.cur, ReachBatcher(labels, _config().network).batch(np.arange(8)).cur)


@pytest.mark.parametrize("mirror_average", [False, True])
def test_reachability_estimator_system_matches_the_batched_call(mirror_average):
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource

    from topodrake.learning.networks import NetworkConfig, WaypointNetwork
    from topodrake.learning.reachability.estimator import Reachability
    from topodrake.contract.waypoint import TargetContext
    from topodrake.sensing.camera import Camera
    from topodrake.sensing.config import CameraConfig
    from topodrake.systems.diagram import add_chassis
    from topodrake.systems.reachability import ReachabilityEstimator
    from topodrake.systems.scenario import Scenario
    from topodrake.systems.waypoint_net import TargetSource
    from topodrake.world import load_world

    world = load_world(WORLD)
    torch.manual_seed(3)
    re = Reachability(WaypointNetwork(NetworkConfig(output="reach", k=1), 64), CameraConfig(),
                      mirror_average=mirror_average)
    poses = world.sample_free_pose(np.random.default_rng(4), 4)
    images = Camera(world).render(poses)
    b = DiagramBuilder()
    c = add_chassis(b, Scenario(world=WORLD), world, camera=True)
    stop = b.AddSystem(ConstantVectorSource(np.zeros(2)))
    b.Connect(stop.get_output_port(), c.noise.controls_port)
    source = b.AddSystem(TargetSource())
    est = b.AddSystem(ReachabilityEstimator(re))
    b.Connect(c.camera.image_port, est.observation_port)
    b.Connect(source.target_port, est.target_port)
    diagram = b.Build()
    ctx = diagram.CreateDefaultContext()
    c.car.GetMyMutableContextFromRoot(ctx).SetContinuousState(np.array([*poses[0], 0.0, 0.0]))
    est_ctx = est.GetMyContextFromRoot(ctx)
    assert est.probability_port.Eval(est_ctx)[0] == 0.0           # no target yet
    source.set_target(source.GetMyMutableContextFromRoot(ctx),
                      TargetContext(key=7, observations=images[1:]))
    # the camera samples (and the estimator caches the target) at t = 0 when
    # the simulator takes its first step; the car stands still
    from pydrake.systems.analysis import ApplySimulatorConfig, Simulator, SimulatorConfig
    sim = Simulator(diagram, ctx)
    ApplySimulatorConfig(SimulatorConfig(integration_scheme="runge_kutta2", max_step_size=0.1,
                                         use_error_control=False), sim)
    sim.AdvanceTo(0.05)
    held = c.camera.image_port.Eval(c.camera.GetMyContextFromRoot(ctx))
    assert np.array_equal(held, images[0])                       # the image at the start pose
    got = est.probability_port.Eval(est.GetMyContextFromRoot(ctx))[0]
    want = re.probability(images[:1], re.encode_target(images[1:][None]))[0]
    assert got == pytest.approx(want, abs=1e-6) and 0.0 < got < 1.0


def test_bench_reachability_cli_refuses_a_missing_controller(tmp_path, capsys):
    from topodrake.apps.cli import main

    assert main(["bench", "reachability", "--controller", str(tmp_path / "no.pt")]) == 2
    assert "no.pt does not exist" in capsys.readouterr().err


@pytest.fixture(scope="module")
def tiny_re(tmp_path_factory):
    """(demo folder of test-1 with two drives, untrained tiny RE, its untrained tiny C_WP)."""
    from topodrake.demonstrations import CollectConfig, collect
    from topodrake.learning.checkpoint import save_checkpoint
    from topodrake.learning.networks import NetworkConfig, WaypointNetwork
    from topodrake.learning.reachability.controllers import controller_identity
    from topodrake.sensing.config import CameraConfig

    tmp = tmp_path_factory.mktemp("tiny_re")
    demos = collect("test-1", tmp / "demos", CollectConfig(protocol="random", count=2, seed=5),
                    progress=False)
    torch.manual_seed(0)
    tiny = dict(k=1, channels=[8, 8, 16], feature_dim=16, combine_channels=16, hidden=16)
    ctrl = save_checkpoint(tmp / "cwp.pt", WaypointNetwork(NetworkConfig(**tiny), 64), CameraConfig())
    net = WaypointNetwork(NetworkConfig(output="reach", **tiny), 64)
    save_checkpoint(tmp / "re.pt", net, CameraConfig(),
                    extra={"controller": controller_identity(ctrl)})
    return demos, tmp / "re.pt", ctrl


def test_sparsify_cli_end_to_end(tiny_re, tmp_path, capsys):
    from topodrake.apps.cli import main

    demos, re_path, ctrl = tiny_re
    args = ["sparsify", "test-1", "--reach", str(re_path), "--controller", str(ctrl),
            "--demos", str(demos), "--p", "0.3", "--out", str(tmp_path / "a.png"), "--json"]
    assert main(args + ["--hop-runs", "1"]) in (0, None)
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert 0.0 <= out["hop_success"] <= 1.0
    assert out["anchor_frames"][0] == 0 and out["anchor_frames"][-1] == out["frames"] - 1
    assert out["keep_ratio"] == pytest.approx(out["anchors"] / out["frames"], abs=1e-4)
    assert (tmp_path / "a.png").stat().st_size > 10000
    other = tmp_path / "other.pt"
    other.write_bytes(b"o")
    args[5] = str(other)
    args[args.index("--out") + 1] = str(tmp_path / "b.png")   # a.png exists: its check comes first
    assert main(args) == 2
    assert "trained for controller" in capsys.readouterr().err
    assert main(args[:4] + ["--controller", str(ctrl), "--demos", str(tmp_path / "none")]) == 2
    assert "no demonstrations" in capsys.readouterr().err


def test_sparsification_study_compares_estimators_on_the_longest_drive(tiny_re, tmp_path):
    from study_run import run_study
    from topodrake.demonstrations import load_demos

    demos, re_path, ctrl = tiny_re
    est = f"a={re_path}:{ctrl},b={re_path}:{ctrl}"
    code, out, err = run_study("sparsification", "--world", "test-1", "--demos", demos,
                               "--estimators", est, "--p", "0.3", "--hop-runs", "2",
                               "--out", tmp_path, "--json")
    assert code == 0, err
    summary = json.loads(out.strip().splitlines()[-1])
    saved = json.loads((tmp_path / "sparsification.json").read_text())
    lengths = [len(d.poses) for d in load_demos(demos, successful_only=True)[1]]
    assert saved["drive"] == int(np.argmax(lengths)) and saved["frames"] == max(lengths)
    assert summary["a"] == summary["b"]                     # the same RE twice: the same anchors
    frames = saved["results"]["a"]["anchor_frames"]
    assert frames[0] == 0 and frames[-1] == max(lengths) - 1
    assert summary["a"]["keep_ratio"] == pytest.approx(len(frames) / max(lengths), abs=1e-4)
    hops = saved["results"]["a"]["hop_successes"]             # two noisy runs per anchor hop
    assert len(hops) == len(frames) - 1 and all(0 <= h <= 2 for h in hops)
    assert summary["a"]["hop_success"] == pytest.approx(sum(hops) / (2 * len(hops)), abs=1e-4)
    assert (tmp_path / "sparsification.png").stat().st_size > 10000
    code, _, err = run_study("sparsification", "--world", "test-1", "--demos", demos,
                             "--estimators", est, "--drive", "7", "--out", tmp_path)
    assert code == 2
    assert "--drive must be in 0..1" in err
    # the same check over the first drives of each house named
    root = tmp_path / "data" / "demos" / "pairs-s0"
    root.mkdir(parents=True)
    (root / "test-1").symlink_to(demos)
    base = ["--world", "test-1", "--demos", str(demos), "--estimators", f"a={re_path}:{ctrl}",
            "--p", "0.3", "--out", str(tmp_path), "--data", str(tmp_path / "data"), "--json",
            "--check-worlds", "test-1"]
    code, out, err = run_study("sparsification", *base, "--hop-runs", "2", "--check-drives", "1")
    assert code == 0, err
    checked = json.loads(out.strip().splitlines()[-1])["a"]["test_houses"]
    first = load_demos(demos, successful_only=True)[1][0]
    assert checked["drives"] == 1 and checked["frames"] == len(first.poses)
    assert checked["hops"] == checked["anchors"] - 1
    assert checked["failed_runs"] == round(2 * checked["hops"] * (1 - checked["hop_success"]))
    code, _, err = run_study("sparsification", *base, "--hop-runs", "0", "--check-drives", "1")
    assert code == 2
    assert "--check-drives needs --hop-runs" in err


def test_houses_are_sparsified_under_other_calibrations_from_the_same_features(tiny_re, tmp_path):
    from topodrake.learning.reachability.estimator import Reachability
    from topodrake.experiments.hops import sparsify_houses

    demos, re_path, ctrl = tiny_re
    (tmp_path / "test-1").symlink_to(demos)
    re = Reachability.from_checkpoint(re_path, ctrl)
    out = sparsify_houses(re, ["test-1"], tmp_path, p=0.3, other_calibrations={
        "same": re.anchor_platt, "doubtful": (re.anchor_platt[0], re.anchor_platt[1] - 5.0)})
    assert out["keep_ratios"]["same"] == out["keep_ratio"]
    # lower probabilities everywhere: every frame fails p, so every frame is kept
    assert out["keep_ratios"]["doubtful"] == 1.0 > out["keep_ratio"]
    assert "keep_ratios" not in sparsify_houses(re, ["test-1"], tmp_path, p=0.3)


def test_houses_report_the_share_of_hops_that_advance_one_frame(tiny_re, tmp_path):
    from topodrake.demonstrations import load_demos
    from topodrake.learning.reachability.estimator import Reachability
    from topodrake.experiments.hops import sparsify_houses
    from topodrake.world import load_world

    demos, re_path, ctrl = tiny_re
    (tmp_path / "test-1").symlink_to(demos)
    re = Reachability.from_checkpoint(re_path, ctrl)
    hops = []
    for d in load_demos(demos, successful_only=True)[1]:
        hops.append(np.diff(re.sparsify(re.observe(load_world("test-1"), d.poses), p=0.3)))
    hops = np.concatenate(hops)
    out = sparsify_houses(re, ["test-1"], tmp_path, p=0.3)
    assert out["one_frame_hops"] == round(float(np.mean(hops == 1)), 4)
    # a bar no pair clears keeps every frame: every hop advances one frame
    stalled = sparsify_houses(re, ["test-1"], tmp_path, p=1.0 - 1e-12)
    assert stalled["keep_ratio"] == 1.0 and stalled["one_frame_hops"] == 1.0


def test_calibration_study_refuses_bad_estimators(tmp_path):
    from study_run import run_study

    code, _, err = run_study("reachability_calibration", "--estimators", "x=only-one-path",
                             "--out", tmp_path)
    assert code == 2
    assert "name=RE.pt:CWP.pt" in err
    code, _, err = run_study("reachability_calibration", "--estimators",
                             f"x={tmp_path}/a.pt:{tmp_path}/b.pt")
    assert code == 2
    assert "a.pt does not exist" in err


def test_calibration_study_splits_auroc_by_how_pairs_start():
    from topodrake.experiments.calibration_trials import summarise_trials

    # reached pairs (p 0.6-0.9), two driven failures ranked among them,
    # blind starts (no overlap) all below every reached pair
    recs = ([{"p": v, "success": True, "start_overlap": [0.8, 0.6]} for v in (0.6, 0.7, 0.8, 0.9)]
            + [{"p": v, "success": False, "start_overlap": [0.5, 0.4]} for v in (0.75, 0.85)]
            + [{"p": v, "success": False, "start_overlap": [0.0, 0.01]} for v in (0.1, 0.2, 0.3)])
    s = summarise_trials(recs)
    assert s["n"] == 9 and s["share_not_overlapping"] == pytest.approx(3 / 9)
    assert s["auroc_reached_vs_not_overlapping"] == pytest.approx(1.0)
    assert s["auroc_overlapping"] == pytest.approx(3 / 8)   # 2 + 1 reached pairs above them
    assert s["auroc"] == pytest.approx((3 + 12) / 20)
    assert sum(s["reliability"]["count"]) == 9


def test_label_folders_name_what_the_labels_depend_on_not_the_data_path(tmp_path):
    from topodrake.learning.reachability.labels import ReachLabelConfig
    from topodrake.learning.reachability.train import label_folder

    ident = {"sha1": "ab" * 20}
    args = ("train", "pairs-s0", ["train-00"], 100, 0)
    rel = label_folder("data", ident, *args, ReachLabelConfig())
    absolute = label_folder(tmp_path / "data", ident, *args, ReachLabelConfig())
    assert rel.name == absolute.name and rel.name.startswith("ababababab-train-")
    assert absolute.parent == tmp_path / "data" / "reach-labels"
    other = [label_folder("data", ident, "train", "pairs-s0", ["train-00"], 100, 1, ReachLabelConfig()),
             label_folder("data", ident, "train", "random20-s0", ["train-00"], 100, 0, ReachLabelConfig()),
             label_folder("data", ident, *args, ReachLabelConfig(unjittered_sources=0.5))]
    assert len({rel.name, *(o.name for o in other)}) == 4


def test_anchor_hops_get_their_own_temperature_also_after_training(labels, tmp_path):
    from topodrake.learning.reachability.controllers import controller_identity, load_reachability
    from topodrake.learning.reachability.estimator import Reachability
    from topodrake.learning.reachability.labels import ReachLabels
    from topodrake.learning.reachability.train import AnchorCalibration, train_reachability

    ctrl = tmp_path / "cwp.pt"
    ctrl.write_bytes(b"controller weights")
    ident = controller_identity(ctrl)
    # "anchor hops": the easy pairs (mostly reached), unlike the validation mix
    pick = np.concatenate([np.flatnonzero(labels.label == 1), np.flatnonzero(labels.label == 0)[:2]])
    hops = ReachLabels(labels.trajectories, {k: v[pick] for k, v in labels.fields.items()}, {})
    none = _config(max_samples=320, anchor_calibration=AnchorCalibration(pairs=0),
                   mirror_average=False)
    train_reachability(none, tmp_path / "re", labels=(labels, labels), controller=ident,
                       progress=False)
    ck = load_reachability(tmp_path / "re" / "checkpoint.pt", ctrl)
    assert "anchor_platt" not in ck.meta["extra"]
    # rerunning the finished run with anchor hops only refits the calibration
    again = train_reachability(_config(max_samples=320, mirror_average=False), tmp_path / "re",
                               labels=(labels, labels, hops), controller=ident, progress=False)
    assert again.samples_seen == 320 and again.train_samples_per_s > 0
    ck2 = load_reachability(tmp_path / "re" / "checkpoint.pt", ctrl)
    assert torch.equal(ck2.model.state_dict()["reach.0.weight"], ck.model.state_dict()["reach.0.weight"])
    card = json.loads((tmp_path / "re" / "card.json").read_text())
    platt = tuple(ck2.meta["extra"]["anchor_platt"])
    assert card["anchor_platt"] == list(platt) and card["anchor_pairs"] == len(pick)
    assert card["anchor_success_rate"] == pytest.approx(labels.label[pick].mean(), abs=1e-4)
    # fitted to the hops: a lower BCE on them than the temperature gives
    assert card["anchor_metrics"]["bce"] < card["anchor_metrics_temperature"]["bce"]
    re = Reachability.from_checkpoint(tmp_path / "re" / "checkpoint.pt", ctrl)
    assert re.temperature == card["temperature"] and re.anchor_platt == platt
    assert not re.mirror_average and card["mirror_average"] is False
    # and with mirror_average the calibrations are refitted on the averaged logit
    train_reachability(_config(max_samples=320, mirror_average=True), tmp_path / "re",
                       labels=(labels, labels, hops), controller=ident, progress=False)
    card2 = json.loads((tmp_path / "re" / "card.json").read_text())
    re2 = Reachability.from_checkpoint(tmp_path / "re" / "checkpoint.pt", ctrl)
    assert re2.mirror_average and card2["mirror_average"] is True
    assert re2.anchor_platt == tuple(card2["anchor_platt"]) != platt


def test_anchor_calibration_config_is_checked():
    from topodrake.learning.reachability.train import AnchorCalibration

    with pytest.raises(TopodrakeError, match="anchor_calibration.seed 1"):
        _config(anchor_calibration=AnchorCalibration(seed=1)).validate()
    with pytest.raises(TopodrakeError, match="pairs must be >= 0"):
        _config(anchor_calibration=AnchorCalibration(pairs=-1)).validate()
    _config(anchor_calibration=AnchorCalibration(pairs=0, seed=1)).validate()


def test_limits_study_ceiling_and_hop_bins(tmp_path):
    from study_run import run_study
    from topodrake.experiments.reach_limits import oracle_auroc, success_by_distance

    # deterministic outcomes: the other runs predict each run perfectly
    fixed = np.array([[1, 1, 1], [0, 0, 0], [1, 1, 1], [0, 0, 0]])
    assert oracle_auroc(fixed) == 1.0
    # coin flips: the other runs know nothing (AUROC about 0.5)
    flips = (np.random.default_rng(0).random((400, 4)) < 0.5).astype(int)
    assert abs(oracle_auroc(flips) - 0.5) < 0.08
    with pytest.raises(TopodrakeError, match="two runs"):
        oracle_auroc(fixed[:, :1])
    bins = success_by_distance(np.array([0.1, 0.2, 0.7, 3.0]), np.array([1, 0, 1, 1]))
    assert [b["n"] for b in bins] == [2, 0, 1, 0, 0, 0, 1]        # 3.0 m counts in the last bin
    assert bins[0]["success"] == 0.5 and bins[1]["success"] is None
    code, _, err = run_study("reachability_limits", "--runs", "1", "--out", tmp_path)
    assert code == 2
    assert "--runs >= 2" in err
    code, _, err = run_study("reachability_limits", "--keep-runs", "0", "--out", tmp_path)
    assert code == 2                               # refused by the option's type
    assert "argument --keep-runs: must be an integer >= 1, got 0" in err


def test_limits_study_compares_res_keep_ratio_with_the_controllers_own(tiny_re):
    from topodrake.demonstrations import load_demos
    from topodrake.learning.reachability.estimator import Reachability
    from topodrake.experiments.reach_limits import controller_keep
    from topodrake.learning.samples import TrajectorySet
    from topodrake.learning.waypoint.policy import AStarOracle
    from topodrake.world import load_world

    demos, re_path, ctrl = tiny_re
    poses = load_demos(demos, successful_only=True)[1][0].poses[:60]
    trajs = TrajectorySet(["test-1"], np.zeros(1, np.int32), np.array([0, 60]), poses,
                          np.column_stack([poses, np.zeros((60, 2))]))
    world = load_world("test-1")
    re = Reachability.from_checkpoint(re_path, ctrl)
    out = controller_keep(re, AStarOracle(world), trajs, 1, runs=2, seed=0, progress=False)
    assert out["drives"] == 1 and out["frames"] == 60 and out["runs"] == 2
    # hops of at most MAX_HOP_FRAMES: at least 0, 40, 59 are kept
    assert out["keep_ratio"] >= round(3 / 60, 4) and 0.0 <= out["hop_success"] <= 1.0
    assert out["scan_rollouts"] > 0 and out["scan_rollouts"] % 2 == 0
    assert out["re_keep_ratio"] == round(len(re.sparsify(re.observe(world, poses))) / 60, 4)


@pytest.mark.parametrize("name", ["reach_camera_k2", "reach_camera_k5_base", "reach_camera_k5",
                                  "reach_lidar_k5", "reach_lidar_reg", "reach_lidar_k5_dagger",
                                  "reach_lidar_k5_onpolicy", "reach_lidar_k5_scale",
                                  "reach_camera_k5_scale"])
def test_shipped_res_were_trained_with_their_configs_and_controllers(name):
    """A shipped RE matches its YAML (so the card's command reproduces it)
    and the C_WP file it measured; label sets name catalogue houses only."""
    from pathlib import Path

    from topodrake.fileio import file_sha1
    from topodrake.learning.checkpoint import load_checkpoint
    from topodrake.learning.reachability.controllers import controller_identity
    from topodrake.learning.reachability.train import load_reach_config
    from topodrake.learning.waypoint.train import config_change
    from topodrake.world.catalogue import catalogue_names

    root = Path(__file__).resolve().parents[1]
    cfg = load_reach_config(root / "configs" / f"{name}.yaml")
    ck = load_checkpoint(root / "checkpoints" / name / "checkpoint.pt", output="reach")
    assert config_change(ck, cfg.to_dict()) is None
    # calibrated as the config says (a calibration switch changed without
    # rerunning the command would leave the shipped calibration stale)
    assert ck.meta["extra"].get("mirror_average", False) == cfg.mirror_average
    assert ("anchor_platt" in ck.meta["extra"]) == bool(cfg.anchor_calibration.pairs)
    trained_for = ck.meta["extra"]["controller"]
    assert trained_for["checkpoint"] == cfg.controller
    named = cfg.controller if cfg.controller == "registration" else root / cfg.controller
    assert trained_for["sha1"] == controller_identity(named)["sha1"]
    houses = set(catalogue_names())
    for more in cfg.labels.more:
        assert set(more.worlds or []) <= houses
    if cfg.init not in ("controller", "scratch"):     # fine-tuned from the RE it names, as shipped
        card = json.loads((root / "checkpoints" / name / "card.json").read_text())
        assert card["init"]["sha1"] == file_sha1(root / cfg.init)


def test_registration_controller_is_named_by_its_settings(labels, tmp_path):
    """The registration C_WP has no checkpoint file: its RE is tied to the
    fingerprint of its settings, and a registration controller with other
    settings (or a C_WP checkpoint) is refused next to it."""
    from topodrake.fileio import file_sha1
    from topodrake.learning.reachability.controllers import (controller_identity, controller_policy,
                                                             load_reachability,
                                                             registration_identity)
    from topodrake.learning.reachability.estimator import Reachability
    from topodrake.learning.reachability.train import train_reachability
    from topodrake.registration.policy import RegistrationConfig, RegistrationPolicy

    ident = controller_identity("registration")
    assert ident == registration_identity() == controller_identity(RegistrationPolicy())
    assert ident["checkpoint"] == "registration" and len(ident["sha1"]) == 40
    other = RegistrationPolicy(RegistrationConfig(lookahead_m=2.0))
    assert controller_identity(other)["sha1"] != ident["sha1"]
    assert isinstance(controller_policy("registration"), RegistrationPolicy)
    with pytest.raises(TopodrakeError, match="C_WP checkpoint path"):
        controller_identity(3)
    # no network to start from
    with pytest.raises(TopodrakeError, match="no network to start from"):
        _config(controller="registration", init="controller").validate()
    train_reachability(_config(controller="registration", max_samples=32), tmp_path / "re",
                       labels=(labels, labels), controller=ident, progress=False)
    path = tmp_path / "re" / "checkpoint.pt"
    assert load_reachability(path, "registration").meta["extra"]["controller"] == ident
    reach = Reachability.from_checkpoint(path, RegistrationPolicy())
    assert reach.controller == ident
    with pytest.raises(TopodrakeError, match="trained for controller 'registration'"):
        Reachability.from_checkpoint(path, other)
    cwp = tmp_path / "cwp.pt"
    cwp.write_bytes(b"controller weights")
    with pytest.raises(TopodrakeError, match="trained for controller 'registration'"):
        load_reachability(path, cwp)
    # an RE of another controller seeds it only when the config says so
    base = tmp_path / "base"
    train_reachability(_config(max_samples=32), base, labels=(labels, labels),
                       controller=controller_identity(cwp), progress=False)
    init = str(base / "checkpoint.pt")
    with pytest.raises(TopodrakeError, match="trained for controller"):
        train_reachability(_config(controller="registration", max_samples=16, init=init),
                           tmp_path / "x", labels=(labels, labels), controller=ident,
                           progress=False)
    assert not (tmp_path / "x").exists()
    train_reachability(_config(controller="registration", max_samples=16, init=init,
                               init_any_controller=True), tmp_path / "warm",
                       labels=(labels, labels), controller=ident, progress=False)
    card = json.loads((tmp_path / "warm" / "card.json").read_text())
    assert card["controller"] == ident
    assert card["init"] == {"checkpoint": init, "sha1": file_sha1(init), "samples_seen": 32,
                            "controller": controller_identity(cwp)}


def test_maps_and_followers_load_the_registration_controller_by_name(labels, tmp_path):
    """A map built with a registration RE records the controller by name;
    the follower's networks load from that name, and a mismatched pair is
    refused."""
    from topodrake.learning.networks import NetworkConfig
    from topodrake.learning.reachability.controllers import controller_identity
    from topodrake.learning.reachability.train import train_reachability
    from topodrake.registration.policy import RegistrationPolicy
    from topodrake.topomap.sources import load_networks, make_scorer

    cfg = _config(controller="registration", max_samples=16)
    cfg.network = NetworkConfig(modality="lidar", output="reach", k=5, channels=[8, 8, 16],
                                feature_dim=16, combine_channels=16, hidden=16)
    train_reachability(cfg, tmp_path / "re", labels=(labels, labels),
                       controller=controller_identity("registration"), progress=False)
    path = tmp_path / "re" / "checkpoint.pt"
    policy, reach = load_networks("registration", path)
    assert isinstance(policy, RegistrationPolicy) and reach.observation == "lidar"
    assert (policy.k, policy.frame_step) == (reach.k, reach.frame_step)
    scorer = make_scorer("lidar", reach=path, controller="registration")
    assert scorer.identity["controller"] == "registration"
    assert scorer.identity["controller_sha1"] == controller_identity("registration")["sha1"]
    with pytest.raises(TopodrakeError, match="not a camera one"):
        make_scorer("camera", reach=path, controller="registration")
    cwp = tmp_path / "cwp.pt"
    cwp.write_bytes(b"controller weights")
    with pytest.raises(TopodrakeError, match="trained for controller 'registration'"):
        load_networks(cwp, path)
    with pytest.raises(TopodrakeError, match="give the RE checkpoint"):
        load_networks(cwp)
    with pytest.raises(TopodrakeError, match="missing.pt does not exist"):
        load_networks("registration", tmp_path / "missing.pt")


def test_sparsification_scenarios_are_the_defaults_and_the_figures_command():
    from study_run import check_scenarios

    from topodrake.experiments.sparsify_compare import SparsifyStudy

    check_scenarios("sparsification", SparsifyStudy, ("default", "figure"),
                    {"figure": ["--check-drives", "3", "--json"]})


def test_reachability_limits_default_scenario_is_the_defaults():
    from study_run import check_scenarios

    from topodrake.experiments.reach_limits import ReachLimitsStudy

    check_scenarios("reachability_limits", ReachLimitsStudy)


def test_reachability_calibration_default_scenario_is_the_figures_command():
    from study_run import check_scenarios

    from topodrake.experiments.calibration_trials import CalibrationStudy

    check_scenarios("reachability_calibration", CalibrationStudy, ("default",),
                    {"default": ["--pairs", "1000", "--json"]})
