"""Training samples for the waypoint network C_WP (the paper's "Designing a Robust Local Controller").

A sample pairs a *source* frame i and a *target* frame j of one successful
expert trajectory:

* the target lies at signed arc-length distance ``d ~ U(-0.5, 3.0)`` m from
  the source along the trajectory (negative = behind);
* the source pose is jittered sideways by ``clip(0.3 N(0,1), +-1)`` m and in
  heading by ``N(0, 9 deg)``; the jittered reference point must be in the
  free configuration space of the reachable region (re-drawn up to
  ``jitter_tries`` times, else the draw is dropped);
* both image overlaps between the jittered source and the target exceed
  ``min_overlap`` (0.1);
* the waypoint label is the A* expert's waypoint *from the jittered source
  to the target*: A* from the jittered position to the target position
  (not to the trajectory's goal, so targets behind the car get a waypoint
  behind it), then the expert's rule (the farthest path point within
  ``lookahead_m`` of path length with a clear line of sight), shortened to
  the straight-line distance from the jittered source to the target, and
  expressed in the jittered source's car frame. A target whose cell is not
  in the free c-space (the car may pass a wall closer than the c-space
  radius) is planned to the nearest free cell within 0.3 m;
* also stored: the heading difference (target minus jittered source), both
  overlaps (R_src->tgt, R_tgt->src), the source's replayed speed and
  steering, and the direct-control label: the laser RMP's controls at the
  jittered state toward the label waypoint (what "waypoint + RMP" would do,
  so the direct-control baseline learns the same behaviour end to end).

Context frames are *not* stored: :meth:`SampleSet.context_rows` derives
frames ``j - k*step .. j + k*step`` (clamped to the trajectory) for any k,
so one sample set serves k = 0, 2, 5, camera and lidar. Images are rendered
from poses when a batch is drawn (:mod:`topodrake.learning.data`).

Everything is drawn from explicit seeds: one generator per world, spawned
from the set's seed, so a set is reproduced by (worlds, drives, seed, config).

File format (``.npz``, written atomically): ``format = "topodrake-samples"``,
``version``, ``meta`` (JSON: config, seed, worlds), the trajectory arrays
(``traj_world``, ``traj_offsets``, ``poses``, ``states``) and the per-sample
arrays listed in :class:`SampleSet`.
"""

from __future__ import annotations

import io
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from topodrake.contract.frames import context_frames
from topodrake.control import controls_toward
from topodrake.demonstrations import CollectConfig, collect, load_demos
from topodrake.errors import TopodrakeError
from topodrake.expert import ExpertConfig, PackedPaths, expert_waypoints
from topodrake.fileio import atomic_write_bytes, read_tagged_npz
from topodrake.montecarlo import trial_seeds
from topodrake.rmp import RmpConfig
from topodrake.sensing.config import CameraConfig, LidarConfig
from topodrake.sensing.lidar import Lidar
from topodrake.sensing.overlap import mutual_overlap
from topodrake.vehicle import VehicleConfig, vehicle_step
from topodrake.world import load_world

FORMAT = "topodrake-samples"
VERSION = 1


@dataclass
class SampleConfig:
    """How C_WP samples are drawn (defaults: the authors' values)."""

    distance_min_m: float = -0.5
    distance_max_m: float = 3.0
    min_overlap: float = 0.1
    lateral_std_m: float = 0.3
    lateral_clip_m: float = 1.0
    heading_std_deg: float = 9.0
    jitter_tries: int = 10
    overlap_rays: int = 100
    lookahead_m: float = 5.0
    target_snap_m: float = 0.3      # A* goal = nearest free cell within this of the target


# ---------------------------------------------------------------- trajectories

@dataclass
class TrajectorySet:
    """Expert trajectories of several worlds, concatenated.

    Trajectory t has rows ``traj_offsets[t]:traj_offsets[t+1]`` of ``poses``
    (x, y, heading) and ``states`` (x, y, heading, speed, steering; replayed
    from the stored controls) and lives in ``worlds[traj_world[t]]``.
    """

    worlds: list[str]
    traj_world: np.ndarray     # (T,) int32
    traj_offsets: np.ndarray   # (T + 1,) int64
    poses: np.ndarray          # (P, 3)
    states: np.ndarray         # (P, 5)

    @property
    def count(self) -> int:
        return len(self.traj_world)

    def rows(self, t: int) -> slice:
        return slice(int(self.traj_offsets[t]), int(self.traj_offsets[t + 1]))

    @classmethod
    def from_drives(cls, worlds: list[str], drives: list[tuple[int, np.ndarray, np.ndarray]],
                    vehicle=None) -> "TrajectorySet":
        """``drives``: (world index, poses (K+1, 3), controls (K, 2)) of each drive.

        Speeds and steering angles are replayed from rest through the
        vehicle model (the expert starts every drive at rest); a replay that
        departs from the stored poses by more than 1 mm is refused."""
        vehicle = vehicle or VehicleConfig()
        drives = [d for d in drives if len(d[1]) >= 2]
        if not drives:
            raise TopodrakeError("no expert trajectories with at least two frames")
        lengths = np.array([len(p) for _, p, _ in drives])
        n, kmax = len(drives), int(lengths.max())
        states = np.zeros((n, kmax, 5))
        controls = np.zeros((n, kmax - 1, 2))
        for i, (_, p, u) in enumerate(drives):
            states[i, 0, :3] = p[0]
            controls[i, :len(u)] = u
        for k in range(kmax - 1):
            states[:, k + 1] = vehicle_step(states[:, k], controls[:, k], vehicle)
        out_states, out_poses = [], []
        for i, (_, p, _) in enumerate(drives):
            s = states[i, :len(p)]
            err = np.abs(s[:, :2] - p[:, :2]).max()
            if err > 1e-3:
                raise TopodrakeError(f"replaying drive {i} departs from its poses by {err:.3g} m; "
                                     "were the demonstrations made with another vehicle config?")
            s[:, :3] = p
            out_states.append(s)
            out_poses.append(np.asarray(p, np.float64))
        offsets = np.zeros(n + 1, np.int64)
        offsets[1:] = np.cumsum(lengths)
        return cls(list(worlds), np.array([w for w, _, _ in drives], np.int32), offsets,
                   np.concatenate(out_poses), np.concatenate(out_states))

    @classmethod
    def from_demo_folders(cls, folders: list) -> "TrajectorySet":
        """Successful drives of demonstration sets written by
        :func:`topodrake.demonstrations.collect` (one folder per world)."""
        worlds, drives = [], []
        for folder in folders:
            manifest, demos = load_demos(folder, successful_only=True)
            worlds.append(manifest["world"])
            drives += [(len(worlds) - 1, d.poses, d.controls) for d in demos]
        return cls.from_drives(worlds, drives)

    def context_rows(self, traj: np.ndarray, frames: np.ndarray, k: int, frame_step: int
                     ) -> np.ndarray:
        """(M, 2k+1) rows of :attr:`poses` that form the contexts of frames
        ``frames`` of trajectories ``traj`` (each clamped to its own drive)."""
        lo = self.traj_offsets[traj][:, None]
        return lo + context_frames(self.traj_offsets[traj + 1][:, None] - lo, frames, k, frame_step)

    @classmethod
    def concat(cls, sets: list["TrajectorySet"]) -> "TrajectorySet":
        """The trajectories of ``sets``, one after another (worlds too). Sets
        of different worlds only: a world in two sets would stand for two
        different sets of drives."""
        worlds = [w for ts in sets for w in ts.worlds]
        if len(set(worlds)) != len(worlds):
            raise TopodrakeError(f"cannot join trajectory sets that share worlds ({worlds})")
        w_off = np.cumsum([0] + [len(ts.worlds) for ts in sets])
        r_off = np.cumsum([0] + [len(ts.poses) for ts in sets])
        offsets = np.concatenate([[0]] + [ts.traj_offsets[1:] + r for ts, r in zip(sets, r_off)])
        return cls(worlds, np.concatenate([ts.traj_world + w for ts, w in zip(sets, w_off)]).astype(np.int32),
                   offsets.astype(np.int64), np.concatenate([ts.poses for ts in sets]),
                   np.concatenate([ts.states for ts in sets]))

    def select_worlds(self, names: list[str]) -> "TrajectorySet":
        keep_w = [self.worlds.index(n) for n in names]
        remap = {w: i for i, w in enumerate(keep_w)}
        ts = [t for t in range(self.count) if int(self.traj_world[t]) in remap]
        rows = [self.rows(t) for t in ts]
        lengths = np.array([r.stop - r.start for r in rows], np.int64)
        offsets = np.zeros(len(ts) + 1, np.int64)
        offsets[1:] = np.cumsum(lengths)
        return TrajectorySet(list(names), np.array([remap[int(self.traj_world[t])] for t in ts], np.int32),
                             offsets, np.concatenate([self.poses[r] for r in rows]),
                             np.concatenate([self.states[r] for r in rows]))


def collect_trajectories(world_names: list[str], demo_root, *, protocol: str = "pairs",
                         count: int = 90, seed: int = 0, progress: bool = True) -> TrajectorySet:
    """Expert demonstrations of each world (collected into ``demo_root/<world>``
    once, resumed or reused afterwards), as a :class:`TrajectorySet`."""
    folders = []
    for name in world_names:
        folder = Path(demo_root) / name
        collect(name, folder, CollectConfig(protocol=protocol, count=count, seed=seed),
                progress=progress)
        folders.append(folder)
    return TrajectorySet.from_demo_folders(folders)


# ---------------------------------------------------------------- labels

def _arclength(poses: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(poses[:, :2], axis=0).T))])


def _snap_free(world, xy: np.ndarray, radius: float) -> np.ndarray | None:
    """``xy`` if the car may stand there, else the nearest reachable free cell
    centre within ``radius``, else None."""
    grid = world.grid
    rc = grid.to_cell(xy)
    if grid.in_bounds(rc) and grid.reachable[rc[0], rc[1]]:
        return xy
    r = int(np.ceil(radius / grid.resolution))
    r0, c0 = rc
    lo = np.maximum([r0 - r, c0 - r], 0)
    hi = np.minimum([r0 + r + 1, c0 + r + 1], grid.shape)
    if np.any(hi <= lo):
        return None
    sub = grid.reachable[lo[0]:hi[0], lo[1]:hi[1]]
    cells = np.argwhere(sub) + lo
    if len(cells) == 0:
        return None
    centres = grid.to_world(cells)
    d = np.hypot(*(centres - xy).T)
    i = int(np.argmin(d))
    return centres[i] if d[i] <= radius else None


def expert_waypoint_labels(world, src_poses: np.ndarray, tgt_xy: np.ndarray,
                           lookahead_m: float = 5.0, snap_m: float = 0.3,
                           start_snap_m: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The A* expert's waypoint from each source pose toward its target.

    Returns (waypoints (N, 2) in each source's car frame, valid (N,) bool).
    A* runs from the source position to the target position (snapped to the
    nearest free cell within ``snap_m``); the waypoint is the farthest path
    point within ``lookahead_m`` with a clear line of sight, shortened to the
    straight-line source-target distance. A source inside a wall's c-space
    margin has no path (invalid) unless ``start_snap_m`` > 0: then A* and
    the line of sight start from the nearest free cell within it (the car
    drives out of the margin along the path instead of aiming through the
    wall). Also the A* oracle
    of :class:`topodrake.learning.waypoint.policy.AStarOracle`.
    """
    src_poses = np.asarray(src_poses, np.float64).reshape(-1, 3)
    tgt_xy = np.asarray(tgt_xy, np.float64).reshape(-1, 2)
    n = len(src_poses)
    valid = np.zeros(n, bool)
    sight = src_poses[:, :2].copy()
    paths = []
    for i in range(n):
        goal = _snap_free(world, tgt_xy[i], snap_m)
        start = src_poses[i, :2]
        path = None
        free = start if world.grid.is_free(start[None])[0] else \
            (_snap_free(world, start, start_snap_m) if start_snap_m > 0 else None)
        if goal is not None and free is not None:
            try:
                path = world.astar(free, goal)
                sight[i] = free         # the waypoint is the one in sight from there
                valid[i] = True
            except TopodrakeError:
                path = None
        paths.append(path if path is not None else start[None].copy())
    packed = PackedPaths.pack(paths)
    wp, _ = expert_waypoints(world.grid, packed, packed.offsets[:-1], sight,
                             ExpertConfig(lookahead_m=lookahead_m))
    vec = wp - src_poses[:, :2]
    length = np.hypot(*vec.T)
    dist = np.hypot(*(tgt_xy - src_poses[:, :2]).T)
    scale = np.where(length > dist, dist / np.maximum(length, 1e-12), 1.0)
    vec = vec * scale[:, None]
    c, s = np.cos(src_poses[:, 2]), np.sin(src_poses[:, 2])
    local = np.column_stack([c * vec[:, 0] + s * vec[:, 1], -s * vec[:, 0] + c * vec[:, 1]])
    return local, valid


def wrap_angle(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


# ---------------------------------------------------------------- samples

@dataclass
class SampleSet:
    """C_WP samples over a :class:`TrajectorySet` (one row per sample)."""
    trajectories: TrajectorySet
    traj: np.ndarray           # (M,) int32 trajectory index
    src: np.ndarray            # (M,) int32 source frame (within its trajectory)
    tgt: np.ndarray            # (M,) int32 target frame (within its trajectory)
    src_pose: np.ndarray       # (M, 3) jittered source pose
    src_speed_steer: np.ndarray  # (M, 2) replayed speed and steering at the source frame
    distance: np.ndarray       # (M,) drawn signed arc-length distance (m)
    waypoint: np.ndarray       # (M, 2) label, jittered source's car frame (m)
    heading_diff: np.ndarray   # (M,) target minus source heading (rad, wrapped)
    overlap: np.ndarray        # (M, 2) R_src->tgt, R_tgt->src
    control: np.ndarray        # (M, 2) direct-control label (accel, steering rate)
    meta: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.traj)

    @property
    def world_index(self) -> np.ndarray:
        """(M,) index into ``trajectories.worlds`` of each sample."""
        return self.trajectories.traj_world[self.traj]

    def target_rows(self) -> np.ndarray:
        return self.trajectories.traj_offsets[self.traj] + self.tgt

    def context_rows(self, k: int, step: int = 3, idx=None) -> np.ndarray:
        """(M, 2k+1) rows of ``trajectories.poses``: frames tgt - k*step ..
        tgt + k*step, clamped to each trajectory, past to future."""
        sel = slice(None) if idx is None else idx
        traj, tgt = self.traj[sel], self.tgt[sel]
        lo = self.trajectories.traj_offsets[traj]
        hi = self.trajectories.traj_offsets[traj + 1] - 1
        frames = tgt[:, None] + step * np.arange(-k, k + 1)[None]
        return np.clip(lo[:, None] + frames, lo[:, None], hi[:, None])

    def subset(self, idx) -> "SampleSet":
        f = {name: getattr(self, name)[idx] for name in _SAMPLE_FIELDS}
        return SampleSet(self.trajectories, meta=dict(self.meta), **f)

    # -- files ----------------------------------------------------------------
    def save(self, path) -> Path:
        t = self.trajectories
        buf = io.BytesIO()
        np.savez_compressed(
            buf, format=np.array(FORMAT), version=np.array(VERSION),
            meta=np.array(json.dumps({**self.meta, "worlds": t.worlds})),
            traj_world=t.traj_world, traj_offsets=t.traj_offsets, poses=t.poses, states=t.states,
            **{name: getattr(self, name) for name in _SAMPLE_FIELDS})
        return atomic_write_bytes(path, buf.getvalue())

    @classmethod
    def load(cls, path) -> "SampleSet":
        z = read_tagged_npz(path, FORMAT, VERSION, "sample")
        try:
            meta = json.loads(str(z["meta"]))
            trajs = TrajectorySet(list(meta["worlds"]), z["traj_world"], z["traj_offsets"],
                                  z["poses"], z["states"])
            f = {name: z[name] for name in _SAMPLE_FIELDS}
        except (KeyError, ValueError):
            raise TopodrakeError(f"{path} is corrupt or not a sample file") from None
        return cls(trajs, meta=meta, **f)


_SAMPLE_FIELDS = ("traj", "src", "tgt", "src_pose", "src_speed_steer", "distance", "waypoint",
                  "heading_diff", "overlap", "control")


def draw_jitter(rng: np.random.Generator, m: int, cfg: SampleConfig) -> tuple[np.ndarray, np.ndarray]:
    """Sideways offsets and heading changes, ``cfg.jitter_tries`` tries for
    each of ``m`` draws: two (tries, m) arrays."""
    lat = np.clip(cfg.lateral_std_m * rng.standard_normal((cfg.jitter_tries, m)),
                  -cfg.lateral_clip_m, cfg.lateral_clip_m)
    dth = np.radians(cfg.heading_std_deg) * rng.standard_normal((cfg.jitter_tries, m))
    return lat, dth


def apply_jitter(world, base: np.ndarray, lat: np.ndarray, dth: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The first try of each draw whose reference point lies in the reachable
    free space: jittered poses (m, 3) and (m,) True where some try was free."""
    jit = np.repeat(base[None], len(lat), axis=0)
    jit[..., 0] -= lat * np.sin(base[:, 2])
    jit[..., 1] += lat * np.cos(base[:, 2])
    jit[..., 2] += dth
    rc = world.grid.to_cell(jit[..., :2])
    inb = world.grid.in_bounds(rc)
    rcc = np.clip(rc, 0, np.array(world.grid.shape) - 1)
    free = inb & world.grid.reachable[rcc[..., 0], rcc[..., 1]]
    first = np.argmax(free, axis=0)
    return jit[first, np.arange(base.shape[0])], free.any(axis=0)


def label_samples(world, trajs: TrajectorySet, traj: np.ndarray, src: np.ndarray,
                  tgt: np.ndarray, src_pose: np.ndarray, speed_steer: np.ndarray,
                  distance: np.ndarray, cfg: SampleConfig, lidar=None, controls: bool = True) -> dict:
    """Label source poses toward target frames of one world: the sample
    fields of the rows whose both overlaps exceed ``cfg.min_overlap`` and
    whose A* label exists (rows dropped otherwise, order kept). ``src`` is
    the frame a source came from (bookkeeping), ``speed_steer`` (M, 2) the
    car's speed and steering there (for the direct-control label;
    ``controls=False`` leaves that label zero, for C_WP-only sets)."""
    lidar = lidar or Lidar(world, LidarConfig())
    traj, src, tgt = (np.asarray(a, np.int64) for a in (traj, src, tgt))
    src_pose = np.asarray(src_pose, np.float64).reshape(-1, 3)
    tgt_pose = trajs.poses[trajs.traj_offsets[traj] + tgt]
    ov = mutual_overlap(world, src_pose, tgt_pose, CameraConfig(), cfg.overlap_rays) \
        if len(src_pose) else np.zeros((0, 2))
    idx = np.flatnonzero((ov > cfg.min_overlap).all(axis=1))
    wp, valid = expert_waypoint_labels(world, src_pose[idx], tgt_pose[idx, :2],
                                       cfg.lookahead_m, cfg.target_snap_m)
    idx, wp = idx[valid], wp[valid]
    state = np.column_stack([src_pose[idx], np.asarray(speed_steer, np.float64)[idx]])
    if not controls:
        return {"traj": traj[idx], "src": src[idx], "tgt": tgt[idx], "src_pose": src_pose[idx],
                "src_speed_steer": state[:, 3:5], "distance": np.asarray(distance)[idx],
                "waypoint": wp, "heading_diff": wrap_angle(tgt_pose[idx, 2] - src_pose[idx, 2]),
                "overlap": ov[idx], "control": np.zeros((len(idx), 2))}
    # direct-control label: the RMP toward the label waypoint at the source state
    ranges = lidar.scan(src_pose[idx])
    c, s = np.cos(state[:, 2]), np.sin(state[:, 2])
    wp_world = state[:, :2] + np.column_stack([c * wp[:, 0] - s * wp[:, 1],
                                               s * wp[:, 0] + c * wp[:, 1]])
    u = controls_toward(state, wp_world, ranges, lidar.config,
                        RmpConfig(), VehicleConfig()) if len(idx) else np.zeros((0, 2))
    return {"traj": traj[idx], "src": src[idx], "tgt": tgt[idx], "src_pose": src_pose[idx],
            "src_speed_steer": state[:, 3:5], "distance": np.asarray(distance)[idx],
            "waypoint": wp, "heading_diff": wrap_angle(tgt_pose[idx, 2] - src_pose[idx, 2]),
            "overlap": ov[idx], "control": u}


def _world_samples(world, trajs: TrajectorySet, traj_ids: np.ndarray, n: int,
                   rng: np.random.Generator, cfg: SampleConfig, controls: bool = True) -> dict:
    """Up to ``n`` samples from the trajectories ``traj_ids`` of one world."""
    lidar = Lidar(world, LidarConfig())
    lengths = np.array([trajs.rows(t).stop - trajs.rows(t).start for t in traj_ids])
    arcs = [_arclength(trajs.poses[trajs.rows(t)]) for t in traj_ids]
    out: dict[str, list] = {name: [] for name in _SAMPLE_FIELDS}
    have = 0
    rounds = 0
    while have < n:
        rounds += 1
        if rounds > 50:
            break
        m = int(1.5 * (n - have)) + 32
        # source frames uniform over all frames of the world's trajectories
        pick = rng.choice(len(traj_ids), size=m, p=lengths / lengths.sum())
        src = (rng.random(m) * lengths[pick]).astype(np.int64)
        dist = rng.uniform(cfg.distance_min_m, cfg.distance_max_m, m)
        lat, dth = draw_jitter(rng, m, cfg)
        tgt = np.empty(m, np.int64)
        ok = np.ones(m, bool)
        for q in range(m):
            a = arcs[pick[q]]
            s = a[src[q]] + dist[q]
            if s < 0.0 or s > a[-1]:
                ok[q] = False
                continue
            j = int(np.searchsorted(a, s))
            if j > 0 and (j == len(a) or s - a[j - 1] < a[j] - s):
                j -= 1
            tgt[q] = min(j, len(a) - 1)
        rows0 = trajs.traj_offsets[traj_ids[pick]]
        base = trajs.poses[rows0 + src]
        src_pose, free = apply_jitter(world, base, lat, dth)
        ok &= free
        idx = np.flatnonzero(ok)
        got = label_samples(world, trajs, traj_ids[pick[idx]], src[idx], tgt[idx], src_pose[idx],
                            trajs.states[rows0[idx] + src[idx], 3:5], dist[idx], cfg, lidar,
                            controls)
        take = min(len(got["traj"]), n - have)
        if take == 0:
            continue
        for name in _SAMPLE_FIELDS:
            out[name].append(got[name][:take])
        have += take
    return {k: np.concatenate(v) if v else np.zeros(_SHAPES.get(k, (0,))) for k, v in out.items()}


_DTYPES = {"traj": np.int32, "src": np.int32, "tgt": np.int32, "src_pose": np.float64,
           "src_speed_steer": np.float32, "distance": np.float32, "waypoint": np.float32,
           "heading_diff": np.float32, "overlap": np.float32, "control": np.float32}
_SHAPES = {"src_pose": (0, 3), "src_speed_steer": (0, 2), "waypoint": (0, 2),
           "overlap": (0, 2), "control": (0, 2)}


def make_samples(trajs: TrajectorySet, n: int, seed: int = 0,
                 config: SampleConfig | None = None, progress: bool = False) -> SampleSet:
    """``n`` samples spread evenly over the worlds of ``trajs`` (deterministic
    in ``seed``). Worlds are loaded with :func:`topodrake.world.load_world`."""
    from tqdm import tqdm


    cfg = config or SampleConfig()
    worlds = trajs.worlds
    per = np.full(len(worlds), n // len(worlds))
    per[:n % len(worlds)] += 1
    seeds = trial_seeds(seed, len(worlds))
    parts = []
    bar = tqdm(total=n, desc="samples", unit="sample", disable=not progress)
    for w, name in enumerate(worlds):
        ids = np.flatnonzero(trajs.traj_world == w)
        if per[w] == 0:
            continue
        if len(ids) == 0:
            raise TopodrakeError(f"no trajectories of world {name!r} to draw samples from")
        part = _world_samples(load_world(name), trajs, ids, int(per[w]),
                              np.random.default_rng(seeds[w]), cfg)
        if len(part["traj"]) < per[w]:
            raise TopodrakeError(f"world {name!r}: only {len(part['traj'])} of {per[w]} samples "
                                 "satisfy the constraints; are its trajectories too short?")
        parts.append(part)
        bar.update(int(per[w]))
    bar.close()
    fields = {}
    for name in _SAMPLE_FIELDS:
        arrs = [p[name] for p in parts] or [np.zeros(_SHAPES.get(name, (0,)))]
        fields[name] = np.concatenate(arrs).astype(_DTYPES[name])
    meta = {"seed": int(seed), "config": asdict(cfg), "count": int(n)}
    return SampleSet(trajs, meta=meta, **fields)
