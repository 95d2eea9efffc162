"""Run a built expert diagram until goal, collision or timeout."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from pydrake.common import RandomGenerator
from pydrake.systems.analysis import Simulator, SimulatorConfig, ApplySimulatorConfig
from pydrake.systems.framework import EventStatus

from topodrake.vehicle import in_collision


@dataclass
class RunResult:
    success: bool
    collision: bool
    timeout: bool
    time_s: float
    distance_to_goal_m: float
    poses: np.ndarray = field(repr=False)   # (K + 1, 3) at 10 Hz
    noise: np.ndarray = field(repr=False)   # (K, 2) standard normals applied in each step
    wall_time_s: float = 0.0

    @property
    def outcome(self) -> str:
        return "success" if self.success else "collision" if self.collision else "timeout"

    def summary(self) -> dict:
        return {"outcome": self.outcome, "time_s": round(self.time_s, 2),
                "distance_to_goal_m": round(self.distance_to_goal_m, 3),
                "wall_time_s": round(self.wall_time_s, 3)}


class ExpertRunner:
    """A simulator over one built diagram, reused across runs (a Monte Carlo
    trial only resets the context)."""

    def __init__(self, built):
        self.built = built
        self.simulator = Simulator(built.diagram)
        ApplySimulatorConfig(SimulatorConfig(
            integration_scheme="runge_kutta2", max_step_size=built.scenario.vehicle.dt,
            use_error_control=False, target_realtime_rate=0.0,
            publish_every_time_step=False), self.simulator)

    def run(self, start=None, goal=None, seed: int | None = None,
            t_max_s: float | None = None) -> RunResult:
        b = self.built
        sc = b.scenario
        world = b.world
        start = sc.start_pose(world) if start is None else world.check_pose(start, "start")
        goal = sc.goal_xy(world) if goal is None else world.check_pose(goal, "goal")[:2]
        t_max = sc.t_max_s if t_max_s is None else t_max_s
        seed = sc.seed if seed is None else seed
        diagram = b.diagram
        context = self.simulator.get_mutable_context()
        diagram.SetDefaultContext(context)
        diagram.SetRandomContext(context, RandomGenerator(int(seed) % (2 ** 32)))
        context.SetTime(0.0)
        car_ctx = b.car.GetMyMutableContextFromRoot(context)
        car_ctx.SetContinuousState(np.array([*start[:3], 0.0, 0.0]))
        b.expert.set_goal(b.expert.GetMyMutableContextFromRoot(context), goal)
        b.pose_logger.FindMutableLog(context).Clear()
        b.noise_logger.FindMutableLog(context).Clear()
        tol = sc.goal_tolerance_m
        vehicle = sc.vehicle
        clearance = world.grid.clearance_at
        flags = {"success": False, "collision": False}

        def monitor(root):
            x = b.car.GetMyContextFromRoot(root).get_continuous_state_vector().CopyToVector()
            if np.hypot(x[0] - goal[0], x[1] - goal[1]) < tol:
                flags["success"] = True
                return EventStatus.ReachedTermination(diagram, "goal reached")
            if in_collision(x[None], clearance, vehicle)[0]:
                flags["collision"] = True
                return EventStatus.ReachedTermination(diagram, "collision")
            return EventStatus.Succeeded()

        self.simulator.set_monitor(monitor)
        wall = time.perf_counter()
        self.simulator.Initialize()
        self.simulator.AdvanceTo(t_max)
        wall = time.perf_counter() - wall
        x = b.car.GetMyContextFromRoot(context).get_continuous_state_vector().CopyToVector()
        log = b.pose_logger.FindLog(context)
        poses = np.vstack([log.data().T, x[None, :3]])
        dist = float(np.hypot(x[0] - goal[0], x[1] - goal[1]))
        return RunResult(flags["success"], flags["collision"],
                         not (flags["success"] or flags["collision"]),
                         float(context.get_time()), dist, poses,
                         self._applied_noise(context), wall)

    def _applied_noise(self, context) -> np.ndarray:
        # Publish events run at the end of a step, so the sample logged at
        # t_k+1 is the one held during step k; the first entry (t = 0) is the
        # value before the first update.
        return self.built.noise_logger.FindLog(context).data().T[1:].copy()


def run_scenario(scenario, meshcat=None) -> RunResult:
    """Build the expert diagram for a scenario and run it once."""
    from topodrake.systems.diagram import build_expert_diagram

    return ExpertRunner(build_expert_diagram(scenario, meshcat=meshcat)).run()
