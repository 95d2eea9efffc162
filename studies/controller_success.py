"""The paper's Table I: success rate of each local controller, in Drake.

For every controller (C_WP camera k=0/2/5, lidar k=5, the registration
C_WP ``lidar_reg`` (lidar teach and repeat, no network), the direct-control
baseline; optionally the A* oracle as a protocol check) and for clean and
noisy actuation, run ``--trials`` seeded Monte Carlo trials of the C_WP + RMP
diagram (``topodrake.systems.trials.controller_trial``): source on a
test-house expert trajectory, target 1 m behind to 3 m ahead, success =
within 0.27 m of the target or both image overlaps > 0.7 within the time
limit, collision = failure. The pairs depend only on the trial seeds, so all
controllers and both noise settings are scored on the same pairs.

    python studies/controller_success.py --trials 400 --json

prints ``{"camera_k0": {"clean": p, "noisy": p}, ...}`` and writes
``results/controller_success.json`` (the same object),
``results/controller_success_details.json`` (outcome counts, Wilson 95 %
intervals, the command) and ``results/controller_success.png``.

Each (controller, noise) block of trials is kept in
``results/controller_success_runs/`` with the checkpoint's hash; a rerun with
the same settings reuses finished blocks, so the study can be run as the
checkpoints arrive (``--controllers camera_k2``) and resumed after a stop.
"""

from __future__ import annotations

import hashlib
import json
import math
import sys
import time
from pathlib import Path

from topodrake import argtypes as at
from topodrake.errors import TopodrakeError
from topodrake.fileio import atomic_write_json
from topodrake.montecarlo import add_study_arguments, study_main

CONTROLLERS = ("camera_k0", "camera_k2", "camera_k5", "lidar_k5", "lidar_reg", "direct_k0")
#: Controllers without a checkpoint folder: name -> what the trials run.
BUILT_IN = {"oracle": "oracle", "lidar_reg": "registration"}
#: Table I of the paper (clean actuation; no lidar row there).
PAPER = {"direct_k0": 0.46, "camera_k0": 0.88, "camera_k2": 0.91, "camera_k5": 0.95}


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


def run_block(name: str, cond: str, checkpoint: str, noise: float, seeds: list[int], args) -> list:
    """The trials of one controller and noise setting, reused from the run
    cache when the seeds, noise and checkpoint are the same."""
    from topodrake.montecarlo import run_trials
    from topodrake.systems.trials import controller_trial

    key = {"controller": name, "condition": cond, "noise_std": noise, "seed": args.seed,
           "trials": len(seeds), "checkpoint": _fingerprint(checkpoint), "data": str(args.data)}
    cache = Path(args.out) / "controller_success_runs" / f"{name}-{cond}.json"
    if cache.is_file():
        try:
            stored = json.loads(cache.read_text())
            if stored.get("key") == key:
                return stored["results"]
        except (OSError, ValueError):
            pass                                   # unreadable: run again
    results = run_trials(controller_trial, seeds, workers=args.workers, ray_address=args.ray,
                         progress=not args.quiet, desc=f"{name} {cond}", checkpoint=checkpoint,
                         noise_std=noise, data_dir=args.data)
    atomic_write_json(cache, {"key": key, "results": results})
    return results


def plot(summary: dict, details: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from topodrake.world.plot import save_figure

    names = list(summary)
    x = np.arange(len(names))
    fig, ax = plt.subplots(figsize=(7.5, 3.6), dpi=120)
    for off, cond, colour in ((-0.2, "clean", "#3b75af"), (0.2, "noisy", "#ef8636")):
        vals = [summary[n][cond] for n in names]
        ci = np.array([details[n][cond]["ci95"] for n in names]).T
        ax.bar(x + off, vals, 0.38, color=colour, label=f"{cond} actuation")
        ax.errorbar(x + off, vals, yerr=[np.array(vals) - ci[0], ci[1] - np.array(vals)],
                    fmt="none", ecolor="k", capsize=3, lw=0.8)
    for i, n in enumerate(names):
        if n in PAPER:
            ax.plot([i - 0.4, i + 0.4], [PAPER[n]] * 2, "k--", lw=1,
                    label="paper (Table I)" if i == 0 else None)
    ax.set_xticks(x, [n.replace("_", " ") for n in names])
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("success rate")
    ax.set_title(f"Local controller success, {details[names[0]]['clean']['trials']} trials each")
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)


def main(argv=None) -> int:
    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    ap.add_argument("--trials", type=at.count, default=400, help="trials per controller and noise setting")
    ap.add_argument("--controllers", default=",".join(CONTROLLERS),
                    help="comma-separated checkpoint folder names under --checkpoints "
                         "('oracle' = the A* oracle, 'lidar_reg' = the registration C_WP)")
    ap.add_argument("--checkpoints", default="checkpoints", help="folder of the checkpoints")
    add_study_arguments(ap, "cache of the test houses' demonstrations")
    return study_main(_run, ap.parse_args(argv))


def _run(args) -> int:
    from topodrake.montecarlo import trial_seeds

    if args.trials < 1:
        raise TopodrakeError("--trials must be >= 1")
    names = [n.strip() for n in args.controllers.split(",") if n.strip()]
    checkpoints = {}
    for name in names:
        if name in BUILT_IN:
            checkpoints[name] = BUILT_IN[name]
            continue
        path = Path(args.checkpoints) / name / "checkpoint.pt"
        if not path.is_file():
            raise TopodrakeError(f"no checkpoint {path}; train it first (see README, 'Checkpoints')")
        checkpoints[name] = str(path)
    seeds = trial_seeds(args.seed, args.trials)
    summary, details = {}, {}
    t0 = time.perf_counter()
    for name in names:
        summary[name], details[name] = {}, {}
        for cond, noise in (("clean", 0.0), ("noisy", args.noise)):
            results = run_block(name, cond, checkpoints[name], noise, seeds, args)
            s = summarize(results)
            summary[name][cond] = round(s["success"], 4)
            details[name][cond] = s
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "controller_success.json", summary)
    atomic_write_json(out / "controller_success_details.json", {
        "command": "python studies/controller_success.py " + " ".join(sys.argv[1:]),
        "trials": args.trials, "seed": args.seed, "noise_std": args.noise,
        "checkpoints": checkpoints, "wall_time_s": round(time.perf_counter() - t0, 1),
        "paper": PAPER, "results": details})
    plot(summary, details, out / "controller_success.png")
    if args.json:
        print(json.dumps(summary))
    else:
        for name in names:
            c, n = details[name]["clean"], details[name]["noisy"]
            print(f"{name:<10} clean {c['success']:.3f} {c['ci95']}  noisy {n['success']:.3f} "
                  f"{n['ci95']}  (collisions {c['collisions']}/{n['collisions']})")
        print(f"wrote {out / 'controller_success.json'} and {out / 'controller_success.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
