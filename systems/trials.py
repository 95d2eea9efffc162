"""Monte Carlo trial functions over Drake diagrams, for ``topodrake.montecarlo``.

A trial takes a seed and keyword settings and returns a small dict. Each
worker process builds its diagram once (cached per settings) and reuses it
across its trials, resetting only the context.
"""

from __future__ import annotations

from functools import lru_cache


@lru_cache(maxsize=8)
def _runner(world: str, noise_std: float, camera: bool):
    from topodrake.systems.diagram import build_expert_diagram
    from topodrake.systems.run import ExpertRunner
    from topodrake.systems.scenario import Scenario

    return ExpertRunner(build_expert_diagram(
        Scenario(world=world, noise_std=noise_std, camera_enabled=camera)))


def expert_trial(seed: int, world: str = "test-0", start_place: int = 0, goal_place: int = 1,
                 noise_std: float = 0.33, camera: bool = False, t_max_s: float = 150.0) -> dict:
    """One expert drive between two places of ``world``; returns its summary
    (without the wall time, so results compare across machines)."""
    runner = _runner(world, float(noise_std), bool(camera))
    w = runner.built.world
    result = runner.run(start=w.places[start_place], goal=w.places[goal_place, :2],
                        seed=seed, t_max_s=t_max_s)
    summary = result.summary()
    summary.pop("wall_time_s")
    summary["seed"] = seed
    return summary
