"""Replanning when the follower gives up (beyond the paper's single plan).

The paper replans from dead reckoning (first after 5 failing periods, then
every 3) and accepts a new plan when it beats the old one; its authors
never detected loops. Here a car whose follower gives up (dead reckoning
ran out, or Search found no anchor) stops where it is, the edge it was
failing on (last visited anchor -> active anchor) joins the edges that car
may no longer use, and the planner is asked again from the car's current
observation; the car drives the new plan for the time it has left. A car
that gives up on the same edge twice has looped, and excluding the edge is
what breaks the loop. The engine's ``FollowerConfig.dr_max_iterations``
sets how soon a car gives up, so a replanning study runs its engine with a
short one (the paper's first replan comes after 5 periods).

:func:`follow_with_replanning` works on any planner through a callback
``replan(trial, pose, excluded_edges) -> Route | None`` and on any
:class:`~topodrake.navigation.engine.NavigationEngine`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from topodrake.errors import TopodrakeError

GIVE_UP = ("dead_reckoning_gave_up", "search_failed")


@dataclass
class ReplanResult:
    """Per trial: the outcome of its last drive ("goal" = stopped at the
    goal place), the distance from its last pose to the goal place, success,
    control periods driven in all, the plans it drove, the edges it excluded
    and its poses over all its drives."""

    outcome: list[str]
    final_distance_m: np.ndarray
    success: np.ndarray
    steps: np.ndarray
    plans: np.ndarray
    excluded: list[list[tuple[int, int]]] = field(default_factory=list)
    poses: list[np.ndarray] = field(default_factory=list)


def failing_edge(route, visited: int, active: int) -> tuple[int, int] | None:
    """The map edge (u, v) a follower gave up on: from its last visited
    anchor to its active one (None when either is not a map vertex)."""
    if not (0 <= visited < len(route) and 0 <= active < len(route)):
        return None
    u, v = int(route.vertices[visited]), int(route.vertices[active])
    return (u, v) if u >= 0 and v >= 0 and u != v else None


def follow_with_replanning(engine, starts: np.ndarray, routes: list, goals: np.ndarray, replan,
                           t_max_s: float, max_replans: int = 5, radius: float = 0.54,
                           batch: int = 32, min_time_s: float = 1.0) -> ReplanResult:
    """Drive trials from ``starts`` (n, 3) along ``routes`` (None: no plan)
    toward the goal places ``goals`` (n, 3) within ``t_max_s`` each; a car
    that gives up is replanned with ``replan(i, pose, excluded)`` (a Route,
    or None when no plan avoids the excluded edges) at most ``max_replans``
    times while at least ``min_time_s`` is left. Success: the car came
    within ``radius`` of its goal without colliding."""
    from topodrake.navigation.engine import NAV_COLLISION, NAV_OUTCOMES
    from topodrake.navigation.plan_trials import GoalWatch

    if max_replans < 0:
        raise TopodrakeError(f"max_replans must be >= 0, got {max_replans}")
    dt = engine.config.rollout.vehicle.dt
    n = len(starts)
    starts = np.asarray(starts, np.float64).reshape(n, 3)
    goals = np.asarray(goals, np.float64).reshape(n, 3)
    outcome = ["no_plan"] * n
    success = np.zeros(n, bool)
    steps = np.zeros(n, np.int64)
    plans = np.array([int(r is not None) for r in routes], np.int64)
    excluded: list[list[tuple[int, int]]] = [[] for _ in range(n)]
    poses = [starts[i][None].copy() for i in range(n)]
    pose = starts.copy()
    current = list(routes)
    pending = [i for i in range(n) if current[i] is not None]
    for attempt in range(max_replans + 1):
        if not pending:
            break
        again = []
        for lo in range(0, len(pending), batch):
            part = pending[lo:lo + batch]
            left = np.array([t_max_s - steps[i] * dt for i in part])
            watch = GoalWatch(goals[part], radius)
            res = engine.run(pose[part], [current[i] for i in part], t_max_s=left, watch=watch)
            for j, i in enumerate(part):
                k = int(res.steps[j])
                steps[i] += k
                poses[i] = np.vstack([poses[i], res.poses[j, 1:k + 1]])
                pose[i] = res.poses[j, k]
                code = int(res.outcome[j])
                success[i] = code != NAV_COLLISION and bool(watch.arrived[j])
                outcome[i] = "goal" if watch.arrived[j] else NAV_OUTCOMES[code]
                if (outcome[i] in GIVE_UP and attempt < max_replans
                        and t_max_s - steps[i] * dt >= min_time_s):
                    edge = failing_edge(current[i], int(res.follower.visited[j]),
                                        int(res.follower.active[j]))
                    if edge is not None and edge not in excluded[i]:
                        excluded[i].append(edge)
                    new = replan(i, pose[i].copy(), list(excluded[i]))
                    if new is not None:
                        current[i] = new
                        plans[i] += 1
                        again.append(i)
        pending = again
    dist = np.array([float(np.hypot(*(pose[i, :2] - goals[i, :2]))) for i in range(n)])
    return ReplanResult(outcome, dist, success, steps, plans, excluded, poses)
