"""The local controllers' success table (the paper's Table I): blocks of seeded trials.

Each (controller, noise) block runs ``topodrake.systems.trials.controller_trial``
on the same trial seeds and is kept in ``OUT/controller_success_runs/`` with
the settings and the checkpoint's hash that made it (:func:`run_block`), so a
rerun reuses finished blocks; :func:`summarize` gives a block's success rate
with its Wilson 95 % interval (:func:`wilson`); :func:`success_table` runs
every block of a study's options and assembles its summary and details.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

from topodrake.errors import TopodrakeError
from topodrake.experiments.scenarios import option
from topodrake.fileio import atomic_write_json
from topodrake.montecarlo import run_trials, trial_seeds
from topodrake.systems.trials import controller_trial
from topodrake.validate import check_count, check_nonnegative, check_seed

CONTROLLERS = ("camera_k0", "camera_k2", "camera_k5", "lidar_k5", "lidar_reg", "direct_k0")
#: Controllers without a checkpoint folder: name -> what the trials run.
BUILT_IN = {"oracle": "oracle", "lidar_reg": "registration"}
#: Table I of the paper (clean actuation; no lidar row there).
PAPER = {"direct_k0": 0.46, "camera_k0": 0.88, "camera_k2": 0.91, "camera_k5": 0.95}


@dataclass
class SuccessTableStudy:
    """The success table's settings: trials per controller and noise
    setting, the controllers (checkpoint folder names under
    ``checkpoints``, or :data:`BUILT_IN` ones), the base seed, the
    demonstration cache, the actuation noise of the noisy blocks, and the
    local workers (None: all cores) or Ray cluster the trials run on."""

    trials: int = option(400, "trials per controller and noise setting")
    controllers: list[str] = option(list(CONTROLLERS), "comma-separated checkpoint folder names "
                                    "under --checkpoints ('oracle' = the A* oracle, 'lidar_reg' "
                                    "= the registration C_WP)")
    checkpoints: str = option("checkpoints", "folder of the checkpoints")
    seed: int = option(0, "base seed of the trial seeds")
    data: str = option("data", "cache of the test houses' demonstrations")
    noise: float = option(0.33, "actuation noise std of the noisy runs")
    workers: int | None = option(None, "local worker processes (default: all cores)")
    ray: str | None = option(None, "run the trials on a Ray cluster")

    def validate(self) -> "SuccessTableStudy":
        """Check every field; a bad one raises a one-line TopodrakeError."""
        check_count("controller-success scenario: trials", self.trials)
        check_seed("controller-success scenario: seed", self.seed)
        check_nonnegative("controller-success scenario: noise", self.noise)
        if self.workers is not None:
            check_count("controller-success scenario: workers", self.workers)
        return self


def wilson(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval of a success rate."""
    if n == 0:
        return (0.0, 1.0)
    p = successes / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (max(0.0, centre - half), min(1.0, centre + half))


def summarize(results: list[dict]) -> dict:
    n = len(results)
    counts = {o: sum(r["outcome"] == o for r in results) for o in ("success", "collision", "timeout")}
    plural = {"success": "successes", "collision": "collisions", "timeout": "timeouts"}
    lo, hi = wilson(counts["success"], n)
    # Pairs already solved at the first control step (target within
    # tolerance or overlapping the source view): part of the protocol,
    # reported so the rate can be read without them.
    immediate = sum(r["outcome"] == "success" and r["time_s"] <= 0.1 + 1e-9 for r in results)
    return {"success": counts["success"] / n, "ci95": [round(lo, 3), round(hi, 3)],
            **{plural[o]: c for o, c in counts.items()}, "trials": n,
            "immediate_successes": immediate,
            "success_nontrivial": (counts["success"] - immediate) / max(n - immediate, 1)}


def _fingerprint(checkpoint: str) -> str:
    if checkpoint == "oracle":
        return "oracle"
    if checkpoint == "registration":
        from topodrake.learning.reachability.controllers import registration_runs_key

        return registration_runs_key()
    return hashlib.sha1(Path(checkpoint).read_bytes()).hexdigest()[:16]


def run_block(name: str, cond: str, checkpoint: str, noise: float, seeds: list[int], *,
              seed: int, data: str, runs_dir, workers: int | None = None, ray: str | None = None,
              quiet: bool = True) -> list:
    """The trials of one controller and noise setting (``seeds`` drawn from
    the base ``seed``; demonstrations in ``data``), reused from the run cache
    in ``runs_dir`` when the seeds, noise and checkpoint are the same."""
    key = {"controller": name, "condition": cond, "noise_std": noise, "seed": seed,
           "trials": len(seeds), "checkpoint": _fingerprint(checkpoint), "data": str(data)}
    cache = Path(runs_dir) / f"{name}-{cond}.json"
    if cache.is_file():
        try:
            stored = json.loads(cache.read_text())
            if stored.get("key") == key:
                return stored["results"]
        except (OSError, ValueError):
            pass                                   # unreadable: run again
    results = run_trials(controller_trial, seeds, workers=workers, ray_address=ray,
                         progress=not quiet, desc=f"{name} {cond}", checkpoint=checkpoint,
                         noise_std=noise, data_dir=data)
    atomic_write_json(cache, {"key": key, "results": results})
    return results


def controller_checkpoints(names: list[str], folder) -> dict:
    """name -> what its trials run: a built-in controller's kind, or
    ``FOLDER/<name>/checkpoint.pt``, which must exist."""
    checkpoints = {}
    for name in names:
        if name in BUILT_IN:
            checkpoints[name] = BUILT_IN[name]
            continue
        path = Path(folder) / name / "checkpoint.pt"
        if not path.is_file():
            raise TopodrakeError(f"no checkpoint {path}; train it first (see README, 'Checkpoints')")
        checkpoints[name] = str(path)
    return checkpoints


def success_table(study: SuccessTableStudy, command: str, out="results",
                  quiet: bool = False) -> tuple[dict, dict]:
    """(summary ``{name: {"clean": p, "noisy": p}}``, details document) of
    ``study``; blocks are cached in ``OUT/controller_success_runs/``;
    ``command`` is recorded; ``quiet``: no progress bars."""
    if study.trials < 1:
        raise TopodrakeError("--trials must be >= 1")
    names = [n.strip() for n in study.controllers if n.strip()]
    checkpoints = controller_checkpoints(names, study.checkpoints)
    seeds = trial_seeds(study.seed, study.trials)
    summary, details = {}, {}
    t0 = time.perf_counter()
    for name in names:
        summary[name], details[name] = {}, {}
        for cond, noise in (("clean", 0.0), ("noisy", study.noise)):
            results = run_block(name, cond, checkpoints[name], noise, seeds, seed=study.seed,
                                data=study.data, runs_dir=Path(out) / "controller_success_runs",
                                workers=study.workers, ray=study.ray, quiet=quiet)
            s = summarize(results)
            summary[name][cond] = round(s["success"], 4)
            details[name][cond] = s
    return summary, {
        "command": command, "trials": study.trials, "seed": study.seed, "noise_std": study.noise,
        "checkpoints": checkpoints, "wall_time_s": round(time.perf_counter() - t0, 1),
        "paper": PAPER, "results": details}
