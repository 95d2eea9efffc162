"""The expert's final approach: reach a goal *pose* with Reeds-Shepp paths.

A place is a pose (x, y, heading): a demonstration that ends at a place must
arrive at the place's position *and* heading, so that its last views are the
place's view and the map links arrivals to departures. The A* expert drives
the car to within ``start_m`` of the goal; from there :func:`plan_pose_path`
plans a Reeds-Shepp path (forward and reverse arcs of radius ``turn_radius_m``
and straight lines: U-turns and three-point turns included) to the goal pose
with OMPL, checked against the occupancy grid's clearance map, and
:func:`track_pose_path` drives it.

Planning: the analytic shortest Reeds-Shepp curve is tried first (most
places face open space); where it touches a wall OMPL's RRT-Connect in the
Reeds-Shepp state space searches around it, seeded, then its path is
shortcut. A state is valid while the clearance at the car's reference point
exceeds the grid's car radius plus ``clearance_margin_m`` (relaxed to what the
start and goal themselves have, so a car that stands close to a wall can
still leave).

Tracking: pure pursuit on the current segment of one driving direction (the
circle through the car tangent to its heading and through a point
``lookahead_m`` ahead on the path, which holds for reversing too), slowing
toward each cusp; past a segment's end it takes the next one. A car that
ends the path outside the tolerance plans again from where it stands.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from topodrake.errors import TopodrakeError


@dataclass(frozen=True)
class ApproachConfig:
    start_m: float = 1.0            # the approach starts this close (straight line) to the goal
    heading_tol_deg: float = 15.0   # a pose goal is reached within this heading error
    turn_radius_m: float = 0.5      # Reeds-Shepp radius (the car turns down to 0.425 m)
    clearance_margin_m: float = 0.03
    speed: float = 0.3              # m/s along the path (slower toward cusps and the goal)
    lookahead_m: float = 0.2
    step_m: float = 0.02            # path sample spacing
    plan_time_s: float = 2.0        # RRT-Connect's budget where the analytic curve collides
    replans: int = 4                # new paths from where the car stands, at most

    def check(self) -> "ApproachConfig":
        for name in ("start_m", "turn_radius_m", "speed", "lookahead_m", "step_m", "plan_time_s"):
            if not getattr(self, name) > 0:
                raise TopodrakeError(f"approach {name} must be > 0, got {getattr(self, name)}")
        if not 0 < self.heading_tol_deg <= 180:
            raise TopodrakeError(f"approach heading_tol_deg must be in (0, 180], got "
                                 f"{self.heading_tol_deg}")
        return self


def wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def pose_reached(poses: np.ndarray, goals: np.ndarray, tolerance_m: float,
                 heading_tol_deg: float) -> np.ndarray:
    """Whether cars at ``poses`` (N, 3) stand within ``tolerance_m`` and
    ``heading_tol_deg`` of ``goals`` (N, 3)."""
    poses = np.asarray(poses, np.float64).reshape(-1, 3)
    goals = np.asarray(goals, np.float64).reshape(-1, 3)
    near = np.hypot(*(poses[:, :2] - goals[:, :2]).T) < tolerance_m
    return near & (np.abs(wrap(poses[:, 2] - goals[:, 2])) < math.radians(heading_tol_deg))


def _space(grid, config: ApproachConfig):
    from ompl import base as ob

    space = ob.ReedsSheppStateSpace(config.turn_radius_m)
    lo, hi = grid.bbox()
    bounds = ob.RealVectorBounds(2)
    bounds.setLow(0, float(lo[0]))
    bounds.setLow(1, float(lo[1]))
    bounds.setHigh(0, float(hi[0]))
    bounds.setHigh(1, float(hi[1]))
    space.setBounds(bounds)
    return space


def _state(space, pose):
    s = space.allocState()
    s.setX(float(pose[0]))
    s.setY(float(pose[1]))
    s.setYaw(float(pose[2]))
    return s


def _samples(space, states: list, step: float) -> np.ndarray:
    """(M, 3) poses every ``step`` metres along the Reeds-Shepp curves
    joining consecutive ``states``."""
    out = [np.array([[states[0].getX(), states[0].getY(), states[0].getYaw()]])]
    tmp = space.allocState()
    for a, b in zip(states[:-1], states[1:]):
        n = max(2, int(math.ceil(space.distance(a, b) / step)) + 1)
        seg = np.empty((n - 1, 3))
        for i, t in enumerate(np.linspace(0.0, 1.0, n)[1:]):
            space.interpolate(a, b, float(t), tmp)
            seg[i] = tmp.getX(), tmp.getY(), tmp.getYaw()
        out.append(seg)
    return np.concatenate(out)


def _with_direction(poses: np.ndarray) -> np.ndarray:
    """(M, 4) poses and the driving direction (+1 forward, -1 reverse) toward
    the next sample (the last repeats the one before)."""
    d = np.diff(poses[:, :2], axis=0)
    along = d[:, 0] * np.cos(poses[:-1, 2]) + d[:, 1] * np.sin(poses[:-1, 2])
    sign = np.where(along < 0, -1.0, 1.0)
    sign = np.append(sign, sign[-1] if len(sign) else 1.0)
    return np.column_stack([poses, sign])


def plan_pose_path(grid, start, goal, config: ApproachConfig | None = None, seed: int = 0
                   ) -> np.ndarray | None:
    """A collision-free Reeds-Shepp path from pose ``start`` to pose ``goal``:
    (M, 4) rows ``x, y, heading, direction`` every ``step_m``; None when OMPL
    finds none within its budget."""
    from ompl import base as ob
    from ompl import geometric as og
    from ompl import util as ou

    cfg = (config or ApproachConfig()).check()
    start = np.asarray(start, np.float64).reshape(3)
    goal = np.asarray(goal, np.float64).reshape(3)
    ends = grid.clearance_at(np.array([start[:2], goal[:2]]))
    thr = min(grid.car_radius + cfg.clearance_margin_m, 0.98 * float(ends.min()))

    space = _space(grid, cfg)
    a, b = _state(space, start), _state(space, goal)
    direct = _samples(space, [a, b], cfg.step_m)
    if np.all(grid.clearance_at(direct[:, :2]) > thr):
        return _with_direction(direct)

    ou.setLogLevel(ou.LOG_NONE)
    ou.RNG.setSeed(int(seed) % (2 ** 31 - 1) + 1)
    setup = og.SimpleSetup(space)
    clearance = grid.clearance_at

    def valid(s) -> bool:
        return bool(clearance(np.array([[s.getX(), s.getY()]]))[0] > thr)

    setup.setStateValidityChecker(valid)
    info = setup.getSpaceInformation()
    lo, hi = grid.bbox()
    info.setStateValidityCheckingResolution(cfg.step_m / max(float(np.max(hi - lo)), 1e-6))
    setup.setPlanner(og.RRTConnect(info))
    setup.setStartAndGoalStates(a, b)
    setup.solve(cfg.plan_time_s)
    if not setup.haveExactSolutionPath():
        return None
    setup.simplifySolution(0.5)
    path = setup.getSolutionPath()
    states = [path.getState(i) for i in range(path.getStateCount())]
    poses = _samples(space, states, cfg.step_m)
    if not np.all(grid.clearance_at(poses[:, :2]) > 0.98 * thr):
        return None
    return _with_direction(poses)


@dataclass
class PathTracker:
    """Per-car progress along a planned pose path."""

    path: np.ndarray          # (M, 4)
    index: int = 0
    replans: int = 0

    def segment_end(self) -> int:
        d = self.path[:, 3]
        i = self.index
        change = np.flatnonzero(d[i:] != d[i])
        return len(d) - 1 if change.size == 0 else i + int(change[0]) - 1


def track_pose_path(tracker: PathTracker, state: np.ndarray, config: ApproachConfig,
                    vehicle) -> tuple[np.ndarray, np.ndarray, bool]:
    """Controls (2,) that drive the car (``state`` (5,)) along its path, the
    world-frame pursuit point (2,), and whether the path is done (the car
    stands at or past its last sample)."""
    p = tracker.path
    x, y, th, v, steer = state
    while True:
        end = tracker.segment_end()
        window = p[tracker.index:end + 1, :2]
        near = tracker.index + int(np.argmin(np.hypot(*(window - (x, y)).T)))
        tracker.index = near
        d = p[end, 3]
        # past the segment's end (along the direction of travel there)?
        ex = math.cos(p[end, 2]) * d, math.sin(p[end, 2]) * d
        beyond = (x - p[end, 0]) * ex[0] + (y - p[end, 1]) * ex[1]
        at_end = near >= end - 1 and (beyond > -0.02 or math.hypot(x - p[end, 0], y - p[end, 1]) < 0.03)
        if at_end and end < len(p) - 1:
            tracker.index = end + 1
            continue
        break
    last = end == len(p) - 1
    remaining = (end - tracker.index) * config.step_m
    if last and at_end:
        return np.array([(0.0 - v) / vehicle.dt, (0.0 - steer) / vehicle.dt]), p[-1, :2].copy(), True
    ahead = tracker.index + int(round(config.lookahead_m / config.step_m))
    if ahead <= end:
        target = p[ahead, :2]
    else:   # past the cusp or the goal: continue along the end heading
        extra = (ahead - end) * config.step_m
        target = p[end, :2] + extra * d * np.array([math.cos(p[end, 2]), math.sin(p[end, 2])])
    dx, dy = target[0] - x, target[1] - y
    xc = math.cos(th) * dx + math.sin(th) * dy
    yc = -math.sin(th) * dx + math.cos(th) * dy
    curvature = 2.0 * yc / max(xc * xc + yc * yc, 1e-6)
    steer_goal = float(np.clip(math.atan(vehicle.wheelbase * curvature),
                               -vehicle.steer_limit, vehicle.steer_limit))
    speed = d * float(np.clip(1.5 * remaining + 0.06, 0.08, config.speed))
    u = np.array([(speed - v) / vehicle.dt, (steer_goal - steer) / vehicle.dt])
    return u, np.asarray(target, np.float64), False
