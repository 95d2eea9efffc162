"""Grow a map one drive at a time (the paper's "Building a Topological Map").

:func:`add_trajectory` adds a drive from its observations (and, for a camera
drive, the lidar scans taken with them), with the settings of the map's
:class:`~topodrake.topomap.graph.MapConfig`:

1. **Sparsify** it into anchors (``sparsify``;
   :func:`topodrake.learning.reachability.sparsify.sparsify_chain`).
2. **Reuse**: an existing vertex v stands in for an anchor (``reuse``).
   Rule "resume": at anchor frame j, where RE(source, v) and
   RE(v, frame j + 1) both exceed ``reuse.p`` (source: where the scan
   stands, a frame or a reused vertex), and the scan resumes from v; rule
   "paper": after sparsifying, v replaces anchor i where RE(prev, v) and
   RE(v, next anchor) exceed it. The largest product wins; vertices of one
   older drive keep that drive's order, and no vertex appears twice in a
   chain. Where the map checks joins by scans
   (:func:`~topodrake.topomap.scan_match.joins_by_scans`) v's scan must
   also match the frame's; see :func:`_resume_chain` for the other checks.
3. **Trajectory edges** between consecutive chain nodes (p = RE), with the
   drive's odometry as legs (``teach_odometry``).
4. **Cross edges** between each new vertex x and its ``retrieval_k``
   nearest vertices in the place embedding, both ways, where the single
   pair's RE and the minimum RE over the aligned chain neighbours
   (``cross.sequence_window`` either side) exceed ``cross.p``; the edge
   keeps the single pair's RE, and with ``cross.legs`` the pose the two
   scans register to (:func:`join_legs`).
5. **Junction edges**: every other drive's last vertex -> the new drive's
   first and its last -> every other drive's first, where RE exceeds
   ``junction.p`` both ways (on a lidar map the scans must also match, to
   ``junction.scan_match``); the edge keeps RE(arrival, departure) and,
   where the map places joins by scans, the registered pose.

With ``audit=True`` step 4 also scores every vertex of the map and records
which cross edges the exhaustive pass makes (:attr:`BuildStats.recall`).
"""

from __future__ import annotations

from dataclasses import dataclass

import networkx as nx
import numpy as np

from topodrake.contract.frames import context_frames
from topodrake.contract.route import LEG_POINTS, teach_legs
from topodrake.errors import TopodrakeError
from topodrake.learning.reachability.sparsify import hop_caps, sparsify, sparsify_chain
from topodrake.odometry import OdometryConfig, odometry_along
from topodrake.registration.icp import IcpConfig, register
from topodrake.se2 import compose, invert, relative
from topodrake.topomap.graph import TopoMap, Trajectory
from topodrake.topomap.scan_match import checks_scans, joins_by_scans, scans_match, vertex_scans


@dataclass
class BuildStats:
    """What adding trajectories did (cumulative when reused)."""

    trajectories: int = 0
    frames: int = 0
    anchors: int = 0
    reused: int = 0
    new_vertices: int = 0
    cross_edges: int = 0
    junctions: int = 0            # junction edges between drives' ends
    re_pairs: int = 0
    exhaustive_edges: int = 0     # audit: cross edges the exhaustive pass makes
    found_edges: int = 0          # audit: ... of which the retrieval pass made too

    @property
    def recall(self) -> float | None:
        return self.found_edges / self.exhaustive_edges if self.exhaustive_edges else None


def context_rows(n_frames: int, frames: np.ndarray, k: int, step: int) -> np.ndarray:
    return context_frames(n_frames, np.asarray(frames, np.int64), k, step).reshape(-1, 2 * k + 1)


class _Scored:
    """Counts RE pairs while scoring bank rows."""

    def __init__(self, topomap: TopoMap, stats: BuildStats):
        self.bank = topomap.bank
        self.stats = stats

    def __call__(self, source, rows) -> np.ndarray:
        source = np.asarray(source, np.int64).reshape(-1)
        self.stats.re_pairs += len(source)
        return self.bank.score(source, rows)


def add_trajectory(topomap: TopoMap, observations: np.ndarray, poses: np.ndarray | None = None,
                   name: str = "", stats: BuildStats | None = None,
                   audit: bool = False, scans: np.ndarray | None = None) -> BuildStats:
    """Add one drive (its observations (T, ...) in time order; ``poses``
    (T, 3) ride along as metadata, and the odometry the drive recorded,
    simulated from them as :attr:`MapConfig.teach_odometry` says, goes on its
    trajectory edges) to ``topomap``. ``scans`` (T, beams): the lidar scans a
    camera drive took with its frames, which the map keeps for the route
    tracker."""
    m, cfg = topomap, topomap.config
    stats = stats or BuildStats()
    obs = np.asarray(observations)
    n = len(obs)
    if n < 1:
        raise TopodrakeError(f"trajectory {name!r} has no frames")
    score = _Scored(m, stats)
    k, step = m.k, m.frame_step
    start = len(m.bank)
    t = len(m.trajectories)
    odo = drive_odometry(cfg.teach_odometry, poses, t)
    along = odo if odo is not None else poses      # where the drive went, by its odometry
    caps = hop_caps(along, cfg.sparsify.max_hop_m) if along is not None and m.modality == "lidar" \
        else None                                  # (a lidar-only setting: LIDAR_ONLY)
    rows = m.bank.append(obs, poses, scans=scans)
    m.bank.ensure(rows)
    ctx_local = context_rows(n, np.arange(n), k, step)
    if cfg.reuse.enabled and cfg.reuse.rule == "resume":
        anchors, chain = _resume_chain(m, obs, start, ctx_local, score, stats, odo, caps)
        emb = m.embedding.embed(obs[anchors])
    else:
        anchors = sparsify(n, lambda i, js: score(np.full(len(js), start + i), start + ctx_local[js]),
                           cfg.sparsify.p, cfg.sparsify.window, slack=cfg.sparsify.slack,
                           cap=caps)
        emb = m.embedding.embed(obs[anchors])
        chain = _paper_chain(m, anchors, emb, start, ctx_local, score, stats)

    # -- keep the frames the new vertices need, create them
    new_idx = [node[1] for node in chain if node[0] == "a"]
    keep = np.unique(start + ctx_local[anchors[new_idx]]) if new_idx else np.zeros(0, np.int64)
    remap = m.bank.keep_tail(start, keep)
    traj = Trajectory(name or f"trajectory-{t}", n)
    m.trajectories.append(traj)
    ids: list[int] = []
    new_vertices: list[int] = []
    for pos, node in enumerate(chain):
        if node[0] == "v":
            ids.append(node[1])
            continue
        a = int(anchors[node[1]])
        v = m.add_vertex(t, a, pos, remap[a], remap[ctx_local[a]])
        ids.append(v)
        new_vertices.append(v)
    traj.chain = ids
    m.raw_frames += n
    stats.trajectories += 1
    stats.frames += n
    stats.anchors += len(anchors)
    stats.new_vertices += len(new_vertices)

    # -- trajectory edges between consecutive chain nodes, with the drive's odometry
    pairs = [(i, u, v) for i, (u, v) in enumerate(zip(ids[:-1], ids[1:])) if u != v]
    if pairs:
        offsets = _reuse_offsets(m, obs if m.modality == "lidar" else scans, chain, anchors) \
            if cfg.reuse.legs and cfg.teach_odometry != "none" else {}
        legs = _teach_legs(odo, chain, anchors, [i for i, _, _ in pairs], offsets)
        _, us, vs = np.array(pairs).T
        for u, v, p, (leg, path) in zip(us, vs, score(m.centers(us), m.contexts(vs)), legs):
            m.add_edge(int(u), int(v), float(p), "trajectory", leg, path)

    if new_vertices:
        new_pos = [ids.index(v) for v in new_vertices]
        queries = emb[[chain[p][1] for p in new_pos]]
        m.index.add(np.array(new_vertices), queries)
        _cross_edges(m, new_vertices, ids, new_pos, queries, score, stats, audit)
    if cfg.junction.enabled:
        _junctions(m, t, score, stats)
    return stats


def _junctions(m: TopoMap, t: int, score, stats: BuildStats) -> None:
    """Junction edges between drive ``t``'s ends and the other drives':
    every other drive's last vertex -> ``t``'s first, and ``t``'s last ->
    every other drive's first, where RE passes ``junction.p`` both ways."""
    chain = m.trajectories[t].chain
    others = [o.chain for i, o in enumerate(m.trajectories) if i != t and o.chain]
    pairs = {(o[-1], chain[0]) for o in others} | {(chain[-1], o[0]) for o in others}
    pairs = sorted((u, x) for u, x in pairs if u != x and not m.graph.has_edge(u, x))
    if not pairs:
        return
    us, xs = np.array(pairs, np.int64).T
    ahead = score(m.centers(us), m.contexts(xs))
    back = score(m.centers(xs), m.contexts(us))
    keep = np.flatnonzero(np.minimum(ahead, back) > m.config.junction.p)
    if len(keep) and checks_scans(m):
        keep = keep[scans_match(vertex_scans(m, xs[keep]), vertex_scans(m, us[keep]),
                                m.config.junction.scan_match)]
    legs = _junction_legs(m, us[keep], xs[keep])
    for i, (leg, path) in zip(keep, legs):
        m.add_edge(int(us[i]), int(xs[i]), float(ahead[i]), "junction", leg, path)
    stats.junctions += len(keep)


def _junction_legs(m: TopoMap, us: np.ndarray, xs: np.ndarray) -> list:
    """(leg, leg path) of each junction u -> x: on a lidar map (or a camera
    map that places its joins by its kept scans, :func:`places_by_scans`),
    x's pose in u's frame from registering x's scan onto u's (kept when the
    fit pins the translation; the path a straight line), else (None, None)."""
    if not joins_carry_legs(m) or not len(us):
        return [(None, None)] * len(us)
    return join_legs(vertex_scans(m, xs), vertex_scans(m, us), wide=False)


def drive_odometry(kind: str, poses, seed: int) -> np.ndarray | None:
    """The odometry a drive recorded (T, 3) as :attr:`MapConfig.teach_odometry`
    says (``kind``; wheel odometry's errors drawn from ``seed``), simulated
    from its ``poses``; None for "none" or where the poses are unknown."""
    if kind == "none" or poses is None or not np.all(np.isfinite(poses)):
        return None
    poses = np.asarray(poses, np.float64)
    return poses if kind == "perfect" else odometry_along(poses, OdometryConfig.wheel(), seed)


def _teach_legs(odo, chain, anchors, positions, offsets: dict | None = None) -> list:
    """(leg, leg path) of the hop from chain node ``i`` to ``i + 1`` for each
    ``i`` in ``positions``: the drive's odometry ``odo`` (:func:`drive_odometry`)
    between its frames at the two nodes; a reused vertex at node ``j`` needs
    its pose in the drive's frame there (``offsets[j]``, from
    :func:`_reuse_offsets`), else (None, None)."""
    offsets = offsets or {}
    if odo is None:
        return [(None, None)] * len(positions)
    legs, paths = teach_legs(odo, anchors)          # between the drive's frames at the nodes
    out = []
    for i in positions:
        ends = [np.zeros(3) if chain[j][0] == "a" else offsets.get(j) for j in (i, i + 1)]
        if any(e is None for e in ends):
            out.append((None, None))
            continue
        into_u = invert(ends[0][None])
        path = compose(np.repeat(into_u, len(paths[i]), 0), paths[i])
        leg = compose(compose(into_u, legs[i:i + 1]), ends[1][None])[0]
        path[-1] = leg
        out.append((leg, path))
    return out


def places_by_scans(m: TopoMap) -> bool:
    """Whether ``m`` places a reused vertex and a junction's far end by
    registering scans: a lidar map, or a camera map that keeps its drives'
    scans, with ``camera.legs``."""
    return m.modality == "lidar" or (m.modality == "camera" and m.config.camera.legs
                                     and m.bank.scans is not None)


def joins_carry_legs(m: TopoMap) -> bool:
    """Whether ``m``'s joins (junctions, cross edges, the goal link) can
    carry legs: it places them by scans and keeps the drives' odometry
    (a map without odometry has a leg on no hop)."""
    return places_by_scans(m) and m.config.teach_odometry != "none"


def _reuse_offsets(m: TopoMap, scans, chain, anchors) -> dict:
    """Each reused vertex's pose in the drive's frame where it stood in
    (chain position -> (3,)) on a map that places them by scans
    (:func:`places_by_scans`): the vertex's scan registered onto the drive's
    (``scans``, (T, beams)) there, kept when the fit pins the translation;
    none for other maps."""
    if not places_by_scans(m) or scans is None:
        return {}
    pos = [i for i, node in enumerate(chain) if node[0] == "v"]
    source = vertex_scans(m, [chain[i][1] for i in pos]) if pos else None
    poses = _pinned_poses(source, np.asarray(scans)[anchors[pos]]) if pos else []
    return {i: pose for i, pose in zip(pos, poses) if pose is not None}


def _pinned_poses(source, target, config=None, share: float = 0.0) -> list:
    """Each lidar scan of ``source`` registered onto the scan of ``target``
    beside it (from the identity; ``config``: the ICP settings, default
    :class:`~topodrake.registration.icp.IcpConfig`): its pose in that
    scan's frame (3,), or None where the fit is rejected, pairs less than
    ``share`` of either scan's points, or does not pin the translation (a
    corridor slides)."""
    if not len(source):
        return []
    res = register(np.asarray(source, np.float64), np.asarray(target, np.float64), None, config)
    good = res.accepted & (res.constraint >= REUSE_PINNED) \
        & (np.minimum(res.inlier, res.inlier_back) >= share)
    return [pose if ok else None for pose, ok in zip(res.pose, good)]


#: a reused vertex's registration must pin the translation this well (corridors slide)
REUSE_PINNED = 0.05


def join_icp():
    """ICP settings that place the two ends of a join (a cross edge, the goal
    link) from the identity: the ends lie up to a few metres and half a
    right angle apart, farther than a reuse's."""
    return IcpConfig(gate_m=1.0, max_shift_m=2.5, max_turn_rad=0.8)


#: a join's fit must pair this share of both scans' points (the wider search of
#: :func:`join_icp` fits rooms metres apart that share a wall or two at 0.6-0.7)
JOIN_SHARE = 0.7


def join_legs(source_scans, target_scans, wide: bool = True) -> list:
    """(leg, leg path) of each join target -> source where registering the
    source's scan onto the target's pins it (:func:`_pinned_poses`; with
    ``wide`` the search of :func:`join_icp` held to :data:`JOIN_SHARE`, else
    a reuse's; the path a straight line), else (None, None)."""
    line = np.linspace(0.0, 1.0, LEG_POINTS)[:, None]
    poses = _pinned_poses(source_scans, target_scans, join_icp() if wide else None,
                          JOIN_SHARE if wide else 0.0)
    return [(None, None) if leg is None else (leg, line * leg[None]) for leg in poses]


def _paper_chain(m: TopoMap, anchors: np.ndarray, emb: np.ndarray, start: int,
                 ctx_local: np.ndarray, score, stats: BuildStats) -> list[tuple[str, int]]:
    """The paper's reuse: after sparsifying, an existing vertex v replaces
    anchor i when RE(prev, v) and RE(v, anchor i + 1) both pass ``reuse.p``."""
    cfg = m.config
    # -- reuse: the chain as ("v", vertex) or ("a", anchor index) nodes
    def src(node) -> int:
        return m.graph.nodes[node[1]]["center"] if node[0] == "v" else start + anchors[node[1]]

    def ctx(node) -> np.ndarray:
        return m.graph.nodes[node[1]]["context"] if node[0] == "v" else start + ctx_local[anchors[node[1]]]

    chain: list[tuple[str, int]] = []
    used: set[int] = set()
    for i in range(len(anchors)):
        here = ("a", i)
        choice = here
        if cfg.reuse.enabled and len(m.index):
            prev = chain[-1] if chain else here
            nxt = ("a", i + 1) if i + 1 < len(anchors) else here
            after = prev[1] if prev[0] == "v" else None
            best = _stand_in(m, emb[i], used, after, src(prev), ctx(nxt), score, stats,
                             cfg.reuse.p)
            if best is not None:
                choice = ("v", best)
        chain.append(choice)
    return chain


def _resume_chain(m: TopoMap, obs: np.ndarray, start: int, ctx_local: np.ndarray, score,
                  stats: BuildStats, odo: np.ndarray | None = None, caps: np.ndarray | None = None
                  ) -> tuple[np.ndarray, list[tuple[str, int]]]:
    """The chain of a drive under the "resume" reuse rule: (anchor frames,
    chain nodes ("a", anchor index) or ("v", vertex)). At each anchor frame
    j an existing vertex v stands in for it when RE(source, v) and RE(v,
    frame j + 1) pass ``reuse.p`` (at the drive's end RE(v, frame j)), and
    the scan resumes from v. Where the map checks joins by scans, v's scan
    must match frame j's; with ``reuse.loop_check_m`` and the drive's
    odometry ``odo``, v must lie where that odometry puts it
    (:func:`loop_consistent`); with ``reuse.pinned`` a lidar map's v must
    register onto frame j's scan, pinning the translation. ``caps``: the
    farthest frame each anchor's hop may reach (``sparsify.max_hop_m``)."""
    cfg = m.config
    n = len(obs)
    used: set[int] = set()
    reused: list[tuple[int, int]] = []         # (frame, vertex) of the drive's reuses so far

    def row(source) -> int:
        return m.graph.nodes[source[1]]["center"] if isinstance(source, tuple) else start + source

    def frame_scan(j: int) -> np.ndarray:       # the lidar scan the drive took at frame j
        return obs[j] if m.modality == "lidar" else m.bank.scans[start + j]

    def reach(source, js):
        return score(np.full(len(js), row(source)), start + ctx_local[js])

    pin = (m.modality == "lidar" and cfg.reuse.pinned and cfg.reuse.legs
           and cfg.teach_odometry != "none")

    def snap(j: int, source):
        if not len(m.index):
            return j
        ahead = start + ctx_local[min(j + 1, n - 1)]
        after = source[1] if isinstance(source, tuple) else None
        checks = ([lambda v: _same_place(m, v, frame_scan(j))] if joins_by_scans(m) else []) \
            + ([lambda v: _pinned_poses(vertex_scans(m, [v]), frame_scan(j)[None])[0] is not None]
               if pin else [])
        if cfg.reuse.loop_check_m > 0 and odo is not None and reused:
            i_w, w = reused[-1]
            moved = relative(odo[i_w][None], odo[j][None])[0]
            checks.append(lambda v: loop_consistent(m, w, v, moved))
        best = _stand_in(m, m.embedding.embed(obs[j:j + 1])[0], used, after, row(source), ahead,
                         score, stats, cfg.reuse.p,
                         confirm=(lambda v: all(c(v) for c in checks)) if checks else None)
        if best is None:
            return j
        reused.append((j, best))
        return ("v", best)

    anchors, sources = sparsify_chain(n, reach, cfg.sparsify.p, cfg.sparsify.window,
                                      slack=cfg.sparsify.slack, snap=snap, cap=caps)
    chain = [src if isinstance(src, tuple) else ("a", i) for i, src in enumerate(sources)]
    return anchors, chain


def leg_of(m: TopoMap, u: int, x: int) -> np.ndarray | None:
    """x's pose in u's frame by the drives' odometry on the edge between them
    (either way round), or None where neither edge keeps a leg."""
    g = m.graph
    if g.has_edge(u, x) and "leg" in g.edges[u, x]:
        return g.edges[u, x]["leg"]
    if g.has_edge(x, u) and "leg" in g.edges[x, u]:
        return invert(g.edges[x, u]["leg"][None])[0]
    return None


def loop_consistent(m: TopoMap, w: int, v: int, moved: np.ndarray) -> bool:
    """Whether vertex v lies where a drive's odometry puts it: ``moved`` is
    the drive's motion since it stood at vertex w, and the map's legs,
    composed along the shortest path of edges that keep one from w to v,
    put v somewhere too. The two must agree within ``reuse.loop_check_m``
    metres plus ``reuse.loop_check_per_m`` of the metres both measured;
    where no such path joins them there is nothing to check."""
    cfg = m.config.reuse
    if w == v:
        return bool(np.hypot(*moved[:2]) <= cfg.loop_check_m)

    def metres(u, x, _):
        leg = leg_of(m, u, x)
        return None if leg is None else float(np.hypot(*leg[:2])) + 1e-6

    try:
        path = nx.bidirectional_dijkstra(m.graph.to_undirected(as_view=True), w, v,
                                         weight=metres)[1]
    except nx.NetworkXNoPath:
        return True
    pose, along = np.zeros((1, 3)), 0.0
    for u, x in zip(path[:-1], path[1:]):
        leg = leg_of(m, u, x)
        pose = compose(pose, leg[None])
        along += float(np.hypot(*leg[:2]))
    off = float(np.hypot(*(pose[0, :2] - moved[:2])))
    return off <= cfg.loop_check_m + cfg.loop_check_per_m * (along + float(np.hypot(*moved[:2])))


def _same_place(m: TopoMap, v: int, scan: np.ndarray) -> bool:
    """Whether vertex v's scan registers onto the drive's ``scan`` (a
    look-alike room passes RE, rarely the scan match)."""
    return bool(scans_match(vertex_scans(m, [v]), scan, m.config.scan_match)[0])


def _stand_in(m: TopoMap, query: np.ndarray, used: set[int], after: int | None, source_row: int,
              target_context: np.ndarray, score, stats: BuildStats, need: float,
              confirm=None) -> int | None:
    """The existing vertex v (among the ``retrieval_k`` nearest to ``query``,
    none of ``used``) with the largest RE(source, v) RE(v, target) where
    both pass ``need`` and ``confirm(v)`` holds (when given); None when none
    does. After a reused vertex ``after``, vertices of its drive must come
    later in it."""
    cfg = m.config
    cands = m.index.search(query, cfg.retrieval_k, exclude=np.fromiter(used, np.int64))[0]
    if after is not None:      # keep the order of a drive we reuse from
        u = m.graph.nodes[after]
        cands = np.array([v for v in cands if m.graph.nodes[v]["traj"] != u["traj"]
                          or m.graph.nodes[v]["pos"] > u["pos"]], np.int64)
    if not len(cands):
        return None
    s1 = score(np.full(len(cands), source_row), m.contexts(cands))
    ok = cands[s1 > need]
    if not len(ok):
        return None
    s2 = score(m.centers(ok), np.repeat(target_context[None], len(ok), 0))
    if not (s2 > need).any():
        return None
    prod = np.where(s2 > need, s1[s1 > need] * s2, -1.0)
    best = int(ok[np.argmax(prod)])
    if confirm is not None:
        order = [int(ok[i]) for i in np.argsort(-prod, kind="stable") if prod[i] > 0]
        best = next((v for v in order if confirm(v)), None)
        if best is None:
            return None
    used.add(best)
    stats.reused += 1
    return best


def _cross_edges(m: TopoMap, xs: list[int], chain: list[int], positions: list[int],
                 queries: np.ndarray, score, stats: BuildStats, audit: bool) -> None:
    """Cross edges between the new vertices ``xs`` (at ``positions`` of
    ``chain``) and their retrieved candidates, all scored in a few batches."""
    cfg = m.config
    excludes = [np.array(chain[max(0, p - 1):p + 2], np.int64) for p in positions]
    d = _ranking(m, chain, positions, queries) if cfg.cross.sequence_retrieval \
        else m.index.distances(queries)
    found = [m.index.nearest(row, cfg.retrieval_k, ex)[0] for row, ex in zip(d, excludes)]
    edges = _passing(m, xs, chain, positions, found, score)
    legs = [(None, None)] * len(edges)
    if edges and cfg.cross.legs and joins_carry_legs(m):
        us, vs = np.array(list(edges), np.int64).T
        legs = join_legs(vertex_scans(m, vs), vertex_scans(m, us))
    for ((u, v), p), (leg, path) in zip(edges.items(), legs):
        m.add_edge(u, v, p, "cross", leg, path)
    stats.cross_edges += len(edges)
    if audit:
        everyone = [m.index.ids[~np.isin(m.index.ids, ex)] for ex in excludes]
        every = _passing(m, xs, chain, positions, everyone, lambda s, r: m.bank.score(s, r))
        stats.exhaustive_edges += len(every)
        stats.found_edges += len(set(every) & set(edges))


def _ranking(m: TopoMap, chain: list[int], positions: list[int], queries: np.ndarray) -> np.ndarray:
    """(len(positions), N) distances for retrieval with the sequence in view:
    |x - v|^2 + |x_prev - v_prev|^2 + |x_next - v_next|^2, each vertex's
    neighbours taken along the drive that made it (a missing neighbour
    counts as the pair itself). Cross edges must pass RE over aligned
    neighbours, so ranking by them keeps look-alike single frames out of
    the top K."""
    idx = m.index
    ids = idx.ids
    row_of = {int(v): i for i, v in enumerate(ids)}
    prev_row = np.full(len(ids), -1)
    next_row = np.full(len(ids), -1)
    for i, v in enumerate(ids):
        other, j = m.origin_chain(int(v))
        if j > 0:
            prev_row[i] = row_of.get(other[j - 1], -1)
        if j + 1 < len(other):
            next_row[i] = row_of.get(other[j + 1], -1)
    d0 = idx.distances(queries)
    total = d0.copy()
    for step, rows in ((-1, prev_row), (1, next_row)):
        mine = [row_of.get(chain[p + step], -1) if 0 <= p + step < len(chain) else -1
                for p in positions]
        have = np.array(mine) >= 0
        term = d0.copy()
        if have.any():
            dn = idx.distances(idx.vectors[np.array(mine)[have]])
            aligned = np.where(rows >= 0, dn[:, np.maximum(rows, 0)], d0[have])
            term[have] = aligned
        total += term
    return total


def _passing(m: TopoMap, xs: list[int], chain: list[int], positions: list[int],
             candidates: list[np.ndarray], score) -> dict:
    """Cross edges {(u, v): p} between each new vertex ``xs[i]`` (at
    ``positions[i]`` of ``chain``) and its ``candidates[i]`` that pass the
    single RE and sequence matching (both directions)."""
    cfg = m.config.cross
    x_of = np.concatenate([np.full(len(c), x) for x, c in zip(xs, candidates)]).astype(np.int64)
    pos_of = np.concatenate([np.full(len(c), p) for p, c in zip(positions, candidates)]).astype(np.int64)
    v_of = np.concatenate(candidates).astype(np.int64) if candidates else np.zeros(0, np.int64)
    if len(v_of) == 0:
        return {}
    p_out = score(m.centers(x_of), m.contexts(v_of))      # x -> v
    p_in = score(m.centers(v_of), m.contexts(x_of))       # v -> x
    # sequence matching over the aligned neighbours of the single pairs that pass
    src, dst, owner, tests = [], [], [], []
    for c in np.flatnonzero((p_out > cfg.p) | (p_in > cfg.p)):
        pos, v = int(pos_of[c]), int(v_of[c])
        other, j = m.origin_chain(v)
        offsets = [d for d in range(-cfg.sequence_window, cfg.sequence_window + 1)
                   if d and 0 <= pos + d < len(chain) and 0 <= j + d < len(other)]
        for forward, p in ((True, p_out[c]), (False, p_in[c])):
            if p <= cfg.p:
                continue
            tests.append((c, forward))
            for d in offsets:
                a, b = chain[pos + d], other[j + d]
                src.append(a if forward else b)
                dst.append(b if forward else a)
                owner.append(len(tests) - 1)
    if not tests:
        return {}
    low = np.ones(len(tests))
    if src:
        np.minimum.at(low, np.array(owner), score(m.centers(src), m.contexts(dst)))
    out = {}
    for (c, forward), lowest in zip(tests, low):
        if lowest > cfg.p:
            x, v = int(x_of[c]), int(v_of[c])
            out[(x, v) if forward else (v, x)] = float(p_out[c] if forward else p_in[c])
    return out


def build_map(topomap: TopoMap, trajectories, progress: bool = True, audit: bool = False,
              desc: str = "map build") -> BuildStats:
    """Add ``trajectories`` (an iterable of (observations, poses, name) or
    (observations, poses, name, scans)) one by one."""
    from tqdm import tqdm

    items = list(trajectories) if not hasattr(trajectories, "__len__") else trajectories
    stats = BuildStats()
    bar = tqdm(items, desc=desc, disable=not progress, unit="traj")
    for obs, poses, name, *scans in bar:
        add_trajectory(topomap, obs, poses, name, stats, audit, scans=scans[0] if scans else None)
        bar.set_postfix(vertices=len(topomap), edges=topomap.n_edges)
    return stats
