"""Throughput of the waypoint network: training and closed-loop inference.

``bench_networks()`` returns the figures ``topodrake bench networks --json``
prints:

* ``train_samples_per_s``: full training steps (render the batch from
  poses, forward, backward, Adam) on real samples of one house;
* ``infer_naive_per_s``: closed-loop steps per second at batch 1, the full
  network on the 2k + 1 stacked [current, frame, current - frame] inputs;
* ``infer_cached_per_s``: the same with the target half of the first layer
  cached (what a follower does while it follows one anchor);
* ``infer_*_batch_per_s``: the same per sample at batch ``batch`` (the
  batched engine), and ``cached_speedup`` = cached / naive at batch 1;
* ``registration_per_s``: lidar scan pairs registered per second by the
  compiled ICP (:mod:`topodrake.experiments.bench_registration`).

Naive and cached are timed in alternating windows (median of 5 each), so a
change of load during the run affects both figures alike.

Rates count one thread unless ``threads`` says otherwise.
"""

from __future__ import annotations

import time
from contextlib import contextmanager

import numpy as np
import torch

from topodrake.experiments.bench_registration import registration_rate
from topodrake.learning.reachability.labels import ReachLabelConfig, draw_pairs, rollout_pairs
from topodrake.learning.samples import TrajectorySet, make_samples
from topodrake.montecarlo import trial_seeds
from topodrake.rollout import ExpertRollout, RolloutConfig
from topodrake.sensing.observe import observe
from topodrake.world import load_world


@contextmanager
def torch_threads(n: int):
    """Run the block with ``n`` torch threads, then restore the previous count."""
    old = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old)


def _rate(fn, n_items: int, min_seconds: float) -> float:
    fn()
    calls, start = 0, time.perf_counter()
    while True:
        fn()
        calls += 1
        elapsed = time.perf_counter() - start
        if elapsed >= min_seconds:
            return calls * n_items / elapsed


def expert_drives(world, place_pairs, t_max_s: float):
    """A :class:`TrajectorySet` of the expert's successful drives between
    ``place_pairs`` (start place, goal place) of ``world``."""
    p = world.places
    res = ExpertRollout(world, RolloutConfig(t_max_s=t_max_s)).run(
        np.array([p[i] for i, _ in place_pairs]), np.array([p[j, :2] for _, j in place_pairs]))
    drives = [(0, res.trajectory(i)["poses"], res.trajectory(i)["controls"])
              for i in range(len(place_pairs)) if res.success[i]]
    return TrajectorySet.from_drives([world.name], drives)


def _paired_rates(fn_a, fn_b, n_items: int, min_seconds: float, rounds: int = 5
                  ) -> tuple[float, float]:
    """Median rates of two calls timed in alternating windows, so that a
    change of machine load during the measurement hits both alike."""
    window = min_seconds / rounds
    a, b = [], []
    for _ in range(rounds):
        a.append(_rate(fn_a, n_items, window))
        b.append(_rate(fn_b, n_items, window))
    return float(np.median(a)), float(np.median(b))


def bench_networks(config=None, world_name: str = "train-00", batch: int = 64,
                   min_seconds: float = 3.0, threads: int = 1, seed: int = 0) -> dict:
    """Train / inference throughput of ``config`` (a TrainConfig; default:
    the default camera k = 5 profile)."""
    from topodrake.learning.config import TrainConfig
    from topodrake.learning.data import SampleBatcher
    from topodrake.learning.networks import WaypointNetwork, input_size
    from topodrake.learning.waypoint.policy import LearnedWaypointPolicy
    from topodrake.learning.waypoint.train import waypoint_loss

    cfg = config or TrainConfig()
    net_cfg = cfg.network
    with torch_threads(threads):
        world = load_world(world_name)
        trajs = expert_drives(world, [(0, 3), (2, 5), (4, 1), (6, 8)], 90.0)
        samples = make_samples(trajs, 8 * batch, seed)
        batcher = SampleBatcher(samples, net_cfg, cfg.camera, cfg.lidar)
        torch.manual_seed(seed)
        model = WaypointNetwork(net_cfg, input_size(net_cfg, cfg.lidar.beams))
        opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
        rng = np.random.default_rng(seed)

        def train_step():
            b = batcher.batch(rng.choice(len(samples), batch, replace=False))
            loss, _ = waypoint_loss(model.forward_split(b.cur, b.ctx), b, net_cfg.output)
            opt.zero_grad()
            loss.backward()
            opt.step()

        out = {"modality": net_cfg.modality, "k": net_cfg.k, "image_size": net_cfg.image_size,
               "channels": list(net_cfg.channels), "threads": threads,
               "train_samples_per_s": _rate(train_step, batch, min_seconds)}
        model.eval()
        sensor = cfg.camera if net_cfg.modality == "camera" else cfg.lidar
        policy = LearnedWaypointPolicy(model, sensor)
        rows = samples.context_rows(net_cfg.k, net_cfg.frame_step)
        src = batcher.source
        wi = samples.world_index
        ctx = src.raw(np.repeat(wi[:batch], rows.shape[1]),
                      samples.trajectories.poses[rows[:batch].ravel()]).reshape(
                          batch, rows.shape[1], *src.raw(wi[:1], samples.src_pose[:1]).shape[1:])
        cur = src.raw(wi[:batch], samples.src_pose[:batch])
        feats1 = policy.encode_target(ctx[:1])
        feats = policy.encode_target(ctx)
        out["infer_naive_per_s"], out["infer_cached_per_s"] = _paired_rates(
            lambda: policy.predict_naive(cur[:1], ctx[:1]), lambda: policy.predict(cur[:1], feats1),
            1, 2 * min_seconds)
        out["infer_naive_batch_per_s"], out["infer_cached_batch_per_s"] = _paired_rates(
            lambda: policy.predict_naive(cur, ctx), lambda: policy.predict(cur, feats),
            batch, 2 * min_seconds)
        out["encode_target_per_s"] = _rate(lambda: policy.encode_target(ctx[:1]), 1, min_seconds)
        out["cached_speedup"] = out["infer_cached_per_s"] / out["infer_naive_per_s"]
        out["registration_per_s"] = registration_rate(world, trajs.poses[trajs.rows(0)], 256,
                                                       min_seconds, seed)
        out["batch"] = batch
        return {k: (round(v, 1) if isinstance(v, float) else v) for k, v in out.items()}


def bench_reachability(config=None, controller: str | None = None, world_name: str = "test-0",
                       pairs: int = 256, label_pairs: int = 128, min_seconds: float = 3.0,
                       threads: int = 1, seed: int = 0) -> dict:
    """The RE throughput figures (``topodrake bench reachability``).

    * ``pairs_per_s_naive``: RE on (source image, 2k + 1 context images)
      pairs, the full network on the stacked inputs;
    * ``pairs_per_s_cached``: the same pairs from per-image first-layer
      features computed once per image (``frame_features_per_s``), as map
      building queries many pairs of the same trajectories;
    * ``label_rollouts_per_s``: labelled pairs per second of the batched
      C_WP + RMP rollouts that make RE's training labels (``controller``:
      a C_WP checkpoint; default an untrained network of the default profile,
      which costs the same per step).

    The network (``config``: a ReachTrainConfig, whose ``mirror_average``
    doubles both RE paths) is untrained: throughput does not depend on the
    weights."""
    from topodrake.learning.networks import WaypointNetwork, input_size
    from topodrake.learning.reachability.estimator import Reachability
    from topodrake.learning.reachability.train import ReachTrainConfig
    from topodrake.learning.waypoint.policy import LearnedWaypointPolicy

    cfg = config or ReachTrainConfig()
    net_cfg = cfg.network
    with torch_threads(threads):
        world = load_world(world_name)
        trajs = expert_drives(world, [(0, 5), (3, 8), (6, 1), (2, 7)], 120.0)
        poses = trajs.poses[trajs.rows(0)]
        sensor = cfg.camera if net_cfg.modality == "camera" else cfg.lidar
        obs = observe(world, net_cfg.modality, poses, sensor)
        torch.manual_seed(seed)
        re = Reachability(WaypointNetwork(net_cfg, input_size(net_cfg, cfg.lidar.beams)), sensor,
                          mirror_average=cfg.mirror_average)
        rng = np.random.default_rng(seed)
        src = rng.integers(0, len(poses), pairs)
        rows = re.context_rows(len(poses), rng.integers(0, len(poses), pairs))
        out = {"modality": net_cfg.modality, "k": net_cfg.k, "threads": threads, "pairs": pairs,
               "trajectory_frames": len(poses)}
        feats = re.frame_features(obs)
        out["pairs_per_s_naive"], out["pairs_per_s_cached"] = _paired_rates(
            lambda: re.probability_naive(obs[src], obs[rows]),
            lambda: re.pairwise(feats, src, rows), pairs, 2 * min_seconds)
        out["frame_features_per_s"] = _rate(lambda: re.frame_features(obs), len(obs), min_seconds)
        out["cached_speedup"] = out["pairs_per_s_cached"] / out["pairs_per_s_naive"]

        if controller:
            policy = LearnedWaypointPolicy.from_checkpoint(controller)
        else:
            from topodrake.learning.config import TrainConfig
            tc = TrainConfig()
            torch.manual_seed(seed)
            policy = LearnedWaypointPolicy(
                WaypointNetwork(tc.network, input_size(tc.network, tc.lidar.beams)), tc.camera)
        lcfg = ReachLabelConfig()
        drawn = draw_pairs(world, trajs, np.arange(trajs.count), label_pairs, rng, lcfg)
        seeds = np.array(trial_seeds(seed, label_pairs), np.int64)
        start = time.perf_counter()
        chunk = rollout_pairs(world, policy, trajs, drawn, seeds, lcfg)
        out["label_rollouts_per_s"] = label_pairs / (time.perf_counter() - start)
        out["label_success_rate"] = float(chunk["label"].mean())
        out["label_car_steps"] = int(chunk["steps"].sum())
        return {k: (round(v, 1) if isinstance(v, float) else v) for k, v in out.items()}
