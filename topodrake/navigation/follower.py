"""The follower state machine (Search, Follow, Dead reckoning) as batched functions.

:func:`follower_step` advances N followers by one control period, each on
its own route of ``n_anchors[i]`` anchors. The networks are reached through
an ``evaluate(cars, anchors, cwp, re)`` callback
(:class:`~topodrake.navigation.evaluate.Evaluator`): the Drake
``FollowerFsm`` calls this logic with a batch of one, the navigation engine
with N cars. Each period, by mode (:class:`Mode`):

* **Search** (the first period): RE toward every anchor; the best above
  ``p_search`` (with ``search_first``, the first anchor where RE passes)
  becomes active and the car follows; otherwise it fails (``search_failed``).
* **Follow**: :func:`_visits` marks anchors of the ``lookahead`` window
  visited by C_WP's proximity (the mean of its two predicted overlaps) and
  waypoint length (:class:`VisitConfig`); the route's last anchor visited
  ends it (``reached``). :func:`_advance` makes the next unvisited anchor
  active, or the one after it (``advance``). :func:`_lost` sends cars whose
  RE toward the active anchor is at most ``p_follow`` to Dead reckoning.
* **Dead reckoning**: the car drives to the held waypoint (odometry frame)
  while RE is asked over a window of anchors that widens with time
  (:class:`DeadReckoningConfig`); the best above ``p_follow`` returns it to
  Follow; it fails after ``dr_max_iterations`` periods
  (``dead_reckoning_gave_up``).

On routes with legs the route tracker (:mod:`topodrake.navigation.tracker`,
``FollowerConfig.tracker``) checks C_WP's waypoints, passes anchors and
ends routes; a C_WP waypoint inside the car's turning circle is driven as a
point behind the car (``reverse_inside_turn``). Each rule's reason and
measured effect: docs/follower.md; :meth:`FollowerConfig.paper` turns the
rules that are not the paper's off.

The state (:class:`FollowerState`) is a handful of numbers per car, and
``track``, a stateful C_WP's per-car floats, which the follower carries for
the executors and never reads.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field, fields, is_dataclass, replace
from typing import Callable

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.navigation import tracker
from topodrake.navigation.manoeuvre import ManoeuvreConfig
from topodrake.navigation.tracker import TrackerConfig
from topodrake.vehicle import VehicleConfig, car_to_world, world_to_car


class Mode(enum.IntEnum):
    """A follower's mode (the values are stored in Drake state and arrays)."""

    SEARCH = 0
    FOLLOW = 1
    DEAD_RECKONING = 2
    REACHED = 3
    FAILED = 4


class Reason(enum.IntEnum):
    """Why a follower failed (``NONE`` while it has not)."""

    NONE = 0
    SEARCH_FAILED = 1
    DEAD_RECKONING_GAVE_UP = 2


MODES = tuple(m.name.lower() for m in Mode)      # "search", ..., "failed": names by value
REASONS = ("", "search_failed", "dead_reckoning_gave_up")


@dataclass
class VisitConfig:
    """When C_WP's answers mark an anchor visited and the goal reached.
    Proximity: the mean of C_WP's two predicted overlaps (0-1)."""

    p_visited: float = 0.65         # proximity that marks an anchor visited ...
    visit_m: float = 0.35           # ... where C_WP's waypoint toward it is shorter than this
                                    # (m) or points backwards (but for the goal)
    p_visited_close: float = 0.3    # proximity enough within visit_m where no earlier anchor
                                    # of the window looks nearer
    p_goal: float = 0.75            # proximity the route's last anchor (the goal) needs ...
    goal_m: float = 0.35            # ... with C_WP's waypoint toward it shorter than this (m)

    def check(self) -> "VisitConfig":
        if not self.visit_m > 0:
            raise TopodrakeError(f"follower visit_m must be > 0, got {self.visit_m}")
        for name in ("p_visited", "p_visited_close", "p_goal"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise TopodrakeError(f"follower {name} must be in [0, 1], got {v}")
        return self


@dataclass
class DeadReckoningConfig:
    """Dead reckoning: RE's window of anchors, arrival at the held waypoint, giving up."""

    dr_max_iterations: int = 200    # periods in Dead reckoning before the car gives up
    dr_widen_every: int = 10        # periods per widening of the window by one anchor each way
    dr_max_window: int = 15         # anchors asked per period at most
    dr_arrive_m: float = 0.3        # within this of the held waypoint (m), C_WP gives the next
    dr_back_anchors: int = 1        # anchors the window reaches back at most (0: forward only;
                                    # -1: as far as it widens, the paper's)

    def check(self) -> "DeadReckoningConfig":
        if not self.dr_arrive_m > 0:
            raise TopodrakeError(f"follower dr_arrive_m must be > 0, got {self.dr_arrive_m}")
        if self.dr_back_anchors < -1:
            raise TopodrakeError(f"follower dr_back_anchors must be >= -1 (-1: unbounded), got "
                                 f"{self.dr_back_anchors}")
        for name in ("dr_max_iterations", "dr_widen_every", "dr_max_window"):
            if getattr(self, name) < 1:
                raise TopodrakeError(f"follower {name} must be >= 1, got {getattr(self, name)}")
        return self


@dataclass
class FollowerConfig:
    """The follower's settings, grouped by who reads them. The defaults are
    ours; :meth:`paper` gives the paper's follower. Build one from study
    overrides with :meth:`from_dict`."""

    p_search: float = 0.8           # RE (0-1) Search needs toward the anchor it takes
    search_first: bool = True       # Search takes the route's first anchor where RE passes
                                    # p_search toward it (off: the best anchor)
    p_follow: float = 0.92          # RE toward the active anchor that keeps a car following
    p_near: float = 0.6             # proximity the anchor after the next needs to become active
    advance: str = "next"           # the advance candidate: "next", the anchor after the next
                                    # (the paper's); "proximity", the window's anchor of
                                    # highest proximity (its authors' code)
    lookahead: int = 2              # anchors after the last visited one that Follow asks about
    stall_periods: int = 50         # Follow periods on one active anchor (but the goal) after
                                    # which it counts as visited
    visit: VisitConfig = field(default_factory=VisitConfig)
    dead_reckoning: DeadReckoningConfig = field(default_factory=DeadReckoningConfig)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    reverse_inside_turn: float = 0.1  # a C_WP waypoint in Follow inside the car's turning
                                    # circle (its radius widened by this share) is replaced by
                                    # a point BACK_UP_M straight behind the car (negative: off)
    turn_radius_m: float = field(default_factory=lambda: VehicleConfig().turn_radius())
                                    # the car's smallest turning radius (m)
    manoeuvres: bool = True         # the expert's check and manoeuvre search run toward the
                                    # follower's waypoint on the map the car sensed ...
    manoeuvre: ManoeuvreConfig = field(default_factory=ManoeuvreConfig)   # ... with these

    @classmethod
    def paper(cls) -> "FollowerConfig":
        """The paper's follower: its thresholds, its look-ahead of 5 anchors
        and its unbounded Dead reckoning window, with every rule of ours off
        (the rule for a car that arrives at its held waypoint cannot be
        turned off and stays)."""
        return cls.from_dict({
            "p_search": 0.92, "visit_m": 1e9, "goal_m": 1e9, "p_visited_close": 1.0,
            "p_goal": 0.65, "lookahead": 5, "dr_back_anchors": -1, "dr_max_window": 10 ** 6,
            "stall_periods": 10 ** 9, "odometry_check": False, "scan_fix": False,
            "tracked_sure_m": 0.0, "sure_follow_m": 0.0, "reverse_inside_turn": -1.0,
            "legs_m": 0.0, "manoeuvres": False, "search_first": False})

    @classmethod
    def from_dict(cls, overrides: dict | None = None) -> "FollowerConfig":
        """The defaults changed by ``overrides`` (None: none), checked.
        Keys are fields, nested as the config is (``{"tracker":
        {"scan_fix": false}}``) or, for a field of a nested config, flat
        (``{"scan_fix": false}``: every field name is unique in the tree).
        An unknown or ambiguous key raises TopodrakeError naming it."""
        return _changed(cls(), {} if overrides is None else overrides, "follower").check()

    def check(self) -> "FollowerConfig":
        """Refuses a bad setting in one line (TopodrakeError naming it)."""
        if self.advance not in ("next", "proximity"):
            raise TopodrakeError(f"follower advance must be 'next' or 'proximity', got "
                                 f"{self.advance!r}")
        for name in ("p_search", "p_follow", "p_near"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise TopodrakeError(f"follower {name} must be in [0, 1], got {v}")
        if not self.turn_radius_m > 0:
            raise TopodrakeError(f"follower turn_radius_m must be > 0, got {self.turn_radius_m}")
        for name in ("lookahead", "stall_periods"):
            if getattr(self, name) < 1:
                raise TopodrakeError(f"follower {name} must be >= 1, got {getattr(self, name)}")
        for name, kind in (("visit", VisitConfig), ("dead_reckoning", DeadReckoningConfig),
                           ("tracker", TrackerConfig), ("manoeuvre", ManoeuvreConfig)):
            if not isinstance(getattr(self, name), kind):
                raise TopodrakeError(f"follower {name} must be a {kind.__name__}, got "
                                     f"{getattr(self, name)!r}")
        self.visit.check()
        self.dead_reckoning.check()
        self.tracker.check()
        return self


def _changed(obj, overrides, where: str):
    """The dataclass ``obj`` with ``overrides`` (a dict) applied: a key of
    ``obj``'s own fields (for a nested dataclass, a dict changes its fields,
    an instance replaces it), else the one field of that name in a nested
    dataclass."""
    if not isinstance(overrides, dict):
        raise TopodrakeError(f"{where} settings must be a mapping of fields, got {overrides!r}")
    own = {f.name for f in fields(obj)}
    tree: dict = {}
    for key, value in overrides.items():
        if key in own:
            path = (key,)
        else:
            paths = _nested_fields(obj).get(key, [])
            if len(paths) != 1:
                nested = ", ".join(".".join(p) for p in paths)
                what = f"is ambiguous: give it nested as one of {nested}" if paths else \
                    "names no setting"
                raise TopodrakeError(f"{where} setting {key!r} {what}")
            path = paths[0]
        node = tree
        for part in path[:-1]:
            node = node.setdefault(part, {})
        if isinstance(value, dict) and isinstance(node.get(path[-1]), dict):
            node[path[-1]].update(value)
        else:
            node[path[-1]] = dict(value) if isinstance(value, dict) else value
    changes = {}
    for name, value in tree.items():
        current = getattr(obj, name)
        nested = is_dataclass(current) and not is_dataclass(value)
        changes[name] = _changed(current, value, f"{where}.{name}") if nested else value
    return replace(obj, **changes)


def _nested_fields(obj, prefix: tuple = ()) -> dict[str, list[tuple[str, ...]]]:
    """Field name -> the paths (tuples of names) of the fields of that name
    in the dataclasses nested in ``obj`` (not ``obj``'s own)."""
    out: dict[str, list[tuple[str, ...]]] = {}
    for f in fields(obj):
        value = getattr(obj, f.name)
        if not is_dataclass(value):
            continue
        for g in fields(value):
            out.setdefault(g.name, []).append(prefix + (f.name, g.name))
        for name, paths in _nested_fields(value, prefix + (f.name,)).items():
            out.setdefault(name, []).extend(paths)
    return out


def follower_fields(text: str | None) -> dict:
    """The follower settings a ``--follower`` JSON object changes
    (:meth:`FollowerConfig.from_dict`'s keys), checked (``{}`` for none); a
    bad one is refused in one line."""
    import json

    if not text:
        return {}
    try:
        overrides = json.loads(text)
        if not isinstance(overrides, dict):
            raise ValueError("not a JSON object")
    except ValueError as e:
        raise TopodrakeError(f"--follower {text!r} is not a JSON object of FollowerConfig "
                             f"fields ({e})") from None
    FollowerConfig.from_dict(overrides)
    return overrides


@dataclass
class FollowerState:
    """Per-car follower state, arrays over N cars."""

    mode: np.ndarray                 # (N,) int: a Mode
    active: np.ndarray               # (N,) int: active anchor (-1 = none yet)
    visited: np.ndarray              # (N,) int: last visited anchor (-1 = none)
    waypoint: np.ndarray             # (N, 2) world (odometry) frame: the last Follow waypoint
    dr_count: np.ndarray             # (N,) int: periods spent in Dead reckoning since Follow
    reason: np.ndarray               # (N,) int: why a follower failed (a Reason)
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
        return cls(np.full(n, Mode.SEARCH, np.int64), np.full(n, -1, np.int64),
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
    return (proximity > cfg.visit.p_goal) & (length < cfg.visit.goal_m)


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
    ``n_anchors[i]`` anchors; ``car_state`` (N, 5) the held car states in
    the odometry frame). ``evaluate(cars, anchors, cwp, re)`` answers for
    cars ``cars`` (rows of this batch) toward their anchors ``anchors``:
    C_WP's waypoint and overlaps when ``cwp``, RE's probability when ``re``.
    Returns the new state and what to drive; cars already REACHED or FAILED
    keep their state and get a NaN waypoint."""
    cfg = config or FollowerConfig()
    n = len(state)
    new = state.copy()
    car_state = np.asarray(car_state, np.float64).reshape(n, 5)
    frames = getattr(evaluate, "anchor_frames", None) if cfg.tracker.odometry_check else None
    if frames is not None:
        tracker.advance(new, car_state[:, :3], cfg.tracker)
    per = _Period(cfg, state, new, np.broadcast_to(np.asarray(n_anchors, np.int64), (n,)),
                  car_state, evaluate, frames, np.full((n, 2), np.nan), np.full((n, 2), np.nan),
                  np.full(n, np.nan), np.zeros(n, bool), np.zeros(n, bool))
    _search(per, np.flatnonzero(state.mode == Mode.SEARCH))
    _follow(per, np.flatnonzero(state.mode == Mode.FOLLOW))
    _dead_reckoning(per, np.flatnonzero(state.mode == Mode.DEAD_RECKONING))
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
    new.mode[got] = Mode.FOLLOW
    per.need[got] = True
    new.mode[s[~ok]] = Mode.FAILED
    new.reason[s[~ok]] = Reason.SEARCH_FAILED


@dataclass
class _Window:
    """Follow's window of (car row, anchor) queries and C_WP's answers to them."""

    rows: np.ndarray                  # (M,) rows into the Follow cars, ascending
    anchors: np.ndarray               # (M,)
    answers: Answers
    proximity: np.ndarray             # (M,) the mean of each answer's two overlaps


def _follow(per: _Period, f: np.ndarray) -> None:
    """Follow (cars ``f``): visits over the lookahead window, then the
    advance to the next active anchor, and cars lost to Dead reckoning."""
    if not f.size:
        return
    window = _visits(per, f)
    done = per.new.visited[f] >= per.n_anchors[f] - 1
    per.new.mode[f[done]] = Mode.REACHED
    keep = ~done
    if keep.any():
        p_active = _advance(per, f, keep, window)
        _lost(per, f[keep], p_active)


def _visits(per: _Period, f: np.ndarray) -> _Window:
    """Marks the anchors Follow cars ``f`` have visited (``new.visited``):
    over the ``lookahead`` anchors after the last visited one (after the
    active one where that stalled ``stall_periods``, but for the goal), the
    farthest that C_WP's answer puts close (:class:`VisitConfig`; the goal
    by :func:`_at_goal`) and a sure tracker does not put far. Returns the
    window and its answers."""
    cfg, state, new, n_anchors, evaluate = per.cfg, per.state, per.new, per.n_anchors, per.evaluate
    vc = cfg.visit
    start = state.visited[f].copy()
    stuck = ((state.stall[f] >= cfg.stall_periods) & (state.active[f] < n_anchors[f] - 1)
             & (state.active[f] > start))
    start[stuck] = state.active[f][stuck]
    lo = start + 1
    hi = np.minimum(start + cfg.lookahead, n_anchors[f] - 1)
    rows, anchors = _windows(lo, hi)
    ans = evaluate(f[rows], anchors, True, False)
    if per.frames is not None:
        tracker.apply_answers(new, f[rows], anchors, ans.waypoint, ans.heading, per.frames,
                              cfg.tracker)
    prox = ans.overlap.mean(axis=1)
    length = np.hypot(*ans.waypoint.T)
    # passed: the waypoint points backwards (the goal only counts when close)
    passed = (ans.waypoint[:, 0] < 0.0) & (anchors < n_anchors[f[rows]] - 1)
    last = anchors == n_anchors[f[rows]] - 1
    # no earlier anchor of the row looks nearer (rows ascend and proximities lie in
    # [0, 1]: shifting each row by 2 per row keeps the running maximum within its row)
    nearest = prox >= np.maximum.accumulate(prox + 2.0 * rows) - 2.0 * rows
    there = (((prox > vc.p_visited) & ((length < vc.visit_m) | passed))
             | ((prox > vc.p_visited_close) & (length < vc.visit_m) & nearest))
    there = np.where(last, _at_goal(prox, length, cfg), there)
    there &= ~np.where(last, _tracked_far(per, f[rows], anchors, cfg.tracker.tracked_goal_m),
                       _tracked_far(per, f[rows], anchors, TRACKED_PASS_M))
    visited = start.copy()
    for m in np.flatnonzero(there):
        visited[rows[m]] = max(visited[rows[m]], anchors[m])
    new.visited[f] = visited
    return _Window(rows, anchors, ans, prox)


def _advance(per: _Period, f: np.ndarray, keep: np.ndarray, window: _Window) -> np.ndarray:
    """The active anchor of Follow cars ``f[keep]`` (not at the goal): the
    next unvisited one, or the advance candidate (``advance``) where its
    proximity is above ``p_near`` and RE toward it above ``p_follow``.
    Keeps C_WP's answer toward it where the window asked, counts stalled
    periods, and returns RE toward the active anchors."""
    cfg, state, new, evaluate = per.cfg, per.state, per.new, per.evaluate
    rows, anchors, ans, prox = window.rows, window.anchors, window.answers, window.proximity
    fk = f[keep]
    nxt = new.visited[fk] + 1
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
    for m in range(len(rows)):
        r = pos[rows[m]]
        if r >= 0 and anchors[m] == new.active[fk[r]]:
            per.local[fk[r]] = ans.waypoint[m]
            per.local_overlap[fk[r]] = ans.overlap[m]
            if ans.heading is not None:
                per.local_heading[fk[r]] = ans.heading[m]
            per.have_wp[fk[r]] = True
    same = (new.active[fk] == state.active[fk]) & (new.visited[fk] == state.visited[fk])
    new.stall[fk] = np.where(same, state.stall[fk] + 1, 0)
    per.need[fk] = True         # (a car entering Dead reckoning holds this period's waypoint)
    return p_active


def _lost(per: _Period, fk: np.ndarray, p_active: np.ndarray) -> None:
    """Follow cars ``fk`` whose RE toward the active anchor ``p_active`` is
    at most ``p_follow`` enter Dead reckoning, but where a sure tracker puts
    that anchor within ``sure_follow_m``."""
    cfg, new = per.cfg, per.new
    lost = (p_active <= cfg.p_follow) & ~_tracked_near(per, fk, new.active[fk],
                                                       sure_follow_m(cfg, per.evaluate))
    new.mode[fk[lost]] = Mode.DEAD_RECKONING
    new.dr_count[fk[lost]] = 0


def _dead_reckoning(per: _Period, d: np.ndarray) -> None:
    """Dead reckoning (cars ``d``): RE over a widening window; back to
    Follow above ``p_follow``; the goal in sight ends the route; a car at
    its held waypoint takes C_WP's next one; giving up after
    ``dr_max_iterations`` periods."""
    if not d.size:
        return
    cfg, state, new, n_anchors = per.cfg, per.state, per.new, per.n_anchors
    car_state, evaluate = per.car_state, per.evaluate
    dr = cfg.dead_reckoning
    # (a car that entered Dead reckoning this period searches from the next one)
    grow = state.dr_count[d] // dr.dr_widen_every
    nxt = state.visited[d] + 1
    if dr.dr_back_anchors == 0:
        lo = nxt
        hi = np.minimum(nxt + cfg.lookahead - 1 + 2 * grow, n_anchors[d] - 1)
    else:
        back = grow if dr.dr_back_anchors < 0 else np.minimum(grow, dr.dr_back_anchors)
        lo = np.maximum(nxt - back, 0)
        hi = np.minimum(nxt + cfg.lookahead - 1 + grow, n_anchors[d] - 1)
    lo = np.maximum(lo, hi - dr.dr_max_window + 1)
    rows, anchors = _windows(lo, hi)
    p = evaluate(d[rows], anchors, False, True).probability
    p = np.where(_tracked_far(per, d[rows], anchors, cfg.tracker.tracked_reach_m), 0.0, p)
    arg, best = _best_per_row(rows, p, d.size, prefer_last=True)
    new.best_p[d] = np.where(np.isfinite(best), best, 0.0)
    back = best > cfg.p_follow
    db = d[back]
    new.active[db] = anchors[arg[back]]
    new.visited[db] = new.active[db] - 1
    new.mode[db] = Mode.FOLLOW
    new.dr_count[db] = 0
    per.need[db] = True
    stay = d[~back]
    # the goal in sight ends the route
    near = stay[new.visited[stay] + cfg.lookahead >= n_anchors[stay] - 1]
    if near.size:
        ans = evaluate(near, n_anchors[near] - 1, True, False)
        home = near[_at_goal(ans.overlap.mean(axis=1), np.hypot(*ans.waypoint.T), cfg)
                    & ~_tracked_far(per, near, n_anchors[near] - 1, cfg.tracker.tracked_goal_m)]
        new.visited[home] = n_anchors[home] - 1
        new.mode[home] = Mode.REACHED
        stay = stay[new.mode[stay] == Mode.DEAD_RECKONING]
    new.dr_count[stay] = state.dr_count[stay] + 1
    gave_up = stay[new.dr_count[stay] >= dr.dr_max_iterations]
    new.mode[gave_up] = Mode.FAILED
    new.reason[gave_up] = Reason.DEAD_RECKONING_GAVE_UP
    # at the held waypoint without RE's consent: a new leg from C_WP
    going = stay[new.mode[stay] == Mode.DEAD_RECKONING]
    arrived = going[np.hypot(*(state.waypoint[going] - car_state[going, :2]).T)
                    < dr.dr_arrive_m]
    if arrived.size:
        leg = evaluate(arrived, new.active[arrived], True, False).waypoint
        # standing on the active anchor (but the goal): it counts as visited and the
        # leg goes to the next one
        on = np.flatnonzero((np.hypot(*leg.T) < cfg.visit.visit_m)
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
    moving = (new.mode == Mode.FOLLOW) | (new.mode == Mode.DEAD_RECKONING)
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
    follow = np.flatnonzero(new.mode == Mode.FOLLOW)
    if frames is not None:
        scans = getattr(evaluate, "scan_fixes", None) if cfg.tracker.scan_fix else None
        tracked = _check_waypoints(new, follow,
                                   np.flatnonzero(new.mode == Mode.DEAD_RECKONING), local,
                                   car_state, n_anchors, frames, cfg, scans)
        follow = np.setdiff1d(follow, tracked)
    target[follow] = new.active[follow]
    drive = np.full((n, 2), np.nan)
    drive[new.mode == Mode.FOLLOW] = new.waypoint[new.mode == Mode.FOLLOW]
    dr = np.flatnonzero(new.mode == Mode.DEAD_RECKONING)
    drive[dr] = new.waypoint[dr]           # held (C_WP is not asked: target stays -1)
    off = target < 0
    local[off], local_overlap[off], local_heading[off] = np.nan, np.nan, np.nan
    held = off & ((new.mode == Mode.FOLLOW) | (new.mode == Mode.DEAD_RECKONING))
    if cfg.reverse_inside_turn >= 0:
        answer = np.flatnonzero((new.mode == Mode.FOLLOW) & ~held)
        drive[answer], backed = back_up_inside_turn(drive[answer], car_state[answer], cfg)
        held[answer[backed]] = True             # the follower's own waypoint now
    return StepOutput(drive, target, local, local_overlap, local_heading, held)


BACK_UP_M = 1.0     # how far behind the car the backing-up waypoint lies (m)


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
    the car, and which were replaced (N,)."""
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


def _check_waypoints(new: FollowerState, follow: np.ndarray, dead: np.ndarray, local: np.ndarray,
                     car_state: np.ndarray, n_anchors: np.ndarray, frames,
                     cfg: FollowerConfig, scans=None) -> np.ndarray:
    """The route tracker's rules for moving cars (Follow cars ``follow``,
    then Dead reckoning cars ``dead``); returns the Follow cars that drive
    the tracker's waypoint. ``scans``: the Evaluator's scan fixes
    (:func:`tracker.apply_scans`), applied first. An active anchor (but the
    goal) that the tracker puts within ``visit_m``, or behind the car within
    ``TRACKED_PASS_M``, counts as visited and the next one becomes active; a
    sure tracker (position sigma under ``tracked_sure_m``) within ``goal_m``
    of the goal ends the route (``reached``); a Follow waypoint more than
    ``check_deg`` off the tracked pursuit point (on the taught poses into
    the active anchor), and every Dead reckoning waypoint, is replaced by
    that point."""
    tc = cfg.tracker
    moving = np.concatenate([follow, dead])
    tracker.follow_visits(new, moving, frames)
    if scans is not None:
        tracker.apply_scans(new, moving, frames, scans, tc)
    q, known, aim = tracker.tracked_anchor(new, moving, new.active[moving], frames)
    dist = np.hypot(q[:, 0], q[:, 1])
    passed = known & ((dist < cfg.visit.visit_m) | ((q[:, 0] < 0.0) & (dist < TRACKED_PASS_M))) \
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
    sure = known & (_position_sigma(new.var[moving]) < tc.tracked_sure_m)
    home = sure & (dist < cfg.visit.goal_m) & (new.active[moving] == n_anchors[moving] - 1)
    if home.any():
        c = moving[home]
        new.visited[c] = new.active[c]
        new.mode[c] = Mode.REACHED
    w = local[moving]
    cos = (w * aim).sum(axis=1) / np.maximum(np.hypot(*w.T) * np.hypot(*aim.T), 1e-9)
    off = ~(cos >= np.cos(np.radians(tc.check_deg)))          # NaN answers count as off
    in_follow = np.arange(len(moving)) < len(follow)
    use = known & (dist > 0.3) & (off | ~in_follow | passed) & ~home
    if use.any():
        c = moving[use]
        new.waypoint[c] = car_to_world(aim[use, None], car_state[c])[:, 0]
    return moving[(use | passed | home) & in_follow]


TRACKED_PASS_M = 1.0    # an anchor the tracker puts behind the car and this close (m) is passed


def _tracked_far(per: _Period, cars: np.ndarray, anchors: np.ndarray, reach_m: float
                 ) -> np.ndarray:
    """(M,) whether a sure tracker (position sigma under ``tracked_sure_m``
    after the last period's fixes) puts each car's anchor farther than
    ``reach_m``; none where the route has no legs or the rule is off
    (``tracked_sure_m`` or ``reach_m`` 0)."""
    if reach_m <= 0:
        return np.zeros(len(cars), bool)
    return _sure_distance(per, cars, anchors) > reach_m


def sure_follow_m(cfg: FollowerConfig, evaluate) -> float:
    """The reach (m) within which a sure tracker keeps a doubted car in
    Follow: ``cfg.tracker.sure_follow_m``, or where that is None the C_WP's
    own choice (the evaluator's ``sure_follow_m``, from its policy; 0, off,
    where it has none)."""
    if cfg.tracker.sure_follow_m is not None:
        return float(cfg.tracker.sure_follow_m)
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
    if per.frames is None or per.cfg.tracker.tracked_sure_m <= 0:
        return out
    q, known, _ = tracker.tracked_anchor(per.new, cars, anchors, per.frames)
    sure = known & (_position_sigma(per.state.var[cars]) < per.cfg.tracker.tracked_sure_m)
    out[sure] = np.hypot(q[sure, 0], q[sure, 1])
    return out


def _position_sigma(var: np.ndarray) -> np.ndarray:
    """The larger position sigma (M,) of tracker covariances ``var`` (M, 9)."""
    return np.sqrt(np.maximum(var[:, 0], var[:, 4]))


def outcome_of(state: FollowerState) -> list[str]:
    """"reached", the failure reason, or the mode of followers still running."""
    out = []
    for m, r in zip(state.mode, state.reason):
        out.append("reached" if m == Mode.REACHED else REASONS[r] if m == Mode.FAILED
                   else MODES[m])
    return out
