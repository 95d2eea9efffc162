"""Is RE calibrated (the reachability-calibration study)? Its probability against closed-loop outcomes.

:func:`calibration_trials` runs, for every RE of a study's options and for
clean and noisy actuation, seeded Drake trials
(``topodrake.systems.trials.reach_trial``), summarises them
(:func:`summarise_trials`: ECE, Brier, AUROC split by how pairs start,
reliability bins), adds RE's keep ratio on the test houses' drives
(:func:`keep_ratios`) and assembles the result document.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from topodrake.errors import TopodrakeError
from topodrake.experiments.hops import sparsify_houses
from topodrake.experiments.scenarios import option
from topodrake.learning.reachability.calibration import calibration_summary, reliability
from topodrake.learning.reachability.labels import ReachLabelConfig
from topodrake.learning.samples import collect_trajectories
from topodrake.montecarlo import run_trials, trial_seeds
from topodrake.systems.trials import reach_trial
from topodrake.validate import check_count, check_nonnegative, check_probability, check_seed

WORLDS = ("test-0", "test-1", "test-2", "test-3", "test-4")
#: the REs the study calibrates by default (name=RE.pt:CWP.pt, comma-separated)
DEFAULT_ESTIMATORS = (
    "camera_k5=checkpoints/reach_camera_k5/checkpoint.pt:checkpoints/camera_k5/checkpoint.pt,"
    "lidar_k5=checkpoints/reach_lidar_k5/checkpoint.pt:checkpoints/lidar_k5/checkpoint.pt")


@dataclass
class CalibrationStudy:
    """The reachability-calibration study's settings: labelled pairs per RE,
    the REs (``name=RE.pt:CWP.pt``, comma-separated), p_sparsify of the keep
    ratio and the drives per house it reads (None: all), the base seed, the
    demonstration cache, the actuation noise of the noisy runs, and the
    local workers (None: all cores) or Ray cluster the trials run on."""

    pairs: int = option(1000, "labelled pairs per estimator")
    estimators: str = option(DEFAULT_ESTIMATORS, "name=RE.pt:CWP.pt, comma-separated")
    p: float = option(0.99, "p_sparsify for keep_ratio")
    keep_drives: int | None = option(None, "drives per house for keep_ratio (default all)")
    seed: int = option(0, "base seed of the trial seeds")
    data: str = option("data", "cache of demonstrations (test houses)")
    noise: float = option(0.33, "actuation noise std of the noisy runs")
    workers: int | None = option(None, "local worker processes (default: all cores)")
    ray: str | None = option(None, "run the trials on a Ray cluster")

    def validate(self) -> "CalibrationStudy":
        """Check the numbers; a bad one raises a one-line TopodrakeError."""
        where = "reachability-calibration scenario"
        check_count(f"{where}: pairs", self.pairs)
        check_probability(f"{where}: p", self.p)
        for name in ("keep_drives", "workers"):
            if getattr(self, name) is not None:
                check_count(f"{where}: {name}", getattr(self, name))
        check_seed(f"{where}: seed", self.seed)
        check_nonnegative(f"{where}: noise", self.noise)
        return self


def keep_ratios(reach: str, controller: str, data_dir: str, p: float,
                drives: int | None) -> tuple[float, float]:
    """Anchors kept / frames over the test houses' successful expert drives,
    with RE's anchor-hop calibration and with its temperature (as for any
    other pair), from one pass over the drives."""
    from topodrake.learning.reachability.estimator import Reachability

    re = Reachability.from_checkpoint(reach, controller)
    out = sparsify_houses(re, list(WORLDS), Path(data_dir) / "demos" / "pairs-s0", p,
                          drives=drives,
                          other_calibrations={"temperature": (1.0 / re.temperature, 0.0)})
    return out["keep_ratio"] or 0.0, out["keep_ratios"]["temperature"] or 0.0


def summarise_trials(res: list[dict]) -> dict:
    """ECE, Brier, AUROC and reliability bins of trial records (``p``,
    ``success``, ``start_overlap``), and AUROC split by the pairs' start.

    Pairs that see nothing of each other at the start fail at once (both
    overlaps < 0.05): ``auroc_reached_vs_not_overlapping`` says how well RE
    tells the reached pairs from those, ``auroc_overlapping`` how well it
    ranks the pairs that are actually driven."""
    p = np.array([r["p"] for r in res], float)
    y = np.array([r["success"] for r in res], int)
    seeing = np.array([max(r["start_overlap"]) >= ReachLabelConfig().overlap_lost for r in res])

    def auroc_of(sel):
        return calibration_summary(p[sel], y[sel])["auroc"] if sel.any() else None

    s = calibration_summary(p, y)
    s["share_not_overlapping"] = float(1 - seeing.mean())
    s["auroc_overlapping"] = auroc_of(seeing)
    s["auroc_reached_vs_not_overlapping"] = auroc_of(~seeing | (y == 1))
    rel = reliability(p, y)
    s["reliability"] = {"edges": rel.edges.tolist(), "count": rel.count.tolist(),
                        "rate": [None if np.isnan(v) else float(v) for v in rel.rate],
                        "mean_pred": [None if np.isnan(v) else float(v) for v in rel.mean_pred]}
    return s


def calibration_trials(study: CalibrationStudy, command: str, quiet: bool = False) -> dict:
    """The study's result document for ``study``; ``command`` is recorded;
    ``quiet``: no progress bars."""
    from topodrake.learning.reachability.estimator import parse_estimators

    if study.pairs < 1:
        raise TopodrakeError("--pairs must be >= 1")
    estimators = parse_estimators(study.estimators)
    # make sure the test houses' demonstrations exist before the workers start
    collect_trajectories(list(WORLDS), Path(study.data) / "demos" / "pairs-s0",
                         progress=not quiet)
    seeds = trial_seeds(study.seed, study.pairs)
    summary, details = {}, {}
    t0 = time.perf_counter()
    for name, (reach, controller) in estimators.items():
        details[name] = {}
        for cond, noise in (("clean", 0.0), ("noisy", study.noise)):
            res = run_trials(reach_trial, seeds, workers=study.workers, ray_address=study.ray,
                             progress=not quiet, desc=f"{name} {cond}", reach=reach,
                             controller=controller, noise_std=noise, data_dir=study.data,
                             worlds=WORLDS)
            details[name][cond] = summarise_trials(res)
    # The keep ratios run RE in this process, so they come after every
    # forked Monte Carlo block (a fork after torch has started its OpenMP
    # threads can hang the children).
    for name, (reach, controller) in estimators.items():
        ratio, under_t = keep_ratios(reach, controller, study.data, study.p, study.keep_drives)
        details[name]["keep_ratio_temperature"] = round(under_t, 4)
        n = details[name]["noisy"]
        summary[name] = {"ece": round(n["ece"], 4), "brier": round(n["brier"], 4),
                         "auroc": None if n["auroc"] is None else round(n["auroc"], 4),
                         "keep_ratio": round(ratio, 4)}
    return {
        "command": command,
        "pairs": study.pairs, "seed": study.seed, "noise_std": study.noise, "p_sparsify": study.p,
        "estimators": {k: {"reach": r, "controller": c} for k, (r, c) in estimators.items()},
        "wall_time_s": round(time.perf_counter() - t0, 1), "summary": summary, "details": details}
