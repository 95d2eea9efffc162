"""Plan on a map (the paper's "Planning"): Dijkstra on -log p.

:func:`plan_path` plans from the car's current observation to an
observation of the destination; neither needs to be a vertex. Both become
temporary vertices, linked by the map's
:class:`~topodrake.topomap.graph.MapConfig` ``links`` settings:

- the start to the vertices v among its ``links.k`` nearest in the place
  embedding with RE(start, v) above ``links.p``; those v with RE(v, goal)
  above it to the goal (whose context is the goal observation repeated,
  or a full context when given), at min(RE(v, goal), RE(goal, v)) with
  ``links.goal_mutual``;
- with ``links.consensus``, the links of each end in groups, one place each
  (:func:`link_groups`), and the plan between one group per end, the most
  trusted pairs first; on a map that checks links by scans, groups whose
  scans match the view first (:func:`matched_first`), and plans first
  from the vertices near the car (:func:`near_start_links`);
- a direct start-goal link where RE passes, the scans match (where checked)
  and, with ``links.direct_check``, both ends' links are one place
  (:func:`one_place`).

Dijkstra adds up -log p over the hops, counting ``plan`` settings
(:func:`_hop_weight`); the path's probability is exp(-cost). Given a time
limit, the plan is the path most likely to be driven within it
(:func:`within_time`, :mod:`topodrake.topomap.route_time`). The route's hops
keep the map's legs, and with ``links.goal_leg`` the hop into the goal the
pose the goal's scan registers to. An unreachable goal is a result
(:attr:`PlanResult.reachable` False with a reason), never an exception.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import networkx as nx
import numpy as np

from topodrake.contract.route import LEG_POINTS, Route
from topodrake.errors import TopodrakeError
from topodrake.se2 import invert, relative
from topodrake.topomap.build import join_legs, joins_carry_legs
from topodrake.topomap.coverage import registered_links, uncovered_reason
from topodrake.topomap.graph import EDGE_KINDS, TopoMap
from topodrake.topomap.route_time import DrivingTime, edge_metres, path_metres
from topodrake.topomap.scan_match import checks_scans, joins_by_scans, scans_match, vertex_scans

START, GOAL = -1, -2
#: prices of a metre (added to -log p) tried for a path that fits the time limit
METRE_PRICES = (0.003, 0.01, 0.03, 0.1, 0.3, 1.0)
#: a path this likely to be driven in time is kept without looking for shorter ones
ON_TIME_ENOUGH = 0.999
#: map edges between drives (``plan.switch_p``)
SWITCH_KINDS = ("cross", "junction")


@dataclass
class PlanResult:
    reachable: bool
    probability: float = 0.0
    vertices: list[int] = field(default_factory=list)   # map vertices in driving order
    route: Route | None = None                          # vertices' contexts + the goal
    reason: str = ""
    start_links: int = 0
    goal_links: int = 0
    on_time: float = 1.0          # probability of driving it within the time limit (1: no limit)
    uncovered: str = ""           # "start" or "goal": the end the map does not cover (no plan)

    def summary(self) -> dict:
        return {"reachable": self.reachable, "path": [int(v) for v in self.vertices],
                "probability": round(self.probability, 6), "start_links": self.start_links,
                "goal_links": self.goal_links, "on_time": round(self.on_time, 6),
                **({"reason": self.reason} if self.reason else {}),
                **({"uncovered": self.uncovered} if self.uncovered else {})}


def _check_observation(topomap: TopoMap, obs: np.ndarray, what: str) -> np.ndarray:
    obs = np.asarray(obs)
    want = topomap.bank.observations.shape[1:]
    if obs.shape != want:
        raise TopodrakeError(f"the {what} observation has shape {obs.shape}; this "
                             f"{topomap.modality} map needs {want}")
    return obs


def link_groups(topomap: TopoMap, links: list[tuple[int, float]],
                hops: int) -> list[list[tuple[int, float]]]:
    """``links`` ((vertex, p)) in groups, the most trusted first: the most
    probable link left leads a group of the links within ``hops`` edges of
    it (edges taken either way), and so on. A group is one place: a chain
    of links along a corridor that looks alike for metres does not merge
    into one group."""
    undirected = topomap.graph.to_undirected(as_view=True)
    left = sorted(links, key=lambda link: -link[1])
    groups = []
    while left:
        near = nx.single_source_shortest_path_length(undirected, left[0][0], cutoff=hops)
        groups.append([link for link in left if link[0] in near])
        left = [link for link in left if link[0] not in near]
    return groups


def one_place(topomap: TopoMap, a: list[tuple[int, float]], b: list[tuple[int, float]],
              hops: int) -> bool:
    """Whether two groups of links reach one place: a vertex of ``a`` within
    ``hops`` edges (either way) of a vertex of ``b``; an empty group agrees
    with anything."""
    if not a or not b:
        return True
    undirected = topomap.graph.to_undirected(as_view=True)
    near = nx.multi_source_dijkstra_path_length(undirected, {v for v, _ in a}, cutoff=hops,
                                                weight=lambda u, v, d: 1)
    return any(v in near for v, _ in b)


def matched_first(topomap: TopoMap, groups: list[list[tuple[int, float]]],
                  view: np.ndarray) -> list[list[tuple[int, float]]]:
    """``groups`` of links with those first where a vertex's scan matches
    ``view`` (:func:`topodrake.topomap.scan_match.scans_match`), each part
    in its order: RE links a view to a look-alike room as readily as to its
    own place, the scans tell them apart."""
    if len(groups) < 2:
        return groups
    vertices = [v for group in groups for v, _ in group]
    ok = dict(zip(vertices, scans_match(vertex_scans(topomap, vertices), view,
                                        topomap.config.scan_match)))
    matched = [any(ok[v] for v, _ in group) for group in groups]
    return [g for g, hit in zip(groups, matched) if hit] + \
        [g for g, hit in zip(groups, matched) if not hit]


def near_start_links(topomap: TopoMap, links: list[tuple[int, float]],
                     start_scan: np.ndarray) -> list[tuple[int, float]]:
    """The ``links`` from the start to vertices near the car
    (:func:`_near_start`, by registering the start's scan onto theirs,
    pinning the pose), where there are any; else all ``links``."""
    cfg = topomap.config.links
    if cfg.near_m <= 0 or len(links) < 2:
        return links
    vertices = [v for v, _ in links]
    source = np.repeat(np.asarray(start_scan, np.float64)[None], len(vertices), 0)
    near = [leg is not None and _near_start(leg, cfg)
            for leg, _ in join_legs(source, vertex_scans(topomap, vertices))]
    if not any(near):
        return links
    return [link for link, ok in zip(links, near) if ok]


def _near_start(leg: np.ndarray, cfg) -> bool:
    """Whether a vertex at which the start's pose registers to ``leg`` (the
    car in the vertex's frame) is near, by ``cfg`` (a LinkConfig): within
    ``near_m``, facing the car's way within ``near_deg`` and at most
    ``near_behind_m`` behind the car."""
    if float(np.hypot(leg[0], leg[1])) > cfg.near_m:
        return False
    if abs(math.degrees(float(leg[2]))) > cfg.near_deg:
        return False
    ahead = float(invert(leg)[0, 0])          # the vertex's x in the car's frame
    return ahead >= -cfg.near_behind_m


def link_scans(topomap: TopoMap, start_obs: np.ndarray, goal_obs: np.ndarray,
               view_scans=None) -> tuple[np.ndarray, np.ndarray] | None:
    """The lidar scans (start's, goal's) a plan checks its links by: a lidar
    map's own views (:func:`checks_scans`); on a camera map that checks its
    joins by its kept scans (:func:`joins_by_scans`) the ``view_scans`` taken
    with the two views, where given; None otherwise."""
    if checks_scans(topomap):
        return start_obs, goal_obs
    if view_scans is None or not joins_by_scans(topomap):
        return None
    beams = topomap.bank.scans.shape[1]
    out = []
    for name, scan in zip(("start", "goal"), view_scans):
        scan = np.asarray(scan, np.float64)
        if scan.shape != (beams,):
            raise TopodrakeError(f"the {name}'s scan must hold {beams} ranges, as the map's "
                                 f"scans do (got shape {scan.shape})")
        out.append(scan)
    return out[0], out[1]


def _link_choices(topomap: TopoMap, links_s: list, links_g: list, scans) -> list:
    """(start links, goal links) pairs to plan between, in the order tried:
    with ``links.consensus`` one place at each end, the most trusted pairs
    first (:func:`link_groups`, on maps that check scans :func:`matched_first`);
    else all links at once."""
    m = topomap
    if not m.config.links.consensus:
        return [(links_s, links_g)]
    starts = link_groups(m, links_s, m.config.links.hops) or [[]]
    goals = link_groups(m, links_g, m.config.links.hops) or [[]]
    if scans is not None:
        starts, goals = matched_first(m, starts, scans[0]), matched_first(m, goals, scans[1])
    tries = sorted(((i, j) for i in range(len(starts)) for j in range(len(goals))),
                   key=lambda ij: (ij[0] + ij[1], ij))
    return [(starts[i], goals[j]) for i, j in tries]


def _pose_legs(topomap: TopoMap, vertices: list[int], goal_pose, legs: np.ndarray,
               leg_paths: np.ndarray) -> None:
    """Sets the hops without a leg (joins, the goal link) of a pose oracle
    map's route in place from the poses it observes, their paths a straight
    line: perfect perception places a join exactly, as a lidar map places
    it by registering its scans."""
    if not vertices:
        return
    poses = np.vstack([topomap.bank.observations[topomap.centers(vertices)].reshape(-1, 3),
                       np.asarray(goal_pose, np.float64).reshape(1, 3)])
    hops = relative(poses[:-1], poses[1:])
    missing = ~np.isfinite(legs).all(axis=1)
    legs[missing] = hops[missing]
    line = np.linspace(0.0, 1.0, LEG_POINTS)[None, :, None]
    leg_paths[missing] = line * hops[missing][:, None]


def _goal_leg(topomap: TopoMap, vertices: list[int], goal_scan, legs: np.ndarray,
              leg_paths: np.ndarray) -> None:
    """Sets the last hop's leg (into the goal view) in place where the map
    places joins by scans (``links.goal_leg``) and the goal's scan registers onto
    the last vertex's, pinning the pose."""
    if not (topomap.config.links.goal_leg and vertices and goal_scan is not None
            and joins_carry_legs(topomap)):
        return
    (leg, path), = join_legs(np.asarray(goal_scan, np.float64)[None],
                             vertex_scans(topomap, vertices[-1:]))
    if leg is not None:
        legs[-1], leg_paths[-1] = leg, path


def _hop_weight(topomap: TopoMap, banned: set):
    """Dijkstra's weight of a hop: -log p, none for a ``banned`` map edge,
    and on a map that places joins by scans a map edge without a leg counts
    its p times ``plan.legless_p``; a hop between drives (a cross or
    junction edge) counts its p times ``plan.switch_p``."""
    extra = -math.log(topomap.config.plan.legless_p) if joins_carry_legs(topomap) else 0.0
    switch = -math.log(topomap.config.plan.switch_p)

    def weight(u, v, d):
        if (u, v) in banned:
            return None
        kind = d.get("kind")
        legless = extra > 0 and kind in EDGE_KINDS and "leg" not in d
        return (d["weight"] + (extra if legless else 0.0)
                + (switch if kind in SWITCH_KINDS else 0.0))
    return weight


def _route_scans(topomap: TopoMap, vertices: list[int]) -> np.ndarray | None:
    """The lidar scans a camera map keeps for a route through ``vertices``
    and into the goal view (which has none: NaN); None where it keeps none."""
    scans = topomap.bank.scans
    if scans is None or topomap.modality == "lidar":
        return None
    rows = scans[topomap.centers(vertices)] if vertices else np.zeros((0, scans.shape[1]))
    return np.vstack([rows, np.full((1, scans.shape[1]), np.nan)])


def within_time(g, cost: float, path: list, weight, limit_s: float,
                driving: DrivingTime) -> tuple[float, list, float]:
    """(cost, path, on-time probability) of the path from START to GOAL of
    ``g`` most likely to succeed within ``limit_s``: the most probable path
    (``cost``, ``path``) or one found with each metre priced at one of
    :data:`METRE_PRICES` (``weight``: Dijkstra's weight, a function or key),
    whichever has the largest product of probability and on-time probability."""
    metres, typical = edge_metres(g)

    def on_time(p: list) -> float:
        return driving.on_time(path_metres(p, metres, typical), len(p) - 1, limit_s)

    best = (cost, path, on_time(path))
    if best[2] >= ON_TIME_ENOUGH:
        return best
    base = weight if callable(weight) else (lambda u, v, d: d[weight])
    for price in METRE_PRICES:
        def priced(u, v, d, price=price):
            w = base(u, v, d)
            return None if w is None else w + price * metres.get((u, v), typical)
        p = nx.dijkstra_path(g, START, GOAL, weight=priced)
        c = float(sum(base(u, v, g.edges[u, v]) for u, v in zip(p[:-1], p[1:])))
        cand = (c, p, on_time(p))
        if math.exp(-cand[0]) * cand[2] > math.exp(-best[0]) * best[2]:
            best = cand
    return best


def plan_path(topomap: TopoMap, start_observation: np.ndarray, goal_observation: np.ndarray,
              goal_context: np.ndarray | None = None, start_pose=None, goal_pose=None,
              excluded_edges=(), retrieval_k: int | None = None, time_limit_s: float | None = None,
              driving: DrivingTime | None = None, view_scans=None,
              start_vertex: int | None = None) -> PlanResult:
    """The most probable path from ``start_observation`` to the goal, or
    with ``time_limit_s`` the path most likely to be driven within it
    (:func:`within_time`, the follower's pace ``driving``).

    ``goal_context`` (2k+1, ...) replaces the repeated goal observation as
    the goal's target; ``start_pose``/``goal_pose`` are metadata for the
    route (plots, evaluation); ``excluded_edges``: (u, v) map edges to
    ignore (a replanning follower's failed ones); ``view_scans``: the lidar
    scans (start's, goal's; a pair or a (2, beams) array) taken with the
    two views, by which a camera map that keeps its drives' scans checks
    the links as a lidar map does
    (:func:`link_scans`); ``start_vertex``: the path starts at this map
    vertex instead of the start's links (:func:`plan_from_vertex`)."""
    if time_limit_s is not None and not (math.isfinite(time_limit_s) and time_limit_s > 0):
        raise TopodrakeError(f"the time limit must be a number of seconds > 0, not {time_limit_s}")
    m = topomap
    if len(m) == 0:
        raise TopodrakeError("the map has no vertices")
    cfg = m.config.links
    k = retrieval_k or cfg.k
    frames = 2 * m.k + 1
    start_obs = _check_observation(m, start_observation, "start")
    goal_obs = _check_observation(m, goal_observation, "goal")
    scans = link_scans(m, start_obs, goal_obs, view_scans)
    if goal_context is None:
        goal_context = np.repeat(goal_obs[None], frames, 0)
    goal_context = np.asarray(goal_context)
    if goal_context.shape != (frames, *goal_obs.shape):
        raise TopodrakeError(f"the goal context must hold {frames} observations")
    nan_pose = np.full(3, np.nan)
    first = len(m.bank)
    m.bank.append(np.concatenate([start_obs[None], goal_context]),
                  np.vstack([start_pose if start_pose is not None else nan_pose,
                             np.repeat([goal_pose if goal_pose is not None else nan_pose],
                                       frames, 0)]))
    s_row, g_rows = first, np.arange(first + 1, first + 1 + frames)
    g = m.graph
    try:
        emb = m.embedding.embed(np.stack([start_obs, goal_obs]))
        from_start, to_goal = m.index.search(emb, k)
        p_start = m.bank.score(np.full(len(from_start), s_row), m.contexts(from_start))
        p_goal = m.bank.score(m.centers(to_goal), np.repeat(g_rows[None], len(to_goal), 0))
        p_direct = float(m.bank.score([s_row], g_rows[None])[0])
        links_s = [(int(v), float(p)) for v, p in zip(from_start, p_start) if p > cfg.p]
        if cfg.goal_mutual:
            # RE toward a goal whose context is one image repeated is overconfident (0.9 from
            # vertices 5 m away, behind a door); RE from the goal back to v reads v's own
            # context: a link's probability is the smaller of the two
            back = m.bank.score(np.full(len(to_goal), g_rows[0]), m.contexts(to_goal))
            p_goal = np.minimum(p_goal, back)
            p_direct = min(p_direct, float(m.bank.score([g_rows[0]],
                                                        np.full((1, frames), s_row))[0]))
        links_g = [(int(v), float(p)) for v, p in zip(to_goal, p_goal) if p > cfg.p]
        if scans is not None and p_direct > cfg.p \
                and not scans_match(scans[1], scans[0], m.config.scan_match)[0]:
            p_direct = 0.0      # a look-alike of the goal, not the goal
        if start_vertex is not None:      # the car returns to a vertex it saw: no start link
            links_s, p_direct = [(int(start_vertex), 1.0)], 0.0
        result = PlanResult(False, start_links=len(links_s), goal_links=len(links_g))
        if scans is not None and cfg.cover > 0:
            ends = [("goal", links_g, scans[1])]
            if start_vertex is None:
                ends.insert(0, ("start", links_s, scans[0]))
            for end, links, scan in ends:
                if not links or p_direct > cfg.p:
                    continue
                kept, best = registered_links(m, links, scan, cfg.cover)
                if not kept:
                    result.reason = uncovered_reason(end, len(links), best, cfg.cover)
                    result.uncovered = end
                    return result
        if not links_s and p_direct <= cfg.p:
            result.reason = (f"no map vertex is reachable from the start (best RE "
                             f"{max(p_start, default=0.0):.2f} <= {cfg.p})")
            return result
        if not links_g and p_direct <= cfg.p:
            result.reason = (f"the goal is reachable from no map vertex (best RE "
                             f"{max(p_goal, default=0.0):.2f} <= {cfg.p})")
            return result
        # the start's links by the anchors its scan places near first, then all of them
        near = near_start_links(m, links_s, scans[0]) \
            if scans is not None and start_vertex is None else links_s
        choices = [pair for from_start in ([near, links_s] if near != links_s else [links_s])
                   for pair in _link_choices(m, from_start, links_g, scans)]
        banned = {(int(u), int(v)) for u, v in excluded_edges}
        weight = _hop_weight(m, banned)
        path = None
        for from_start, into_goal in choices:
            g.add_node(START)
            g.add_node(GOAL)
            for v, p in from_start:
                g.add_edge(START, v, p=p, weight=-math.log(p), kind="start")
            for v, p in into_goal:
                g.add_edge(v, GOAL, p=p, weight=-math.log(p), kind="goal")
            if p_direct > cfg.p and (not cfg.direct_check or one_place(
                    m, from_start, into_goal, cfg.hops)):
                g.add_edge(START, GOAL, p=p_direct, weight=-math.log(p_direct), kind="direct")
            try:
                cost, path = nx.single_source_dijkstra(g, START, GOAL, weight=weight)
                result.start_links, result.goal_links = len(from_start), len(into_goal)
                break
            except nx.NetworkXNoPath:
                g.remove_nodes_from([START, GOAL])
        if path is None:
            result.reason = "no path of the map joins the start's links to the goal's"
            return result
        if time_limit_s is not None:
            cost, path, result.on_time = within_time(g, cost, path, weight, time_limit_s,
                                                     driving or DrivingTime())
        probs = [math.exp(-weight(u, v, g.edges[u, v])) for u, v in zip(path[:-1], path[1:])]
        vertices = [int(v) for v in path[1:-1]]
        # the drives' odometry between the map's anchors; into the goal view, its scan's
        # registration onto the last vertex's
        legs, leg_paths = m.legs(vertices + [GOAL])
        goal_scan = scans[1] if scans is not None else goal_obs if m.modality == "lidar" else None
        _goal_leg(m, vertices, goal_scan, legs, leg_paths)
        if m.modality == "pose" and goal_pose is not None:
            _pose_legs(m, vertices, goal_pose, legs, leg_paths)
        route = Route(
            contexts=np.concatenate([m.bank.observations[m.contexts(vertices)],
                                     goal_context[None]]) if vertices else goal_context[None],
            poses=np.vstack([m.pose(vertices).reshape(-1, 3),
                             (goal_pose if goal_pose is not None else nan_pose)[None]]),
            vertices=np.array(vertices + [-1], np.int64),
            edge_probability=np.array(probs[1:]),
            probability=math.exp(-cost), modality=m.modality, start_probability=probs[0],
            legs=legs, leg_paths=leg_paths, scans=_route_scans(m, vertices),
            on_time=result.on_time)
        result.reachable, result.probability = True, math.exp(-cost)
        result.vertices, result.route = vertices, route
        return result
    finally:
        if START in g:
            g.remove_node(START)
        if GOAL in g:
            g.remove_node(GOAL)
        m.bank.keep_tail(first, np.zeros(0, np.int64))


def plan_from_vertex(topomap: TopoMap, vertex: int, goal_observation: np.ndarray,
                     goal_scan=None, **kwargs) -> PlanResult:
    """The path :func:`plan_path` finds from the map vertex ``vertex`` (a
    replanning car that returns to an anchor it saw) to the goal;
    ``goal_scan``: the goal view's lidar scan, where a camera map checks its
    goal links by scans; ``kwargs`` as :func:`plan_path`'s (a start pose
    defaults to the vertex's)."""
    m = topomap
    if vertex not in m.graph:
        raise TopodrakeError(f"vertex {vertex} is not a vertex of the map ({len(m)} vertices)")
    start_obs = m.bank.observations[m.centers([vertex])[0]]
    scans = None
    if goal_scan is not None and m.modality != "lidar":
        scans = (vertex_scans(m, [vertex])[0], goal_scan)
    kwargs.setdefault("start_pose", m.pose([vertex])[0])
    return plan_path(m, start_obs, goal_observation, view_scans=scans, start_vertex=vertex,
                     **kwargs)
