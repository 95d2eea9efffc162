"""The follower state machine (Search, Follow, Dead reckoning) as batched functions.

One call of :func:`follower_step` advances N followers by one control
period. Each follower drives its own route of ``n_anchors[i]`` anchors; the
networks are reached through an ``evaluate(cars, anchors, cwp, re)``
callback (:class:`topodrake.navigation.evaluate.Evaluator`), so the Drake
``FollowerFsm`` (a batch of one) and the batched navigation engine (N cars)
run exactly this logic.

Per period, with the current observation:

* **Search** (the first period): RE toward every anchor; the best one above
  ``p_search`` becomes the active anchor (the one before it counts as
  visited) and the follower enters Follow; otherwise it gives up
  (``search_failed``).
* **Follow**: C_WP toward the ``lookahead`` anchors after the last visited
  one (the paper looks up to 5 ahead; 2 followed more of the study's test
  trajectories: see ``studies/trajectory_following.py``). Proximity = the mean of the two predicted overlaps; the farthest
  anchor with proximity above ``p_visited`` *and* a C_WP waypoint shorter
  than ``visit_m`` (or pointing backwards: passed), or with a waypoint
  shorter than ``visit_m`` and proximity above only ``p_visited_close``
  (ours: a car standing on an anchor at another heading, at a junction or
  in a turn, sees less of its view; without it the car circled such
  anchors) when no earlier anchor of the window looks nearer (ours: a camera C_WP
  that said "here" toward an anchor a room away marked it visited, and the
  car lost the route), becomes the last visited one; the route's last anchor (the
  goal) needs proximity above ``p_goal`` as well (ours: near a wall the A*
  waypoint is short while the goal is still a metre off) (the last anchor of the route visited ends the plan:
  ``reached``). The distance condition is ours:
  in a straight corridor the predicted overlap of an anchor 2 m ahead
  already passes 0.65, and marking it visited made the follower aim at
  anchors too far for RE. The active anchor is the next unvisited one, or
  the one after it when RE toward that one is above ``p_follow`` and its
  proximity above ``p_near`` (the paper's advance rule). If RE toward the
  active anchor is above ``p_follow`` the waypoint is C_WP's toward it;
  otherwise the follower enters Dead reckoning. An active anchor that is
  neither visited nor left behind for ``stall_periods`` periods (5 s) counts
  as visited (ours: an obstacle the map never saw may stand on it, and the
  RMP keeps the car out of its visiting distance), unless it is the last.
* **Dead reckoning**: the car drives to the last Follow waypoint, held in
  the odometry frame (the car's integrated pose, which drifts:
  :mod:`topodrake.odometry`). Each period RE is asked
  about a window of anchors around the next unvisited one, which widens by
  one anchor each way every ``dr_widen_every`` periods, as the paper's
  does, but reaches back ``dr_back_anchors`` (1) anchors at most (ours: a
  learned C_WP that drifts off the route finds it again more often when the
  window may reach back, while with the paper's unbounded window the A*
  oracle took anchors far behind and drove routes backwards until time ran
  out; 0 keeps the window forward only, widening two anchors ahead, and -1
  is the paper's; see docs/figures.md); the best above
  ``p_follow`` becomes active and the follower returns to Follow. A car
  that arrives within ``dr_arrive_m`` of the held waypoint while RE still
  says no holds C_WP's next waypoint toward the active anchor instead, or,
  when that waypoint is shorter than ``visit_m`` (the car overshot a
  junction and stands on the anchor), marks it visited and holds the
  waypoint toward the next one (ours:
  the paper replans at that point, which a single route cannot; without it
  a car that stands at an anchor at the wrong heading waits until it gives
  up). After ``dr_max_iterations`` periods it gives up
  (``dead_reckoning_gave_up``).

A Follow waypoint of C_WP's that lies inside the car's turning circle
(``reverse_inside_turn``; ours) is driven as a point straight behind the
car: driving forward at full lock the car would circle it (an anchor
beside the car), and a near answer far off the heading (C_WP's typical
large error) would swing the car round; backing up brings the target
where the car can turn onto it, and the next answer comes from farther.
With ``skip_inside_first`` (off: an ablation) such an anchor among the
route's first counts as passed instead when C_WP puts the next one ahead,
where the car can drive onto it: at the start the car has not seen what
lies behind it (its lidar looks ahead), and backing up drove it into walls.

Along routes with the teach drives' legs a route tracker
(:mod:`topodrake.navigation.tracker`; ``odometry_check``) keeps each car's
pose by odometry, corrected by C_WP's answers and, on routes that keep
their anchors' lidar scans, by the car's scan registered onto them
(``scan_fix``); it replaces
C_WP's waypoints that disagree with it, counts anchors it puts behind the
car as passed, and where the scans pin it (``tracked_sure_m``) refuses Dead
reckoning anchors it puts far away and ends the route at the goal.

The state is a handful of numbers per car (:class:`FollowerState`): mode,
active anchor, last visited anchor, the held waypoint and counters, and
``track``: (N, S) floats that a stateful C_WP keeps per car (S =
``policy.track_size``, 0 for the stateless networks; see
:class:`topodrake.navigation.evaluate.Evaluator`). The follower logic never
reads it; it travels with the state so both executors keep it alike.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.navigation import tracker
from topodrake.se2 import wrap
from topodrake.vehicle import VehicleConfig, car_to_world, world_to_car

SEARCH, FOLLOW, DEAD_RECKONING, REACHED, FAILED = 0, 1, 2, 3, 4
MODES = ("search", "follow", "dead_reckoning", "reached", "failed")
NO_REASON, SEARCH_FAILED, DR_GAVE_UP = 0, 1, 2
REASONS = ("", "search_failed", "dead_reckoning_gave_up")


@dataclass
class FollowerConfig:
    """The follower's thresholds (the paper's and its authors' code's values,
    but for ``p_search``, ``visit_m`` and ``lookahead``)."""

    p_search: float = 0.8           # RE needed to pick the first active anchor (the paper: 0.92;
                                    # from 2 of 40 jittered starts our RE stays below 0.92 toward
                                    # every anchor, yet C_WP follows the route from there)
    search_first: bool = True       # Search takes the route's first anchor where RE passes
                                    # p_search toward it (a plan links the car's view to it; a
                                    # look-alike further on may rate higher), else the best
    p_follow: float = 0.92          # RE needed to keep following the active anchor
    p_visited: float = 0.65         # proximity (mean predicted overlap) that marks an anchor visited
    p_near: float = 0.6             # proximity the anchor after the next needs to become active
    visit_m: float = 0.35           # ... and C_WP's waypoint toward a visited anchor is this short
    p_visited_close: float = 0.3    # proximity enough within visit_m (the car stands on the
                                    # anchor at another heading: a turn or a junction)
    p_goal: float = 0.75            # proximity that the route's last anchor (the goal) needs
    goal_m: float = 0.35            # ... and C_WP's waypoint toward it is this short
    lookahead: int = 2              # anchors after the last visited one checked in Follow (<= 5)
    advance: str = "next"           # "next": the paper's advance rule; "proximity": the authors' code
    dr_max_iterations: int = 200    # Dead reckoning gives up after this many periods
    dr_widen_every: int = 10        # the Dead reckoning search widens by one anchor each side
    dr_max_window: int = 15         # at most this many anchors asked per Dead reckoning period
    dr_arrive_m: float = 0.3        # at the held waypoint, C_WP gives the next one (see above)
    dr_back_anchors: int = 1        # the Dead reckoning window reaches back this many anchors
                                    # at most (0: forward only; -1: as far as it widens, the paper)
    stall_periods: int = 50         # Follow periods on one active anchor before it is skipped
    odometry_check: bool = True     # track the car along the route's legs with odometry, C_WP's
                                    # answers as fixes, and drive toward the tracked anchor when
                                    # C_WP's waypoint disagrees (routes without legs: no effect)
    check_deg: float = 35.0         # ... by more than this angle
    scan_fix: bool = True           # the tracker also registers the car's lidar scan onto the
                                    # active and last visited anchors' taught scans (routes
                                    # that keep them: lidar, camera) from the tracked pose:
                                    # fixes that share none of C_WP's errors
    tracked_sure_m: float = 0.1     # a tracker this sure (position sigma; the scans pin it)
                                    # ends the route within goal_m of the goal, outvotes
                                    # C_WP's "here" toward an anchor a metre away and ...
    tracked_reach_m: float = 2.5    # ... refuses Dead reckoning an anchor it puts farther than
                                    # this (RE's look-alike anchors further on; 0: off), and ...
    tracked_goal_m: float = 0.5     # ... refuses C_WP's "at the goal" where it puts the goal
                                    # farther than this (near a wall C_WP's waypoint is short
                                    # with the goal still 0.7-0.9 m off; 0: off), and ...
    sure_follow_m: float | None = None  # ... keeps a car in Follow where RE doubts an
                                    # active anchor it puts within this (the scans place the
                                    # car; RE rates the view, not the place; 0: off; None:
                                    # the C_WP's own choice, its ``sure_follow_m`` attribute,
                                    # off where it has none: a C_WP whose waypoints come
                                    # from registration trusts the scans, a learned one
                                    # needs Dead reckoning to catch its wrong answers)
    pass_turn_deg: float = 180.0    # the tracker passes an anchor (near it, or just behind
                                    # the car) only where the car's heading is within this of
                                    # the taught one (180: off, the default; 90 mends teach
                                    # drives that turn on the spot but loses more routes
                                    # than it saves, docs/figures.md)
    merge_turn_m: float = 0.0       # the anchors of a teach drive's turn on the spot (a run of
    merge_turn_deg: float = 60.0    # hops each shorter than merge_turn_m that ends within it,
                                    # turned by merge_turn_deg or more) are left out of the
                                    # plans the planning study follows, the turn driven as one
                                    # manoeuvre (0: off, the default: it mends turns on the
                                    # spot in one house and loses routes in another,
                                    # docs/figures.md)
    legs_m: float = 2.0             # a hop without a leg (a join or goal link the scans did
                                    # not place) takes C_WP's answer from the anchor's own view
                                    # toward the next as its leg, where that waypoint is
                                    # shorter than this (0: off; the tracker then starts
                                    # again after such a hop)
    reverse_inside_turn: float = 0.1  # a C_WP waypoint inside the car's turning circle (its
                                    # radius widened by this share) is replaced by a point
                                    # straight behind: the car backs up until it can turn onto
                                    # it (negative: off)
    skip_inside_first: int = 0      # ... but an anchor among the route's first this many,
    skip_inside_m: float = 1.0      # this close, counts as passed when C_WP puts the next one
                                    # where the car can drive onto it (a car started beside its
                                    # route's first anchors would back up into ground its lidar
                                    # has not seen; later, behind it lies the way it came;
                                    # either 0: off, the default: an ablation, it trusts a
                                    # near answer that a learned C_WP gets wrong)
    turn_radius_m: float = field(default_factory=lambda: VehicleConfig().turn_radius())
                                    # the car's smallest turning radius
    manoeuvres: bool = True         # the expert's closed-loop check and manoeuvre search run
                                    # toward the waypoint on the map the car has sensed
                                    # (:mod:`topodrake.navigation.manoeuvre`)

    @classmethod
    def paper(cls) -> "FollowerConfig":
        """The paper's follower: its thresholds, its look-ahead of 5 anchors
        and its unbounded Dead reckoning window, with every rule of ours off
        (no distance condition on visits, no looser proximity close by, no
        separate goal test, no skipping of stalled anchors, no odometry
        check; the rule for a car that arrives at its held waypoint cannot
        be turned off and stays)."""
        return cls(p_search=0.92, visit_m=1e9, goal_m=1e9, p_visited_close=1.0, p_goal=0.65,
                   lookahead=5, dr_back_anchors=-1, dr_max_window=10 ** 6, stall_periods=10 ** 9,
                   odometry_check=False, scan_fix=False, tracked_sure_m=0.0, sure_follow_m=0.0,
                   reverse_inside_turn=-1.0, skip_inside_first=0, legs_m=0.0,
                   manoeuvres=False, search_first=False)

    def check(self) -> "FollowerConfig":
        if self.advance not in ("next", "proximity"):
            raise TopodrakeError(f"follower advance must be 'next' or 'proximity', got {self.advance!r}")
        for name in ("visit_m", "dr_arrive_m"):
            if not getattr(self, name) > 0:
                raise TopodrakeError(f"follower {name} must be > 0, got {getattr(self, name)}")
        for name in ("p_search", "p_follow", "p_visited", "p_visited_close", "p_goal", "p_near"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise TopodrakeError(f"follower {name} must be in [0, 1], got {v}")
        if not (np.isfinite(self.skip_inside_m) and self.skip_inside_m >= 0.0
                and self.skip_inside_first >= 0):
            raise TopodrakeError(f"follower skip_inside_m and skip_inside_first must be >= 0 "
                                 f"(0: off), got {self.skip_inside_m} and "
                                 f"{self.skip_inside_first}")
        if not self.turn_radius_m > 0:
            raise TopodrakeError(f"follower turn_radius_m must be > 0, got {self.turn_radius_m}")
        if not 0.0 < self.check_deg <= 180.0:
            raise TopodrakeError(f"follower check_deg must be in (0, 180], got {self.check_deg}")
        if not 0.0 < self.pass_turn_deg <= 180.0:
            raise TopodrakeError(f"follower pass_turn_deg must be in (0, 180] (180: off), got "
                                 f"{self.pass_turn_deg}")
        if not (np.isfinite(self.tracked_goal_m) and self.tracked_goal_m >= 0.0):
            raise TopodrakeError(f"follower tracked_goal_m must be >= 0 (0: off), got "
                                 f"{self.tracked_goal_m}")
        if self.sure_follow_m is not None and not (np.isfinite(self.sure_follow_m)
                                                   and self.sure_follow_m >= 0.0):
            raise TopodrakeError(f"follower sure_follow_m must be >= 0 (0: off) or None (the "
                                 f"C_WP's choice), got {self.sure_follow_m}")
        if not (self.tracked_reach_m >= 0.0 and self.tracked_sure_m >= 0.0):
            raise TopodrakeError(f"follower tracked_reach_m and tracked_sure_m must be >= 0 "
                                 f"(0: off), got {self.tracked_reach_m} and "
                                 f"{self.tracked_sure_m}")
        if not (np.isfinite(self.merge_turn_m) and self.merge_turn_m >= 0.0):
            raise TopodrakeError(f"follower merge_turn_m must be >= 0 (0: off), got "
                                 f"{self.merge_turn_m}")
        if not 0.0 <= self.merge_turn_deg <= 180.0:
            raise TopodrakeError(f"follower merge_turn_deg must be in [0, 180], got "
                                 f"{self.merge_turn_deg}")
        if not (np.isfinite(self.legs_m) and self.legs_m >= 0.0):
            raise TopodrakeError(f"follower legs_m must be >= 0 (0: off), got {self.legs_m}")
        if self.dr_back_anchors < -1:
            raise TopodrakeError(f"follower dr_back_anchors must be >= -1 (-1: unbounded), got "
                                 f"{self.dr_back_anchors}")
        for name in ("lookahead", "dr_max_iterations", "dr_widen_every", "dr_max_window",
                     "stall_periods"):
            if getattr(self, name) < 1:
                raise TopodrakeError(f"follower {name} must be >= 1, got {getattr(self, name)}")
        return self


def follower_fields(text: str | None) -> dict:
    """The FollowerConfig fields a ``--follower`` JSON object changes,
    checked (``{}`` for none); a bad one is refused in one line."""
    import json

    if not text:
        return {}
    try:
        fields = json.loads(text)
        if not isinstance(fields, dict):
            raise ValueError("not a JSON object")
        FollowerConfig(**fields).check()
    except (ValueError, TypeError) as e:
        raise TopodrakeError(f"--follower {text!r} is not a JSON object of FollowerConfig "
                             f"fields ({e})") from None
    return fields


@dataclass
class FollowerState:
    """Per-car follower state, arrays over N cars."""

    mode: np.ndarray                 # (N,) int: SEARCH ... FAILED
    active: np.ndarray               # (N,) int: active anchor (-1 = none yet)
    visited: np.ndarray              # (N,) int: last visited anchor (-1 = none)
    waypoint: np.ndarray             # (N, 2) world (odometry) frame: the last Follow waypoint
    dr_count: np.ndarray             # (N,) int: periods spent in Dead reckoning since Follow
    reason: np.ndarray               # (N,) int: why a follower failed (REASONS)
    best_p: np.ndarray               # (N,) float: RE of the last choice (for reports)
    stall: np.ndarray                # (N,) int: Follow periods on the same active anchor
    track: np.ndarray | None = None  # (N, S) float: a stateful C_WP's per-car state (S may be 0)
    ref: np.ndarray | None = None    # (N,) int: the anchor the car is tracked from (-1: not tracked)
    rel: np.ndarray | None = None    # (N, 3): the car's pose in that anchor's frame
    var: np.ndarray | None = None    # (N, 9): its covariance (3 x 3 over x, y, heading)
    odo: np.ndarray | None = None    # (N, 3): the odometry pose of the last period (NaN: none)
    misses: np.ndarray | None = None  # (N,) int: answers outvoted in a row
    seen: np.ndarray | None = None   # (N, 3): the odometry pose at which the last visited
                                     # anchor was marked visited (NaN: none)

    def __post_init__(self) -> None:
        n = len(self.mode)
        if self.track is None:
            self.track = np.zeros((n, 0))
        if self.ref is None:
            self.ref = np.full(n, -1, np.int64)
        if self.rel is None:
            self.rel = np.zeros((n, 3))
        if self.var is None:
            self.var = np.zeros((n, 9))
        if self.odo is None:
            self.odo = np.full((n, 3), np.nan)
        if self.misses is None:
            self.misses = np.zeros(n, np.int64)
        if self.seen is None:
            self.seen = np.full((n, 3), np.nan)

    @classmethod
    def initial(cls, n: int, track: np.ndarray | int = 0) -> "FollowerState":
        """``n`` followers before their first period; ``track``: the policy's
        initial per-car state (N, S) or its size S (zeros)."""
        t = np.zeros((n, int(track))) if np.ndim(track) == 0 else np.array(track, np.float64)
        if t.ndim != 2 or len(t) != n:
            raise TopodrakeError(f"a track state for {n} followers must be ({n}, S), got {t.shape}")
        return cls(np.full(n, SEARCH, np.int64), np.full(n, -1, np.int64),
                   np.full(n, -1, np.int64), np.full((n, 2), np.nan), np.zeros(n, np.int64),
                   np.zeros(n, np.int64), np.zeros(n), np.zeros(n, np.int64), t)

    def __len__(self) -> int:
        return len(self.mode)

    def take(self, idx) -> "FollowerState":
        return FollowerState(*(np.array(getattr(self, f)[idx]) for f in _FIELDS))

    def put(self, idx, other: "FollowerState") -> None:
        for f in _FIELDS:
            getattr(self, f)[idx] = getattr(other, f)

    def copy(self) -> "FollowerState":
        return self.take(slice(None))

    def to_vector(self) -> np.ndarray:
        """One car's state as STATE_SIZE floats (for a Drake discrete state; without ``track``)."""
        if len(self) != 1:
            raise ValueError("to_vector packs the state of one car")
        return np.array([self.mode[0], self.active[0], self.visited[0], *self.waypoint[0],
                         self.dr_count[0], self.reason[0], self.best_p[0], self.stall[0],
                         self.ref[0], *self.rel[0], *self.var[0], *self.odo[0], self.misses[0],
                         *self.seen[0]], np.float64)

    @classmethod
    def from_vector(cls, v) -> "FollowerState":
        v = np.asarray(v, np.float64)
        i = lambda x: np.array([int(round(x))], np.int64)   # noqa: E731
        return cls(i(v[0]), i(v[1]), i(v[2]), v[None, 3:5].copy(), i(v[5]), i(v[6]),
                   np.array([v[7]]), i(v[8]), None, i(v[9]), v[None, 10:13].copy(),
                   v[None, 13:22].copy(), v[None, 22:25].copy(), i(v[25]), v[None, 26:29].copy())


_FIELDS = ("mode", "active", "visited", "waypoint", "dr_count", "reason", "best_p", "stall",
           "track", "ref", "rel", "var", "odo", "misses", "seen")
STATE_SIZE = 29


@dataclass
class Answers:
    """The networks' answers for M (car, anchor) queries; NaN where not asked."""

    waypoint: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))   # (M, 2) car frame
    overlap: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))    # (M, 2)
    probability: np.ndarray = field(default_factory=lambda: np.zeros(0))     # (M,) RE
    heading: np.ndarray | None = None                                        # (M,) C_WP's heading
                                                                             # difference, if known


Evaluate = Callable[[np.ndarray, np.ndarray, bool, bool], Answers]


@dataclass
class StepOutput:
    """What a period's decision drives: the world-frame waypoint (N, 2)
    (NaN = stop) and the anchor whose context C_WP sees (-1 = none), with
    C_WP's answer toward that anchor from this period's observation (car-frame
    waypoint (N, 2), overlaps (N, 2), heading difference (N,); NaN where no
    anchor is followed), so that a consumer of the target need not ask again."""

    waypoint: np.ndarray
    target: np.ndarray
    local: np.ndarray | None = None
    overlap: np.ndarray | None = None
    heading: np.ndarray | None = None
    held: np.ndarray | None = None      # (N,) bool: the waypoint is the follower's own (Dead
                                        # reckoning, or the tracker's in Follow), not C_WP's


def _at_goal(proximity: np.ndarray, length: np.ndarray, cfg: FollowerConfig) -> np.ndarray:
    """C_WP's answers toward the route's last anchor that say the car is there."""
    return (proximity > cfg.p_goal) & (length < cfg.goal_m)


def _windows(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(row, anchor) pairs of the inclusive ranges lo[i]..hi[i] (empty when hi < lo)."""
    counts = np.maximum(hi - lo + 1, 0)
    rows = np.repeat(np.arange(len(lo)), counts)
    starts = np.repeat(lo - np.cumsum(counts) + counts, counts)
    return rows, starts + np.arange(counts.sum())


def _best_per_row(rows: np.ndarray, values: np.ndarray, n: int, prefer_last: bool = False
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Per row, the index into ``values`` of its maximum (-1 for rows without
    values) and that maximum (-inf). Ties go to the first value (the last
    with ``prefer_last``)."""
    best = np.full(n, -np.inf)
    arg = np.full(n, -1, np.int64)
    for m in range(len(values)):       # M is small (a window per car); keeps ties explicit
        r, v = rows[m], values[m]
        if v > best[r] or (prefer_last and v == best[r]):
            best[r] = v
            arg[r] = m
    return arg, best


def follower_step(state: FollowerState, n_anchors: np.ndarray, car_state: np.ndarray,
                  evaluate: Evaluate, config: FollowerConfig | None = None
                  ) -> tuple[FollowerState, StepOutput]:
    """One period for N followers (``state``, each on a route of
    ``n_anchors[i]`` anchors; ``car_state`` (N, 5) the held car states).
    ``evaluate(cars, anchors, cwp, re)`` answers for cars ``cars`` (rows of
    this batch) toward their anchors ``anchors``: C_WP's waypoint and
    overlaps when ``cwp``, RE's probability when ``re``. Returns the new
    state and what to drive; cars already REACHED or FAILED keep their
    state and get a NaN waypoint."""
    cfg = config or FollowerConfig()
    n = len(state)
    new = state.copy()
    car_state = np.asarray(car_state, np.float64).reshape(n, 5)
    # the car's pose along its route by odometry, checked by C_WP's answers
    frames = getattr(evaluate, "anchor_frames", None) if cfg.odometry_check else None
    if frames is not None:
        tracker.advance(new, car_state[:, :3], TRACKER)
    per = _Period(cfg, state, new, np.broadcast_to(np.asarray(n_anchors, np.int64), (n,)),
                  car_state, evaluate, frames, np.full((n, 2), np.nan), np.full((n, 2), np.nan),
                  np.full(n, np.nan), np.zeros(n, bool), np.zeros(n, bool))
    _search(per, np.flatnonzero(state.mode == SEARCH))
    _follow(per, np.flatnonzero(state.mode == FOLLOW))
    _dead_reckoning(per, np.flatnonzero(state.mode == DEAD_RECKONING))
    marked = (new.visited != state.visited) & (new.visited >= 0)
    new.seen[marked] = car_state[marked, :3]
    return new, _drive(per)


@dataclass
class _Period:
    """What one period's modes share: the settings, the state before and
    after, the inputs, and C_WP's answer toward each car's new active anchor."""

    cfg: FollowerConfig
    state: FollowerState              # before the period
    new: FollowerState                # after it (updated in place)
    n_anchors: np.ndarray             # (N,)
    car_state: np.ndarray             # (N, 5)
    evaluate: Evaluate
    frames: Callable | None           # the route tracker's anchor frames (None: no tracker)
    local: np.ndarray                 # (N, 2) C_WP's waypoint toward the new active anchor
    local_overlap: np.ndarray         # (N, 2) ... its overlaps
    local_heading: np.ndarray         # (N,) ... its heading difference
    have_wp: np.ndarray               # (N,) bool: that answer is known
    need: np.ndarray                  # (N,) bool: the car drives a fresh C_WP waypoint


def search_choice(evaluate: Evaluate, cars: np.ndarray, n_anchors: np.ndarray,
                  cfg: FollowerConfig) -> tuple[np.ndarray, np.ndarray]:
    """Search's choice for cars ``cars`` on routes of ``n_anchors`` (one per
    car): RE toward every anchor, the best becomes active (with
    ``search_first``, the first anchor where it passes ``p_search``).
    Returns (that anchor (-1: none), its probability (-inf: none)); Search
    passes where the probability is above ``p_search``. A replanning car's
    new route is taken only where it would (:mod:`~topodrake.navigation.replan`)."""
    cars = np.asarray(cars, np.int64)
    rows, anchors = _windows(np.zeros(cars.size, np.int64), np.asarray(n_anchors, np.int64) - 1)
    if not anchors.size:
        return np.full(cars.size, -1, np.int64), np.full(cars.size, -np.inf)
    p = evaluate(cars[rows], anchors, False, True).probability
    arg, best = _best_per_row(rows, p, cars.size)
    if cfg.search_first:
        first = np.flatnonzero(anchors == 0)            # each car's first anchor (rows in order)
        take = p[first] > cfg.p_search
        arg[rows[first[take]]], best[rows[first[take]]] = first[take], p[first[take]]
    return np.where(arg >= 0, anchors[np.maximum(arg, 0)], -1), best


def _search(per: _Period, s: np.ndarray) -> None:
    """Search (cars ``s``): :func:`search_choice` becomes active where it passes."""
    if not s.size:
        return
    cfg, new = per.cfg, per.new
    anchor, best = search_choice(per.evaluate, s, per.n_anchors[s], cfg)
    ok = best > cfg.p_search
    new.best_p[s] = np.where(np.isfinite(best), best, 0.0)
    got = s[ok]
    new.active[got] = anchor[ok]
    new.visited[got] = new.active[got] - 1
    new.mode[got] = FOLLOW
    per.need[got] = True
    new.mode[s[~ok]] = FAILED
    new.reason[s[~ok]] = SEARCH_FAILED


def _follow(per: _Period, f: np.ndarray) -> None:
    """Follow (cars ``f``): visits from proximity over the lookahead window, then RE
    toward the active anchor (or the one after it)."""
    if not f.size:
        return
    cfg, state, new, n_anchors, evaluate = per.cfg, per.state, per.new, per.n_anchors, per.evaluate
    # an anchor the car has not reached for stall_periods (an obstacle the
    # map never saw stands on it, or the car circles it) counts as visited,
    # but for the route's last one
    start = state.visited[f].copy()
    stuck = ((state.stall[f] >= cfg.stall_periods) & (state.active[f] < n_anchors[f] - 1)
             & (state.active[f] > start))
    start[stuck] = state.active[f][stuck]
    lo = start + 1
    hi = np.minimum(start + cfg.lookahead, n_anchors[f] - 1)
    rows, anchors = _windows(lo, hi)
    ans = evaluate(f[rows], anchors, True, False)
    if per.frames is not None:
        tracker.apply_answers(new, f[rows], anchors, ans.waypoint, ans.heading, per.frames, TRACKER)
    prox = ans.overlap.mean(axis=1)
    # close (a short waypoint) or already passed (the waypoint points backwards)
    length = np.hypot(*ans.waypoint.T)
    # (the route's last anchor, the goal, only when close: passing it is not arriving)
    passed = (ans.waypoint[:, 0] < 0.0) & (anchors < n_anchors[f[rows]] - 1)
    last = anchors == n_anchors[f[rows]] - 1
    # (the looser proximity only where no earlier anchor of the window looks nearer:
    # a C_WP that says "here" toward an anchor a room away is wrong)
    # (rows ascend and proximities lie in [0, 1]: shifting each row by 2 per row keeps
    # the running maximum within its row)
    nearest = prox >= np.maximum.accumulate(prox + 2.0 * rows) - 2.0 * rows
    there = (((prox > cfg.p_visited) & ((length < cfg.visit_m) | passed))
             | ((prox > cfg.p_visited_close) & (length < cfg.visit_m) & nearest))
    there = np.where(last, _at_goal(prox, length, cfg), there)
    # (not where a sure tracker puts the anchor a metre or more away, the goal more than
    # tracked_goal_m: C_WP's wrong "here")
    there &= ~np.where(last, _tracked_far(per, f[rows], anchors, cfg.tracked_goal_m),
                       _tracked_far(per, f[rows], anchors, TRACKED_PASS_M))
    visited = start.copy()
    for m in np.flatnonzero(there):
        visited[rows[m]] = max(visited[rows[m]], anchors[m])
    new.visited[f] = visited
    done = visited >= n_anchors[f] - 1
    new.mode[f[done]] = REACHED
    keep = ~done
    fk = f[keep]
    if fk.size:
        # the candidate to advance to: the one after the next (the paper's
        # rule) or the open anchor of highest proximity (the authors' code)
        nxt = visited[keep] + 1
        pos = np.full(len(f), -1, np.int64)
        pos[keep] = np.arange(fk.size)
        cand = np.full(fk.size, -1, np.int64)
        cand_prox = np.full(fk.size, -np.inf)
        for m in range(len(rows)):
            r = pos[rows[m]]
            if r < 0 or anchors[m] <= nxt[r]:
                continue
            if cfg.advance == "next" and anchors[m] == nxt[r] + 1:
                cand[r], cand_prox[r] = anchors[m], prox[m]
            elif cfg.advance == "proximity" and prox[m] > cand_prox[r]:
                cand[r], cand_prox[r] = anchors[m], prox[m]
        two = (cand >= 0) & (cand_prox > cfg.p_near)
        cars = np.concatenate([np.arange(fk.size), np.flatnonzero(two)])
        p = evaluate(fk[cars], np.concatenate([nxt, cand[two]]), False, True).probability
        p_next = p[:fk.size]
        p_cand = np.full(fk.size, -np.inf)
        p_cand[two] = p[fk.size:]
        advance = p_cand > cfg.p_follow
        new.active[fk] = np.where(advance, cand, nxt)
        p_active = np.where(advance, p_cand, p_next)
        new.best_p[fk] = p_active
        # C_WP's waypoint toward the active anchor, when it was in the window
        for m in range(len(rows)):
            r = pos[rows[m]]
            if r >= 0 and anchors[m] == new.active[fk[r]]:
                per.local[fk[r]] = ans.waypoint[m]
                per.local_overlap[fk[r]] = ans.overlap[m]
                if ans.heading is not None:
                    per.local_heading[fk[r]] = ans.heading[m]
                per.have_wp[fk[r]] = True
        same = (new.active[fk] == state.active[fk]) & (visited[keep] == state.visited[fk])
        new.stall[fk] = np.where(same, state.stall[fk] + 1, 0)
        lost = (p_active <= cfg.p_follow) & ~_tracked_near(per, fk, new.active[fk],
                                                           sure_follow_m(cfg, evaluate))
        new.mode[fk[lost]] = DEAD_RECKONING
        new.dr_count[fk[lost]] = 0
        per.need[fk] = True         # (entering Dead reckoning holds this period's waypoint)


def _dead_reckoning(per: _Period, d: np.ndarray) -> None:
    """Dead reckoning (cars ``d``): RE over a widening window; back to Follow above
    ``p_follow``."""
    if not d.size:
        return
    cfg, state, new, n_anchors = per.cfg, per.state, per.new, per.n_anchors
    car_state, evaluate = per.car_state, per.evaluate
    # (a car that entered Dead reckoning this period searches from the next one)
    grow = state.dr_count[d] // cfg.dr_widen_every
    nxt = state.visited[d] + 1
    if cfg.dr_back_anchors == 0:
        lo = nxt
        hi = np.minimum(nxt + cfg.lookahead - 1 + 2 * grow, n_anchors[d] - 1)
    else:
        # the paper's window widens both ways; ours reaches back dr_back_anchors at most
        back = grow if cfg.dr_back_anchors < 0 else np.minimum(grow, cfg.dr_back_anchors)
        lo = np.maximum(nxt - back, 0)
        hi = np.minimum(nxt + cfg.lookahead - 1 + grow, n_anchors[d] - 1)
    lo = np.maximum(lo, hi - cfg.dr_max_window + 1)
    rows, anchors = _windows(lo, hi)
    p = evaluate(d[rows], anchors, False, True).probability
    p = np.where(_tracked_far(per, d[rows], anchors, cfg.tracked_reach_m), 0.0, p)
    arg, best = _best_per_row(rows, p, d.size, prefer_last=True)
    new.best_p[d] = np.where(np.isfinite(best), best, 0.0)
    back = best > cfg.p_follow
    db = d[back]
    new.active[db] = anchors[arg[back]]
    new.visited[db] = new.active[db] - 1
    new.mode[db] = FOLLOW
    new.dr_count[db] = 0
    per.need[db] = True
    stay = d[~back]
    # the goal in sight ends the route in Dead reckoning too (RE often doubts the
    # last metre: the car stands on the goal in Dead reckoning)
    near = stay[new.visited[stay] + cfg.lookahead >= n_anchors[stay] - 1]
    if near.size:
        ans = evaluate(near, n_anchors[near] - 1, True, False)
        home = near[_at_goal(ans.overlap.mean(axis=1), np.hypot(*ans.waypoint.T), cfg)
                    & ~_tracked_far(per, near, n_anchors[near] - 1, cfg.tracked_goal_m)]
        new.visited[home] = n_anchors[home] - 1
        new.mode[home] = REACHED
        stay = stay[new.mode[stay] == DEAD_RECKONING]
    new.dr_count[stay] = state.dr_count[stay] + 1
    gave_up = stay[new.dr_count[stay] >= cfg.dr_max_iterations]
    new.mode[gave_up] = FAILED
    new.reason[gave_up] = DR_GAVE_UP
    # arrived at the held waypoint without RE's consent: a new leg from C_WP
    going = stay[new.mode[stay] == DEAD_RECKONING]
    arrived = going[np.hypot(*(state.waypoint[going] - car_state[going, :2]).T)
                    < cfg.dr_arrive_m]
    if arrived.size:
        leg = evaluate(arrived, new.active[arrived], True, False).waypoint
        # standing on the active anchor (a junction overshot): it counts as visited and
        # the leg goes to the next one, which RE may not see from this heading
        on = np.flatnonzero((np.hypot(*leg.T) < cfg.visit_m)
                            & (new.active[arrived] < n_anchors[arrived] - 1)
                            & ~_tracked_far(per, arrived, new.active[arrived], TRACKED_PASS_M))
        if on.size:
            cars_on = arrived[on]
            new.visited[cars_on] = new.active[cars_on]
            new.active[cars_on] += 1
            leg[on] = evaluate(cars_on, new.active[cars_on], True, False).waypoint
        new.waypoint[arrived] = car_to_world(leg[:, None], car_state[arrived])[:, 0]


def _drive(per: _Period) -> StepOutput:
    """C_WP toward active anchors not asked yet, and the waypoints to drive."""
    cfg, new, car_state, evaluate = per.cfg, per.new, per.car_state, per.evaluate
    local, local_overlap, local_heading = per.local, per.local_overlap, per.local_heading
    have_wp, need, frames, n_anchors = per.have_wp, per.need, per.frames, per.n_anchors
    n = len(new)
    target = np.full(n, -1, np.int64)
    moving = (new.mode == FOLLOW) | (new.mode == DEAD_RECKONING)
    ask = np.flatnonzero(need & ~have_wp & moving)
    if ask.size:
        asked = evaluate(ask, new.active[ask], True, False)
        local[ask] = asked.waypoint
        local_overlap[ask] = asked.overlap
        if asked.heading is not None:
            local_heading[ask] = asked.heading
    fresh = np.flatnonzero(need & moving)
    if fresh.size:
        new.waypoint[fresh] = car_to_world(local[fresh, None], car_state[fresh])[:, 0]
    follow = np.flatnonzero(new.mode == FOLLOW)
    if frames is not None:
        scans = getattr(evaluate, "scan_fixes", None) if cfg.scan_fix else None
        tracked = _check_waypoints(new, follow, np.flatnonzero(new.mode == DEAD_RECKONING),
                                   local, car_state, n_anchors, frames, cfg, scans)
        follow = np.setdiff1d(follow, tracked)
    target[follow] = new.active[follow]
    drive = np.full((n, 2), np.nan)
    drive[new.mode == FOLLOW] = new.waypoint[new.mode == FOLLOW]
    dr = np.flatnonzero(new.mode == DEAD_RECKONING)
    drive[dr] = new.waypoint[dr]           # held (C_WP is not asked: target stays -1)
    off = target < 0
    local[off], local_overlap[off], local_heading[off] = np.nan, np.nan, np.nan
    held = off & ((new.mode == FOLLOW) | (new.mode == DEAD_RECKONING))
    if cfg.reverse_inside_turn >= 0:
        answer = np.flatnonzero((new.mode == FOLLOW) & ~held)
        _skip_inside_turn(per, answer, drive, target)
        drive[answer], backed = back_up_inside_turn(drive[answer], car_state[answer], cfg)
        held[answer[backed]] = True             # the follower's own waypoint now
    return StepOutput(drive, target, local, local_overlap, local_heading, held)


def _skip_inside_turn(per: _Period, cars: np.ndarray, drive: np.ndarray, target: np.ndarray
                      ) -> None:
    """Cars among ``cars`` whose active anchor is one of the route's first
    ``skip_inside_first``, whose answer toward it lies inside the turning
    circle within ``skip_inside_m``, and whose answer toward the
    next anchor lies ahead outside it: the near anchor counts as visited and
    they drive the next answer (in place)."""
    cfg, new = per.cfg, per.new
    if cfg.skip_inside_m <= 0 or cfg.skip_inside_first <= 0 or not cars.size:
        return                                  # off (the default): no work each period
    cars = cars[new.active[cars] < cfg.skip_inside_first]
    local = per.local[cars]
    near = np.isfinite(local).all(axis=1) & (np.hypot(*local.T) < cfg.skip_inside_m) \
        & inside_turn(np.nan_to_num(local), cfg.turn_radius_m, cfg.reverse_inside_turn) \
        & (new.active[cars] < per.n_anchors[cars] - 1)
    c = cars[near]
    if not c.size:
        return
    ans = per.evaluate(c, new.active[c] + 1, True, False)
    w = np.asarray(ans.waypoint, np.float64)
    ok = np.isfinite(w).all(axis=1) & (w[:, 0] > 0.0) \
        & ~inside_turn(np.nan_to_num(w), cfg.turn_radius_m, cfg.reverse_inside_turn)
    c, w = c[ok], w[ok]
    if not c.size:
        return
    new.visited[c] = new.active[c]
    new.active[c] += 1
    new.stall[c] = 0
    per.local[c] = w
    per.local_overlap[c] = ans.overlap[ok]
    if ans.heading is not None:
        per.local_heading[c] = np.asarray(ans.heading)[ok]
    target[c] = new.active[c]
    drive[c] = new.waypoint[c] = car_to_world(w[:, None], per.car_state[c])[:, 0]


BACK_UP_M = 1.0     # how far behind the car the backing-up waypoint lies


def inside_turn(local: np.ndarray, radius: float, widen: float = 0.0) -> np.ndarray:
    """Car-frame points (N, 2) inside the car's turning circle on their side
    (radius widened by the share ``widen``): driving forward at full lock
    the car circles them without coming onto them."""
    side = np.where(local[:, 1] >= 0.0, 1.0, -1.0)
    return np.hypot(local[:, 0], local[:, 1] - side * radius) < radius * (1.0 + widen)


def back_up_inside_turn(waypoint: np.ndarray, car_state: np.ndarray, cfg: FollowerConfig
                        ) -> tuple[np.ndarray, np.ndarray]:
    """World waypoints (N, 2) with those inside the car's turning circle
    (:func:`inside_turn`) replaced by a point ``BACK_UP_M`` straight behind
    the car: it reverses until it can reach them driving forward (a near
    C_WP answer far off the heading, or an anchor beside the car, which it
    would otherwise circle), and which were replaced (N,)."""
    out = np.array(waypoint, np.float64)
    if not len(out):
        return out, np.zeros(0, bool)
    local = world_to_car(out[:, None], car_state)[:, 0]
    inside = np.isfinite(local).all(axis=1) & inside_turn(local, cfg.turn_radius_m,
                                                          cfg.reverse_inside_turn)
    if inside.any():
        behind = np.tile([[-BACK_UP_M, 0.0]], (int(inside.sum()), 1))
        out[inside] = car_to_world(behind[:, None], car_state[inside])[:, 0]
    return out, inside


TRACKER = tracker.TrackerConfig()


def _check_waypoints(new: FollowerState, follow: np.ndarray, dead: np.ndarray, local: np.ndarray,
                     car_state: np.ndarray, n_anchors: np.ndarray, frames,
                     cfg: FollowerConfig, scans=None) -> np.ndarray:
    """Returns the Follow cars that drive the tracker's waypoint. Tracked cars: an active anchor (but the goal) that the tracker puts
    behind the car or within ``visit_m`` counts as visited and the next one
    becomes active; in Follow, a C_WP waypoint more than ``check_deg`` off
    the tracked pursuit point (on the taught poses into the active anchor)
    is replaced by that point; in Dead reckoning the car drives to the
    pursuit point instead of the held waypoint. ``scans``: the Evaluator's
    scan fixes (:func:`tracker.apply_scans`), applied first. A sure tracker (position
    sigma under ``tracked_sure_m``) within ``goal_m`` of the goal ends the
    route (``reached``)."""
    moving = np.concatenate([follow, dead])
    tracker.follow_visits(new, moving, frames)
    if scans is not None:
        tracker.apply_scans(new, moving, frames, scans, TRACKER)
    q, known, aim = tracker.tracked_anchor(new, moving, new.active[moving], frames)
    dist = np.hypot(q[:, 0], q[:, 1])
    aligned = np.abs(wrap(q[:, 2])) <= np.radians(cfg.pass_turn_deg)
    passed = known & aligned \
        & ((dist < cfg.visit_m) | ((q[:, 0] < 0.0) & (dist < TRACKED_PASS_M))) \
        & (new.active[moving] < n_anchors[moving] - 1)
    if passed.any():
        c = moving[passed]
        new.visited[c] = new.active[c]
        new.active[c] += 1
        new.stall[c] = 0
        tracker.follow_visits(new, c, frames)
        q[passed], known[passed], aim[passed] = tracker.tracked_anchor(new, c, new.active[c],
                                                                       frames)
        dist = np.hypot(q[:, 0], q[:, 1])
    # the goal: a sure tracker within goal_m of it ends the route
    sure = known & (_position_sigma(new.var[moving]) < cfg.tracked_sure_m)
    home = sure & (dist < cfg.goal_m) & (new.active[moving] == n_anchors[moving] - 1)
    if home.any():
        c = moving[home]
        new.visited[c] = new.active[c]
        new.mode[c] = REACHED
    w = local[moving]
    cos = (w * aim).sum(axis=1) / np.maximum(np.hypot(*w.T) * np.hypot(*aim.T), 1e-9)
    off = ~(cos >= np.cos(np.radians(cfg.check_deg)))          # NaN answers count as off
    in_follow = np.arange(len(moving)) < len(follow)
    use = known & (dist > 0.3) & (off | ~in_follow | passed) & ~home
    if use.any():
        c = moving[use]
        new.waypoint[c] = car_to_world(aim[use, None], car_state[c])[:, 0]
    return moving[(use | passed | home) & in_follow]


TRACKED_PASS_M = 1.0    # an anchor the tracker puts behind the car and this close is passed


def _tracked_far(per: _Period, cars: np.ndarray, anchors: np.ndarray, reach_m: float
                 ) -> np.ndarray:
    """(M,) whether a sure tracker (position sigma under ``tracked_sure_m``
    after the last period's scan fixes: C_WP's answers hold it at their
    floor) puts each car's anchor farther than ``reach_m``; none where the
    route has no legs or the rule is off (``tracked_sure_m`` or ``reach_m`` 0)."""
    if reach_m <= 0:
        return np.zeros(len(cars), bool)
    return _sure_distance(per, cars, anchors) > reach_m


def sure_follow_m(cfg: FollowerConfig, evaluate) -> float:
    """The reach within which a sure tracker keeps a doubted car in Follow:
    ``cfg.sure_follow_m``, or where that is None the C_WP's own choice (the
    evaluator's ``sure_follow_m``, from its policy; 0, off, where it has none)."""
    if cfg.sure_follow_m is not None:
        return float(cfg.sure_follow_m)
    return float(getattr(evaluate, "sure_follow_m", 0.0) or 0.0)


def _tracked_near(per: _Period, cars: np.ndarray, anchors: np.ndarray, reach_m: float
                  ) -> np.ndarray:
    """(M,) whether a sure tracker puts each car's anchor within ``reach_m``
    (none where the route has no legs or the rule is off)."""
    if reach_m <= 0:
        return np.zeros(len(cars), bool)
    return _sure_distance(per, cars, anchors) <= reach_m


def _sure_distance(per: _Period, cars: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """(M,) the distance a sure tracker puts between each car and its anchor
    (NaN where it is not sure or does not know, or the route has no legs)."""
    out = np.full(len(cars), np.nan)
    if per.frames is None or per.cfg.tracked_sure_m <= 0:
        return out
    q, known, _ = tracker.tracked_anchor(per.new, cars, anchors, per.frames)
    sure = known & (_position_sigma(per.state.var[cars]) < per.cfg.tracked_sure_m)
    out[sure] = np.hypot(q[sure, 0], q[sure, 1])
    return out


def _position_sigma(var: np.ndarray) -> np.ndarray:
    """The larger position sigma (M,) of tracker covariances ``var`` (M, 9)."""
    return np.sqrt(np.maximum(var[:, 0], var[:, 4]))


def outcome_of(state: FollowerState) -> list[str]:
    """"reached", the failure reason, or the mode of followers still running."""
    out = []
    for m, r in zip(state.mode, state.reason):
        out.append("reached" if m == REACHED else REASONS[r] if m == FAILED else MODES[m])
    return out
