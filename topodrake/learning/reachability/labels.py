"""Reachability labels: does a given controller get from a source to a target?

The reachability estimator RE learns the outcome of the controller itself
(the paper's section "Learning the Reachability Estimator"), so its labels
come from closed-loop rollouts of that controller (C_WP + RMP, or any
:class:`~topodrake.learning.waypoint.policy.WaypointPolicy`) in the batched engine
(:class:`~topodrake.rollout.PolicyRollout`), with actuation noise:

* the source is a frame of an expert trajectory, jittered as for the C_WP
  samples (sideways ``clip(0.3 N, +-1)`` m, heading ``N(0, 9 deg)``, in the
  reachable free space); the car starts there at rest;
* with probability ``same_trajectory`` (0.6) the target is a frame of the same
  trajectory at signed arc-length distance ``U(distance_min_m,
  distance_max_m)``, otherwise any frame of another trajectory of the same
  house;
* success: within 0.27 m of the target position, or both image overlaps
  above ``overlap_success`` (0.7), before ``t_max = A*(source, target) /
  v_min`` (``v_min`` = 0.25 m/s; at least one control period);
* failure: timeout, both overlaps below ``overlap_lost`` (0.05), or a
  collision (a failure to reach, not a discarded sample);
* with ``tracked_start``, a tracking controller (the registration C_WP)
  starts each same-trajectory pair already tracking its target, as a
  following car's tracker holds the anchors ahead (off the truth by
  ``tracked_error_m`` / ``tracked_error_rad``); other pairs start cold.

Pairs are drawn per world from seeds derived from one base seed. Rollouts
run in chunks written atomically into a folder with a ``manifest.json``
(format ``topodrake-reach-labels``, version 1) that records the config, seed,
the trajectories' source and the controller's fingerprint; an interrupted
run resumes at the first missing chunk, and a folder made for another
controller or config is refused.
"""

from __future__ import annotations

import io
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_bytes, atomic_write_json
from topodrake.fileio import read_manifest as _read_manifest
from topodrake.learning.samples import (
    SampleConfig,
    TrajectorySet,
    _arclength,
    _snap_free,
    apply_jitter,
    draw_jitter,
)
from topodrake.montecarlo import trial_seeds
from topodrake.rollout import SUCCESS, PolicyRollout, RolloutConfig

FORMAT = "topodrake-reach-labels"
VERSION = 1
#: Per-pair arrays of a chunk (and of :class:`ReachLabels`).
FIELDS = ("src_traj", "src", "src_pose", "traj", "tgt", "same", "t_max", "outcome", "steps",
          "overlap", "label", "seed")


@dataclass
class ReachLabelConfig:
    same_trajectory: float = 0.6
    distance_min_m: float = -1.0     # same-trajectory targets: signed arc length
    distance_max_m: float = 5.0
    v_min: float = 0.25              # m/s: t_max = A* length / v_min
    overlap_success: float = 0.7
    overlap_lost: float = 0.05
    noise_std: float = 0.33
    target_snap_m: float = 0.3       # A* goal: nearest free cell within this of the target
    unjittered_sources: float = 0.0  # share of sources on the expert pose itself
    # a tracking controller (the registration C_WP) starts tracking same-drive targets, as a
    # following car does (None: no, as configs before the option read) ...
    tracked_start: bool | None = None
    tracked_error_m: float | None = None     # ... its estimate off the truth by N(0, this) per
    tracked_error_rad: float | None = None   # axis (None: 0.1 m and 0.05 rad)
    batch: int = 128                 # cars per engine run
    chunk: int = 1024                # pairs per file
    jitter: SampleConfig = field(default_factory=SampleConfig)

    def validate(self) -> "ReachLabelConfig":
        for name in ("same_trajectory", "unjittered_sources"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise TopodrakeError(f"{name} must be a probability, got {getattr(self, name)}")
        if not self.v_min > 0 or self.batch < 1 or self.chunk < 1:
            raise TopodrakeError("need v_min > 0, batch >= 1 and chunk >= 1")
        if self.distance_min_m >= self.distance_max_m:
            raise TopodrakeError("need distance_min_m < distance_max_m")
        if any(v is not None and not (np.isfinite(v) and v >= 0)
               for v in (self.tracked_error_m, self.tracked_error_rad)):
            raise TopodrakeError("need tracked_error_m and tracked_error_rad >= 0")
        return self


@dataclass
class ReachLabels:
    """Labelled (source, target) pairs over a :class:`TrajectorySet`.

    ``traj``/``tgt`` name the target frame (its context is rendered from
    that trajectory), ``src_traj``/``src`` the frame the jittered
    ``src_pose`` came from; ``label`` is 1 for success. ``outcome`` uses
    :data:`topodrake.rollout.OUTCOMES`."""

    trajectories: TrajectorySet
    fields: dict
    meta: dict

    def __len__(self) -> int:
        return len(self.fields["label"])

    def __getattr__(self, name):
        try:
            return self.__dict__["fields"][name]
        except KeyError:
            raise AttributeError(name) from None


def draw_pairs(world, trajs: TrajectorySet, traj_ids: np.ndarray, n: int,
               rng: np.random.Generator, cfg: ReachLabelConfig) -> dict:
    """``n`` (jittered source, target) pairs among the trajectories ``traj_ids``
    of one world (no rollouts yet)."""
    lengths = np.array([trajs.rows(t).stop - trajs.rows(t).start for t in traj_ids])
    if len(traj_ids) == 0 or lengths.sum() < 2:
        raise TopodrakeError(f"world {world.name!r} has no trajectories to draw pairs from")
    arcs = [_arclength(trajs.poses[trajs.rows(t)]) for t in traj_ids]
    out = {k: [] for k in ("src_traj", "src", "src_pose", "traj", "tgt", "same")}
    have, rounds = 0, 0
    while have < n:
        rounds += 1
        if rounds > 50:
            raise TopodrakeError(f"world {world.name!r}: could not draw {n} valid pairs")
        m = int(1.3 * (n - have)) + 16
        pick = rng.choice(len(traj_ids), size=m, p=lengths / lengths.sum())
        src = (rng.random(m) * lengths[pick]).astype(np.int64)
        same = rng.random(m) < cfg.same_trajectory
        if len(traj_ids) == 1:
            same[:] = True
        dist = rng.uniform(cfg.distance_min_m, cfg.distance_max_m, m)
        other = (pick + 1 + rng.integers(0, max(len(traj_ids) - 1, 1), m)) % len(traj_ids)
        other_u = rng.random(m)
        lat, dth = draw_jitter(rng, m, cfg.jitter)
        if cfg.unjittered_sources > 0:   # (no extra draw otherwise: old pair sets stay as they were)
            on_path = rng.random(m) < cfg.unjittered_sources
            lat[:, on_path] = 0.0
            dth[:, on_path] = 0.0
        tpick = np.where(same, pick, other)
        tgt = np.empty(m, np.int64)
        ok = np.ones(m, bool)
        for q in range(m):
            if same[q]:
                a = arcs[pick[q]]
                s = a[src[q]] + dist[q]
                if s < 0.0 or s > a[-1]:
                    ok[q] = False
                    continue
                tgt[q] = min(int(np.searchsorted(a, s)), len(a) - 1)
            else:
                tgt[q] = int(other_u[q] * lengths[tpick[q]])
        base = trajs.poses[trajs.traj_offsets[traj_ids[pick]] + src]
        src_pose, free = apply_jitter(world, base, lat, dth)
        idx = np.flatnonzero(ok & free)[: n - have]
        out["src_traj"].append(traj_ids[pick[idx]])
        out["src"].append(src[idx])
        out["src_pose"].append(src_pose[idx])
        out["traj"].append(traj_ids[tpick[idx]])
        out["tgt"].append(tgt[idx])
        out["same"].append(same[idx])
        have += len(idx)
    return {k: np.concatenate(v) for k, v in out.items()}


def time_limits(world, src_pose: np.ndarray, tgt_xy: np.ndarray, cfg: ReachLabelConfig,
                dt: float = 0.1) -> np.ndarray:
    """``A*(source, target) / v_min`` per pair, in whole control periods
    (straight-line distance where no path exists)."""
    out = np.empty(len(src_pose))
    for i, (p, g) in enumerate(zip(src_pose, tgt_xy)):
        goal = _snap_free(world, g, cfg.target_snap_m)
        length = float(np.hypot(*(g - p[:2])))
        if goal is not None:
            try:
                path = world.astar(p, goal)
                length = float(np.hypot(*np.diff(path, axis=0).T).sum()) if len(path) > 1 else 0.0
            except TopodrakeError:
                pass
        out[i] = max(dt, np.ceil(length / cfg.v_min / dt - 1e-9) * dt)
    return out


def rollout_pairs(world, policy, trajs: TrajectorySet, pairs: dict, seeds: np.ndarray,
                  cfg: ReachLabelConfig) -> dict:
    """Roll out ``policy`` on (source pose, target frame) ``pairs`` of one
    world (the fields of :func:`draw_pairs`), one noise seed each, and label
    them by the rules of the module docstring: the pairs' fields plus
    ``t_max``, ``outcome``, ``steps``, final ``overlap``, ``label`` and ``seed``."""
    tgt_pose = trajs.poses[trajs.traj_offsets[pairs["traj"]] + pairs["tgt"]]
    out = rollout_to_targets(
        world, policy, pairs["src_pose"], tgt_pose,
        lambda sl: target_contexts(world, policy, trajs, pairs["traj"][sl], pairs["tgt"][sl]),
        seeds, cfg, tracked=pairs["same"])
    return {**pairs, **out, "seed": np.asarray(seeds, np.int64)}


def rollout_to_targets(world, policy, src_pose: np.ndarray, tgt_pose: np.ndarray, contexts,
                       seeds: np.ndarray, cfg: ReachLabelConfig,
                       tracked: np.ndarray | None = None) -> dict:
    """Drive ``policy`` from ``src_pose`` (N, 3) toward targets taken at
    ``tgt_pose`` (N, 3), whose context observations ``contexts(slice)``
    returns batch by batch, one noise seed each, under the labels' rules:
    ``t_max``, ``outcome``, ``steps``, final ``overlap`` and ``label``.
    With ``cfg.tracked_start``, a tracking policy starts the pairs marked in
    ``tracked`` (N,; default all) already tracking the target
    (:func:`tracked_starts`)."""
    t_max = time_limits(world, src_pose, tgt_pose[:, :2], cfg)
    engine = PolicyRollout(world, policy, RolloutConfig(noise_std=cfg.noise_std),
                           overlap_success=cfg.overlap_success, overlap_lost=cfg.overlap_lost)
    n = len(seeds)
    outcome = np.empty(n, np.int8)
    steps = np.empty(n, np.int32)
    overlap = np.empty((n, 2), np.float32)
    for lo in range(0, n, cfg.batch):
        sl = slice(lo, min(lo + cfg.batch, n))
        feats = policy.encode_target(contexts(sl))
        track = None
        if cfg.tracked_start and hasattr(policy, "tracked_start"):
            track = tracked_starts(policy, src_pose[sl], tgt_pose[sl], seeds[sl], cfg,
                                   None if tracked is None else np.asarray(tracked)[sl])
        res = engine.run(src_pose[sl], tgt_pose[sl], feats, t_max_s=t_max[sl], seeds=seeds[sl],
                         initial_track=track)
        outcome[sl] = res.outcome
        steps[sl] = res.steps
        overlap[sl] = res.overlap
    return {"t_max": t_max.astype(np.float32), "outcome": outcome, "steps": steps,
            "overlap": overlap, "label": (outcome == SUCCESS).astype(np.uint8)}


def tracked_starts(policy, src_pose: np.ndarray, tgt_pose: np.ndarray, seeds: np.ndarray,
                   cfg: ReachLabelConfig, tracked: np.ndarray | None = None) -> np.ndarray:
    """The tracking state a following car would start a hop with: ``policy``
    tracking each target from its source (``policy.tracked_start``), its
    estimate off the truth by the config's error drawn from the pair's
    seed; rows not ``tracked`` start untracked."""
    n = len(src_pose)
    sd_m = 0.1 if cfg.tracked_error_m is None else cfg.tracked_error_m
    sd_rad = 0.05 if cfg.tracked_error_rad is None else cfg.tracked_error_rad
    error = np.empty((n, 3))
    for i, s in enumerate(np.asarray(seeds, np.int64)):
        e = np.random.default_rng([int(s), 7]).standard_normal(3)
        error[i] = e * [sd_m, sd_m, sd_rad]
    track = policy.tracked_start(src_pose, tgt_pose, error)
    if tracked is not None:
        cold = ~np.asarray(tracked, bool)
        track[cold] = policy.initial_track(int(cold.sum()))
    return track


def target_contexts(world, net, trajs, traj, tgt) -> np.ndarray:
    """(M, 2k+1, ...) context observations of frames ``tgt`` of trajectories
    ``traj``, as ``net`` (a waypoint policy or an RE) sees them (poses, for
    the oracle)."""
    rows = trajs.context_rows(traj, tgt, net.k, net.frame_step)
    poses = trajs.poses[rows.ravel()]
    if net.observation == "pose":
        obs = poses
    else:
        from topodrake.sensing.observe import observe
        obs = observe(world, net.observation, poses, net.sensor)
    return obs.reshape(*rows.shape, *obs.shape[1:])


def label_reachability(trajs: TrajectorySet, policy, out_dir, n: int, *, seed: int = 0,
                       controller: dict | None = None, config: ReachLabelConfig | None = None,
                       load_world=None, progress: bool = True) -> Path:
    """Label ``n`` pairs (spread evenly over the worlds of ``trajs``) with
    rollouts of ``policy`` into ``out_dir`` (resumable; see the module
    docstring). ``policy`` is a waypoint policy, or a function of the world
    that returns one (the A* oracle is made per world). ``controller`` (e.g.
    ``{"checkpoint": path, "sha1": ...}``) identifies the policy in the
    manifest; a folder labelled for another controller, config, seed or size
    is refused. ``load_world`` (default: the catalogue's) turns the worlds'
    names into worlds."""
    from tqdm import tqdm


    if load_world is None:
        from topodrake.world import load_world
    policy_for = policy if not hasattr(policy, "predict") else (lambda world: policy)
    cfg = (config or ReachLabelConfig()).validate()
    out = Path(out_dir)
    worlds = trajs.worlds
    per = np.full(len(worlds), n // len(worlds))
    per[: n % len(worlds)] += 1
    manifest = open_label_folder(out, trajs, n, seed, cfg, controller or {})
    done = set(manifest["chunks"])
    world_seeds = trial_seeds(seed, len(worlds))
    bar = tqdm(total=int(n), desc="reach labels", unit="pair", disable=not progress)
    for w, name in enumerate(worlds):
        if per[w] == 0:
            continue
        n_chunks = -(-int(per[w]) // cfg.chunk)
        names = [f"{w:03d}-{c:05d}.npz" for c in range(n_chunks)]
        sizes = [min(cfg.chunk, int(per[w]) - c * cfg.chunk) for c in range(n_chunks)]
        bar.update(sum(s for nm, s in zip(names, sizes) if nm in done))
        if all(nm in done for nm in names):
            continue
        world = load_world(name)
        rng = np.random.default_rng(world_seeds[w])
        pairs = draw_pairs(world, trajs, np.flatnonzero(trajs.traj_world == w), int(per[w]),
                           rng, cfg)
        seeds = np.array(trial_seeds(world_seeds[w] + 1, int(per[w])), np.int64)
        for c, (nm, size) in enumerate(zip(names, sizes)):
            if nm in done:
                continue
            sl = slice(c * cfg.chunk, c * cfg.chunk + size)
            chunk = rollout_pairs(world, policy_for(world), trajs, {k: v[sl] for k, v in pairs.items()},
                                 seeds[sl], cfg)
            write_label_chunk(out, nm, chunk, manifest)
            bar.update(size)
            bar.set_postfix(success=f"{np.mean(chunk['label']):.2f}")
    bar.close()
    return out


def open_label_folder(out: Path, trajs: TrajectorySet, n: int, seed: int,
                      config: ReachLabelConfig, controller: dict, what: str = "reachability labels",
                      **extra) -> dict:
    """The manifest of the label folder ``out``: a new one (written with the
    trajectories), or the one there when it was made with the same settings
    (``extra``: more settings it records), with its finished chunks; a
    folder made otherwise is refused (``what`` names its labels)."""
    manifest = {"format": FORMAT, "version": VERSION, "n": int(n), "seed": int(seed),
                "config": asdict(config), "controller": controller, "worlds": trajs.worlds,
                "trajectories": _trajectory_digest(trajs), "chunks": [], **extra}
    if (out / "manifest.json").exists():
        old = read_manifest(out)
        for key in ("n", "seed", "config", "controller", "worlds", "trajectories", *extra):
            if old.get(key) != manifest[key]:
                raise TopodrakeError(f"{out} holds {what} of another {key}; use a new folder")
        manifest["chunks"] = old["chunks"]
    else:
        _write_trajectories(out / "trajectories.npz", trajs)
        atomic_write_json(out / "manifest.json", manifest)
    return manifest


def write_label_chunk(out: Path, name: str, chunk: dict, manifest: dict) -> None:
    """Write one finished chunk of pairs and record it in the manifest."""
    buf = io.BytesIO()
    np.savez_compressed(buf, format=np.array(FORMAT), version=np.array(VERSION), **chunk)
    atomic_write_bytes(out / name, buf.getvalue())
    manifest["chunks"].append(name)
    atomic_write_json(out / "manifest.json", manifest)


def _trajectory_digest(trajs: TrajectorySet) -> str:
    import hashlib

    h = hashlib.sha1()
    for a in (trajs.traj_world, trajs.traj_offsets, trajs.poses):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


def _write_trajectories(path: Path, trajs: TrajectorySet) -> None:
    buf = io.BytesIO()
    np.savez_compressed(buf, worlds=np.array(json.dumps(trajs.worlds)), traj_world=trajs.traj_world,
                        traj_offsets=trajs.traj_offsets, poses=trajs.poses, states=trajs.states)
    atomic_write_bytes(path, buf.getvalue())


def read_manifest(folder) -> dict:
    return _read_manifest(folder, FORMAT, VERSION, "a reachability label set",
                          ("n", "config", "controller", "chunks"))


def load_reach_labels(folder) -> ReachLabels:
    """All finished chunks of a label folder, with their trajectories."""
    folder = Path(folder)
    manifest = read_manifest(folder)
    try:
        with np.load(folder / "trajectories.npz", allow_pickle=False) as z:
            trajs = TrajectorySet(json.loads(str(z["worlds"])), z["traj_world"], z["traj_offsets"],
                                  z["poses"], z["states"])
        parts = []
        for name in sorted(manifest["chunks"]):
            with np.load(folder / name, allow_pickle=False) as z:
                if str(z["format"]) != FORMAT:
                    raise TopodrakeError(f"{folder / name} is not a {FORMAT} chunk")
                parts.append({k: z[k] for k in FIELDS})
    except TopodrakeError:
        raise
    except Exception as e:
        raise TopodrakeError(f"{folder} holds a missing or corrupt file ({type(e).__name__})") from None
    if not parts:
        raise TopodrakeError(f"{folder} has no finished chunks yet")
    fields = {k: np.concatenate([p[k] for p in parts]) for k in FIELDS}
    return ReachLabels(trajs, fields, manifest)


def concat_reach_labels(parts: list[ReachLabels]) -> ReachLabels:
    """One label set of several (their manifests under ``meta["parts"]``),
    joined house by house: a house in several parts keeps one copy of its
    drives (which must be the same in every part), so parts may cover the
    same, other or partly shared houses; the pairs' trajectory indices move
    to match."""
    if not parts:
        raise TopodrakeError("no label sets to join")
    if len(parts) == 1:
        return parts[0]
    houses: dict[str, tuple[TrajectorySet, str]] = {}
    for part in parts:
        for name in part.trajectories.worlds:
            alone = part.trajectories.select_worlds([name])
            digest = _trajectory_digest(alone)
            if houses.setdefault(name, (alone, digest))[1] != digest:
                raise TopodrakeError(f"label sets disagree on the drives of {name}; were they "
                                     "rolled out from other demonstrations?")
    trajs = TrajectorySet.concat([alone for alone, _ in houses.values()])
    first = dict(zip(houses, np.cumsum([0] + [alone.count for alone, _ in houses.values()])))
    fields = {k: np.concatenate([part.fields[k] for part in parts]) for k in FIELDS}
    for key in ("src_traj", "traj"):
        fields[key] = np.concatenate([_house_order(part.trajectories, first)[part.fields[key]]
                                      for part in parts])
    return ReachLabels(trajs, fields, {"parts": [part.meta for part in parts]})


def _house_order(trajs: TrajectorySet, first: dict[str, int]) -> np.ndarray:
    """Where each trajectory of ``trajs`` sits in a set that holds each
    house's drives in one block starting at ``first[house]``."""
    out = np.empty(trajs.count, np.int64)
    for w, name in enumerate(trajs.worlds):
        mine = np.flatnonzero(trajs.traj_world == w)
        out[mine] = first[name] + np.arange(len(mine))
    return out
