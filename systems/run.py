"""Run a built navigation diagram until success, collision or timeout.

:class:`ExpertRunner` drives the expert diagram to a goal position;
:class:`TargetRunner` drives a C_WP diagram (``build_waypoint_diagram``)
toward a target pose, where success is the paper's controller criterion:
within the goal tolerance of the target position, or both image overlaps
between the car's and the target's camera above ``overlap_success``. Both
share one simulator set-up, reset and stop logic (:class:`DiagramRunner`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from pydrake.common import RandomGenerator
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator, SimulatorConfig
from pydrake.systems.framework import EventStatus

from topodrake.errors import TopodrakeError
from topodrake.sensing.overlap import mutual_overlap
from topodrake.vehicle import in_collision
from topodrake.world import path_length


@dataclass
class RunResult:
    success: bool
    collision: bool
    timeout: bool
    time_s: float
    distance_to_goal_m: float
    poses: np.ndarray = field(repr=False)   # (K + 1, 3) at 10 Hz
    noise: np.ndarray = field(repr=False)   # (K, 2) standard normals applied in each step
    wall_time_s: float = 0.0    # simulation only; start-up is startup_s
    startup_s: float = 0.0      # first run of a runner: loading or compiling kernels

    @property
    def outcome(self) -> str:
        return "success" if self.success else "collision" if self.collision else "timeout"

    @property
    def distance_m(self) -> float:
        """The length of the driven path (m)."""
        return path_length(self.poses[:, :2]) if len(self.poses) else 0.0

    def summary(self) -> dict:
        return {"outcome": self.outcome, "time_s": round(self.time_s, 2),
                "distance_m": round(self.distance_m, 2),
                "distance_to_goal_m": round(self.distance_to_goal_m, 3),
                "wall_time_s": round(self.wall_time_s, 3), "startup_s": round(self.startup_s, 3)}


class DiagramRunner:
    """A simulator over one built diagram, reused across runs (a Monte Carlo
    trial only resets the context). ``built`` has ``diagram``, ``car``,
    ``pose_logger``, ``noise_logger``, ``world`` and ``scenario``, and may
    have ``changes`` (a
    :class:`~topodrake.systems.changes.WorldChangesSource`: touching what
    changed is a collision too)."""

    def __init__(self, built):
        self.built = built
        self.warm = False
        self.simulator = Simulator(built.diagram)
        ApplySimulatorConfig(SimulatorConfig(
            integration_scheme="runge_kutta2", max_step_size=built.scenario.vehicle.dt,
            use_error_control=False, target_realtime_rate=0.0,
            publish_every_time_step=False), self.simulator)

    def _reset(self, start: np.ndarray, seed: int):
        b = self.built
        context = self.simulator.get_mutable_context()
        b.diagram.SetDefaultContext(context)
        b.diagram.SetRandomContext(context, RandomGenerator(int(seed) % (2 ** 32)))
        context.SetTime(0.0)
        b.car.GetMyMutableContextFromRoot(context).SetContinuousState(
            np.array([*start[:3], 0.0, 0.0]))
        b.pose_logger.FindMutableLog(context).Clear()
        b.noise_logger.FindMutableLog(context).Clear()
        return context

    def _simulate(self, reached, t_max: float, lost=None) -> dict:
        """Advance to ``t_max`` or until ``reached(state)`` (success), a
        collision or ``lost(state)`` (a failure that ends the run early);
        returns the outcome flags, final state, poses and wall time. The
        check runs after each control period's step, before the next
        period's updates (the engine's order)."""
        b = self.built
        diagram = b.diagram
        clearance = b.world.grid.clearance_at
        vehicle = b.scenario.vehicle
        changes = getattr(b, "changes", None)
        flags = {"success": False, "collision": False, "lost": False}

        def touching(root, x) -> bool:
            return changes is not None and changes.touching(
                changes.GetMyContextFromRoot(root), x, vehicle)

        def monitor(root):
            x = b.car.GetMyContextFromRoot(root).get_continuous_state_vector().CopyToVector()
            if reached(x):
                flags["success"] = True
                return EventStatus.ReachedTermination(diagram, "goal reached")
            if in_collision(x[None], clearance, vehicle)[0] or touching(root, x):
                flags["collision"] = True
                return EventStatus.ReachedTermination(diagram, "collision")
            if lost is not None and lost(x):
                flags["lost"] = True
                return EventStatus.ReachedTermination(diagram, "target lost")
            return EventStatus.Succeeded()

        startup = 0.0 if self.warm else self._warm_up()
        self.simulator.set_monitor(monitor)
        wall = time.perf_counter()
        self.simulator.Initialize()
        self.simulator.AdvanceTo(t_max)
        wall = time.perf_counter() - wall
        context = self.simulator.get_context()
        x = b.car.GetMyContextFromRoot(context).get_continuous_state_vector().CopyToVector()
        log = b.pose_logger.FindLog(context)
        # Publish events run at the end of a step, so the noise sample logged
        # at t_k+1 is the one held during step k; the first entry (t = 0) is
        # the value before the first update.
        noise = b.noise_logger.FindLog(context).data().T[1:].copy()
        return {**flags, "state": x, "time_s": float(context.get_time()),
                "poses": np.vstack([log.data().T, x[None, :3]]), "noise": noise, "wall": wall,
                "startup": startup}

    def _warm_up(self) -> float:
        """Advance the freshly reset context by two control periods and put
        it back, so that the first run's wall time excludes compiling or
        loading the kernels (and the first network call); returns the
        seconds this took."""
        t0 = time.perf_counter()
        b = self.built
        context = self.simulator.get_mutable_context()
        saved = context.Clone()
        self.simulator.clear_monitor()
        self.simulator.Initialize()
        self.simulator.AdvanceTo(context.get_time() + 2.0 * b.scenario.vehicle.dt)
        context.SetTimeStateAndParametersFrom(saved)
        b.pose_logger.FindMutableLog(context).Clear()
        b.noise_logger.FindMutableLog(context).Clear()
        self.warm = True
        return time.perf_counter() - t0


class ExpertRunner(DiagramRunner):
    """Runs the expert diagram (``build_expert_diagram``) to a goal position."""
    def run(self, start=None, goal=None, seed: int | None = None,
            t_max_s: float | None = None) -> RunResult:
        b = self.built
        sc = b.scenario
        world = b.world
        start = sc.start_pose(world) if start is None else world.check_pose(start, "start")
        goal = sc.goal_xy(world) if goal is None else world.check_pose(goal, "goal")[:2]
        context = self._reset(start, sc.seed if seed is None else seed)
        b.expert.set_goal(b.expert.GetMyMutableContextFromRoot(context), goal)
        tol = sc.goal_tolerance_m
        r = self._simulate(lambda x: np.hypot(x[0] - goal[0], x[1] - goal[1]) < tol,
                           sc.t_max_s if t_max_s is None else t_max_s)
        x = r["state"]
        return RunResult(r["success"], r["collision"], not (r["success"] or r["collision"]),
                         r["time_s"], float(np.hypot(x[0] - goal[0], x[1] - goal[1])),
                         r["poses"], r["noise"], r["wall"], r["startup"])


@dataclass
class TargetRunResult(RunResult):
    """A :class:`RunResult` toward a target pose, with the final overlaps."""

    overlap: np.ndarray = field(default_factory=lambda: np.zeros(2), repr=False)
    reached_by: str = ""       # "distance", "overlap" or "" (not reached)
    lost: bool = False         # ended early: both overlaps fell below overlap_lost

    @property
    def outcome(self) -> str:
        return "lost" if self.lost else super().outcome

    def summary(self) -> dict:
        out = super().summary()
        out["overlap"] = [round(float(v), 3) for v in self.overlap]
        out["reached_by"] = self.reached_by
        return out


class TargetRunner(DiagramRunner):
    """Runs a C_WP diagram (``build_waypoint_diagram``) toward a target pose.

    Success: within ``scenario.goal_tolerance_m`` of the target position, or
    both geometric image overlaps (car -> target, target -> car) above
    ``overlap_success``. Collision is failure; so is running out of time, and
    (with ``overlap_lost``) both overlaps below it, which ends the run early
    as the batched engine's ``PolicyRollout`` does."""

    def __init__(self, built, overlap_success: float = 0.7, overlap_lost: float | None = None):
        super().__init__(built)
        self.overlap_success = overlap_success
        self.overlap_lost = overlap_lost

    def run(self, start, target_pose, target, seed: int = 0, t_max_s: float = 30.0
            ) -> TargetRunResult:
        """``target``: the :class:`~topodrake.learning.waypoint.policy.TargetContext`
        the network sees; ``target_pose`` (3,): where it was taken."""
        b = self.built
        world = b.world
        # Poses of expert drives may pass closer to walls than the c-space
        # radius, so the start is checked against the car's body instead.
        start = world.check_pose(start, "start", free=False)
        goal = world.check_pose(target_pose, "target", free=False)[:3]
        if in_collision(np.array([[*start[:3], 0.0, 0.0]]), world.grid.clearance_at,
                        b.scenario.vehicle)[0]:
            raise TopodrakeError(f"start ({start[0]:.2f}, {start[1]:.2f}) puts the car's body "
                                 f"into a wall of {world.name!r}")
        context = self._reset(start, seed)
        b.target_source.set_target(b.target_source.GetMyMutableContextFromRoot(context), target)
        tol = b.scenario.goal_tolerance_m
        camera = b.scenario.camera
        how = {"by": ""}

        def reached(x):
            if np.hypot(x[0] - goal[0], x[1] - goal[1]) < tol:
                how["by"] = "distance"
                return True
            ov = mutual_overlap(world, x[None, :3], goal[None], camera)[0]
            if ov.min() > self.overlap_success:
                how["by"] = "overlap"
                return True
            return False

        def lost(x):
            ov = mutual_overlap(world, x[None, :3], goal[None], camera)[0]
            return ov.max() < self.overlap_lost

        r = self._simulate(reached, t_max_s, lost if self.overlap_lost is not None else None)
        x = r["state"]
        overlap = mutual_overlap(world, x[None, :3], goal[None], camera)[0]
        ended = r["success"] or r["collision"] or r["lost"]
        return TargetRunResult(r["success"], r["collision"], not ended,
                               r["time_s"], float(np.hypot(x[0] - goal[0], x[1] - goal[1])),
                               r["poses"], r["noise"], r["wall"], r["startup"], overlap=overlap,
                               reached_by=how["by"], lost=r["lost"])


def run_scenario(scenario, meshcat=None) -> RunResult:
    """Build the expert diagram for a scenario and run it once."""
    from topodrake.systems.diagram import build_expert_diagram

    return ExpertRunner(build_expert_diagram(scenario, meshcat=meshcat)).run()
