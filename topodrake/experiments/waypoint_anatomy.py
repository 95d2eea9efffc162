"""Where a C_WP's validation error lies: by target distance, and split into
the waypoint's length and its direction.

The mean waypoint error (the figure a C_WP's card reports) mixes two things
the follower treats very differently: the direction of the waypoint, which
steers the car, and its length, which the RMP mostly discards (it stretches
every waypoint to its look-ahead). This bench draws one validation set,
runs every named C_WP on it and reports, per C_WP:

* the mean, median and tail percentiles of the error, and the share of the
  mean that its worst tenth carries;
* the same by signed target distance band;
* ``direction_error_m``: the error of a waypoint with C_WP's direction and
  the label's length, and ``length_error_m``: ``| |prediction| - |label| |``;
* the angle error toward waypoints longer than 0.3 m;
* with two or more C_WPs, each one's paired difference in mean error to
  the first, with a bootstrap 95 % interval over the samples.
"""

from __future__ import annotations

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.learning.samples import SampleConfig, collect_trajectories, make_samples
from topodrake.montecarlo import paired_difference as paired

#: signed target distance bands (m) the error is broken down by
BANDS = ((-0.5, 0.0), (0.0, 1.0), (1.0, 2.0), (2.0, 3.0), (3.0, 5.0))


def predict_waypoints(checkpoint, samples, batch: int = 512) -> np.ndarray:
    """(M, 2) waypoints of a loaded C_WP checkpoint on every sample."""
    import torch

    from topodrake.learning.data import SampleBatcher

    batcher = SampleBatcher(samples, checkpoint.network, checkpoint.camera,
                            None if checkpoint.camera is not None else checkpoint.sensor)
    model = checkpoint.model.eval()
    out = []
    with torch.no_grad():
        for start in range(0, len(batcher), batch):
            b = batcher.batch(np.arange(start, min(start + batch, len(batcher))))
            out.append(model.forward_split(b.cur, b.ctx)["waypoint"].numpy())
    return np.concatenate(out) if out else np.zeros((0, 2), np.float32)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = np.arctan2(a[:, 1], a[:, 0]) - np.arctan2(b[:, 1], b[:, 0])
    return np.degrees(np.abs((d + np.pi) % (2 * np.pi) - np.pi))


def anatomy(pred: np.ndarray, label: np.ndarray, distance: np.ndarray) -> dict:
    """The error figures of one C_WP's ``pred`` against ``label`` (both (M, 2),
    car frame) on samples at signed target ``distance`` (M,)."""
    err = np.linalg.norm(pred - label, axis=1)
    n = len(err)
    if n == 0:
        raise ValueError("no samples to score")
    p_len, l_len = np.linalg.norm(pred, axis=1), np.linalg.norm(label, axis=1)
    unit = pred / np.maximum(p_len, 1e-9)[:, None]
    direction = np.linalg.norm(unit * l_len[:, None] - label, axis=1)
    ranked = np.sort(err)[::-1]
    tenth = max(n // 10, 1)
    long = l_len > 0.3
    out = {"samples": n, "error_m": round(float(err.mean()), 4),
           "median_m": round(float(np.median(err)), 4),
           "p90_m": round(float(np.percentile(err, 90)), 4),
           "p98_m": round(float(np.percentile(err, 98)), 4),
           "worst_tenth_share": round(float(ranked[:tenth].sum() / max(err.sum(), 1e-12)), 3),
           "direction_error_m": round(float(direction.mean()), 4),
           "length_error_m": round(float(np.abs(p_len - l_len).mean()), 4),
           "angle_error_deg": round(float(_angle_deg(pred[long], label[long]).mean()), 2)
           if long.any() else None,
           "bands": {}}
    for lo, hi in BANDS:
        k = (distance >= lo) & (distance < hi)
        if k.any():
            out["bands"][f"{lo:g}..{hi:g}"] = {
                "share": round(float(k.mean()), 3), "error_m": round(float(err[k].mean()), 4),
                "median_m": round(float(np.median(err[k])), 4),
                "direction_error_m": round(float(direction[k].mean()), 4),
                "length_error_m": round(float(np.abs(p_len[k] - l_len[k]).mean()), 4)}
    return out


def paired_difference(err_a: np.ndarray, err_b: np.ndarray, seed: int = 0) -> dict:
    """Mean of ``err_b - err_a`` (m) with a bootstrap 95 % interval over samples."""
    d = paired(err_a, err_b, seed=seed)
    return {"mean_m": d["mean"], "ci95_m": d["ci95"]}


def bench_waypoint(checkpoints: list[str], worlds: list[str], *, samples: int = 6000,
                   distance_max_m: float = 3.0, seed: int = 1, data: str = "data",
                   progress: bool = False) -> dict:
    """The anatomy of each C_WP in ``checkpoints`` on one validation set of
    ``worlds`` (targets -0.5..``distance_max_m`` m, the sample seed ``seed``:
    1 is the training configs' validation seed)."""
    from pathlib import Path

    from topodrake.learning.checkpoint import load_checkpoint

    if not checkpoints:
        raise TopodrakeError("name at least one C_WP checkpoint")
    loaded = [load_checkpoint(p) for p in checkpoints]
    for p, ck in zip(checkpoints, loaded):
        if ck.network.output != "waypoint":
            raise TopodrakeError(f"{p} is not a waypoint C_WP (output {ck.network.output!r})")
    trajs = collect_trajectories(worlds, Path(data) / "demos" / "pairs-s0", progress=progress)
    cfg = SampleConfig(distance_max_m=distance_max_m)
    sset = make_samples(trajs, samples, seed, cfg, progress=progress)
    label, distance = np.asarray(sset.waypoint), np.asarray(sset.distance)
    result, errors = {}, []
    for p, ck in zip(checkpoints, loaded):
        pred = predict_waypoints(ck, sset)
        errors.append(np.linalg.norm(pred - label, axis=1))
        result[p] = anatomy(pred, label, distance)
        if len(errors) > 1:
            result[p]["paired_to_first"] = paired_difference(errors[0], errors[-1], seed)
    return {"worlds": worlds, "distance_max_m": distance_max_m, "sample_seed": seed,
            "checkpoints": result}
