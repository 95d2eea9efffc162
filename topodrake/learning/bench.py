"""Throughput of the waypoint network: training and closed-loop inference.

``bench_networks()`` returns the figures ``topodrake bench networks --json``
prints (issue 4):

* ``train_samples_per_s``: full training steps (render the batch from
  poses, forward, backward, Adam) on real samples of one house;
* ``infer_naive_per_s``: closed-loop steps per second at batch 1, the full
  network on the 2k + 1 stacked [current, frame, current - frame] inputs;
* ``infer_cached_per_s``: the same with the target half of the first layer
  cached (what a follower does while it follows one anchor);
* ``infer_*_batch_per_s``: the same per sample at batch ``batch`` (the
  batched engine), and ``cached_speedup`` = cached / naive at batch 1.

Naive and cached are timed in alternating windows (median of 5 each), so a
change of load during the run affects both figures alike.

Rates count one thread unless ``threads`` says otherwise.
"""

from __future__ import annotations

import time

import numpy as np
import torch


def _rate(fn, n_items: int, min_seconds: float) -> float:
    fn()
    calls, start = 0, time.perf_counter()
    while True:
        fn()
        calls += 1
        elapsed = time.perf_counter() - start
        if elapsed >= min_seconds:
            return calls * n_items / elapsed


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
    from topodrake.learning.policy import LearnedWaypointPolicy
    from topodrake.learning.samples import TrajectorySet, make_samples
    from topodrake.learning.train import waypoint_loss
    from topodrake.rollout import ExpertRollout, RolloutConfig
    from topodrake.world import load_world

    cfg = config or TrainConfig()
    net_cfg = cfg.network
    old_threads = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        world = load_world(world_name)
        p = world.places
        pairs = [(0, 3), (2, 5), (4, 1), (6, 8)]
        res = ExpertRollout(world, RolloutConfig(t_max_s=90.0)).run(
            np.array([p[i] for i, _ in pairs]), np.array([p[j, :2] for _, j in pairs]))
        drives = [(0, res.trajectory(i)["poses"], res.trajectory(i)["controls"])
                  for i in range(len(pairs)) if res.success[i]]
        samples = make_samples(TrajectorySet.from_drives([world_name], drives), 8 * batch, seed)
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
        out["batch"] = batch
        return {k: (round(v, 1) if isinstance(v, float) else v) for k, v in out.items()}
    finally:
        torch.set_num_threads(old_threads)
