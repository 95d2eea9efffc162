"""Replanning while dead reckoning, and loop breaking.

A car in Dead reckoning asks the planner on a schedule
(:class:`ReplanSchedule`; :meth:`ReplanSchedule.paper` is the paper's: from
the 5th period, every 3, a new plan taken where its probability beats the
current plan's discounted by 0.99 per try; the default asks only in the
last 10 periods before the car gives up and takes any plan it can start).
Each try plans from the car's current observation without the edge the car
is failing on (its last visited anchor -> its active anchor); once a plan
is accepted that edge stays excluded for the car (loop breaking). A plan is
taken only where the follower's Search would pass on it from the car's
current observation (:func:`search_would_start`); the accepted route
replaces the car's current one from the next period and its follower
starts again in Search.

Where no plan starts from the car's view, two ablations place the car
elsewhere: ``return_to_anchor`` plans from the map vertex of its last
visited anchor and dead reckons back to it (:func:`return_anchor`,
:func:`returning_state`); ``oracle_relocalize`` plans from the vertex the
car sees nearest in truth (:func:`nearest_seen_vertex`,
:func:`located_state`).

:class:`Replanner` keeps the per-car bookkeeping of one run; both executors
(the batched engine and the Drake ``FollowerFsm``) call
:meth:`Replanner.step` after each period's follower decision. The planner
is reached through a callback ``plan(car, pose, excluded_edges, vertex=None)
-> Route | None`` (None: no plan avoids the excluded edges; ``vertex``: plan
from that map vertex, or :data:`NEAREST`); ``pose`` is privileged metadata
the callback may render the car's observation at. Reasons and measured
effects: docs/follower.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.navigation.evaluate import Evaluator, encode_routes, initial_track
from topodrake.navigation.follower import FollowerState, Mode, search_choice
from topodrake.odometry import odometry_to_world
from topodrake.se2 import compose, invert

GIVE_UP = ("dead_reckoning_gave_up", "search_failed")
NEAREST = "nearest"     # ``vertex`` of a plan callback: the vertex the oracle locates the car at


@dataclass
class ReplanSchedule:
    """When a car in Dead reckoning asks for a new plan, and which it takes
    (default: in the last 10 periods before the follower's default
    ``dr_max_iterations`` of 200 gives up)."""

    first: int = 190          # Dead reckoning periods before the first try
    every: int = 3            # then a try every this many periods
    discount: float = 0.01    # a new plan is taken when p_new > p_current * discount ** tries
    max_replans: int = 5      # accepted new plans per car and run
    return_to_anchor: bool = False  # where no plan starts from the car's view, the car
                                    # returns to its last visited anchor and drives a plan
                                    # from that vertex (an ablation; see Replanner.step)
    oracle_relocalize: bool = False  # where no plan starts from the car's view, an oracle
                                     # names the vertex it sees nearest in truth and the car
                                     # drives a plan from it (an ablation; see Replanner.step)

    @classmethod
    def paper(cls) -> "ReplanSchedule":
        """The paper's schedule (its authors' follower): tries from the 5th
        period, every 3, a new plan taken when it beats the current one
        discounted by 0.99 per try."""
        return cls(first=5, every=3, discount=0.99, max_replans=5)

    def check(self) -> "ReplanSchedule":
        if self.first < 1 or self.every < 1:
            raise TopodrakeError(f"replanning needs first >= 1 and every >= 1, got {self.first} "
                                 f"and {self.every}")
        if not 0.0 < self.discount <= 1.0:
            raise TopodrakeError(f"the replanning discount must be in (0, 1], got {self.discount}")
        for name in ("return_to_anchor", "oracle_relocalize"):
            if not isinstance(getattr(self, name), bool):
                raise TopodrakeError(f"{name} must be true or false, got "
                                     f"{getattr(self, name)!r}")
        if self.max_replans < 0:
            raise TopodrakeError(f"max_replans must be >= 0, got {self.max_replans}")
        return self

    @classmethod
    def from_json(cls, text: str | None) -> "ReplanSchedule":
        """The schedule a ``--replan`` JSON object of its fields gives
        (defaults for the others; none: the default; ``"paper"``: the
        paper's), checked; a bad one is refused in one line."""
        import json

        if not text:
            return cls()
        if text.strip() == "paper":
            return cls.paper()
        try:
            fields = json.loads(text)
            if not isinstance(fields, dict):
                raise ValueError("not a JSON object")
            return cls(**fields).check()
        except (ValueError, TypeError, TopodrakeError) as e:
            raise TopodrakeError(f"--replan {text!r} is not 'paper' or a JSON object of "
                                 f"ReplanSchedule fields ({e})") from None

    def check_against(self, dr_max_iterations: int) -> "ReplanSchedule":
        """Refuse a schedule whose first try comes when Dead reckoning has
        already given up (it would never replan)."""
        if self.first >= dr_max_iterations:
            raise TopodrakeError(f"the replanning schedule tries first at Dead reckoning "
                                 f"period {self.first}, but the follower gives up at "
                                 f"{dr_max_iterations} (dr_max_iterations): set its 'first' "
                                 f"below that")
        return self

    def due(self, dr_count: np.ndarray) -> np.ndarray:
        """Which Dead reckoning period counts are a try."""
        c = np.asarray(dr_count, np.int64)
        return (c >= self.first) & ((c - self.first) % self.every == 0)

    def accepts(self, p_new: float, p_current: float, tries: int) -> bool:
        return bool(p_new > p_current * self.discount ** tries)


def failing_edge(route, visited: int, active: int) -> tuple[int, int] | None:
    """The map edge (u, v) a follower fails on: from its last visited anchor
    to its active one (None when either is not a map vertex)."""
    return hop_edge(route.vertices, visited, active)


def hop_edge(vertices, i: int, j: int) -> tuple[int, int] | None:
    """The map edge from anchor ``i`` to anchor ``j`` of a route whose
    anchors are the map vertices ``vertices`` (None when either is not one)."""
    if not (0 <= i < len(vertices) and 0 <= j < len(vertices)):
        return None
    u, v = int(vertices[i]), int(vertices[j])
    return (u, v) if u >= 0 and v >= 0 and u != v else None


def route_traversals(vertices, visited: int, active: int, reached: bool, timed_out: bool = False
                     ) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
    """What a run along a route of map vertices ``vertices`` tells of its
    map edges: ``(passed, failed)``. Every hop up to the last visited
    anchor was passed (all of them when the car reached the goal); a car
    that failed otherwise than by running out of time failed on the hop from
    its last visited anchor to its active one. Hops to or from anchors that
    are not map vertices are left out."""
    last = len(vertices) - 1 if reached else min(int(visited), len(vertices) - 1)
    passed = [e for e in (hop_edge(vertices, i, i + 1) for i in range(max(last, 0)))
              if e is not None]
    edge = None if reached or timed_out else hop_edge(vertices, visited, active)
    return passed, ([edge] if edge is not None else [])


def traversals_of_records(records: list[dict]) -> tuple[list, list]:
    """``(passed, failed)`` map edges of the planned trials of a planning
    study's records (each with ``plan_vertices``, ``visited``, ``active``,
    ``success`` and ``outcome``); a planned trial without them is refused."""
    passed, failed = [], []
    for r in records:
        if not r.get("planned"):
            continue
        if not all(k in r for k in ("plan_vertices", "visited", "active")):
            raise TopodrakeError(f"trial {r.get('trial')} of {r.get('method')} in "
                                 f"{r.get('house')} has no plan_vertices, visited and active "
                                 f"anchor: it was recorded before the study kept them")
        p, f = route_traversals(r["plan_vertices"], r["visited"], r["active"],
                                bool(r["success"]), r.get("outcome") == "timeout")
        passed += p
        failed += f
    return passed, failed


PlanCallback = Callable[..., object]


def returning_state(state: FollowerState, row: int, fresh: FollowerState) -> FollowerState:
    """The follower state (one car) that starts a route from the anchor the
    car in ``row`` of ``state`` returns to (:func:`return_anchor`): Dead
    reckoning toward it (the route's first anchor), held where the route
    tracker puts it in the odometry frame, the tracked pose kept relative to
    it; a car the tracker lost holds the odometry pose at which it marked
    the anchor visited; ``fresh``: the one-car initial state (the policy's
    initial track)."""
    out = fresh.copy()
    out.mode[0], out.active[0], out.visited[0] = Mode.DEAD_RECKONING, 0, -1
    if _tracked(state, row):
        rel, odo = state.rel[row], state.odo[row]
        out.waypoint[0] = compose(odo, invert(rel))[0, :2]
        out.ref[0], out.rel[0], out.var[0], out.odo[0] = 0, rel, state.var[row], odo
    else:
        out.waypoint[0] = state.seen[row, :2]
    return out


def located_state(route, pose: np.ndarray, odometry: np.ndarray,
                  fresh: FollowerState) -> FollowerState:
    """The follower state (one car) that starts ``route`` dead reckoning to
    its first anchor, where the oracle located the car: the anchor's taught
    position (``route.poses[0]``, in the world) given in the car's odometry
    frame from its true ``pose`` and odometry pose ``odometry`` (3,)."""
    out = fresh.copy()
    out.mode[0], out.active[0], out.visited[0] = Mode.DEAD_RECKONING, 0, -1
    # odometry_to_world with the frames swapped: world -> odometry
    def state(p):
        return np.concatenate([np.asarray(p, np.float64)[:3], np.zeros(2)])[None]

    target = np.asarray(route.poses[0, :2], np.float64)[None, None]
    out.waypoint[0] = odometry_to_world(target, state(pose), state(odometry))[0, 0]
    return out


def nearest_seen_vertex(vertex_poses: np.ndarray, pose: np.ndarray, clearance_at,
                        max_m: float = 4.0, max_turn_deg: float = 60.0,
                        step_m: float = 0.05) -> int | None:
    """The oracle's relocalization: the index into ``vertex_poses`` (V, 3)
    of the vertex nearest the car's true ``pose`` (3,) within ``max_m``
    that the car sees (the straight way to it free: ``clearance_at``, the
    world grid's, above 0 at every ``step_m``) and would face on arrival
    (its taught heading within ``max_turn_deg`` of the way there, or of the
    car's heading where it stands on the vertex); None where none."""
    vp = np.asarray(vertex_poses, np.float64).reshape(-1, 3)
    pose = np.asarray(pose, np.float64)
    d = vp[:, :2] - pose[:2]
    dist = np.hypot(d[:, 0], d[:, 1])
    way = np.where(dist > 0.3, np.arctan2(d[:, 1], d[:, 0]), pose[2])
    turn = np.abs(np.angle(np.exp(1j * (vp[:, 2] - way))))
    ok = np.isfinite(dist) & (dist <= max_m) & (turn <= np.radians(max_turn_deg))
    for v in np.flatnonzero(ok)[np.argsort(dist[ok], kind="stable")]:
        t = np.linspace(0.0, 1.0, max(2, int(np.ceil(dist[v] / step_m)) + 1))[:, None]
        if np.all(clearance_at(pose[:2] + t * d[v]) > 0):
            return int(v)
    return None


def _tracked(state: FollowerState, row: int) -> bool:
    """Whether the route tracker places the car in ``row`` relative to an anchor."""
    return bool(state.ref[row] >= 0 and np.isfinite(state.odo[row]).all())


def kept_features(encoded: dict, route):
    """The features an executor's ``startable`` kept for ``route`` under its
    id (None: it never asked of it, as of a plan from a vertex)."""
    kept, features = encoded.get(id(route), (None, None))
    return features if kept is route else None


def return_anchor(state: FollowerState, row: int, route) -> int | None:
    """The anchor of ``route`` the car in ``row`` can return to: the one the
    route tracker places it relative to, else its last visited one where it
    kept the odometry pose of that visit; None where that is not a map
    vertex or there is none."""
    if _tracked(state, row):
        anchor = int(state.ref[row])
    elif state.visited[row] >= 0 and np.isfinite(state.seen[row]).all():
        anchor = int(state.visited[row])
    else:
        return None
    if not 0 <= anchor < len(route.vertices):
        return None
    return anchor if route.vertices[anchor] >= 0 else None


def search_would_start(policy, reach, route, observation, pose: np.ndarray, ranges, lidar,
                       config, odometry: np.ndarray | None = None) -> tuple[bool, object]:
    """Would the follower's Search (``config``: its FollowerConfig) pass on
    ``route`` from one car's ``observation`` (1, ...; None for pose
    oracles) at ``pose`` (1, 3; its odometry pose ``odometry``, default the
    same), with its lidar scan ``ranges`` (1, beams) or None? Returns that
    and the route's features (:func:`encode_routes`), for the executor to
    keep if the route is taken. Both executors ask this of a replanned
    route before they take it."""
    features = encode_routes([route], policy, reach, legs_m=config.tracker.legs_m)
    ev = Evaluator(policy, reach, features, np.zeros(1, np.int64), observation, poses=pose,
                   track=initial_track(policy, 1), odometry=pose if odometry is None else odometry,
                   lidar=lidar, ranges=ranges)
    _, best = search_choice(ev, np.zeros(1, np.int64), features.n_anchors, config)
    return bool(best[0] > config.p_search), features


class Replanner:
    """The replanning bookkeeping of one run of N cars: each car's current
    route, tries since that route was taken, plans driven (and of them
    plans from an anchor it returned to), edges excluded."""
    def __init__(self, plan: PlanCallback, routes: list, schedule: ReplanSchedule | None = None):
        self.plan = plan
        self.schedule = (schedule or ReplanSchedule()).check()
        self._initial = list(routes)
        self.reset()

    def reset(self) -> None:
        """Back to the routes given (a new run)."""
        self.routes = list(self._initial)
        n = len(self.routes)
        self.tries = np.zeros(n, np.int64)
        self.plans = np.ones(n, np.int64)
        self.returns = np.zeros(n, np.int64)      # of them plans from a vertex driven back to
        self.excluded: list[list[tuple[int, int]]] = [[] for _ in range(n)]

    def step(self, cars: np.ndarray, state, poses: np.ndarray, p_start: float = 0.0,
             startable: Callable[[int, object], bool] | None = None,
             fresh: Callable[[], FollowerState] | None = None,
             odometry: np.ndarray | None = None
             ) -> list[tuple[int, object, FollowerState]]:
        """After a period's decision ``state`` (FollowerState of ``cars``,
        rows in the same order; ``poses`` (len(cars), 3)): ask the planner
        for the cars whose Dead reckoning reached a try, and return the
        (car, new route, the car's follower state to start it with) triples
        accepted. A new route is taken only where the follower can start it:
        ``startable(row, route)`` (the executor's: would the follower's
        Search pass from the car's current observation,
        :func:`~topodrake.navigation.follower.search_choice`), or without
        it, where the plan's start link is above ``p_start`` (the follower's
        p_search; the planner's and the follower's RE calibrations differ,
        so this only approximates Search); it starts in Search (``fresh()``:
        a one-car initial state, by default one with a zero track). With
        ``return_to_anchor`` a car that no such plan starts for takes a plan
        from the map vertex of the anchor it can return to
        (:func:`return_anchor`) instead (``plan(car, pose, excluded,
        vertex=v)``; where none avoids the failing edge, one that may take
        it once more) and starts it dead reckoning back to that anchor
        (:func:`returning_state`); with ``oracle_relocalize`` it takes a
        plan from the vertex the oracle locates it at (``plan(car, pose,
        excluded, vertex=NEAREST)``) and dead reckons to that vertex
        (:func:`located_state`; ``odometry``: the cars' odometry poses,
        default ``poses``)."""
        cars = np.asarray(cars, np.int64)
        odometry = poses if odometry is None else odometry
        if fresh is None:
            fresh = lambda: FollowerState.initial(1, state.track.shape[1])   # noqa: E731
        due = np.flatnonzero((state.mode == Mode.DEAD_RECKONING)
                             & self.schedule.due(state.dr_count))
        taken = []
        for r in due:
            i = int(cars[r])
            if self.plans[i] > self.schedule.max_replans:
                continue
            edge = failing_edge(self.routes[i], int(state.visited[r]), int(state.active[r]))
            excluded = list(self.excluded[i])
            if edge is not None and edge not in excluded:
                excluded.append(edge)
            self.tries[i] += 1
            new = self.plan(i, np.array(poses[r], np.float64), excluded)
            start = None
            if new is not None and self._accepts(new, i) and \
                    (startable(int(r), new) if startable is not None
                     else new.start_probability > p_start):
                start = fresh()
            elif self.schedule.return_to_anchor:
                new = self._plan_back(i, state, int(r), poses[r], excluded)
                if new is not None and self._accepts(new, i):
                    start = returning_state(state, int(r), fresh())
                    self.returns[i] += 1
            elif self.schedule.oracle_relocalize:
                new = self.plan(i, np.array(poses[r], np.float64), excluded, vertex=NEAREST)
                if new is not None and self._accepts(new, i):
                    start = located_state(new, poses[r], odometry[r], fresh())
                    self.returns[i] += 1
            if start is None:
                continue
            self.routes[i], self.excluded[i] = new, excluded
            self.tries[i] = 0
            self.plans[i] += 1
            taken.append((i, new, start))
        return taken

    def _plan_back(self, car: int, state, row: int, pose, excluded: list):
        """The plan from the vertex of the anchor the car can return to: a way
        round the failing hop, else one taking that hop once more (the vertex
        may have no other way on; the hop stays excluded at the next try)."""
        route = self.routes[car]
        anchor = return_anchor(state, row, route)
        if anchor is None:
            return None
        for ex in (excluded, self.excluded[car]):
            new = self.plan(car, np.array(pose, np.float64), ex,
                            vertex=int(route.vertices[anchor]))
            if new is not None:
                return new
        return None

    def _accepts(self, new, car: int) -> bool:
        return self.schedule.accepts(new.probability, self.routes[car].probability,
                                     int(self.tries[car]))
