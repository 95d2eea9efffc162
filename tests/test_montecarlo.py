"""Seeded trials: same results whatever the executor."""

import numpy as np
import pytest

from topodrake.montecarlo import run_trials, trial_seeds


def noisy_sum(seed, scale=1.0):
    return {"seed": seed, "value": float(scale * np.random.default_rng(seed).standard_normal(10).sum())}


def test_trial_seeds_are_reproducible_and_distinct():
    a = trial_seeds(7, 50)
    assert a == trial_seeds(7, 50) and len(set(a)) == 50
    assert a[:10] == trial_seeds(7, 10)      # prefix-stable: more trials keep the first ones
    assert a != trial_seeds(8, 50)


def test_process_pool_matches_serial():
    seeds = trial_seeds(0, 24)
    serial = run_trials(noisy_sum, seeds, workers=1, progress=False, scale=2.0)
    pooled = run_trials(noisy_sum, seeds, workers=2, progress=False, scale=2.0)
    assert serial == pooled
    assert [r["seed"] for r in pooled] == seeds


def test_drake_trials_in_a_pool():
    from topodrake.systems.trials import expert_trial

    seeds = trial_seeds(1, 2)
    pooled = run_trials(expert_trial, seeds, workers=2, progress=False,
                        world="test-0", start_place=0, goal_place=5, noise_std=0.33)
    serial = run_trials(expert_trial, seeds, workers=1, progress=False,
                        world="test-0", start_place=0, goal_place=5, noise_std=0.33)
    assert pooled == serial
    assert all(r["outcome"] == "reached" for r in pooled)       # the CLI's vocabulary


def test_ray_local_cluster_matches_local():
    pytest.importorskip("ray")
    from topodrake.systems.trials import expert_trial

    # Ray workers import trials from the installed package, not from tests/.
    seeds = trial_seeds(3, 2)
    kwargs = dict(world="test-0", start_place=2, goal_place=8, noise_std=0.33)
    local = run_trials(expert_trial, seeds, workers=1, progress=False, **kwargs)
    on_ray = run_trials(expert_trial, seeds, ray_address="local", progress=False, **kwargs)
    assert on_ray == local
