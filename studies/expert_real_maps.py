"""The A* expert on real SLAM maps: all ordered pairs of their 10 places.

    python studies/expert_real_maps.py [--noise 0.33] [--seed 0] [--json]

Prints, per map, how many of the 90 drives reached the goal, collided or
timed out, and writes results/expert_real_maps.json.
"""

import json
import sys
import time
from pathlib import Path

import numpy as np

from topodrake.apps import argtypes as at
from topodrake.demonstrations import CollectConfig, plan_jobs
from topodrake.fileio import atomic_write_json
from topodrake.montecarlo import trial_seeds
from topodrake.rollout import ExpertRollout, RolloutConfig
from topodrake.world import load_world

MAPS = Path(__file__).resolve().parent.parent / "tests" / "data" / "maps"


def main() -> None:
    p = at.Parser(description=at.plain(__doc__.splitlines()[0]))
    p.add_argument("--noise", type=at.nonnegative, default=0.33, help="actuation noise std")
    p.add_argument("--seed", type=at.seed, default=0, help="base seed of the drives' noise")
    p.add_argument("--t-max", type=at.positive, default=400.0, help="seconds per drive")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    args = p.parse_args()
    out = {"command": " ".join(sys.argv), "noise_std": args.noise, "seed": args.seed}
    for yaml in sorted(MAPS.glob("*/map.yaml")):
        world = load_world(str(yaml))
        starts, goals = plan_jobs(world, CollectConfig(protocol="pairs"))
        t0 = time.perf_counter()
        res = ExpertRollout(world, RolloutConfig(noise_std=args.noise, t_max_s=args.t_max)).run(
            starts, goals, seeds=trial_seeds(args.seed, len(starts)))
        success, collision, timeout = np.bincount(res.outcome, minlength=3)[:3].tolist()
        out[world.name] = {"drives": len(starts), "success": success, "collision": collision,
                           "timeout": timeout, "wall_s": round(time.perf_counter() - t0, 1)}
    atomic_write_json(Path("results") / "expert_real_maps.json", out)
    print(json.dumps(out) if args.json else json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
