"""Source/target pairs for evaluating a local controller (the paper's Table I).

A pair is drawn from one seed, so a Monte Carlo trial that receives only its
seed rebuilds the same pair in any process, and every controller (and both
noise settings) is scored on the same pairs:

* a test-house trajectory, uniformly over all successful expert drives of
  the evaluation worlds;
* a source frame i on it, uniformly;
* a target frame j at signed arc-length distance ``d ~ U(-1, 3)`` m from i
  (redrawn when it would leave the trajectory), with both image overlaps
  between the source and target poses above ``min_overlap`` (0.1, as for the
  training samples: a target the source cannot see at all is not a local
  control problem);
* the time limit ``t_base_s + A*(source, target) / v_min``.

The car starts at rest at the source pose (no jitter).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.sensing.overlap import mutual_overlap


@dataclass
class PairConfig:
    min_distance_m: float = -1.0
    max_distance_m: float = 3.0
    min_overlap: float = 0.1
    t_base_s: float = 10.0
    v_min: float = 0.3          # m/s; t_max = t_base_s + A* length / v_min
    tries: int = 200


@dataclass
class ControllerPair:
    world: str
    trajectory: int         # index into the TrajectorySet
    source: int             # frame index within the trajectory
    target: int
    distance_m: float       # signed arc length source -> target
    t_max_s: float

    def summary(self) -> dict:
        return {"world": self.world, "trajectory": self.trajectory, "source": self.source,
                "target": self.target, "distance_m": round(self.distance_m, 3),
                "t_max_s": round(self.t_max_s, 2)}


def _arclength(poses: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(poses[:, :2], axis=0).T))])


def sample_controller_pair(trajs, seed: int, worlds: dict, cfg: PairConfig = PairConfig()
                           ) -> ControllerPair:
    """The pair of ``seed`` from a :class:`~topodrake.learning.samples.TrajectorySet`;
    ``worlds`` maps the set's world names to loaded worlds (for overlaps and A*)."""
    if trajs.count == 0:
        raise TopodrakeError("no expert trajectories to draw controller pairs from")
    rng = np.random.default_rng(int(seed))
    for _ in range(cfg.tries):
        t = int(rng.integers(trajs.count))
        poses = trajs.poses[trajs.rows(t)]
        s = _arclength(poses)
        i = int(rng.integers(len(poses)))
        d = rng.uniform(cfg.min_distance_m, cfg.max_distance_m)
        if not s[0] <= s[i] + d <= s[-1]:
            continue
        j = int(np.argmin(np.abs(s - (s[i] + d))))
        if j == i:
            continue
        world = worlds[trajs.worlds[int(trajs.traj_world[t])]]
        ov = mutual_overlap(world, poses[i][None], poses[j][None])[0]
        if ov.min() <= cfg.min_overlap:
            continue
        try:
            path = world.astar(poses[i], poses[j, :2])
            length = float(np.hypot(*np.diff(path, axis=0).T).sum()) if len(path) > 1 else 0.0
        except TopodrakeError:
            # The expert may pass a wall closer than the c-space radius, so a
            # trajectory pose can lie outside the planner's free space.
            length = abs(float(s[j] - s[i]))
        # A whole number of 0.1 s control periods, so the Drake run and the
        # batched engine stop after the same step.
        t_max = math.ceil(10.0 * (cfg.t_base_s + length / cfg.v_min) - 1e-9) / 10.0
        return ControllerPair(world.name, t, i, j, float(s[j] - s[i]), t_max)
    raise TopodrakeError(f"no controller pair found for seed {seed} in {cfg.tries} tries "
                         "(trajectories too short?)")
