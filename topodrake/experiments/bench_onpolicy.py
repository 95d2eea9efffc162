"""The controller on its own states: C_WP error and RE calibration where the follower drives.

A validation set scores C_WP on jittered demonstration poses; the follower
asks it elsewhere (drifted cars, far anchors). This benchmark follows a
fixed, seeded set of chains in the test houses with the learned follower
(the controller's C_WP and RE; :mod:`topodrake.learning.onpolicy.states`; half the
chains with actuation noise), records every other period's state and the
anchor it aimed at, and reports:

* C_WP's waypoint error (m) and angle error (deg, for labels over 0.3 m)
  against the A* expert's label there, overall and by straight-line distance
  to the anchor (0-1, 1-2, 2-3, 3+ m), beside the error on the checkpoint's
  own validation set (``val_error_m``, from its card) and their ratio;
* RE's calibration on those states: ``re_states`` of them are rolled out
  with the controller alone toward the anchor (the RE labels' rules:
  :func:`topodrake.learning.reachability.labels.rollout_to_targets`, with actuation
  noise: :func:`~topodrake.learning.onpolicy.calibration.label_visited_reach`),
  and the probability the follower acts on (its follower calibration where
  the RE has one, else the anchor-hop one: ``re_calibration``) is scored
  against the outcomes (``re_ece``, ``re_auroc``; ``re_ece_temperature``:
  under the validation pairs' temperature);
* the followed chains' cover and outcomes, how far cars were off the path,
  and the cover of the same chains followed with perfect perception (the A*
  oracle C_WP and the geometric oracle RE: ``oracle_cover``).

    topodrake bench follower --json

prints ``{"camera_k5": {"onpolicy_error_m": e, "val_error_m": e, "re_ece": e,
"re_auroc": a, ...}, "lidar_k5": {...}}``.
"""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.learning.onpolicy.calibration import (
    StateLabels,
    follower_probability,
    label_visited_reach,
    platt_probability,
)
from topodrake.learning.onpolicy.states import (
    OnPolicyConfig,
    collect_visited,
    label_visited,
    pick_drives,
    samples_from_fields,
)
from topodrake.learning.reachability.calibration import auroc, ece
from topodrake.learning.samples import collect_trajectories
from topodrake.learning.waypoint.noisy_oracle import is_oracle_spec, parse_oracle_spec
from topodrake.world import load_world

#: name: (C_WP checkpoint, RE checkpoint, the C_WP that RE was trained for)
CONTROLLERS = {
    "camera_k5": ("checkpoints/camera_k5/checkpoint.pt", "checkpoints/reach_camera_k5/checkpoint.pt",
                  "checkpoints/camera_k5/checkpoint.pt"),
    "lidar_k5": ("checkpoints/lidar_k5/checkpoint.pt", "checkpoints/reach_lidar_k5/checkpoint.pt",
                 "checkpoints/lidar_k5/checkpoint.pt"),
    # the C_WP trained at scale, with the RE of the C_WP its chains were made for
    "lidar_k5_scale": ("checkpoints/lidar_k5_scale/checkpoint.pt",
                       "checkpoints/reach_lidar_k5/checkpoint.pt", "checkpoints/lidar_k5/checkpoint.pt"),
    "camera_k5_scale": ("checkpoints/camera_k5_scale/checkpoint.pt",
                        "checkpoints/reach_camera_k5/checkpoint.pt", "checkpoints/camera_k5/checkpoint.pt"),
}
TEST_WORLDS = ("test-0", "test-1", "test-2", "test-3", "test-4")
BANDS_M = (0.0, 1.0, 2.0, 3.0, np.inf)


def validation_error(cwp_path) -> float | None:
    """The checkpoint's validation waypoint error (its card, else its metrics)."""
    card = Path(cwp_path).parent / "card.json"
    if card.is_file():
        try:
            return json.loads(card.read_text())["metrics"]["waypoint_error_m"]
        except (OSError, ValueError, KeyError):
            pass
    from topodrake.learning.checkpoint import load_checkpoint

    return (load_checkpoint(cwp_path).meta.get("metrics") or {}).get("waypoint_error_m")


def _errors(model, network_cfg, sensor, samples) -> tuple[np.ndarray, np.ndarray]:
    """Per-sample waypoint error (m) and angle error (rad) of ``model``."""
    import torch

    from topodrake.learning.data import SampleBatcher

    cam = sensor if network_cfg.modality == "camera" else None
    lid = sensor if network_cfg.modality == "lidar" else None
    batcher = SampleBatcher(samples, network_cfg, cam, lid)
    err, ang = [], []
    model.eval()
    with torch.no_grad():
        for lo in range(0, len(batcher), 256):
            b = batcher.batch(np.arange(lo, min(lo + 256, len(batcher))))
            wp = model.forward_split(b.cur, b.ctx)["waypoint"]
            err.append((wp - b.waypoint).norm(dim=1).numpy())
            a = torch.atan2(wp[:, 1], wp[:, 0]) - torch.atan2(b.waypoint[:, 1], b.waypoint[:, 0])
            ang.append(np.abs(np.angle(np.exp(1j * a.numpy()))))
    return np.concatenate(err), np.concatenate(ang)


def bench_controller(cwp_path, re_path, re_controller, *, data="data", worlds=TEST_WORLDS,
                     drives_per_world: int = 8, re_states: int = 300, seed: int = 0,
                     oracle: bool = True, progress: bool = False) -> dict:
    """The figures of one controller (see the module docstring)."""
    from topodrake.learning.checkpoint import load_checkpoint
    from topodrake.learning.reachability.estimator import Reachability
    from topodrake.learning.waypoint.policy import LearnedWaypointPolicy

    if is_oracle_spec(cwp_path):
        raise TopodrakeError(f"the follower bench measures a network C_WP, not {cwp_path!r} (the "
                             f"oracle's error is set; studies/trajectory_following.py follows it)")
    for p in (cwp_path, re_path, re_controller):
        if not Path(p).is_file():
            raise TopodrakeError(f"checkpoint {p} does not exist")
    ck = load_checkpoint(cwp_path)
    if ck.network.output != "waypoint":
        raise TopodrakeError(f"{cwp_path} is not a waypoint C_WP (output {ck.network.output!r})")
    policy = LearnedWaypointPolicy.from_checkpoint(cwp_path)
    reach = Reachability.from_checkpoint(re_path, re_controller)
    trajs = collect_trajectories(list(worlds), Path(data) / "demos" / "pairs-s0", progress=progress)
    cfg = OnPolicyConfig(drives_per_world=drives_per_world, next_anchor=False)
    cfg = replace(cfg, samples=replace(cfg.samples, min_overlap=0.0))
    parts, covers, offs, dist_parts, outcomes, oracle_covers = [], [], [], [], [], []
    re_labels = StateLabels()
    rng = np.random.default_rng([seed, 7])
    per_world_re = -(-re_states // len(trajs.worlds))
    for w, name in enumerate(trajs.worlds):
        world = load_world(name)
        drives = pick_drives(trajs, w, drives_per_world, seed)
        visited = collect_visited(world, trajs, drives, policy, reach, cfg, seed=seed * 100 + w)
        covers.extend(visited.cover.tolist())
        outcomes.extend(visited.outcomes)
        offs.append(visited.off_path_m)
        fields = label_visited(world, trajs, visited, cfg)
        parts.append(fields)
        tgt = trajs.poses[trajs.traj_offsets[fields["traj"]] + fields["tgt"]]
        dist_parts.append(np.hypot(*(tgt[:, :2] - fields["src_pose"][:, :2]).T))
        if oracle:
            from topodrake.learning.waypoint.policy import AStarOracle
            from topodrake.navigation.evaluate import GeometricReachability

            wide = max(policy.k, reach.k)
            ov = collect_visited(world, trajs, drives, AStarOracle(world, k=wide),
                                 GeometricReachability(world, k=wide), cfg, seed=seed * 100 + w,
                                 chain_reach=reach)
            oracle_covers.extend(ov.cover.tolist())
        if progress:
            print(f"follower bench {Path(cwp_path).parent.name}: {name}: {len(visited)} states, "
                  f"cover {visited.cover.mean():.3f}", flush=True, file=sys.stderr)
        # RE on the follower's own states: roll out C_WP alone toward the anchor
        re_labels = re_labels.extend(label_visited_reach(world, trajs, visited, policy, reach,
                                                         per_world_re, rng, seed * 100 + w))
    samples = samples_from_fields(trajs, parts, {"bench": "follower"})
    err, ang = _errors(ck.model, ck.network, ck.sensor, samples)
    dist = np.concatenate(dist_parts)
    long = np.hypot(*samples.waypoint.T) > 0.3
    val = validation_error(cwp_path)
    bands = {}
    for lo, hi in zip(BANDS_M[:-1], BANDS_M[1:]):
        sel = (dist >= lo) & (dist < hi)
        key = f"{lo:g}-{hi:g}m" if np.isfinite(hi) else f"{lo:g}m+"
        bands[key] = {"share": round(float(sel.mean()), 4),
                      "error_m": round(float(err[sel].mean()), 4) if sel.any() else None,
                      "angle_error_deg": round(float(np.degrees(ang[sel & long].mean())), 2)
                      if (sel & long).any() else None}
    y_re = re_labels.label
    p_re = follower_probability(reach, re_labels.logit)             # what the follower acts on
    p_temp = platt_probability(re_labels.logit, (1.0 / reach.temperature, 0.0))
    off = np.concatenate(offs)
    onpolicy = float(err.mean())
    return {"onpolicy_error_m": round(onpolicy, 4), "val_error_m": val,
            "error_ratio": round(onpolicy / val, 3) if val else None,
            "onpolicy_angle_error_deg": round(float(np.degrees(ang[long].mean())), 2),
            "bands": bands, "states": int(len(err)),
            "re_ece": round(ece(p_re, y_re), 4), "re_auroc": round(auroc(p_re, y_re), 4),
            "re_states": int(len(y_re)), "re_success_rate": round(float(y_re.mean()), 4),
            "re_mean_p": round(float(p_re.mean()), 4),
            "re_calibration": "follower" if reach.follower_platt else "anchor hops",
            "re_ece_temperature": round(ece(p_temp, y_re), 4),
            "followed_cover": round(float(np.mean(covers)), 4), "chains": len(covers),
            "outcomes": {o: outcomes.count(o) for o in sorted(set(outcomes))},
            "oracle_cover": round(float(np.mean(oracle_covers)), 4) if oracle_covers else None,
            "off_path_quartiles_m": [round(float(q), 3) for q in np.quantile(off, [0.25, 0.5, 0.75])]}


def bench_follower(controllers: dict | None = None, **kw) -> dict:
    """:func:`bench_controller` of each named controller (default: camera
    k5 and lidar k5): {name: figures}."""
    controllers = controllers or CONTROLLERS
    return {name: bench_controller(*spec, **kw) for name, spec in controllers.items()}


def parse_controllers(names: str, overrides: list[str], reach: list[str] | None = None, *,
                      table: dict | None = None, must_exist: bool = False) -> dict:
    """The controllers to bench: ``names`` (comma-separated keys of
    ``table``, default :data:`CONTROLLERS`: name -> (C_WP, RE, the C_WP
    that RE was trained for)), with ``NAME=C_WP.pt`` overrides of their C_WP
    (or ``NAME=oracle:KEY=VALUE...``, the A* oracle with a controlled error:
    :mod:`topodrake.learning.waypoint.noisy_oracle`; NAME's RE stays) and
    ``NAME=RE.pt`` overrides of their RE (an RE trained for NAME's C_WP, the
    overridden checkpoint if given); ``must_exist``: an override's file must
    exist."""
    table = CONTROLLERS if table is None else table
    chosen = [n for n in names.split(",") if n]
    unknown = [n for n in chosen if n not in table]
    if unknown or not chosen:
        raise TopodrakeError(f"unknown controllers {unknown}; choose from {', '.join(table)}")
    out = {n: table[n] for n in chosen}
    for flag, items in (("--cwp", overrides), ("--re", reach)):
        for o in items or []:
            name, sep, path = o.partition("=")
            if not sep or name not in out:
                raise TopodrakeError(f"{flag} {o!r} is not NAME=CHECKPOINT with NAME one of {chosen}")
            if flag == "--cwp" and is_oracle_spec(path):
                parse_oracle_spec(path)                  # a spec, not a file: check its keys
            elif must_exist and not Path(path).is_file():
                raise TopodrakeError(f"{flag}: checkpoint {path} does not exist")
            cwp, re, re_for = out[name]
            if flag == "--cwp":
                out[name] = (path, re, re_for)
            else:
                out[name] = (cwp, path, table[name][0] if is_oracle_spec(cwp) else cwp)
    return out
