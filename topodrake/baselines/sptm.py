"""The SPTM baseline's map and planner (Savinov et al., "Semi-parametric topological memory").

Our planner is compared against SPTM as the paper re-implemented it: a
graph of every ``subsampling``-th frame, temporal edges, shortcut edges
from an image retrieval network, top-1 localization of the start and the
goal, an unweighted shortest path, and *our* follower. It is a baseline:
nothing here improves on SPTM. The choices, where SPTM or the paper leave
room, are:

- **Vertices**: frames 0, n, 2n, ... of every drive (n = ``subsampling`` =
  20, the paper's ratio); the last frame is not added (SPTM keeps
  ``frames[::n]``). Vertices are numbered drive after drive.
- **Temporal edges**: consecutive vertices of one drive, both directions
  (the graph is undirected, as SPTM's ``nx.Graph``). Drives are not chained
  to one another (SPTM has one exploration episode; we have many drives).
- **Shortcut edges**: for vertices i < j, the quality is the median of the
  retrieval scores s(frame_i + d, frame_j + d) over the aligned shifts
  d = -W..W (W = ``shortcut_window`` = 10) for which both shifted frames
  exist in their drives (SPTM's bounds check; an even count takes the mean
  of the middle two, as numpy's median). SPTM's window counts memory nodes
  of its 4x-subsampled memory; with 20x subsampling, +-10 vertices would
  span +-10 m of driving, so the window counts raw frames around each vertex.
  Pairs of vertices of one drive fewer than ``min_shortcut_gap`` (5)
  vertices apart are no candidates (SPTM's MIN_SHORTCUT_DISTANCE counts
  memory nodes too); vertices of different drives always are. A candidate
  becomes a shortcut when its quality exceeds ``shortcut_threshold`` (0.99,
  the paper's s_shortcut; compared in float32, the network's precision),
  and only the ``max_shortcuts`` (2,000, SPTM's SMALL_SHORTCUTS_NUMBER)
  best are kept (ties: the lower (i, j) first).
  The retrieval score is symmetric (:mod:`topodrake.baselines.retrieval_net`),
  as SPTM's averaged matrix is.
- **Localization**: top-1, the vertex whose own frame scores highest with
  the observation (ties: the lowest index), for the start and the goal
  alike; no threshold (the paper's "explicit localization", the planning
  failure mode it names). SPTM's own median-of-top-5-above-0.95 rule and
  its 1-7 step waypoint choice belong to its follower, which we replace.
- **Planning**: ``networkx.shortest_path`` without weights (hop count) from
  the start's vertex to the goal's; a missing path is a
  :class:`~topodrake.topomap.plan.PlanResult` with a reason, never an
  exception. SPTM has no probabilities: the result's and the route's
  probability is nan and every hop's probability 1.
- **Route**: the path's vertices, each with its (2k+1)-frame camera context
  from its own drive (k = 5, every 3rd frame, clamped: the camera k5
  controller's), then the goal observation repeated as the last anchor's
  context; the same follower drives it as any planned route.

Poses are metadata: building and planning read only observations and the
retrieval network; poses ride along for plots and evaluation.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import networkx as nx
import numpy as np
import torch

from topodrake.contract.frames import context_frames
from topodrake.contract.route import Route
from topodrake.demonstrations import load_demos
from topodrake.errors import TopodrakeError
from topodrake.sensing.observe import observe
from topodrake.topomap.plan import PlanResult
from topodrake.vehicle import VehicleConfig, in_collision
from topodrake.world import load_world


@dataclass
class SptmConfig:
    subsampling: int = 20            # every n-th frame of a drive is a vertex
    shortcut_window: int = 10        # +- frames of the aligned median
    min_shortcut_gap: int = 5        # vertices of one drive at least this many vertices apart
    shortcut_threshold: float = 0.99
    max_shortcuts: int = 2000
    k: int = 5                       # route contexts: 2k + 1 frames ...
    frame_step: int = 3              # ... every this-th frame of the vertex's drive

    def validate(self) -> "SptmConfig":
        if min(self.subsampling, self.min_shortcut_gap, self.frame_step) < 1:
            raise TopodrakeError("SPTM: subsampling, min_shortcut_gap and frame_step must be >= 1")
        if min(self.shortcut_window, self.max_shortcuts, self.k) < 0:
            raise TopodrakeError("SPTM: shortcut_window, max_shortcuts and k must be >= 0")
        return self


@dataclass
class SptmMap:
    """SPTM's graph over the vertices of several drives.

    ``observations[d]`` (T_d, H, W, 3) and ``poses[d]`` (T_d, 3) are drive
    d's frames (held by reference, for route contexts; poses are metadata);
    vertex v is frame ``vertex_frame[v]`` of drive ``vertex_drive[v]``;
    ``shortcuts`` (S, 3) rows are (i, j, quality), best first; ``candidates``
    (C, 3) every pair above the threshold, of which ``shortcuts`` are the
    first ``max_shortcuts``."""

    names: list[str]
    observations: list[np.ndarray]
    poses: list[np.ndarray]
    vertex_drive: np.ndarray
    vertex_frame: np.ndarray
    vertex_features: torch.Tensor
    graph: nx.Graph
    shortcuts: np.ndarray
    config: SptmConfig
    candidates: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    build_time_s: float = 0.0
    net: object = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.vertex_drive)

    def vertex_poses(self, vertices=None) -> np.ndarray:
        v = np.arange(len(self)) if vertices is None else np.asarray(vertices, np.int64)
        return np.array([self.poses[d][f] for d, f in zip(self.vertex_drive[v],
                                                          self.vertex_frame[v])]).reshape(-1, 3)

    def context(self, v: int) -> np.ndarray:
        """Vertex v's (2k+1)-frame context from its own drive, clamped."""
        d, f = int(self.vertex_drive[v]), int(self.vertex_frame[v])
        obs = self.observations[d]
        return obs[context_frames(len(obs), f, self.config.k, self.config.frame_step)]

    def summary(self) -> dict:
        temporal = sum(1 for _, _, k in self.graph.edges(data="kind") if k == "temporal")
        return {"drives": len(self.observations), "frames": int(sum(len(o) for o in self.observations)),
                "vertices": len(self), "edges": self.graph.number_of_edges(),
                "directed_edges": 2 * self.graph.number_of_edges(), "temporal_edges": temporal,
                "shortcuts": int(len(self.shortcuts)),
                "candidates_above_threshold": int(len(self.candidates)),
                "build_time_s": round(self.build_time_s, 1)}


def subsample(n_frames: int, every: int) -> np.ndarray:
    """SPTM's vertex frames of one drive: 0, every, 2 every, ... < n_frames."""
    return np.arange(0, n_frames, every, dtype=np.int64)


def window_quality(score, frames_i: np.ndarray, len_i: np.ndarray, frames_j: np.ndarray,
                   len_j: np.ndarray, window: int) -> np.ndarray:
    """Median over the aligned shifts d = -window..window (both frames inside
    their drives) of ``score(fi, fj)``, for pairs of vertex frames.

    ``frames_*``/``len_*`` (P,): each vertex's frame and its drive's length;
    ``score(a_shift_rows, b_shift_rows)`` scores index pairs given as
    (P, 2W+1) arrays of (pair, shift) and returns (M,) for the valid ones."""
    shifts = np.arange(-window, window + 1)
    a = frames_i[:, None] + shifts
    b = frames_j[:, None] + shifts
    valid = (a >= 0) & (a < len_i[:, None]) & (b >= 0) & (b < len_j[:, None])
    values = np.full(a.shape, np.nan, np.float64)
    values[valid] = score(valid)
    return np.nanmedian(values, axis=1)


def shortcut_candidates(features: torch.Tensor, frame_offset: np.ndarray, vertex_drive: np.ndarray,
                        vertex_frame: np.ndarray, drive_len: np.ndarray, net,
                        cfg: SptmConfig, progress: bool = False) -> np.ndarray:
    """(C, 3) rows (i, j, quality) of every candidate pair i < j whose
    window quality exceeds the threshold, best first (ties: lower (i, j)).

    ``features`` (N, F): every frame of every drive, drive d's frames at rows
    ``frame_offset[d] + t``."""
    V = len(vertex_drive)
    vidx = np.arange(V)
    out = []
    rows = range(V - 1)
    if progress:
        from tqdm import tqdm
        rows = tqdm(rows, desc="SPTM shortcuts", unit="vertex", mininterval=2.0)
    for i in rows:
        j = vidx[i + 1:]
        same = vertex_drive[j] == vertex_drive[i]
        j = j[~same | (j - i >= cfg.min_shortcut_gap)]
        if not len(j):
            continue
        di, dj = vertex_drive[i], vertex_drive[j]
        fi = np.full(len(j), vertex_frame[i])
        fj = vertex_frame[j]
        shifts = np.arange(-cfg.shortcut_window, cfg.shortcut_window + 1)

        def score(valid, fi=fi, fj=fj, di=di, dj=dj):
            pair, s = np.nonzero(valid)
            ra = frame_offset[di] + fi[pair] + shifts[s]
            rb = frame_offset[dj[pair]] + fj[pair] + shifts[s]
            return net.score_features(features[ra], features[rb])

        q = window_quality(score, fi, np.full(len(j), drive_len[di]), fj, drive_len[dj],
                           cfg.shortcut_window)
        keep = q.astype(np.float32) > np.float32(cfg.shortcut_threshold)
        if keep.any():
            out.append(np.column_stack([np.full(keep.sum(), i), j[keep], q[keep]]))
    if not out:
        return np.zeros((0, 3))
    c = np.concatenate(out)
    order = np.lexsort((c[:, 1], c[:, 0], -c[:, 2]))
    return c[order]


def build_sptm_graph(trajectories, net, config: SptmConfig | None = None,
                     progress: bool = False) -> SptmMap:
    """SPTM's graph of ``trajectories``, a list of (observations (T, H, W, 3)
    uint8, poses (T, 3), name) per drive, with the retrieval network ``net``
    (``encode(images) -> features``, ``score_features(fa, fb) -> scores``)."""
    cfg = (config or SptmConfig()).validate()
    t0 = time.time()
    if not trajectories:
        raise TopodrakeError("SPTM: no trajectories to build a graph from")
    names, observations, poses = [], [], []
    for obs, p, name in trajectories:
        obs, p = np.asarray(obs), np.asarray(p, np.float64).reshape(-1, 3)
        if len(obs) != len(p) or len(obs) == 0:
            raise TopodrakeError(f"SPTM: drive {name!r} has {len(obs)} observations for "
                                 f"{len(p)} poses")
        names.append(str(name))
        observations.append(obs)
        poses.append(p)
    drive_len = np.array([len(o) for o in observations], np.int64)
    frame_offset = np.concatenate([[0], np.cumsum(drive_len)[:-1]])
    features = torch.cat([net.encode(o) for o in observations])
    vertex_drive, vertex_frame = [], []
    for d, n in enumerate(drive_len):
        f = subsample(int(n), cfg.subsampling)
        vertex_drive.append(np.full(len(f), d))
        vertex_frame.append(f)
    vertex_drive = np.concatenate(vertex_drive).astype(np.int64)
    vertex_frame = np.concatenate(vertex_frame).astype(np.int64)
    g = nx.Graph()
    g.add_nodes_from(range(len(vertex_drive)))
    for v in range(len(vertex_drive) - 1):
        if vertex_drive[v] == vertex_drive[v + 1]:
            g.add_edge(v, v + 1, kind="temporal")
    cands = shortcut_candidates(features, frame_offset, vertex_drive, vertex_frame, drive_len, net,
                                cfg, progress)
    kept = cands[:cfg.max_shortcuts]
    for i, j, q in kept:
        if not g.has_edge(int(i), int(j)):
            g.add_edge(int(i), int(j), kind="shortcut", quality=float(q))
    vfeat = features[frame_offset[vertex_drive] + vertex_frame]
    return SptmMap(names, observations, poses, vertex_drive, vertex_frame, vfeat, g, kept, cfg,
                   candidates=cands, build_time_s=time.time() - t0, net=net)


def localize(sptm_map: SptmMap, observation: np.ndarray, net=None) -> tuple[int, float]:
    """Top-1 localization: (the vertex whose frame scores highest with the
    observation, its score); ties go to the lowest vertex index."""
    net = net or sptm_map.net
    if len(sptm_map) == 0:
        raise TopodrakeError("the SPTM graph has no vertices")
    obs = np.asarray(observation)
    want = sptm_map.observations[0].shape[1:]
    if obs.shape != want:
        raise TopodrakeError(f"the observation has shape {obs.shape}; this SPTM graph needs {want}")
    f = net.encode(obs[None])
    s = net.score_features(f.expand(len(sptm_map), -1), sptm_map.vertex_features)
    v = int(np.argmax(s))
    return v, float(s[v])


def plan_sptm(sptm_map: SptmMap, start_observation: np.ndarray, goal_observation: np.ndarray,
              start_pose=None, goal_pose=None, net=None) -> PlanResult:
    """SPTM's plan: localize the start and the goal (top-1), then the
    shortest path in hops; the route ends with the goal observation repeated
    as its context. ``start_pose``/``goal_pose`` are metadata only."""
    m = sptm_map
    vs, _ = localize(m, start_observation, net)
    vg, _ = localize(m, goal_observation, net)
    nan = float("nan")
    try:
        path = [int(v) for v in nx.shortest_path(m.graph, vs, vg)]
    except nx.NetworkXNoPath:
        return PlanResult(False, probability=nan, start_links=1, goal_links=1,
                          reason=f"no path of the SPTM graph joins the start's vertex {vs} to "
                                 f"the goal's vertex {vg}")
    frames = 2 * m.config.k + 1
    goal = np.asarray(goal_observation)
    contexts = np.concatenate([np.stack([m.context(v) for v in path]),
                               np.repeat(goal[None, None], frames, 1)])
    gp = np.full(3, nan) if goal_pose is None else np.asarray(goal_pose, np.float64)
    route = Route(contexts=contexts, poses=np.vstack([m.vertex_poses(path), gp[None]]),
                  vertices=np.array(path + [-1], np.int64), edge_probability=np.ones(len(path)),
                  probability=nan, modality="camera")
    return PlanResult(True, probability=nan, vertices=path, route=route, start_links=1,
                      goal_links=1)


def jittered_start(world, pose: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The planning protocol's start: ``pose`` moved 0.3 m to a random side
    and turned 9 deg to a random side (the other side, or no jitter, when
    that puts the car into a wall)."""
    side, turn = rng.choice([-1.0, 1.0], size=2)
    for sd, tn in ((side, turn), (-side, turn), (0.0, 0.0)):
        q = np.array(pose, np.float64)
        q[0] -= 0.3 * sd * np.sin(pose[2])
        q[1] += 0.3 * sd * np.cos(pose[2])
        q[2] += np.radians(9.0) * tn
        if not in_collision(np.array([[*q, 0.0, 0.0]]), world.grid.clearance_at, VehicleConfig())[0]:
            return q
    return np.array(pose, np.float64)


def place_pairs_study(world_name: str, demo_folder, net, config: SptmConfig | None = None,
                      near_m: float = 1.0, seed: int = 0, progress: bool = True) -> dict:
    """Build SPTM's graph from every drive of ``demo_folder`` in house
    ``world_name`` and plan between all ordered pairs of its places: the
    goal is the camera image at the goal place's pose, the start the image
    at the start place's pose, exact or jittered (:func:`jittered_start`,
    seeded). Reports graph size, shortcut count, build time, the share of
    pairs with a plan (a path joins the top-1 localized vertices), and how
    often the localized start and goal vertices lie within ``near_m`` of the
    true poses (metadata, used only here)."""
    world = load_world(world_name)
    _, drives = load_demos(demo_folder)
    t0 = time.time()
    trajectories = [(observe(world, "camera", d.poses, net.sensor), d.poses, f"drive-{i}")
                    for i, d in enumerate(drives)]
    render_s = time.time() - t0
    m = build_sptm_graph(trajectories, net, config, progress)
    places = np.asarray(world.places, np.float64)
    pairs = [(i, j) for i in range(len(places)) for j in range(len(places)) if i != j]
    rng = np.random.default_rng(seed)
    jittered = np.array([jittered_start(world, places[i], rng) for i, _ in pairs])
    place_obs = observe(world, "camera", places, net.sensor)
    jit_obs = observe(world, "camera", jittered, net.sensor)

    def error(v, pose):
        return float(np.hypot(*(m.vertex_poses([v])[0, :2] - pose[:2])))

    place_loc = [localize(m, o, net) for o in place_obs]
    place_err = [error(v, p) for (v, _), p in zip(place_loc, places)]
    out = {}
    for label, starts, start_obs in (("exact_start", places[[i for i, _ in pairs]],
                                      place_obs[[i for i, _ in pairs]]),
                                     ("jittered_start", jittered, jit_obs)):
        found, hops, s_near, g_near = 0, [], 0, 0
        for (i, j), sp, so in zip(pairs, starts, start_obs):
            vs, _ = localize(m, so, net)
            s_near += error(vs, sp) <= near_m
            g_near += place_err[j] <= near_m
            r = plan_sptm(m, so, place_obs[j], sp, places[j], net)
            if r.reachable:
                found += 1
                hops.append(len(r.vertices) - 1)
        n = len(pairs)
        out[label] = {"plans_found": found, "plan_found_share": round(found / n, 4),
                      "start_within_share": round(s_near / n, 4),
                      "goal_within_share": round(g_near / n, 4),
                      "mean_hops": round(float(np.mean(hops)), 2) if hops else None}
    comps = sorted((len(c) for c in nx.connected_components(m.graph)), reverse=True)

    def true_length(rows):
        ij = rows[:, :2].astype(np.int64)
        length = np.hypot(*(m.vertex_poses(ij[:, 0])[:, :2] - m.vertex_poses(ij[:, 1])[:, :2]).T)
        return ({"median": round(float(np.median(length)), 3),
                 "share_over_0.1m": round(float((length > 0.1).mean()), 4),
                 "share_over_1m": round(float((length > 1.0).mean()), 4),
                 "share_over_3m": round(float((length > 3.0).mean()), 4)} if len(length) else {})
    return {"world": world_name, "demo_folder": str(demo_folder), "place_pairs": len(pairs),
            "near_m": near_m, "seed": seed, "render_time_s": round(render_s, 1),
            "graph": m.summary(), "components": len(comps), "largest_components": comps[:5],
            "shortcut_true_length_m": true_length(m.shortcuts),
            "candidate_true_length_m": true_length(m.candidates),
            **out,
            "place_localization_error_m": [round(e, 3) for e in place_err],
            "place_localization_score": [round(s, 4) for _, s in place_loc]}
