"""Seeded Monte Carlo trials on a local process pool or a Ray cluster.

A trial is a picklable function ``trial(seed, **kwargs) -> dict``; each trial
builds whatever it needs (a Drake diagram, a world) itself, so workers share
nothing. Seeds are derived from one base seed, so a study is reproduced by
its base seed alone, whatever the number of workers or their order.
"""

from __future__ import annotations

import multiprocessing as mp
import os
from typing import Callable

import numpy as np


def trial_seeds(base_seed: int, n: int) -> list[int]:
    """``n`` independent 32-bit seeds derived from ``base_seed``."""
    seq = np.random.SeedSequence(base_seed)
    return [int(s.generate_state(1)[0]) for s in seq.spawn(n)]


def _call(job):
    fn, seed, kwargs = job
    return fn(seed, **kwargs)


def run_trials(trial: Callable[..., dict], seeds: list[int], *, workers: int | None = None,
               ray_address: str | None = None, progress: bool = True,
               desc: str = "trials", **kwargs) -> list[dict]:
    """Run ``trial(seed, **kwargs)`` for every seed; results in seed order.

    ``workers`` defaults to the machine's cores (1 runs in this process).
    Workers are forked: run trials before this process starts torch's
    OpenMP threads (running a network here first can hang the children).
    With ``ray_address`` (``"auto"``, ``"local"`` or ``"ray://host:port"``)
    the trials run as Ray tasks instead.
    """
    from tqdm import tqdm

    if ray_address is not None:
        return _run_ray(trial, seeds, ray_address, progress, desc, kwargs)
    workers = workers or os.cpu_count() or 1
    jobs = [(trial, s, kwargs) for s in seeds]
    bar = tqdm(total=len(jobs), desc=desc, disable=not progress, unit="trial")
    results = []
    if workers == 1 or len(jobs) <= 1:
        for job in jobs:
            results.append(_call(job))
            bar.update()
    else:
        ctx = mp.get_context("fork")
        with ctx.Pool(workers) as pool:
            for r in pool.imap(_call, jobs, chunksize=max(1, len(jobs) // (8 * workers))):
                results.append(r)
                bar.update()
    bar.close()
    return results


def _run_ray(trial, seeds, address, progress, desc, kwargs):
    try:
        import ray
    except ImportError as e:  # pragma: no cover - depends on the extra
        from topodrake.errors import TopodrakeError
        raise TopodrakeError("--ray needs the 'ray' extra: pip install 'topodrake[ray]'") from e
    from tqdm import tqdm

    started_here = False
    if not ray.is_initialized():
        if address == "local":
            ray.init(num_cpus=os.cpu_count(), include_dashboard=False, log_to_driver=False)
        else:
            ray.init(address=address, log_to_driver=False)
        started_here = True
    try:
        remote = ray.remote(_call)
        refs = [remote.remote((trial, s, kwargs)) for s in seeds]
        index = {r: i for i, r in enumerate(refs)}
        results: list = [None] * len(refs)
        pending = list(refs)
        with tqdm(total=len(refs), desc=desc, disable=not progress, unit="trial") as bar:
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                for r in done:
                    results[index[r]] = ray.get(r)
                    bar.update()
        return results
    finally:
        if started_here:
            ray.shutdown()


def paired_difference(before, after, strata=None, seed: int = 0, resamples: int = 2000) -> dict:
    """Mean of ``after - before`` over paired trials, with a bootstrap 95 %
    interval that resamples trials within each stratum (a house: ``strata``
    (N,) labels; default one stratum)."""
    diff = np.asarray(after, np.float64) - np.asarray(before, np.float64)
    if diff.ndim != 1 or len(diff) == 0:
        raise ValueError("paired_difference needs two equal, non-empty 1-D series")
    labels = np.zeros(len(diff), np.int64) if strata is None else np.asarray(strata)
    groups = [diff[labels == g] for g in np.unique(labels)]
    rng = np.random.default_rng(seed)
    means = np.zeros(resamples)
    for g in groups:
        means += g[rng.integers(0, len(g), (resamples, len(g)))].sum(axis=1)
    means /= len(diff)
    return {"mean": round(float(diff.mean()), 4), "ci95": [round(float(np.percentile(means, 2.5)), 4),
                                                          round(float(np.percentile(means, 97.5)), 4)],
            "pairs": int(len(diff))}
