"""A seeded Monte Carlo study of a Drake diagram on a local process pool.

    python docs/tutorials/monte_carlo.py        # about 10 s on 2 CPU cores

The A* expert drives from place 0 to place 5 of ``test-0`` under two levels
of actuation noise, 10 trials each. A trial is a function of its seed
(``topodrake.systems.trials.expert_trial``): each worker builds the diagram
once and resets its Context per trial, so the same seeds give the same
trials with any number of workers, or on a Ray cluster
(``ray_address="auto"``). Prints one JSON object: per noise level the
success rate with its 95 % Wilson interval, the outcomes and the arrival
times; and whether three of the trials, run again in this process alone,
came out the same.
"""

import json

from topodrake.experiments.success_table import wilson
from topodrake.montecarlo import run_trials, trial_seeds
from topodrake.systems.trials import expert_trial

TRIALS = 10
SETTINGS = dict(world="test-0", start_place=0, goal_place=5)

runs, study = {}, {}
for noise_std in (0.33, 1.0):
    runs[noise_std] = run_trials(expert_trial, trial_seeds(7, TRIALS), workers=2,
                                 progress=False, noise_std=noise_std, **SETTINGS)
    reached = sum(r["outcome"] == "reached" for r in runs[noise_std])
    lo, hi = wilson(reached, TRIALS)
    study[str(noise_std)] = {"success": round(reached / TRIALS, 3),
                             "ci95": [round(lo, 3), round(hi, 3)],
                             "outcomes": [r["outcome"] for r in runs[noise_std]],
                             "time_s": [round(r["time_s"], 1) for r in runs[noise_std]]}

again = run_trials(expert_trial, trial_seeds(7, 3), workers=1, progress=False,
                   noise_std=0.33, **SETTINGS)
print(json.dumps({**SETTINGS, "trials": TRIALS, "noise": study,
                  "reproduced": again == runs[0.33][:3]}))
