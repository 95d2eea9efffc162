"""Trajectory-following trials: test drives, their chains of anchors and cached follows.

The trajectory-following study (the paper's cover-rate figure) follows
chains of anchors made from seeded expert drives of the test houses with
each controller of :data:`CONTROLLERS`. Here are the drives
(:func:`load_trajectories`: made from the seed, cached as one ``.npz``),
the chains (RE sparsification, :func:`chains_of`; every n-th frame,
:func:`every_nth`), the follows by the batched navigation engine
(:func:`follow_chains`, watched by :mod:`topodrake.navigation.chains`), and
the run cache that keeps each finished block with the settings that made it
(:class:`RunCache`), so that a long run resumes after a stop.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.experiments.bench_onpolicy import CONTROLLERS as BENCH_CONTROLLERS
from topodrake.fileio import atomic_write_bytes, atomic_write_json, file_sha1
from topodrake.learning.onpolicy.platt import SIDECAR
from topodrake.learning.reachability.controllers import (
    REGISTRATION,
    controller_policy,
    registration_runs_key,
)
from topodrake.learning.waypoint import noisy_oracle
from topodrake.learning.waypoint.noisy_oracle import is_oracle_spec, parse_oracle_spec
from topodrake.montecarlo import trial_seeds
from topodrake.navigation.chains import (
    DIVERGE_M,
    TOLERANCE_M,
    follow_chains_once,
    path_length,
)
from topodrake.navigation.engine import NAV_OUTCOMES, NavigationConfig, NavigationEngine
from topodrake.navigation.follower import FollowerConfig
from topodrake.rollout import ExpertRollout, RolloutConfig
from topodrake.world import load_world

#: name: (C_WP checkpoint, RE checkpoint, the controller the RE was trained for):
#: the follower bench's controllers, the smaller camera ones, and the
#: registration C_WP (no checkpoint: "registration" names it)
CONTROLLERS = {
    "camera_k0": ("checkpoints/camera_k0/checkpoint.pt", "checkpoints/reach_camera_k2/checkpoint.pt",
                  "checkpoints/camera_k2/checkpoint.pt"),
    "camera_k2": ("checkpoints/camera_k2/checkpoint.pt", "checkpoints/reach_camera_k2/checkpoint.pt",
                  "checkpoints/camera_k2/checkpoint.pt"),
    **BENCH_CONTROLLERS,
    "lidar_reg": ("registration", "checkpoints/reach_lidar_reg_tracked/checkpoint.pt",
                  "registration"),
}

#: name: the RE that places the controller's anchors where it is not the one
#: that answers its follower (the registration system: RE on cold-start labels
#: places them, RE on labels that start the controller tracking answers)
CHAIN_REACH = {"lidar_reg": "checkpoints/reach_lidar_reg/checkpoint.pt"}


# ---------------------------------------------------------------- trajectories

def make_trajectories(worlds: list[str], n: int, seed: int, lo_m: float = 10.0,
                      hi_m: float = 20.0) -> list[dict]:
    """``n`` successful noise-free expert drives, round-robin over ``worlds``,
    between random free poses whose A* path is ``lo_m``..``hi_m`` long."""
    rng = np.random.default_rng(seed)
    out: list[dict] = []
    loaded = {w: load_world(w) for w in worlds}
    per = -(-n // len(worlds))
    for name, world in loaded.items():
        got: list[dict] = []
        while len(got) < per:
            starts, goals = [], []
            while len(starts) < 16:
                s, g = world.sample_free_pose(rng), world.sample_free_pose(rng)
                path = world.astar(s, g)
                length = float(np.hypot(*np.diff(path, axis=0).T).sum()) if len(path) > 1 else 0.0
                if lo_m <= length <= hi_m:
                    s[2] = heading_along(path)
                    starts.append(s)
                    goals.append(g[:2])
            res = ExpertRollout(world, RolloutConfig(t_max_s=120.0)).run(np.array(starts),
                                                                         np.array(goals))
            for i in np.flatnonzero(res.success):
                if len(got) < per:
                    got.append({"world": name, "poses": res.trajectory(int(i))["poses"]})
        out.extend(got)
    order = np.random.default_rng(seed + 1).permutation(len(out))[:n]
    return [out[i] for i in sorted(order)]


def heading_along(path: np.ndarray, ahead_m: float = 1.0) -> float:
    """The direction from a path's first point to its point ``ahead_m`` along
    it (an 8-connected A* path's first cells turn by up to 45 deg, so a
    nearer point misleads: the car would start across its path)."""
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))])
    d = path[min(int(np.searchsorted(s, ahead_m)), len(path) - 1)] - path[0]
    return float(np.arctan2(d[1], d[0]))


def trajectories_name(worlds: list[str], n: int, seed: int) -> str:
    """The cache file name of the ``n`` drives of ``worlds`` made from ``seed``."""
    return f"trajectories-v2-s{seed}-n{n}-{'_'.join(worlds)}.npz"


def load_trajectories(data: Path, worlds: list[str], n: int, seed: int) -> list[dict]:
    """The cached trajectories (made from the seed when missing)."""
    import io

    path = data / "trajectory_following" / trajectories_name(worlds, n, seed)
    if path.is_file():
        z = np.load(path, allow_pickle=False)
        off = z["offsets"]
        return [{"world": str(w), "poses": z["poses"][off[i]:off[i + 1]]}
                for i, w in enumerate(z["worlds"])]
    trajs = make_trajectories(worlds, n, seed)
    buf = io.BytesIO()
    np.savez_compressed(buf, worlds=np.array([t["world"] for t in trajs]),
                        poses=np.concatenate([t["poses"] for t in trajs]),
                        offsets=np.concatenate([[0], np.cumsum([len(t["poses"]) for t in trajs])]))
    atomic_write_bytes(path, buf.getvalue())
    return trajs


class Observations:
    """The network's observations along each trajectory, rendered on first
    use (a rerun whose results are all cached renders none)."""
    def __init__(self, network, trajs, world_of):
        self.network, self.trajs, self.world_of = network, trajs, world_of
        self._made: dict[int, np.ndarray] = {}

    def __len__(self) -> int:
        return len(self.trajs)

    def __getitem__(self, m: int) -> np.ndarray:
        if m not in self._made:
            t = self.trajs[m]
            self._made[m] = self.network.observe(self.world_of(t["world"]), t["poses"])
        return self._made[m]

    def __iter__(self):
        return (self[m] for m in range(len(self)))


class RunCache:
    """Finished blocks of a run, one JSON file each in ``folder``, stored
    with the key (settings) that made them and reused only under that key."""

    def __init__(self, folder: Path, base: dict):
        self.folder = Path(folder)
        self.base = base

    def get(self, name: str, key: dict):
        path = self.folder / f"{name}.json"
        if not path.is_file():
            return None
        try:
            stored = json.loads(path.read_text())
        except (OSError, ValueError):
            return None                                # unreadable: run again
        return stored.get("value") if stored.get("key") == {**self.base, **key} else None

    def put(self, name: str, key: dict, value) -> None:
        atomic_write_json(self.folder / f"{name}.json", {"key": {**self.base, **key},
                                                          "value": value})


# ---------------------------------------------------------------- one controller

def chains_of(obs, reach, ps, cache: RunCache | None = None, tag: str = "",
              slack: float = 0.0) -> dict:
    """RE anchors of every trajectory at every p: {p: [anchors, ...]}
    (``slack``: see :func:`topodrake.learning.reachability.sparsify.sparsify`)."""
    out = {}
    for p in ps:
        got = cache.get(f"{tag}chains-p{p}", {"p": p}) if cache else None
        if got is not None:
            out[p] = [np.asarray(a, np.int64) for a in got]
    todo = [p for p in ps if p not in out]
    if todo:
        made = {p: [] for p in todo}
        for o in obs:
            feats = reach.frame_features(o)
            for p in todo:
                made[p].append(reach.sparsify(o, p=p, feats=feats, slack=slack))
        for p in todo:
            out[p] = made[p]
            if cache:
                cache.put(f"{tag}chains-p{p}", {"p": p}, [a.tolist() for a in made[p]])
    return out


def chain_reachability(path: str, controller, reach):
    """The RE at ``path`` (trained for ``controller``) that places anchors
    in ``reach``'s place: it reads the same observations, so it must share
    ``reach``'s sensor."""
    from topodrake.learning.reachability.estimator import Reachability

    placer = Reachability.from_checkpoint(path, controller)
    if (placer.observation, placer.sensor) != (reach.observation, reach.sensor):
        raise TopodrakeError(f"--chain-re {path}: its observations ({placer.observation}) are not "
                             f"the follower RE's ({reach.observation}, the same sensor)")
    return placer


def every_nth(n_frames: int, n: int) -> np.ndarray:
    a = np.arange(0, n_frames, max(int(n), 1))
    return a if a[-1] == n_frames - 1 else np.append(a, n_frames - 1)


def follow_chains(world_of, trajs, obs, chains, policy, reach, wide, noise_std, seed, batch,
                  noisy, follower=None, cache: RunCache | None = None, tag: str = "",
                  oracle: bool = False, key: dict | None = None, odometry=None,
                  oracle_re: bool = False, changes=None) -> tuple[np.ndarray, list[str]]:
    """Cover (M,) and outcomes of following chains[m] of trajs[m] (one
    engine batch per world and chunk of ``batch`` chains; finished batches
    are kept in ``cache`` under ``tag``). ``policy``: a C_WP, or a function
    of the world that makes one (a world-specific C_WP, e.g. the noisy
    oracle; made anew for each batch, so that its draws do not depend on
    which batches were cached). ``oracle``: the same chains followed by the
    A* oracle C_WP and the geometric oracle RE instead of ``policy`` and
    ``reach`` (perfect perception); ``oracle_re``: ``policy`` with the
    geometric oracle RE in the follower's place (the chains stay those of
    ``reach``: what RE's answers cost the follower). ``key``: more settings
    the cached batches depend on.
    ``odometry``: the cars' (and the drives') odometry model (default perfect).
    ``changes``: a :class:`~topodrake.world.changes.WorldChanges` each car
    meets on its drive (a drive with no room for them: cover NaN, outcome
    ``no_room``)."""
    m_all = len(chains)
    cover = np.zeros(m_all)
    outcomes = [""] * m_all
    seeds = trial_seeds(seed, m_all)
    by_world: dict[str, list[int]] = {}
    for m, t in enumerate(trajs):
        by_world.setdefault(t["world"], []).append(m)
    per_world = callable(policy) and not hasattr(policy, "predict")
    config = NavigationConfig(follower=follower or FollowerConfig(),
                              rollout=RolloutConfig(noise_std=noise_std if noisy else 0.0))
    if odometry is not None:
        config.odometry = odometry
    for name, idx in by_world.items():
        world = world_of(name)
        cwp, re = policy, reach
        if oracle or oracle_re:
            from topodrake.learning.waypoint.policy import AStarOracle
            from topodrake.navigation.evaluate import GeometricReachability

            re = GeometricReachability(world, k=wide.k, frame_step=wide.frame_step)
        if oracle:
            cwp = AStarOracle(world, k=wide.k, frame_step=wide.frame_step)
        for lo in range(0, len(idx), batch):
            part = idx[lo:lo + batch]
            block = {**(key or {}), "noisy": noisy, "cars": part,
                     "chains": _hash([chains[m] for m in part])}
            got = cache.get(f"{tag}{name}-{lo}", block) if cache else None
            if got is not None:
                for j, m in enumerate(part):
                    cover[m], outcomes[m] = got["cover"][j], got["outcomes"][j]
                continue
            engine = NavigationEngine(world, policy(world) if per_world and not oracle else cwp,
                                      re, config)
            res, watch, *placed = follow_chains_once(
                engine, [trajs[m]["poses"] for m in part],
                [trajs[m]["poses"] if oracle else obs[m] for m in part],
                [chains[m] for m in part], wide.k, wide.frame_step, [seeds[m] for m in part],
                noisy=noisy, changes=changes)
            for j, m in enumerate(part):
                cover[m] = watch.cover(j)
                outcomes[m] = NAV_OUTCOMES[int(res.outcome[j])]
                if placed and placed[0][j] is None:
                    cover[m], outcomes[m] = np.nan, "no_room"
            if cache:
                cache.put(f"{tag}{name}-{lo}", block, {"cover": [float(cover[m]) for m in part],
                                                     "outcomes": [outcomes[m] for m in part]})
    return cover, outcomes


def _hash(arrays) -> str:
    import hashlib

    h = hashlib.sha1()
    for a in arrays:
        h.update(np.asarray(a, np.int64).tobytes())
        h.update(b"|")
    return h.hexdigest()[:16]


def run_controller(name, spec, trajs, world_of, sc, bar, *, runs_dir, trajectories_file: str,
                   chain_path: str | None = None,
                   sensitivity_of: tuple[str, list[str]] | None = None) -> dict:
    """Controller ``name``'s figures at every p of the scenario ``sc`` (a
    :class:`~topodrake.experiments.follow_scenario.FollowingScenario`): its
    RE chains and every n-th frame chains of ``trajs`` followed as its
    ``runs`` ask (noisy and oracle runs at its ``headline_p`` only), and its
    sensitivity table for ``sensitivity_of`` (KEY, values). ``spec``: (C_WP,
    RE, the controller the RE was trained for); ``chain_path``: the RE that
    places its anchors instead of its own. The scenario's settings, the
    checkpoints and ``trajectories_file`` (the drives' cache name) key the
    run cache in ``runs_dir``; ``bar``: a progress bar updated once per run."""
    import torch

    from topodrake.learning.reachability.estimator import Reachability

    cwp_path, re_path, re_controller = spec
    reach = Reachability.from_checkpoint(re_path, re_controller)
    follower, odometry = sc.follower_config(), sc.odometry_config()
    placer = reach if chain_path is None else chain_reachability(chain_path, re_controller, reach)
    if is_oracle_spec(cwp_path):                     # made per world: it reads the world's A*
        policy, wide = (lambda world: controller_policy(cwp_path, world)), reach
    else:
        policy = controller_policy(cwp_path)
        wide = policy if policy.k >= reach.k else reach
    torch.set_num_threads(1)
    cache = RunCache(Path(runs_dir), {
        "trajectories": trajectories_file, "controller": name,
        "checkpoints": [_fingerprint(f) for f in spec], "seed": sc.seed, "noise": sc.noise,
        "follower": asdict(follower), "tolerance_m": TOLERANCE_M,
        **({} if odometry.is_perfect else {"odometry": asdict(odometry)}),
        "diverge_m": DIVERGE_M, "slack": sc.slack,
        **({} if chain_path is None else {"chain_reach": _fingerprint(chain_path)})})
    obs = Observations(reach, trajs, world_of)
    lengths = np.array([path_length(t["poses"])[-1] for t in trajs])
    frames = np.array([len(t["poses"]) for t in trajs])
    ps = list(sc.p)
    chains = chains_of(obs, placer, ps, cache, f"{name}-", sc.slack)
    out: dict = {"controller": cwp_path, "reach": re_path, "points": []}
    if chain_path is not None:
        out["chain_reach"] = chain_path
    runs = set(sc.runs)

    if sc.changes.any:            # the changed world, beside the runs it changes
        runs |= {"changed"} | ({"changed_oracle"} if "oracle" in runs else set())

    def follow(kind, tag, p, chain_list, noisy=False):
        """One kind of run of ``chain_list``: (covers, outcomes); None when not asked for."""
        if kind not in runs:
            return None
        changed = kind.startswith("changed")
        got = follow_chains(world_of, trajs, obs, chain_list, policy, reach, wide, sc.noise,
                            sc.seed, sc.batch, noisy=noisy, follower=follower,
                            odometry=odometry, cache=cache,
                            tag=f"{name}-p{p}-{tag}-", oracle=kind in ("oracle", "changed_oracle"),
                            oracle_re=kind == "oracle_re",
                            changes=sc.changes if changed else None)
        bar.update()
        return got

    for p in ps:
        anchors = np.array([len(a) for a in chains[p]])
        density = float(anchors.sum() / lengths.sum())
        n = max(1, int(round(frames.sum() / anchors.sum())))
        sub = [every_nth(f, n) for f in frames]
        sub_density = float(sum(len(a) for a in sub) / lengths.sum())
        point = {"p_sparsify": p, "anchors_per_m": round(density, 4), "every_n": n,
                 "subsampled_anchors_per_m": round(sub_density, 4)}
        headline = abs(p - sc.headline_p) < 1e-9
        for kind, tag, suffix, chain_list, noisy, asked in (
                ("re", "re", "", chains[p], False, True),
                ("subsampled", f"every{n}", "_subsampled", sub, False, True),
                ("noisy", "noisy", "_noisy", chains[p], True, headline),
                ("oracle", "oracle", "_oracle", chains[p], False, headline),
                ("oracle_re", "oracle_re", "_oracle_re", chains[p], False, headline),
                ("changed", f"changed-{sc.changes.label}", "_changed", chains[p], False,
                 headline),
                ("changed_oracle", f"changed-oracle-{sc.changes.label}", "_changed_oracle",
                 chains[p], False, headline)):
            got = follow(kind, tag, p, chain_list, noisy) if asked else None
            if got is not None:
                c, o = got
                rated = np.isfinite(c)
                point.update({f"cover{suffix}": float(c[rated].mean()) if rated.any() else None,
                              f"outcomes{suffix}": _count(o),
                              f"covers{suffix}": [None if not ok else v for v, ok
                                                  in zip(c.round(4).tolist(), rated)]})
        out["points"].append(point)
        bar.set_postfix_str(f"{name} p={p}: cover {point.get('cover', float('nan')):.3f}")
    if sensitivity_of:
        out["sensitivity"] = sensitivity(name, cwp_path, reach, trajs, obs, world_of, sc,
                                         sensitivity_of, cache, bar, placer)
    return out


def sensitivity(name, cwp_path, reach, trajs, obs, world_of, sc, table, cache, bar,
                placer=None) -> dict:
    """Cover of ``name``'s RE chains at the scenario's headline p followed by
    the noisy oracle C_WP (and ``name``'s RE) at each value of ``table``
    (KEY, values): the error of ``cwp_path`` if it is an oracle spec, else
    none, with KEY set to each value. ``placer``: the RE that made the
    chains (default ``reach``)."""
    import re as regex


    key, values = table
    p = sc.headline_p
    chains = chains_of(obs, placer or reach, [p], cache, f"{name}-", sc.slack)[p]
    base = parse_oracle_spec(cwp_path if is_oracle_spec(cwp_path) else "oracle")
    rows = []
    for v in values:
        error = base.with_value(key, v)
        text = error.text
        c, o = follow_chains(world_of, trajs, obs, chains,
                             lambda world, text=text: controller_policy(text, world), reach, reach,
                             sc.noise, sc.seed, sc.batch, noisy=False,
                             follower=sc.follower_config(), odometry=sc.odometry_config(),
                             cache=cache,
                             tag=f"{name}-p{p}-sens-{regex.sub(r'[^A-Za-z0-9_.=-]', '_', text)}-",
                             key={"cwp": _fingerprint(text)})
        bar.update()
        rows.append({key: getattr(error, key), "spec": text, "cover": round(float(c.mean()), 4),
                     "trajectories": len(c), "outcomes": _count(o)})
    return {"key": key, "p_sparsify": p, "rows": rows}


def _fingerprint(path: str) -> str:
    """A checkpoint's SHA-1 (with its follower calibration's, where it has
    one), the registration controller's runs key, or an oracle spec's text
    (with a hash of the noisy oracle's source: a code change invalidates its runs)."""
    if is_oracle_spec(path):
        return f"{path}+{file_sha1(noisy_oracle.__file__)[:16]}"
    if path == REGISTRATION:
        return registration_runs_key()
    side = Path(path).parent / SIDECAR
    return file_sha1(path) + (f"+{file_sha1(side)}" if side.is_file() else "")


def _count(outcomes: list[str]) -> dict:
    return {o: outcomes.count(o) for o in sorted(set(outcomes))}
