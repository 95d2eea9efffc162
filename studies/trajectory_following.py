"""Trajectory following: cover rate against anchors per metre (the paper's cover-rate figure).

Test trajectories (seeded expert drives between random free poses of the
test houses whose A* path is 10-20 m, mean about 15 m; cached in
``DATA/trajectory_following/``) are each reduced to a chain of anchors (a)
by RE sparsification at every ``--p`` and (b) by keeping every n-th frame
(the SPTM way) at the density the RE chains of that ``p`` have. Each chain is
followed by the learned follower (:mod:`topodrake.navigation`, the batched
navigation engine) from a jittered start (0.3 m to a random side, turned
9 deg to a random side), with each controller and its RE; at p = 0.99 the RE
chains are followed again with actuation noise N(1, ``--noise``). The robot
stops when it strays more than 1 m from the reference path (``DIVERGE_M``),
collides, the follower ends, or at 2 x frames + 100 periods. Cover: the
share of the reference path's length up to the farthest reference sample the
robot came within 0.5 m of (in order), averaged over trajectories. At
that ``p`` the RE chains are also followed with perfect perception (the A*
oracle C_WP and the geometric oracle RE: ``cover_oracle``), which separates
the follower's design from the networks' errors.
``--follower`` changes the follower's thresholds (an ablation).
``--cwp NAME=oracle:anchor=0.3`` follows NAME's chains with the A* oracle
C_WP plus a controlled error and NAME's RE
(:mod:`topodrake.learning.noisy_oracle`); ``--sensitivity anchor=0.1,0.3``
follows the RE chains at the headline p with it at each error size (the
``sensitivity`` table: cover against error).

Each controller's chains and each engine batch of follows are kept in
``OUT/trajectory_following_runs/`` with the settings and checkpoint hashes
that made them; a rerun with the same settings reuses them, so a long run
(``--trajectories 500``) resumes after a stop.

camera_k0 has no RE of its own: its chains and its follower's RE are the
camera k=2 ones (the network of the nearest controller).

lidar_reg is the registration controller
(:class:`topodrake.registration.policy.RegistrationPolicy`: no network,
scans registered against the anchors' taught scans) with the RE learnt from
its own rollouts (``checkpoints/reach_lidar_reg``); its runs are keyed by
the controller's settings and the registration package's sources instead of
a checkpoint's hash.

    python studies/trajectory_following.py --json

prints at p = 0.99 ``{"camera_k0": {"cover": c, "cover_noisy": c,
"cover_subsampled": c, "cover_oracle": c, "anchors_per_m": a}, ...}`` and writes
``results/trajectory_following.json`` and ``.png``.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from topodrake import argtypes as at
from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_bytes, atomic_write_json
from topodrake.learning.noisy_oracle import is_oracle_spec
from topodrake.navigation.chains import DIVERGE_M, TOLERANCE_M, follow_chains_once, path_length

CONTROLLERS = {
    # name: (C_WP checkpoint, RE checkpoint, the controller the RE was trained for)
    "camera_k0": ("checkpoints/camera_k0/checkpoint.pt", "checkpoints/reach_camera_k2/checkpoint.pt",
                  "checkpoints/camera_k2/checkpoint.pt"),
    "camera_k2": ("checkpoints/camera_k2/checkpoint.pt", "checkpoints/reach_camera_k2/checkpoint.pt",
                  "checkpoints/camera_k2/checkpoint.pt"),
    "camera_k5": ("checkpoints/camera_k5/checkpoint.pt", "checkpoints/reach_camera_k5/checkpoint.pt",
                  "checkpoints/camera_k5/checkpoint.pt"),
    "lidar_k5": ("checkpoints/lidar_k5/checkpoint.pt", "checkpoints/reach_lidar_k5/checkpoint.pt",
                 "checkpoints/lidar_k5/checkpoint.pt"),
    # the C_WP trained at scale, with the RE of the C_WP its chains were made for
    "lidar_k5_scale": ("checkpoints/lidar_k5_scale/checkpoint.pt",
                       "checkpoints/reach_lidar_k5/checkpoint.pt", "checkpoints/lidar_k5/checkpoint.pt"),
    # the registration C_WP has no checkpoint: "registration" names it
    "lidar_reg": ("registration", "checkpoints/reach_lidar_reg/checkpoint.pt", "registration"),
}


# ---------------------------------------------------------------- trajectories

def make_trajectories(worlds: list[str], n: int, seed: int, lo_m: float = 10.0,
                      hi_m: float = 20.0) -> list[dict]:
    """``n`` successful noise-free expert drives, round-robin over ``worlds``,
    between random free poses whose A* path is ``lo_m``..``hi_m`` long."""
    from topodrake.rollout import ExpertRollout, RolloutConfig
    from topodrake.world import load_world

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
    (``slack``: see :func:`topodrake.topomap.sparsify.sparsify`)."""
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


def every_nth(n_frames: int, n: int) -> np.ndarray:
    a = np.arange(0, n_frames, max(int(n), 1))
    return a if a[-1] == n_frames - 1 else np.append(a, n_frames - 1)


def follow_chains(world_of, trajs, obs, chains, policy, reach, wide, noise_std, seed, batch,
                  noisy, follower=None, cache: RunCache | None = None, tag: str = "",
                  oracle: bool = False, key: dict | None = None, odometry=None
                  ) -> tuple[np.ndarray, list[str]]:
    """Cover (M,) and outcomes of following chains[m] of trajs[m] (one
    engine batch per world and chunk of ``batch`` chains; finished batches
    are kept in ``cache`` under ``tag``). ``policy``: a C_WP, or a function
    of the world that makes one (a world-specific C_WP, e.g. the noisy
    oracle; made anew for each batch, so that its draws do not depend on
    which batches were cached). ``oracle``: the same chains followed by the
    A* oracle C_WP and the geometric oracle RE instead of ``policy`` and
    ``reach`` (perfect perception). ``key``: more settings the cached batches depend on.
    ``odometry``: the cars' (and the drives') odometry model (default perfect)."""
    from topodrake.montecarlo import trial_seeds
    from topodrake.navigation.engine import NAV_OUTCOMES, NavigationConfig, NavigationEngine
    from topodrake.navigation.follower import FollowerConfig
    from topodrake.rollout import RolloutConfig

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
        if oracle:
            from topodrake.learning.policy import AStarOracle
            from topodrake.navigation.evaluate import GeometricReachability

            cwp = AStarOracle(world, k=wide.k, frame_step=wide.frame_step)
            re = GeometricReachability(world, k=wide.k, frame_step=wide.frame_step)
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
            res, watch = follow_chains_once(
                engine, [trajs[m]["poses"] for m in part],
                [trajs[m]["poses"] if oracle else obs[m] for m in part],
                [chains[m] for m in part], wide.k, wide.frame_step, [seeds[m] for m in part],
                noisy=noisy)
            for j, m in enumerate(part):
                cover[m] = watch.cover(j)
                outcomes[m] = NAV_OUTCOMES[int(res.outcome[j])]
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


def run_controller(name, spec, trajs, world_of, ps, args, bar) -> dict:
    import torch

    from topodrake.learning.reach_train import controller_policy
    from topodrake.learning.reachability import Reachability

    cwp_path, re_path, re_controller = spec
    reach = Reachability.from_checkpoint(re_path, re_controller)
    if is_oracle_spec(cwp_path):                     # made per world: it reads the world's A*
        policy, wide = (lambda world: controller_policy(cwp_path, world)), reach
    else:
        policy = controller_policy(cwp_path)
        wide = policy if policy.k >= reach.k else reach
    torch.set_num_threads(1)
    cache = RunCache(Path(args.out) / "trajectory_following_runs", {
        "trajectories": args.trajectories_file, "controller": name,
        "checkpoints": [_fingerprint(f) for f in spec], "seed": args.seed, "noise": args.noise,
        "follower": asdict(args.follower_config), "tolerance_m": TOLERANCE_M,
        **({} if args.odometry_config.is_perfect else {"odometry": asdict(args.odometry_config)}),
        "diverge_m": DIVERGE_M, "slack": args.slack})
    obs = Observations(reach, trajs, world_of)
    lengths = np.array([path_length(t["poses"])[-1] for t in trajs])
    frames = np.array([len(t["poses"]) for t in trajs])
    chains = chains_of(obs, reach, ps, cache, f"{name}-", args.slack)
    out: dict = {"controller": cwp_path, "reach": re_path, "points": []}
    runs = args.runs

    def follow(kind, tag, p, chain_list, noisy=False, oracle=False):
        """One kind of run of ``chain_list``: (covers, outcomes); None when not asked for."""
        if kind not in runs:
            return None
        got = follow_chains(world_of, trajs, obs, chain_list, policy, reach, wide, args.noise,
                            args.seed, args.batch, noisy=noisy, follower=args.follower_config,
                            odometry=args.odometry_config, cache=cache,
                            tag=f"{name}-p{p}-{tag}-", oracle=oracle)
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
        headline = abs(p - args.headline_p) < 1e-9
        for kind, tag, suffix, chain_list, noisy, oracle, asked in (
                ("re", "re", "", chains[p], False, False, True),
                ("subsampled", f"every{n}", "_subsampled", sub, False, False, True),
                ("noisy", "noisy", "_noisy", chains[p], True, False, headline),
                ("oracle", "oracle", "_oracle", chains[p], False, True, headline)):
            got = follow(kind, tag, p, chain_list, noisy, oracle) if asked else None
            if got is not None:
                c, o = got
                point.update({f"cover{suffix}": float(c.mean()), f"outcomes{suffix}": _count(o),
                              f"covers{suffix}": c.round(4).tolist()})
        out["points"].append(point)
        bar.set_postfix_str(f"{name} p={p}: cover {point.get('cover', float('nan')):.3f}")
    if args.sensitivity:
        out["sensitivity"] = sensitivity(name, cwp_path, reach, trajs, obs, world_of, args, cache,
                                         bar)
    return out


def sensitivity(name, cwp_path, reach, trajs, obs, world_of, args, cache, bar) -> dict:
    """Cover of ``name``'s RE chains at the headline p followed by the noisy
    oracle C_WP (and ``name``'s RE) at each value of ``args.sensitivity``
    (KEY, values): the error of ``cwp_path`` if it is an oracle spec, else
    none, with KEY set to each value."""
    import re as regex

    from topodrake.learning.noisy_oracle import parse_oracle_spec
    from topodrake.learning.reach_train import controller_policy

    key, values = args.sensitivity
    p = args.headline_p
    chains = chains_of(obs, reach, [p], cache, f"{name}-", args.slack)[p]
    base = parse_oracle_spec(cwp_path if is_oracle_spec(cwp_path) else "oracle")
    rows = []
    for v in values:
        error = base.with_value(key, v)
        text = error.text
        c, o = follow_chains(world_of, trajs, obs, chains,
                             lambda world, text=text: controller_policy(text, world), reach, reach,
                             args.noise, args.seed, args.batch, noisy=False,
                             follower=args.follower_config, odometry=args.odometry_config, cache=cache,
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
    from topodrake.fileio import file_sha1
    from topodrake.learning import noisy_oracle
    from topodrake.learning.follower_platt import SIDECAR
    from topodrake.learning.reach_train import REGISTRATION, registration_runs_key

    if is_oracle_spec(path):
        return f"{path}+{file_sha1(noisy_oracle.__file__)[:16]}"
    if path == REGISTRATION:
        return registration_runs_key()
    side = Path(path).parent / SIDECAR
    return file_sha1(path) + (f"+{file_sha1(side)}" if side.is_file() else "")


def _count(outcomes: list[str]) -> dict:
    return {o: outcomes.count(o) for o in sorted(set(outcomes))}


def plot(results: dict, path: Path, n_traj: int) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from topodrake.world.plot import save_figure

    fig, ax = plt.subplots(figsize=(8, 5.5))
    for i, (name, r) in enumerate(results.items()):
        color = f"C{i}"
        pts = r["points"]
        nan = float("nan")
        ax.plot([q["anchors_per_m"] for q in pts], [q.get("cover", nan) for q in pts], "o-",
                color=color,
                label=f"{name}, RE anchors")
        for q in pts:
            ax.annotate(f"{q['p_sparsify']}", (q["anchors_per_m"], q.get("cover", nan)), fontsize=7,
                        xytext=(3, 3), textcoords="offset points", color=color)
        ax.plot([q["subsampled_anchors_per_m"] for q in pts],
                [q.get("cover_subsampled", nan) for q in pts],
                "s--", color=color, alpha=0.7, label=f"{name}, every n-th frame")
    ax.set_xlabel("anchors per metre")
    ax.set_ylabel("cover rate")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title(f"Trajectory following, {n_traj} test trajectories (points marked with p_sparsify)")
    save_figure(fig, path)


def main(argv=None) -> int:
    from topodrake.montecarlo import study_main

    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    ap.add_argument("--trajectories", type=at.count, default=8, help="test trajectories (paper: 500)")
    ap.add_argument("--worlds", default="test-0,test-1,test-2,test-3,test-4", help="test houses")
    ap.add_argument("--p", default="0.9,0.95,0.98,0.99,0.995", help="p_sparsify values")
    ap.add_argument("--headline-p", type=at.probability, default=0.99,
                    help="p_sparsify of the printed summary and of the noisy runs")
    ap.add_argument("--controllers", default=",".join(CONTROLLERS),
                    help="controllers to follow with")
    ap.add_argument("--cwp", action="append", metavar="NAME=CHECKPOINT",
                    help="follow NAME's chains with another C_WP (NAME's RE stays; repeatable); "
                         "oracle:KEY=VALUE[:...]: the A* oracle with a controlled error (keys "
                         "anchor, fresh, tail, seed)")
    ap.add_argument("--sensitivity", metavar="KEY=V1,V2,...",
                    help="also follow each controller's RE chains at the headline p with the "
                         "oracle C_WP (its --cwp oracle spec, else the exact one) with KEY set to "
                         "each value: cover against error size")
    ap.add_argument("--re", action="append", metavar="NAME=CHECKPOINT",
                    help="with another RE under NAME, trained for NAME's C_WP (the --cwp one if "
                         "given): its chains and its answers; repeatable")
    ap.add_argument("--batch", type=at.count, default=48, help="cars per engine batch")
    ap.add_argument("--seed", type=at.seed, default=0, help="seed of the trajectories, starts and noise")
    ap.add_argument("--noise", type=at.nonnegative, default=0.33, help="actuation noise std of the noisy runs")
    ap.add_argument("--data", default="data", help="cache of the test trajectories")
    ap.add_argument("--out", default="results", help="output folder")
    ap.add_argument("--follower", default="{}",
                    help="follower thresholds to change, as JSON (FollowerConfig fields)")
    ap.add_argument("--runs", default="re,subsampled,noisy,oracle",
                    help="which runs to make (comma-separated of re, subsampled, noisy, oracle; "
                         "noisy and oracle at the headline p only); figures of runs left out "
                         "are null")
    ap.add_argument("--odometry", choices=("perfect", "wheel"), default="wheel",
                    help="the cars' and the drives' odometry: the true pose, or wheel odometry "
                         "that drifts (topodrake.odometry.OdometryConfig.wheel)")
    ap.add_argument("--slack", type=at.fraction, default=0.0,
                    help="sparsify slack where RE passes not even the next frame above p (0: the "
                         "paper's rule; maps use MapConfig.sparsify_slack)")
    ap.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    return study_main(_run, args)


def parse_sensitivity(text: str | None) -> tuple[str, list[str]] | None:
    """``--sensitivity KEY=V1,V2,...`` as (KEY, values), each checked as an oracle spec value."""
    from topodrake.learning.noisy_oracle import OracleError

    if not text:
        return None
    key, sep, values = text.partition("=")
    items = [v for v in values.split(",") if v]
    if not sep or not items:
        raise TopodrakeError(f"--sensitivity {text!r} is not KEY=V1,V2,... (keys: anchor, fresh, "
                             f"tail, seed)")
    for v in items:
        OracleError().with_value(key, v)
    return key, items


def _run(args) -> int:
    from tqdm import tqdm

    from topodrake.world import load_world

    if args.trajectories < 1:
        raise TopodrakeError("--trajectories must be >= 1")
    if args.batch < 1:
        raise TopodrakeError("--batch must be >= 1")
    if args.seed < 0:
        raise TopodrakeError("--seed must be >= 0")
    if not (np.isfinite(args.noise) and args.noise >= 0):
        raise TopodrakeError("--noise must be finite and >= 0")
    try:
        ps = [float(x) for x in args.p.split(",") if x]
    except ValueError:
        raise TopodrakeError(f"--p must be comma-separated numbers, got {args.p!r}") from None
    if not ps or any(not 0 < p < 1 for p in ps):
        raise TopodrakeError("--p values must be in (0, 1)")
    from topodrake.navigation.follower import FollowerConfig

    try:
        args.follower_config = FollowerConfig(**json.loads(args.follower)).check()
    except (ValueError, TypeError) as e:
        raise TopodrakeError(f"--follower is not a JSON object of FollowerConfig fields ({e})") \
            from None
    from topodrake.learning.follower_bench import parse_controllers
    from topodrake.odometry import OdometryConfig

    args.odometry_config = getattr(OdometryConfig, args.odometry)()
    args.runs = {r for r in args.runs.split(",") if r}
    if not args.runs or args.runs - {"re", "subsampled", "noisy", "oracle"}:
        raise TopodrakeError(f"--runs takes re, subsampled, noisy, oracle, got "
                             f"{','.join(sorted(args.runs)) or 'none'}")
    specs = parse_controllers(args.controllers, args.cwp, args.re, table=CONTROLLERS,
                              must_exist=True)
    args.sensitivity = parse_sensitivity(args.sensitivity)
    worlds = [w for w in args.worlds.split(",") if w]
    t0 = time.perf_counter()
    trajs = load_trajectories(Path(args.data), worlds, args.trajectories, args.seed)
    args.trajectories_file = trajectories_name(worlds, args.trajectories, args.seed)
    cache: dict = {}
    world_of = lambda n: cache.setdefault(n, load_world(n))   # noqa: E731
    lengths = [path_length(t["poses"])[-1] for t in trajs]
    headline = any(abs(p - args.headline_p) < 1e-9 for p in ps)
    per_p = ("re" in args.runs) + ("subsampled" in args.runs)
    at_headline = ("noisy" in args.runs) + ("oracle" in args.runs) if headline else 0
    steps = len(specs) * (per_p * len(ps) + at_headline
                          + (len(args.sensitivity[1]) if args.sensitivity else 0))
    results = {}
    with tqdm(total=steps, desc="trajectory following", disable=args.quiet, unit="sweep") as bar:
        for name in specs:
            results[name] = run_controller(name, specs[name], trajs, world_of, ps, args, bar)
    summary = {}
    for name, r in results.items():
        q = min(r["points"], key=lambda q: abs(q["p_sparsify"] - args.headline_p))
        summary[name] = {k: (round(q[k], 4) if k in q else None)
                         for k in ("cover", "cover_noisy", "cover_subsampled", "cover_oracle")}
        summary[name]["anchors_per_m"] = q["anchors_per_m"]
    tables = {name: r["sensitivity"] for name, r in results.items() if "sensitivity" in r}
    out = Path(args.out)
    wall = time.perf_counter() - t0
    atomic_write_json(out / "trajectory_following.json", {
        "command": "python studies/trajectory_following.py " + " ".join(sys.argv[1:]),
        "trajectories": len(trajs), "mean_length_m": round(float(np.mean(lengths)), 2),
        "worlds": worlds, "seed": args.seed, "noise": args.noise, "p_sparsify": ps,
        "tolerance_m": TOLERANCE_M, "diverge_m": DIVERGE_M, "wall_time_s": round(wall, 1),
        "follower": asdict(args.follower_config), "odometry": asdict(args.odometry_config),
        "summary": summary, **({"sensitivity": tables} if tables else {}), "results": results})
    plot(results, out / "trajectory_following.png", len(trajs))
    if args.json:
        print(json.dumps({**summary, **({"sensitivity": tables} if tables else {})}))
    else:
        for name, s in summary.items():
            f = {k: "-" if v is None else f"{v:.3f}" for k, v in s.items()}
            print(f"{name:<10} cover {f['cover']}, oracle {f['cover_oracle']}, "
                  f"noisy {f['cover_noisy']}, every n-th "
                  f"{f['cover_subsampled']} at {s['anchors_per_m']:.2f} anchors/m")
        for name, t in tables.items():
            print(f"{name} RE chains at p = {t['p_sparsify']}, oracle C_WP with {t['key']}:")
            for row in t["rows"]:
                print(f"  {t['key']}={row[t['key']]:<6g} cover {row['cover']:.3f} "
                      f"({row['trajectories']} trajectories, {row['spec']})")
    print(f"{len(trajs)} trajectories (mean {np.mean(lengths):.1f} m), {len(specs)} controllers, "
          f"{len(ps)} p values in {wall / 60:.1f} min", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
