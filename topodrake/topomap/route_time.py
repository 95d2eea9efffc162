"""How long a plan takes to drive, and whether it fits a time limit.

A trial that runs out of time fails however probable its hops are, and
the most probable path (Dijkstra on -log p) is not always one the car can
drive in time: where the hops of a short route are rated lower (a
turn-around at a place, say), the product of probabilities favours a
detour of many confident hops several times as long. With a time limit the
planner weighs both: a path's chance of success is the product of its
hops' probabilities times the chance that the follower drives it within
the limit (:meth:`DrivingTime.on_time`).

A hop's length is what the map knows without privileged poses: the teach
drive's odometry stored on the edge (its leg path); a hop without one (a
cross edge, a link of the start or goal, a hop between drives where the
map left the leg out) counts as the map's median leg.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from topodrake.errors import TopodrakeError

#: a hop's length where the map keeps no legs at all (the anchors' typical spacing)
DEFAULT_HOP_M = 1.0


@dataclass(frozen=True)
class DrivingTime:
    """The follower's time over a route: ``start_s + per_m_s * metres +
    per_hop_s * hops`` on average, spread normally with a standard deviation
    of ``spread`` times that. The defaults are fitted to the oracle
    follower's planned trials in five training houses (``python
    studies/planning.py --fit-driving-time``)."""

    start_s: float = 0.0
    per_m_s: float = 1.47
    per_hop_s: float = 1.28
    spread: float = 0.20

    def __post_init__(self) -> None:
        for name in ("start_s", "per_m_s", "per_hop_s"):
            if not math.isfinite(getattr(self, name)) or getattr(self, name) < 0:
                raise TopodrakeError(f"DrivingTime.{name} must be a finite number >= 0")
        if not math.isfinite(self.spread) or self.spread <= 0:
            raise TopodrakeError("DrivingTime.spread must be a finite number > 0")

    def seconds(self, metres: float, hops: int) -> float:
        """Expected driving time of a route of ``metres`` over ``hops`` hops."""
        return self.start_s + self.per_m_s * metres + self.per_hop_s * hops

    def on_time(self, metres: float, hops: int, limit_s: float | None) -> float:
        """Probability that the route is driven within ``limit_s`` (1 without a limit)."""
        if limit_s is None:
            return 1.0
        mean = self.seconds(metres, hops)
        z = (limit_s - mean) / (self.spread * max(mean, 1e-9))
        return 0.5 * math.erfc(-z / math.sqrt(2.0))


def leg_metres(leg_path: np.ndarray) -> float:
    """Length of one hop's leg path (poses in the hop's first frame, the
    start at the origin left implicit)."""
    xy = np.vstack([np.zeros((1, 2)), np.asarray(leg_path, np.float64)[:, :2]])
    return float(np.hypot(*np.diff(xy, axis=0).T).sum())


def edge_metres(graph) -> tuple[dict, float]:
    """({(u, v): metres} for the edges that keep a leg, the median of
    those; :data:`DEFAULT_HOP_M` where none does)."""
    metres = {(u, v): leg_metres(path) for u, v, path in graph.edges(data="leg_path")
              if path is not None}
    typical = float(np.median(list(metres.values()))) if metres else DEFAULT_HOP_M
    return metres, typical


def path_metres(path: list, metres: dict, typical: float) -> float:
    """Length of a path of graph nodes: legs where known, ``typical`` otherwise."""
    return float(sum(metres.get((u, v), typical) for u, v in zip(path[:-1], path[1:])))


def fit_driving_time(metres, hops, seconds, timed_out, limit_s: float) -> DrivingTime:
    """The :class:`DrivingTime` most likely to have produced driven plans:
    ``metres`` and ``hops`` of each plan (as the planner measures them),
    ``seconds`` it took where it arrived, and ``timed_out`` where it ran
    out of ``limit_s`` (a censored time: only "more than the limit" is
    known). Plans that failed otherwise are left out by the caller."""
    from scipy.optimize import minimize
    from scipy.stats import norm

    metres, hops, seconds = (np.asarray(a, np.float64) for a in (metres, hops, seconds))
    timed_out = np.asarray(timed_out, bool)
    if len(metres) < 4 or (~timed_out).sum() < 3:
        raise TopodrakeError("fitting the driving time needs at least 3 arrivals and 4 plans")

    def nll(x):
        start, per_m, per_hop, spread = np.exp(x)
        mean = start + per_m * metres + per_hop * hops
        sd = spread * mean
        arrived = norm.logpdf(seconds[~timed_out], mean[~timed_out], sd[~timed_out]).sum()
        late = norm.logsf(limit_s, mean[timed_out], sd[timed_out]).sum()
        return -(arrived + late)

    x0 = np.log([3.0, 2.0, 0.5, 0.2])
    fit = minimize(nll, x0, method="Nelder-Mead", options={"maxiter": 4000, "xatol": 1e-4,
                                                           "fatol": 1e-6})
    start, per_m, per_hop, spread = (float(v) for v in np.exp(fit.x))
    return DrivingTime(start_s=round(start, 3), per_m_s=round(per_m, 4),
                       per_hop_s=round(per_hop, 4), spread=round(spread, 4))
